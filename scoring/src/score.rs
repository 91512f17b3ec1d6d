//! Scoring one session file: read it, check the atlas, replay it through the physics while
//! collecting metrics, grade them with the rubric at the session's difficulty.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::Serialize;
use stylet_physics::PunctureAtlas;

use stylet_recorder::reader::{self, Session};

use crate::benchmark::{Benchmark, SkillEstimate};
use crate::metrics::{Metrics, MetricsCollector, PlannedPath};
use crate::reasons::{self, Outcome};
use crate::replay::{Divergence, ReplayError, replay};
use crate::rubric::{Grade, GradeError, Rubric};
use crate::target::TargetDistance;
use crate::trace::{ReviewTrace, TraceCollector};
use stylet_atlas::Exercise;

/// Why a session was not scored.
#[derive(Debug, thiserror::Error)]
pub enum ScoreError {
    #[error("{0}")]
    Unreadable(String),
    #[error(
        "the session was recorded on atlas '{session_atlas}' with content hash {session_hash}, but the atlas given is '{atlas}' with hash {atlas_hash}"
    )]
    AtlasMismatch {
        session_atlas: String,
        session_hash: String,
        atlas: String,
        atlas_hash: String,
    },
    #[error(transparent)]
    Replay(#[from] ReplayError),
    /// The rubric has no level for the session's exercise or difficulty.
    #[error(transparent)]
    Grade(#[from] GradeError),
}

/// Why a [`Scorer`] cannot be built, or cannot start a batch: nothing was scored.
#[derive(Debug, thiserror::Error)]
pub enum ScorerError {
    /// Guided-mode metrics asked for a planned path the atlas does not have (`known`: its paths).
    #[error("the atlas has no insertion path '{name}' (paths: {})", .known.join(", "))]
    UnknownPath { name: String, known: Vec<String> },
    /// No thread pool for the batch.
    #[error(transparent)]
    ThreadPool(#[from] rayon::ThreadPoolBuildError),
}

/// A file and what scoring it gave.
pub type FileScore = (PathBuf, Result<ScoreReport, ScoreError>);

/// The scored session: who and what, the replay check, the metrics and the grade. Reports stored
/// before exercises and outcomes were kept still load: they read as punctures, their outcome
/// comes from `incomplete` and `grade.passed`, their reasons are phrased again from the grade.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
#[serde(from = "StoredReport")]
pub struct ScoreReport {
    pub session_id: String,
    pub trainee: String,
    pub scenario: String,
    pub atlas_id: String,
    pub replay_verified: bool,
    pub divergence: Option<Divergence>,
    pub physics_version: u32,
    /// The file was cut, damaged, or its recording dropped ticks: scored on what is there.
    pub incomplete: bool,
    pub incomplete_reason: Option<String>,
    pub ticks: u64,
    pub digests_checked: u64,
    pub metrics: Metrics,
    pub grade: Grade,
    /// What the scenario practises (its rubric graded the session).
    pub exercise: Exercise,
    /// Passed, failed, or not gradeable (incomplete recordings are never graded).
    pub outcome: Outcome,
    /// Why, in plain words for people (docs/metrics.md "Outcomes and reasons").
    pub reasons: Vec<String>,
    /// The overall skill estimate against the scenario's experts when it was scored (docs/metrics.md
    /// "Skill estimate"), once the scenario has the rubric's `min_experts` references: beside the
    /// grade, not part of it.
    #[serde(default)]
    pub skill: Option<SkillEstimate>,
}

/// A report as stored, any age: the fields added later are optional.
#[derive(serde::Deserialize)]
struct StoredReport {
    session_id: String,
    trainee: String,
    scenario: String,
    atlas_id: String,
    replay_verified: bool,
    divergence: Option<Divergence>,
    physics_version: u32,
    incomplete: bool,
    incomplete_reason: Option<String>,
    ticks: u64,
    digests_checked: u64,
    metrics: Metrics,
    grade: Grade,
    #[serde(default)]
    exercise: Option<Exercise>,
    #[serde(default)]
    outcome: Option<Outcome>,
    #[serde(default)]
    reasons: Option<Vec<String>>,
    #[serde(default)]
    skill: Option<SkillEstimate>,
}

impl From<StoredReport> for ScoreReport {
    fn from(r: StoredReport) -> Self {
        let exercise = r.exercise.unwrap_or(r.grade.exercise);
        let outcome = r.outcome.unwrap_or_else(|| Outcome::of(r.incomplete, r.grade.passed));
        let reasons = r.reasons.unwrap_or_else(|| {
            let incomplete = (outcome == Outcome::NotGradeable)
                .then(|| r.incomplete_reason.clone().unwrap_or_else(|| "unknown cause".into()));
            reasons::reasons(exercise, &r.grade, &r.metrics, incomplete.as_deref())
        });
        ScoreReport {
            session_id: r.session_id,
            trainee: r.trainee,
            scenario: r.scenario,
            atlas_id: r.atlas_id,
            replay_verified: r.replay_verified,
            divergence: r.divergence,
            physics_version: r.physics_version,
            incomplete: r.incomplete,
            incomplete_reason: r.incomplete_reason,
            ticks: r.ticks,
            digests_checked: r.digests_checked,
            metrics: r.metrics,
            grade: r.grade,
            exercise,
            outcome,
            reasons,
            skill: r.skill,
        }
    }
}

/// Scores sessions recorded on one atlas with one rubric. Building it derives what every replay
/// needs once (the target distance map), so batches pay for it once.
pub struct Scorer {
    atlas: Arc<PunctureAtlas>,
    atlas_id: String,
    atlas_hash: String,
    target: TargetDistance,
    paths: Vec<PlannedPath>,
    path: Option<String>,
    rubric: Rubric,
    /// The atlas' declared scenarios (empty: it declares none and any name is accepted).
    scenarios: Vec<String>,
    /// The exercise of each declared scenario (undeclared: puncture).
    exercises: std::collections::BTreeMap<String, Exercise>,
    /// Clinical consequences of the risk labels (atlas TOML).
    consequences: std::collections::BTreeMap<stylet_physics::LabelId, String>,
    /// Dose-area product per second of fluoroscopy of each declared scenario's C-arm.
    dose_area_rates: std::collections::BTreeMap<String, f64>,
    /// The correct breath hold of each declared scenario (undeclared: end-expiration).
    hold_phases: std::collections::BTreeMap<String, stylet_atlas::manifest::HoldPhase>,
}

impl Scorer {
    /// `path`: score guided-mode metrics against this planned path of the atlas (by name).
    pub fn new(atlas: &stylet_atlas::Atlas, rubric: Rubric, path: Option<String>) -> Result<Scorer, ScorerError> {
        let paths = atlas.planned_paths();
        if let Some(name) = &path
            && !paths.iter().any(|p| &p.name == name)
        {
            return Err(ScorerError::UnknownPath {
                name: name.clone(),
                known: paths.iter().map(|p| p.name.clone()).collect(),
            });
        }
        Ok(Scorer {
            atlas: Arc::clone(&atlas.model),
            atlas_id: atlas.manifest.name.clone(),
            atlas_hash: atlas.content_hash.clone(),
            target: TargetDistance::new(&atlas.model),
            paths,
            path,
            rubric,
            scenarios: atlas.manifest.scenarios.iter().map(|s| s.name.clone()).collect(),
            exercises: atlas
                .manifest
                .scenarios
                .iter()
                .map(|s| (s.name.clone(), s.exercise))
                .collect(),
            consequences: stylet_atlas::manifest::consequences(&atlas.manifest.labels),
            dose_area_rates: atlas
                .manifest
                .scenarios
                .iter()
                .map(|s| {
                    (
                        s.name.clone(),
                        s.c_arm.unwrap_or_default().dose_area_rate_gy_cm2_per_s(),
                    )
                })
                .collect(),
            hold_phases: atlas
                .manifest
                .scenarios
                .iter()
                .map(|s| (s.name.clone(), s.hold_phase))
                .collect(),
        })
    }

    pub fn rubric(&self) -> &Rubric {
        &self.rubric
    }

    /// The atlas' planned insertion paths (guided-mode metrics name the one they measured).
    pub fn paths(&self) -> &[PlannedPath] {
        &self.paths
    }

    /// Whether sessions on this atlas may name `scenario` (any name if it declares none).
    pub fn knows_scenario(&self, scenario: &str) -> bool {
        self.scenarios.is_empty() || self.scenarios.iter().any(|s| s == scenario)
    }

    /// The exercise a scenario practises (a scenario the atlas does not declare: puncture).
    pub fn exercise_of(&self, scenario: &str) -> Exercise {
        self.exercises.get(scenario).copied().unwrap_or_default()
    }

    /// The atlas' declared scenario names.
    pub fn scenario_names(&self) -> &[String] {
        &self.scenarios
    }

    /// Reads and scores a session file. A cut or damaged file is scored on its intact part and
    /// flagged incomplete; a file that is not a session is an error.
    pub fn score_file(&self, file: &Path) -> Result<ScoreReport, ScoreError> {
        let session = reader::recover(file).map_err(|e| ScoreError::Unreadable(format!("{}: {e}", file.display())))?;
        self.score_session(&session)
    }

    pub fn score_session(&self, session: &Session) -> Result<ScoreReport, ScoreError> {
        self.run(session, None, None)
    }

    /// Scores a session, the rubric's relative deductions against `benchmark` (the expert
    /// benchmark of the session's scenario; see [`Rubric::grade_against`]).
    pub fn score_session_against(
        &self,
        session: &Session,
        benchmark: Option<&Benchmark>,
    ) -> Result<ScoreReport, ScoreError> {
        self.run(session, None, benchmark)
    }

    /// Scores a session and takes its review trace (what the dashboard draws) in the same replay.
    pub fn score_session_traced(&self, session: &Session) -> Result<(ScoreReport, ReviewTrace), ScoreError> {
        self.score_session_traced_against(session, None)
    }

    /// [`Self::score_session_traced`] graded against `benchmark`.
    pub fn score_session_traced_against(
        &self,
        session: &Session,
        benchmark: Option<&Benchmark>,
    ) -> Result<(ScoreReport, ReviewTrace), ScoreError> {
        let mut trace = TraceCollector::new(session.header.tick_rate_hz);
        let report = self.run(session, Some(&mut trace), benchmark)?;
        let first_tick = session.ticks.first().map_or(0, |t| t.tick);
        trace.device_forces(first_tick, &session.device_forces);
        let trace = trace.finish(&report.metrics);
        Ok((report, trace))
    }

    /// The atlas sessions of this scorer are replayed on.
    pub fn atlas(&self) -> &Arc<PunctureAtlas> {
        &self.atlas
    }

    fn run(
        &self,
        session: &Session,
        mut trace: Option<&mut TraceCollector>,
        benchmark: Option<&Benchmark>,
    ) -> Result<ScoreReport, ScoreError> {
        let h = &session.header;
        if h.atlas_hash != self.atlas_hash {
            return Err(ScoreError::AtlasMismatch {
                session_atlas: h.atlas_id.clone(),
                session_hash: h.atlas_hash.clone(),
                atlas: self.atlas_id.clone(),
                atlas_hash: self.atlas_hash.clone(),
            });
        }
        let exercise = self.exercise_of(&h.scenario);
        let difficulty = self.rubric.session_difficulty(exercise, &h.difficulty)?;
        let mut collector = MetricsCollector::new(
            &self.atlas,
            &self.target,
            &self.paths,
            self.path.clone(),
            h.tick_rate_hz,
            self.rubric.metric_params(),
        )
        .with_consequences(self.consequences.clone());
        let report = replay(session, self.atlas.clone(), &mut |i, o, s| {
            collector.tick(i, o, s);
            if let Some(t) = trace.as_deref_mut() {
                t.tick(i, o);
                t.tip_hidden(collector.tip_hidden());
            }
        })?;
        let mut metrics = collector.finish();
        // The scenario's C-arm (an undeclared scenario: the default one).
        let rate = self
            .dose_area_rates
            .get(&h.scenario)
            .copied()
            .unwrap_or_else(|| stylet_atlas::manifest::CArmToml::default().dose_area_rate_gy_cm2_per_s());
        metrics.dose_area_product_gy_cm2 = metrics.fluoro_time_s * rate;
        if let Some(b) = &mut metrics.breathing {
            let hold = self.hold_phases.get(&h.scenario).copied().unwrap_or_default();
            b.correct_phase = crate::metrics::BreathPhase::of_hold(hold);
        }
        let benchmark = benchmark.filter(|b| b.scenario == h.scenario);
        let grade = self.rubric.grade_against(&metrics, exercise, difficulty, benchmark)?;
        let min_experts = self.rubric.benchmark.as_ref().map_or(3, |b| b.min_experts) as usize;
        let skill = benchmark
            .filter(|b| b.experts.len() >= min_experts && b.exercise == exercise)
            .and_then(|b| b.skill_estimate(&metrics));
        let mut reasons = Vec::new();
        if let Some(d) = &session.damage {
            reasons.push(format!("the file is damaged {d}"));
        }
        match &session.end {
            Some(e) if !e.complete => reasons.push(e.reason.clone()),
            Some(_) => {}
            None => reasons.push("the recording has no end (interrupted)".into()),
        }
        let incomplete_reason = (!reasons.is_empty()).then(|| reasons.join("; "));
        let outcome = Outcome::of(incomplete_reason.is_some(), grade.passed);
        let reasons = reasons::reasons(exercise, &grade, &metrics, incomplete_reason.as_deref());
        Ok(ScoreReport {
            session_id: h.session_id.clone(),
            trainee: h.trainee.clone(),
            scenario: h.scenario.clone(),
            atlas_id: h.atlas_id.clone(),
            replay_verified: report.replay_verified,
            divergence: report.divergence,
            physics_version: stylet_physics::PHYSICS_VERSION,
            incomplete: incomplete_reason.is_some(),
            incomplete_reason,
            ticks: report.ticks,
            digests_checked: report.digests_checked,
            metrics,
            grade,
            exercise,
            outcome,
            reasons,
            skill,
        })
    }

    /// Scores many files on `jobs` threads; `progress` is called once per finished file. The
    /// results come back sorted by file path: independent of `jobs` and of the order of `files`.
    pub fn score_files(
        &self,
        files: &[PathBuf],
        jobs: usize,
        progress: &(dyn Fn() + Sync),
    ) -> Result<Vec<FileScore>, ScorerError> {
        use rayon::prelude::*;
        let pool = rayon::ThreadPoolBuilder::new().num_threads(jobs.max(1)).build()?;
        let mut results: Vec<FileScore> = pool.install(|| {
            files
                .par_iter()
                .map(|f| {
                    let r = self.score_file(f);
                    progress();
                    (f.clone(), r)
                })
                .collect()
        });
        results.sort_by(|a, b| a.0.cmp(&b.0));
        Ok(results)
    }
}
