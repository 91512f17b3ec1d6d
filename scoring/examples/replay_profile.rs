//! Replays one session file for profiling: `replay_profile ATLAS_DIR SESSION [RUNS]`.
use std::sync::Arc;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let atlas = stylet_atlas::load(std::path::Path::new(&args[1])).unwrap();
    let session = stylet_recorder::reader::read(std::path::Path::new(&args[2])).unwrap();
    let runs: usize = args.get(3).map_or(1, |r| r.parse().unwrap());
    let model = Arc::new(atlas.model.clone());
    let t = std::time::Instant::now();
    for _ in 0..runs {
        let r = stylet_scoring::replay(&session, model.clone(), &mut |_, _, _| {}).unwrap();
        if !r.replay_verified {
            eprintln!("not verified: {:?}", r.divergence);
        }
    }
    let s = t.elapsed().as_secs_f64() / runs as f64;
    println!(
        "{:.1} ms per replay = {:.0}× real time",
        s * 1e3,
        session.ticks.len() as f64 / 1000.0 / s
    );
}
