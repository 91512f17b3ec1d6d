//! `stylet sim`: the desktop simulator. Its window is being built (issue 17); what runs today is
//! the simulator's haptic loop, headless, driven by a device script, recording the session as the
//! window will (docs/simulator.md).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use stylet_app::haptic::{Ended, HapticLoop, LoopOptions};
use stylet_recorder::{Recording, SessionInfo, WriterOptions};

use super::script::{Difficulty, script_simulation};

#[derive(Debug, Args)]
pub struct SimArgs {
    /// Atlas directory (the patient).
    #[arg(long)]
    pub atlas: PathBuf,
    /// Run without a window: the haptic loop driven by the device script given with --script.
    #[arg(long, requires = "script")]
    pub headless: bool,
    /// Device script (docs/scripts.md) for --headless.
    #[arg(long)]
    pub script: Option<PathBuf>,
    /// Record the session to this file (docs/session-format.md).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Trainee for the session header: their account username on the scoring service.
    #[arg(long, default_value = "demo-trainee")]
    pub trainee: String,
    /// Difficulty level the session is graded at.
    #[arg(long, value_enum, default_value_t = Difficulty::Beginner)]
    pub difficulty: Difficulty,
    /// Scenario name for the session header (default: the script's file name without extension).
    #[arg(long)]
    pub scenario: Option<String>,
    /// Seed of the session's random generators, recorded in the header.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Tick as fast as the CPU allows instead of at the simulation's rate (same session file).
    #[arg(long)]
    pub unpaced: bool,
}

pub fn run(a: SimArgs) -> anyhow::Result<()> {
    let Some(script) = a.script.as_ref().filter(|_| a.headless) else {
        anyhow::bail!(
            "the simulator's window is not built yet (issue 17); `stylet sim --headless --script FILE --atlas DIR` runs its haptic loop driven by a device script"
        );
    };
    let atlas = stylet_atlas::load(&a.atlas)?;
    let (sim, device) = script_simulation(&atlas, script)?;
    let paced = !a.unpaced;
    let recording = match &a.out {
        Some(path) => {
            let stem = script
                .file_stem()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            let info = SessionInfo {
                trainee: &a.trainee,
                scenario: a.scenario.as_deref().unwrap_or(&stem),
                difficulty: a.difficulty.name(),
                seed: a.seed,
                atlas_id: &atlas.manifest.name,
                atlas_hash: &atlas.content_hash,
            };
            let header = stylet_recorder::recording::header(&sim, &info);
            // Real time: the recorder must never block the loop (a full queue marks the session
            // incomplete); unpaced: it may wait, nothing is lost.
            Some(
                Recording::start(path, &header, paced, WriterOptions::default())
                    .with_context(|| format!("cannot record to {}", path.display()))?,
            )
        }
        None => None,
    };
    let rate_hz = sim.tick_rate_hz();
    let haptic = HapticLoop::spawn(
        sim,
        Box::new(device),
        recording,
        LoopOptions {
            paced,
            ..LoopOptions::default()
        },
    )?;
    let report = haptic.join()?;
    let s = report.stats;
    let wall_s = report.wall.as_secs_f64();
    super::say(&format!(
        "haptic loop {}: {} ticks = {:.3} s simulated in {:.3} s ({:.1} ticks/s), {} missed their deadline (worst {:.2} ms late), {} periods skipped",
        if paced { "paced" } else { "unpaced" },
        s.ticks,
        s.ticks as f64 / f64::from(rate_hz),
        wall_s,
        s.ticks as f64 / wall_s.max(1e-9),
        s.missed,
        s.worst_late.as_secs_f64() * 1e3,
        s.skipped_periods
    ));
    if report.ended == Ended::Stopped {
        super::say("stopped before the script's end");
    }
    if let (Some(result), Some(path)) = (report.recording, &a.out) {
        let summary = result.context("recording the session")?;
        let complete = if summary.complete {
            "complete".to_string()
        } else {
            format!("INCOMPLETE: {} items dropped (queue full)", summary.dropped)
        };
        super::say(&format!(
            "session recorded to {}: {} ticks, {:.1} KiB, {complete}",
            path.display(),
            summary.ticks,
            summary.bytes as f64 / 1024.0
        ));
    }
    Ok(())
}
