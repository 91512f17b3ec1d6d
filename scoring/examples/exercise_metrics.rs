//! Prints the exercise metrics of session files (a tuning aid for docs/metrics.md "Exercises"):
//! `cargo run -p stylet-scoring --example exercise_metrics -- ATLAS_DIR FILES…`.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let atlas = stylet_atlas::load(std::path::Path::new(&args.next().ok_or("usage: ATLAS_DIR FILES…")?))?;
    let scorer = stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None)?;
    for f in args {
        let r = scorer.score_file(std::path::Path::new(&f))?;
        println!(
            "{f}: {} {} score {} palpation {:?} ultrasound {:?} us_time {:.2}\n  reasons {:?}",
            r.exercise,
            r.outcome,
            r.grade.score,
            r.metrics.palpation,
            r.metrics.ultrasound,
            r.metrics.ultrasound_time_s,
            r.reasons
        );
    }
    Ok(())
}
