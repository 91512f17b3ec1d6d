//! The smoke test of a scenario (docs/atlas.md "Validation record"): its example scripts run
//! through the physics, are recorded to session files and scored by replay, the pipeline a
//! trainee's session takes. A success script must reach and confirm the target with no risk hit or
//! bone contact; a risk script must hit the structure it names first. `stylet atlas new` and
//! `stylet atlas validate` run it before they write the validation record, and the service runs it
//! again before it publishes an atlas.

use std::path::Path;
use std::sync::Arc;

use stylet_atlas::Atlas;
use stylet_atlas::validation::{Expect, SmokeEntry, VALIDATION_FORMAT_VERSION, ValidationRecord};
use stylet_devices::script::{parse, scripted_simulation};
use stylet_recorder::{Recording, SessionInfo, WriterOptions};

use crate::{Rubric, Scorer};

/// One example script and what it must do.
#[derive(Debug, Clone, PartialEq)]
pub struct SmokeScript {
    /// File name inside the atlas' `scripts/` folder; its stem is the session's scenario.
    pub file_name: String,
    pub text: String,
    pub expect: Expect,
}

/// What one script did.
#[derive(Debug, Clone, PartialEq)]
pub struct SmokeOutcome {
    pub script: String,
    pub expect: Expect,
    /// What the replayed, scored session did.
    pub got: String,
    pub passed: bool,
    pub seconds: f64,
}

impl SmokeOutcome {
    /// What went wrong, in one sentence, or `None` when the script passed.
    pub fn failure(&self) -> Option<String> {
        (!self.passed).then(|| {
            format!(
                "scripts/{} should: {}; got: {}",
                self.script,
                self.expect.describe(),
                self.got
            )
        })
    }
}

/// A script that could not be run, recorded or scored at all (a script that runs and does the
/// wrong thing is a failed [`SmokeOutcome`], not an error).
#[derive(Debug, thiserror::Error)]
pub enum SmokeError {
    #[error("the atlas cannot be scored: {0}")]
    Scorer(crate::score::ScorerError),
    #[error("scripts/{script}: {reason}")]
    Script { script: String, reason: String },
}

/// Runs every script on `atlas`, recording each session in `work_dir` (a folder the caller
/// removes), in order. Deterministic: the same atlas and scripts give the same outcomes.
pub fn run(atlas: &Atlas, scripts: &[SmokeScript], work_dir: &Path) -> Result<Vec<SmokeOutcome>, SmokeError> {
    let scorer = Scorer::new(atlas, Rubric::default_rubric(), None).map_err(SmokeError::Scorer)?;
    run_with(atlas, &scorer, scripts, work_dir)
}

/// [`run`] with a scorer of `atlas` the caller already has (the service keeps it).
pub fn run_with(
    atlas: &Atlas,
    scorer: &Scorer,
    scripts: &[SmokeScript],
    work_dir: &Path,
) -> Result<Vec<SmokeOutcome>, SmokeError> {
    scripts.iter().map(|s| run_one(atlas, scorer, s, work_dir)).collect()
}

fn run_one(atlas: &Atlas, scorer: &Scorer, s: &SmokeScript, work_dir: &Path) -> Result<SmokeOutcome, SmokeError> {
    let started = std::time::Instant::now();
    let fail = |reason: String| SmokeError::Script {
        script: s.file_name.clone(),
        reason,
    };
    let scenario = s.file_name.trim_end_matches(".txt");
    let session = work_dir.join(format!("smoke-{scenario}.mcap"));
    let script = parse(&s.text).map_err(|e| fail(e.to_string()))?;
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script)
        .map_err(|e| fail(e.to_string()))?;
    let info = SessionInfo {
        trainee: "smoke-test",
        scenario,
        difficulty: crate::Difficulty::Beginner.as_str(),
        seed: 0,
        atlas_id: &atlas.manifest.name,
        atlas_hash: &atlas.content_hash,
    };
    let header = stylet_recorder::recording::header(&sim, &info);
    let mut rec = Recording::start(&session, &header, false, WriterOptions::default())
        .map_err(|e| fail(format!("cannot record to {}: {e}", session.display())))?;
    stylet_devices::run_headless(&mut sim, &mut device, |i, o, s| rec.tick(i, o, s));
    rec.finish()
        .map_err(|e| fail(format!("recording {}: {e}", session.display())))?;
    let r = scorer.score_file(&session).map_err(|e| fail(format!("scoring: {e}")))?;
    let _ = std::fs::remove_file(&session);
    let m = &r.metrics;
    let hits: Vec<&str> = m.risk_hits.iter().map(|h| h.structure.as_str()).collect();
    let passed = r.replay_verified
        && match &s.expect {
            Expect::Success => m.target_reached && m.target_confirmed && hits.is_empty() && m.bone_contacts == 0,
            Expect::Hit { structure } => hits.first() == Some(&structure.as_str()),
        };
    let got = format!(
        "target reached {}, confirmed {}, risk hits [{}], bone contacts {}, replay verified {}",
        m.target_reached,
        m.target_confirmed,
        hits.join(", "),
        m.bone_contacts,
        r.replay_verified
    );
    Ok(SmokeOutcome {
        script: s.file_name.clone(),
        expect: s.expect.clone(),
        got,
        passed,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// The validation record of `outcomes` on `atlas`.
pub fn record(atlas: &Atlas, outcomes: &[SmokeOutcome]) -> ValidationRecord {
    ValidationRecord {
        format_version: VALIDATION_FORMAT_VERSION,
        atlas_hash: atlas.content_hash.clone(),
        physics_version: stylet_physics::PHYSICS_VERSION,
        smoke: outcomes
            .iter()
            .map(|o| SmokeEntry {
                script: o.script.clone(),
                expect: o.expect.clone(),
                passed: o.passed,
                got: o.got.clone(),
            })
            .collect(),
    }
}

/// The scripts a validation record names, read from the atlas' `scripts/` folder (bounded).
pub fn scripts_of(dir: &Path, record: &ValidationRecord) -> Result<Vec<SmokeScript>, stylet_atlas::AtlasError> {
    record
        .smoke
        .iter()
        .map(|e| {
            Ok(SmokeScript {
                file_name: e.script.clone(),
                text: stylet_atlas::validation::read_script(dir, &e.script)?,
                expect: e.expect.clone(),
            })
        })
        .collect()
}

/// The first failed outcome as the reason a scenario is not ready, or `None` when all passed.
pub fn first_failure(outcomes: &[SmokeOutcome]) -> Option<String> {
    outcomes.iter().find_map(SmokeOutcome::failure)
}

/// The example scripts of the atlas' guided path (the beginner's, else its first planned path),
/// generated as `stylet atlas new` does; none when the atlas has no planned path.
pub fn example_scripts(atlas: &Atlas) -> Vec<stylet_atlas::import::scripts::GeneratedScript> {
    match atlas.guided_path() {
        Some(p) => stylet_atlas::import::scripts::generate(&atlas.model, p),
        None => Vec::new(),
    }
}

/// Generated scripts as smoke-test scripts.
pub fn smoke_scripts(generated: &[stylet_atlas::import::scripts::GeneratedScript]) -> Vec<SmokeScript> {
    generated
        .iter()
        .map(|g| SmokeScript {
            file_name: g.file_name.clone(),
            text: g.text.clone(),
            expect: g.expect.to_record(),
        })
        .collect()
}
