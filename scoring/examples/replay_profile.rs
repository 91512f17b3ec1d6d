//! Replays and scores one session file, for profiling: `replay_profile ATLAS_DIR SESSION [RUNS]`.
use std::sync::Arc;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let atlas = stylet_atlas::load(std::path::Path::new(&args[1])).unwrap();
    let session = stylet_recorder::reader::read(std::path::Path::new(&args[2])).unwrap();
    let runs: usize = args.get(3).map_or(1, |r| r.parse().unwrap());
    let model = Arc::clone(&atlas.model);
    let scorer = stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None).unwrap();
    let seconds = session.ticks.len() as f64 / 1000.0;
    let t = std::time::Instant::now();
    for _ in 0..runs {
        let r = stylet_scoring::replay(&session, model.clone(), &mut |_, _, _| {}).unwrap();
        if !r.replay_verified {
            eprintln!("not verified: {:?}", r.divergence);
        }
    }
    let s = t.elapsed().as_secs_f64() / runs as f64;
    println!("replay: {:.1} ms = {:.0}× real time", s * 1e3, seconds / s);
    let t = std::time::Instant::now();
    for _ in 0..runs {
        std::hint::black_box(scorer.score_session(&session).unwrap());
    }
    let s = t.elapsed().as_secs_f64() / runs as f64;
    println!("score: {:.1} ms = {:.0}× real time", s * 1e3, seconds / s);
}
