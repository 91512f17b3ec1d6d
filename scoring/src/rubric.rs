//! Rubrics (TOML, versioned; `scoring/rubrics/`): requirements and deductions per difficulty
//! level that turn [`Metrics`] into a [`Grade`]. docs/metrics.md "Rubrics" describes the format.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::benchmark::Benchmark;
use crate::metrics::{MetricParams, Metrics};
use crate::rubric_metrics::{HIGHER_IS_BETTER, attempted, exercise_metrics, not_attempted_text};
use stylet_atlas::Exercise;

/// The metric names and values rubrics use, also under this module's name.
pub use crate::rubric_metrics::{metric_value, rubric_metrics};
/// The difficulty levels a rubric has rules for (one table per level and exercise).
pub use stylet_atlas::{Difficulty, UnknownDifficulty};

/// The rubric shipped with Stylet (`scoring/rubrics/ptcd.toml`).
pub const DEFAULT_RUBRIC: &str = include_str!("../rubrics/ptcd.toml");

/// Why a rubric is refused when it is read: the table and value at fault, so whoever edits the
/// rubric knows what to fix. `level` is the level's table under `levels` ("expert", or
/// "palpation.expert" for an exercise's own levels).
#[derive(Debug, thiserror::Error)]
pub enum RubricError {
    /// Not TOML of the rubric format: syntax, an unknown key, a wrong type.
    #[error(transparent)]
    Syntax(#[from] toml::de::Error),
    #[error("rubric version must be 1 or more")]
    ZeroVersion,
    /// `what` names the value ("metrics.redirection_mm", "levels.expert: deduction on 'attempts'").
    #[error("{what} is not a finite number")]
    NotFinite { what: String },
    #[error("metrics.redirection_mm and readvance_mm must be positive")]
    NonPositiveDistance,
    /// A level missing from the levels of `table` (none: the puncture's `[levels]`).
    #[error("{}the rubric lacks level '{level}'", .table.as_ref().map(|t| format!("{t}: ")).unwrap_or_default())]
    MissingLevel { table: Option<String>, level: Difficulty },
    #[error("unknown level '{level}' (levels: {})", Difficulty::names())]
    UnknownLevel { level: String },
    #[error("levels.{level}.pass_score must lie in 0…100")]
    PassScore { level: String },
    /// A metric the exercise does not measure.
    #[error(
        "levels.{level}: unknown metric '{metric}' for the {} exercise (known: {})",
        .exercise.label(),
        known_metrics(.exercise)
    )]
    UnknownMetric {
        level: String,
        metric: String,
        exercise: Exercise,
    },
    #[error("levels.{level}: requirement on '{metric}' has neither min nor max")]
    UnboundedRequirement { level: String, metric: String },
    #[error("levels.{level}: relative deduction on '{metric}' has negative points, spreads or max_points")]
    NegativeRelative { level: String, metric: String },
    /// A relative deduction on a metric where more is better: it would punish beating the
    /// experts.
    #[error(
        "levels.{level}: a relative deduction on '{metric}' would cost points for doing better than the experts (more is better for it)"
    )]
    RelativeOnHigherIsBetter { level: String, metric: String },
    #[error("levels.{level}: deduction on '{metric}' has negative points")]
    NegativePoints { level: String, metric: String },
    #[error("relative deductions need a [benchmark] table with min_experts")]
    MissingBenchmark,
    #[error("benchmark.min_experts must be 2 or more (one expert has no spread)")]
    TooFewExperts,
    #[error(
        "benchmark.min_experts must be at most {} (the most expert references a scenario may have)",
        crate::benchmark::MAX_EXPERTS
    )]
    TooManyExperts,
    #[error("the puncture's levels are the top-level [levels], not [exercises.puncture]")]
    PunctureUnderExercises,
}

/// The metrics `exercise` measures, for messages.
fn known_metrics(exercise: &Exercise) -> String {
    exercise_metrics(*exercise).join(", ")
}

/// Why a rubric cannot grade a session: it has no levels for the session's exercise, or not the
/// session's difficulty. Checked before a replay is spent on the session.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GradeError {
    #[error("rubric {rubric} v{version} has no levels for the {} exercise", .exercise.label())]
    NoLevels {
        rubric: String,
        version: u32,
        exercise: Exercise,
    },
    /// `difficulty`: the level as the session names it (not always a level at all).
    #[error(
        "the session's difficulty '{difficulty}' is not a level of this rubric ({})",
        Difficulty::names()
    )]
    UnknownDifficulty { difficulty: String },
}

impl From<UnknownDifficulty> for GradeError {
    fn from(e: UnknownDifficulty) -> Self {
        GradeError::UnknownDifficulty { difficulty: e.name }
    }
}

/// A rubric, checked: every exercise it grades has all three levels.
#[derive(Debug, Clone, PartialEq)]
pub struct Rubric {
    pub name: String,
    pub version: u32,
    pub metrics: RubricMetrics,
    /// The puncture exercise's levels (kept at the top for rubrics written before exercises).
    pub levels: BTreeMap<Difficulty, Level>,
    /// The levels of the other exercises (`[exercises.palpation.levels.beginner]`, …).
    pub exercises: BTreeMap<Exercise, ExerciseRubric>,
    /// Grading relative to the expert benchmark (since version 4): when it applies.
    pub benchmark: Option<RubricBenchmark>,
}

/// A rubric file as written: levels by name, checked and turned into a [`Rubric`] by
/// [`Rubric::parse`].
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RubricToml {
    name: String,
    version: u32,
    metrics: RubricMetrics,
    levels: BTreeMap<String, Level>,
    #[serde(default)]
    exercises: BTreeMap<Exercise, ExerciseToml>,
    #[serde(default)]
    benchmark: Option<RubricBenchmark>,
}

/// `[exercises.<exercise>]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ExerciseToml {
    levels: BTreeMap<String, Level>,
}

/// `[benchmark]`: the levels' `relative` deductions apply only when the scenario has at least
/// `min_experts` expert references (fewer say too little about how experts do it).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RubricBenchmark {
    pub min_experts: u32,
}

/// The levels of one exercise.
#[derive(Debug, Clone, PartialEq)]
pub struct ExerciseRubric {
    pub levels: BTreeMap<Difficulty, Level>,
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RubricMetrics {
    pub redirection_mm: f64,
    pub readvance_mm: f64,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Level {
    pub pass_score: f64,
    #[serde(default)]
    pub require: Vec<Requirement>,
    #[serde(default)]
    pub deduct: Vec<Deduction>,
    /// Deductions against the expert benchmark (need `[benchmark]`).
    #[serde(default)]
    pub relative: Vec<RelativeDeduction>,
}

/// `points` per unit of the metric above the expert mean plus `spreads` expert spreads, at most
/// `max_points`: a [`Deduction`] whose free amount comes from the benchmark.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RelativeDeduction {
    pub metric: String,
    pub spreads: f64,
    pub points: f64,
    pub max_points: Option<f64>,
}

/// The metric must lie within [min, max].
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Requirement {
    pub metric: String,
    pub min: Option<f64>,
    pub max: Option<f64>,
}

/// `points` per unit of the metric above `free`, at most `max_points`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Deduction {
    pub metric: String,
    pub free: f64,
    pub points: f64,
    pub max_points: Option<f64>,
}

/// One deduction applied to a grade.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Applied {
    pub metric: String,
    pub value: f64,
    pub points: f64,
    /// The amount that cost nothing (absent in grades stored before it was kept).
    #[serde(default)]
    pub free: Option<f64>,
    /// For a deduction against the expert benchmark: the expert figures its free amount came from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relative: Option<RelativeFree>,
}

/// Where a relative deduction's free amount came from: expert mean + `spreads` × spread.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RelativeFree {
    pub mean: f64,
    pub spread: f64,
    pub spreads: f64,
}

/// Whether a grade was measured against the expert benchmark (levels with relative deductions).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GradeBenchmark {
    /// Expert references the scenario had when the session was graded.
    pub experts: u32,
    /// The rubric's minimum for its relative deductions to apply.
    pub min_experts: u32,
    /// Whether they applied (`experts ≥ min_experts`).
    pub applied: bool,
    /// The expert sessions (ids, sorted) it was measured against, when it applied.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub references: Vec<String>,
    /// The experts' figures of every metric the level's relative deductions use, when it applied
    /// (a rule that cost nothing is recorded too): with `references`, the grade can be checked
    /// and recomputed whatever is marked later.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub figures: Vec<crate::benchmark::MetricBenchmark>,
}

/// A requirement the session did not meet.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unmet {
    pub metric: String,
    pub value: f64,
    pub min: Option<f64>,
    pub max: Option<f64>,
}

/// A grade: what the rubric makes of the metrics at one difficulty.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Grade {
    pub score: f64,
    pub passed: bool,
    /// The exercise whose rubric graded it.
    #[serde(default)]
    pub exercise: Exercise,
    pub difficulty: Difficulty,
    /// The level's pass mark (absent in grades stored before it was kept).
    #[serde(default)]
    pub pass_score: Option<f64>,
    pub rubric: String,
    pub rubric_version: u32,
    pub physics_version: u32,
    /// Requirements not met, in words (from the table of `metric_words`).
    pub failed: Vec<String>,
    /// The same requirements, as numbers.
    #[serde(default)]
    pub unmet: Vec<Unmet>,
    pub deductions: Vec<Applied>,
    /// The expert benchmark, when the level grades against it (absent otherwise and in grades
    /// stored before rubric version 4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub benchmark: Option<GradeBenchmark>,
    /// False when the session never tried the exercise (no puncture, no touch): it scored 0 with
    /// `failed` saying so, and nothing else was graded. Stored only when false.
    #[serde(default = "yes", skip_serializing_if = "is_yes")]
    pub attempted: bool,
}

fn yes() -> bool {
    true
}

fn is_yes(b: &bool) -> bool {
    *b
}

/// The points a deduction takes: `points` per unit of `value` above `free`, at most `max_points`.
fn deducted(value: f64, free: f64, points: f64, max_points: Option<f64>) -> f64 {
    let p = (value - free).max(0.0) * points;
    max_points.map_or(p, |cap| p.min(cap))
}

/// Checks the levels of one exercise: all three present, pass marks in 0…100, known metrics,
/// finite numbers, no negative points; returns them by level. `at` names the table in messages.
fn check_levels(
    levels: BTreeMap<String, Level>,
    exercise: Exercise,
    at: &str,
) -> Result<BTreeMap<Difficulty, Level>, RubricError> {
    let finite = |v: f64, what: &str| {
        if v.is_finite() {
            Ok(())
        } else {
            Err(RubricError::NotFinite { what: what.to_string() })
        }
    };
    let allowed = exercise_metrics(exercise);
    for level in Difficulty::ALL {
        if !levels.contains_key(level.as_str()) {
            return Err(RubricError::MissingLevel {
                table: (exercise != Exercise::Puncture).then(|| at.to_string()),
                level,
            });
        }
    }
    let mut checked = BTreeMap::new();
    for (key, l) in levels {
        let difficulty: Difficulty = key
            .parse()
            .map_err(|_| RubricError::UnknownLevel { level: key.clone() })?;
        let name = if exercise == Exercise::Puncture {
            key
        } else {
            format!("{}.{key}", exercise.as_str())
        };
        if !(0.0..=100.0).contains(&l.pass_score) {
            return Err(RubricError::PassScore { level: name });
        }
        let at_metric = |metric: &str| (name.clone(), metric.to_string());
        let known = |m: &str| {
            if allowed.contains(&m) {
                Ok(())
            } else {
                Err(RubricError::UnknownMetric {
                    level: name.clone(),
                    metric: m.to_string(),
                    exercise,
                })
            }
        };
        for q in &l.require {
            known(&q.metric)?;
            if q.min.is_none() && q.max.is_none() {
                let (level, metric) = at_metric(&q.metric);
                return Err(RubricError::UnboundedRequirement { level, metric });
            }
            for v in q.min.iter().chain(&q.max) {
                finite(*v, &format!("levels.{name}: requirement on '{}'", q.metric))?;
            }
        }
        for d in &l.relative {
            known(&d.metric)?;
            for v in [d.spreads, d.points].iter().chain(&d.max_points) {
                finite(*v, &format!("levels.{name}: relative deduction on '{}'", d.metric))?;
            }
            if d.points < 0.0 || d.spreads < 0.0 || d.max_points.is_some_and(|m| m < 0.0) {
                let (level, metric) = at_metric(&d.metric);
                return Err(RubricError::NegativeRelative { level, metric });
            }
            if HIGHER_IS_BETTER.contains(&d.metric.as_str()) {
                let (level, metric) = at_metric(&d.metric);
                return Err(RubricError::RelativeOnHigherIsBetter { level, metric });
            }
        }
        for d in &l.deduct {
            known(&d.metric)?;
            for v in [d.free, d.points].iter().chain(&d.max_points) {
                finite(*v, &format!("levels.{name}: deduction on '{}'", d.metric))?;
            }
            if d.points < 0.0 {
                let (level, metric) = at_metric(&d.metric);
                return Err(RubricError::NegativePoints { level, metric });
            }
        }
        checked.insert(difficulty, l);
    }
    Ok(checked)
}

impl Rubric {
    /// Parses and checks a rubric; the error names the problem.
    pub fn parse(text: &str) -> Result<Rubric, RubricError> {
        let r: RubricToml = toml::from_str(text)?;
        if r.version == 0 {
            return Err(RubricError::ZeroVersion);
        }
        let finite = |v: f64, what: &str| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(RubricError::NotFinite { what: what.to_string() })
            }
        };
        finite(r.metrics.redirection_mm, "metrics.redirection_mm")?;
        finite(r.metrics.readvance_mm, "metrics.readvance_mm")?;
        if r.metrics.redirection_mm <= 0.0 || r.metrics.readvance_mm <= 0.0 {
            return Err(RubricError::NonPositiveDistance);
        }
        let levels = check_levels(r.levels, Exercise::Puncture, "levels")?;
        let relative = levels
            .values()
            .chain(r.exercises.values().flat_map(|e| e.levels.values()))
            .any(|l| !l.relative.is_empty());
        match r.benchmark {
            None if relative => {
                return Err(RubricError::MissingBenchmark);
            }
            Some(b) if b.min_experts < 2 => {
                return Err(RubricError::TooFewExperts);
            }
            Some(b) if b.min_experts as usize > crate::benchmark::MAX_EXPERTS => {
                return Err(RubricError::TooManyExperts);
            }
            _ => {}
        }
        let mut exercises = BTreeMap::new();
        for (exercise, e) in r.exercises {
            if exercise == Exercise::Puncture {
                return Err(RubricError::PunctureUnderExercises);
            }
            let at = format!("exercises.{}.levels", exercise.as_str());
            let levels = check_levels(e.levels, exercise, &at)?;
            exercises.insert(exercise, ExerciseRubric { levels });
        }
        Ok(Rubric {
            name: r.name,
            version: r.version,
            metrics: r.metrics,
            levels,
            exercises,
            benchmark: r.benchmark,
        })
    }

    pub fn default_rubric() -> Rubric {
        Rubric::parse(DEFAULT_RUBRIC).expect("the shipped rubric is valid (tested)")
    }

    /// The metric settings this rubric asks for.
    pub fn metric_params(&self) -> MetricParams {
        MetricParams {
            redirection_mm: self.metrics.redirection_mm,
            readvance_mm: self.metrics.readvance_mm,
            ..MetricParams::default()
        }
    }

    /// The levels of `exercise`, if this rubric grades it.
    pub fn levels_for(&self, exercise: Exercise) -> Option<&BTreeMap<Difficulty, Level>> {
        match exercise {
            Exercise::Puncture => Some(&self.levels),
            other => self.exercises.get(&other).map(|e| &e.levels),
        }
    }

    /// The level `difficulty` of `exercise`, if this rubric has it.
    pub fn level(&self, exercise: Exercise, difficulty: Difficulty) -> Option<&Level> {
        self.levels_for(exercise)?.get(&difficulty)
    }

    /// The levels of `exercise`, or why this rubric cannot grade it.
    fn graded_levels(&self, exercise: Exercise) -> Result<&BTreeMap<Difficulty, Level>, GradeError> {
        self.levels_for(exercise).ok_or_else(|| GradeError::NoLevels {
            rubric: self.name.clone(),
            version: self.version,
            exercise,
        })
    }

    /// Whether this rubric grades `exercise` at `difficulty` (checked before a replay is spent
    /// on it).
    pub fn grade_check(&self, exercise: Exercise, difficulty: Difficulty) -> Result<(), GradeError> {
        if self.graded_levels(exercise)?.contains_key(&difficulty) {
            Ok(())
        } else {
            Err(GradeError::UnknownDifficulty {
                difficulty: difficulty.to_string(),
            })
        }
    }

    /// The level a session header names (`name`, as recorded), if this rubric grades `exercise`
    /// at it: [`Self::grade_check`] for a level not yet parsed (a rubric without levels for the
    /// exercise says so first).
    pub fn session_difficulty(&self, exercise: Exercise, name: &str) -> Result<Difficulty, GradeError> {
        self.graded_levels(exercise)?;
        let difficulty: Difficulty = name.parse()?;
        self.grade_check(exercise, difficulty)?;
        Ok(difficulty)
    }

    /// Grades `m` as `exercise` at `difficulty` with no expert benchmark (a level's relative
    /// deductions do not apply).
    pub fn grade(&self, m: &Metrics, exercise: Exercise, difficulty: Difficulty) -> Result<Grade, GradeError> {
        self.grade_against(m, exercise, difficulty, None)
    }

    /// Grades `m` as `exercise` at `difficulty`; the level's relative deductions measure against
    /// `benchmark` (the scenario's) when it has enough experts.
    pub fn grade_against(
        &self,
        m: &Metrics,
        exercise: Exercise,
        difficulty: Difficulty,
        benchmark: Option<&Benchmark>,
    ) -> Result<Grade, GradeError> {
        self.grade_check(exercise, difficulty)?;
        let level = self.level(exercise, difficulty).expect("checked above");
        if !attempted(m, exercise) {
            return Ok(Grade {
                score: 0.0,
                passed: false,
                exercise,
                difficulty,
                pass_score: Some(level.pass_score),
                rubric: self.name.clone(),
                rubric_version: self.version,
                physics_version: stylet_physics::PHYSICS_VERSION,
                failed: vec![not_attempted_text(exercise).to_string()],
                unmet: Vec::new(),
                deductions: Vec::new(),
                benchmark: None,
                attempted: false,
            });
        }
        // Names are checked at parse time; a value is missing only from a stored report older
        // than its metric (a replay measures them all), which counts as nothing to judge.
        let value = |name: &str| metric_value(m, name).unwrap_or(0.0);
        let mut failed = Vec::new();
        let mut unmet = Vec::new();
        for q in &level.require {
            let v = value(&q.metric);
            let below = q.min.is_some_and(|min| v < min);
            let above = q.max.is_some_and(|max| v > max);
            if below || above {
                failed.push(crate::reasons::unmet_text(&q.metric, v, q.min, q.max, m));
                unmet.push(Unmet {
                    metric: q.metric.clone(),
                    value: v,
                    min: q.min,
                    max: q.max,
                });
            }
        }
        let mut deductions = Vec::new();
        for d in &level.deduct {
            let v = value(&d.metric);
            let points = deducted(v, d.free, d.points, d.max_points);
            if points > 0.0 {
                deductions.push(Applied {
                    metric: d.metric.clone(),
                    value: v,
                    points,
                    free: Some(d.free),
                    relative: None,
                });
            }
        }
        let graded_benchmark = match (&self.benchmark, level.relative.is_empty()) {
            (Some(rb), false) => {
                let experts = benchmark.map_or(0, |b| b.experts.len()) as u32;
                let applied = experts >= rb.min_experts;
                let used = benchmark.filter(|_| applied);
                Some(GradeBenchmark {
                    experts,
                    min_experts: rb.min_experts,
                    applied,
                    references: used.map(|b| b.experts.clone()).unwrap_or_default(),
                    figures: used
                        .map(|b| {
                            level
                                .relative
                                .iter()
                                .filter_map(|d| b.figure(&d.metric).cloned())
                                .collect()
                        })
                        .unwrap_or_default(),
                })
            }
            _ => None,
        };
        if let (Some(gb), Some(bench)) = (&graded_benchmark, benchmark)
            && gb.applied
        {
            for d in &level.relative {
                let Some(f) = bench.figure(&d.metric) else { continue };
                let v = value(&d.metric);
                let free = f.mean + d.spreads * f.spread;
                let points = deducted(v, free, d.points, d.max_points);
                if points > 0.0 {
                    deductions.push(Applied {
                        metric: d.metric.clone(),
                        value: v,
                        points,
                        free: Some(free),
                        relative: Some(RelativeFree {
                            mean: f.mean,
                            spread: f.spread,
                            spreads: d.spreads,
                        }),
                    });
                }
            }
        }
        let score = (100.0 - deductions.iter().map(|d| d.points).sum::<f64>()).clamp(0.0, 100.0);
        // Scores are reported to 0.01 points.
        let score = (score * 100.0).round() / 100.0;
        Ok(Grade {
            score,
            passed: failed.is_empty() && score >= level.pass_score,
            exercise,
            difficulty,
            pass_score: Some(level.pass_score),
            rubric: self.name.clone(),
            rubric_version: self.version,
            physics_version: stylet_physics::PHYSICS_VERSION,
            failed,
            unmet,
            deductions,
            benchmark: graded_benchmark,
            attempted: true,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::Metrics;

    fn metrics() -> Metrics {
        crate::metrics::tests_support::example()
    }

    /// A session that never tried the exercise scores 0 with one reason that says so, at every
    /// level; one that tried is graded as before.
    #[test]
    fn an_exercise_not_attempted_scores_zero_and_says_so() {
        use crate::metrics::tests_support::metrics_with;
        let r = Rubric::default_rubric();
        let idle = metrics_with(|m| {
            m.attempts = 0;
            m.target_reached = false;
            m.target_confirmed = false;
        });
        for level in Difficulty::ALL {
            let g = r.grade(&idle, Exercise::Puncture, level).unwrap();
            assert_eq!((g.score, g.passed, g.attempted), (0.0, false, false), "{level:?}");
            assert_eq!(g.failed, ["Not attempted: the needle never entered the skin."]);
            assert!(g.deductions.is_empty() && g.unmet.is_empty());
            let reasons = crate::reasons::reasons(Exercise::Puncture, &g, &idle, None);
            assert_eq!(reasons, g.failed);
        }
        let g = r.grade(&idle, Exercise::Palpation, Difficulty::Beginner).unwrap();
        assert_eq!(g.failed, ["Not attempted: the finger never touched the skin."]);
        let g = r
            .grade(&idle, Exercise::UltrasoundSurvey, Difficulty::Beginner)
            .unwrap();
        assert_eq!(g.failed, ["Not attempted: the probe never touched the skin."]);
        // A grade stored before the field existed reads as attempted; an attempted one stores
        // nothing new.
        let tried = r.grade(&metrics(), Exercise::Puncture, Difficulty::Beginner).unwrap();
        assert!(tried.attempted && tried.score > 0.0);
        let json = serde_json::to_value(&tried).unwrap();
        assert!(json.get("attempted").is_none());
        let back: Grade = serde_json::from_value(json).unwrap();
        assert!(back.attempted);
        let idle_json = serde_json::to_value(r.grade(&idle, Exercise::Puncture, Difficulty::Expert).unwrap()).unwrap();
        assert_eq!(idle_json["attempted"], serde_json::json!(false));
    }

    /// The unmet risk-hit requirement names what was hit.
    #[test]
    fn a_risk_hit_requirement_names_the_structures() {
        use crate::metrics::tests_support::metrics_with;
        let hit = |name: &str, label: u16| -> crate::metrics::RiskHit {
            serde_json::from_value(serde_json::json!({
                "structure": name, "label": label, "t_s": 5.9, "depth_mm": 9.5,
                "duration_s": 1.0, "entries": 1
            }))
            .unwrap()
        };
        let m = metrics_with(|m| m.risk_hits = vec![hit("right lung", 3), hit("portal vein", 7)]);
        let g = Rubric::default_rubric()
            .grade(&m, Exercise::Puncture, Difficulty::Beginner)
            .unwrap();
        assert!(
            g.failed
                .iter()
                .any(|f| f == "2 risk structures hit: right lung, portal vein (none allowed)."),
            "{:?}",
            g.failed
        );
    }

    /// The worked example of docs/metrics.md "Rubrics".
    #[test]
    fn the_shipped_rubric_grades_the_worked_example() {
        let r = Rubric::default_rubric();
        assert_eq!((r.name.as_str(), r.version), ("ptcd", 10));
        let g = r.grade(&metrics(), Exercise::Puncture, Difficulty::Beginner).unwrap();
        // attempts 2 (1 free) −10, redirections 3 (2 free) −3, fluoro 40 s (30 free) −5,
        // no palpation first −5: 100 − 23.
        assert_eq!(g.score, 77.0, "{:?}", g.deductions);
        assert!(g.passed && g.failed.is_empty());
        let g = r.grade(&metrics(), Exercise::Puncture, Difficulty::Expert).unwrap();
        assert!(!g.passed);
        assert!(
            g.failed.iter().any(|f| f == "2 attempts: at most 1 allowed."),
            "{:?}",
            g.failed
        );
        assert!(
            g.failed
                .iter()
                .any(|f| f == "40 s of time under X-ray: at most 30 s allowed."),
            "{:?}",
            g.failed
        );
        let e = r.session_difficulty(Exercise::Puncture, "wizard").unwrap_err();
        assert!(e.to_string().contains("'wizard'"), "{e}");
        assert_eq!(
            e,
            GradeError::UnknownDifficulty {
                difficulty: "wizard".into()
            }
        );
        assert_eq!(
            r.session_difficulty(Exercise::Puncture, "expert"),
            Ok(Difficulty::Expert)
        );
    }

    /// The expert level's relative deductions: nothing without a benchmark or with too few
    /// experts; with three, time above the expert mean + 1 spread costs 0.1 points a second.
    #[test]
    fn the_expert_level_grades_against_the_benchmark() {
        use crate::benchmark::Benchmark;
        use crate::metrics::tests_support::metrics_with;
        let r = Rubric::default_rubric();
        let trainee = metrics_with(|m| {
            m.attempts = 1;
            m.redirections = 0;
            m.fluoro_time_s = 20.0;
            m.time_total_s = 200.0;
        });
        let alone = r.grade(&trainee, Exercise::Puncture, Difficulty::Expert).unwrap();
        assert_eq!(
            alone.benchmark,
            Some(GradeBenchmark {
                experts: 0,
                min_experts: 3,
                applied: false,
                references: Vec::new(),
                figures: Vec::new(),
            })
        );
        assert!(alone.deductions.iter().all(|d| d.relative.is_none()));
        let experts: Vec<Metrics> = [100.0, 120.0, 140.0]
            .iter()
            .map(|&t| {
                metrics_with(|m| {
                    m.time_total_s = t;
                    m.fluoro_time_s = 20.0;
                })
            })
            .collect();
        let refs: Vec<(String, &Metrics)> = experts.iter().enumerate().map(|(i, m)| (format!("e{i}"), m)).collect();
        let two = Benchmark::from_sessions("s", Exercise::Puncture, &refs[..2]);
        let g = r
            .grade_against(&trainee, Exercise::Puncture, Difficulty::Expert, Some(&two))
            .unwrap();
        assert_eq!(g.score, alone.score, "two experts are fewer than min_experts");
        assert!(!g.benchmark.unwrap().applied);
        let three = Benchmark::from_sessions("s", Exercise::Puncture, &refs);
        let g = r
            .grade_against(&trainee, Exercise::Puncture, Difficulty::Expert, Some(&three))
            .unwrap();
        let gb = g.benchmark.as_ref().unwrap();
        assert!(gb.applied);
        assert_eq!(gb.references, ["e0", "e1", "e2"]);
        let recorded: Vec<&str> = gb.figures.iter().map(|f| f.metric.as_str()).collect();
        assert_eq!(
            recorded,
            ["time_total_s", "fluoro_time_s", "shaft_sweep_mm2", "tissue_damage_mm2"]
        );
        // Mean 120 s, spread 20 s: 60 s above 140 s at 0.1 points = 6; fluoroscopy equals the
        // experts' (spread 0) and costs nothing.
        let rel: Vec<&Applied> = g.deductions.iter().filter(|d| d.relative.is_some()).collect();
        assert_eq!(rel.len(), 1, "{rel:?}");
        assert_eq!(rel[0].metric, "time_total_s");
        assert!((rel[0].points - 6.0).abs() < 1e-9, "{}", rel[0].points);
        assert_eq!(rel[0].free, Some(140.0));
        assert_eq!(g.score, alone.score - 6.0);
        // The beginner level has no relative deductions: the benchmark changes nothing there.
        let b = r
            .grade_against(&trainee, Exercise::Puncture, Difficulty::Beginner, Some(&three))
            .unwrap();
        assert_eq!(b, r.grade(&trainee, Exercise::Puncture, Difficulty::Beginner).unwrap());
        assert_eq!(b.benchmark, None);
    }

    /// A two-handed puncture under live ultrasound is graded on keeping the tip in view, harder
    /// by level; a one-handed session (no live guidance) loses nothing for it.
    #[test]
    fn live_guidance_is_graded_per_level() {
        use crate::live_guidance::LiveGuidance;
        let r = Rubric::default_rubric();
        let blind = crate::metrics::tests_support::metrics_with(|m| {
            m.live_guidance = Some(LiveGuidance {
                needle_tip_visible_share: 0.25,
                longest_blind_advance_s: 6.0,
                tip_in_view_at_target_entry: Some(false),
            })
        });
        let one_handed = crate::metrics::tests_support::metrics_with(|_| {});
        let points = |m: &Metrics, level: Difficulty| -> Vec<(String, f64)> {
            let g = r.grade(m, Exercise::Puncture, level).unwrap();
            g.deductions
                .iter()
                .filter(|d| {
                    ["tip_out_of_view_share", "blind_advance_s", "tip_out_of_view_at_target"]
                        .contains(&d.metric.as_str())
                })
                .map(|d| (d.metric.clone(), d.points))
                .collect()
        };
        for level in [Difficulty::Beginner, Difficulty::Advanced, Difficulty::Expert] {
            assert_eq!(points(&one_handed, level), [], "{level:?}");
        }
        // Beginner: out of view 75 % (50 % free) × 20 = 5, 6 s blind (5 free) × 1 = 1.
        let b = points(&blind, Difficulty::Beginner);
        assert_eq!(b.len(), 2, "{b:?}");
        assert!((b[0].1 - 5.0).abs() < 1e-9 && (b[1].1 - 1.0).abs() < 1e-9, "{b:?}");
        // Expert: 55 % × 60 = 33 → 20 (at most), 5 s × 5 = 25 → 20, out of view at the target 10.
        let e = points(&blind, Difficulty::Expert);
        assert_eq!(e.iter().map(|d| d.1).sum::<f64>(), 50.0, "{e:?}");
    }

    #[test]
    fn bad_rubrics_are_named() {
        let base = DEFAULT_RUBRIC;
        let cases = [
            (base.replace("version = 10", "version = 0"), "version"),
            (
                base.replace("[levels.expert]", "[levels.master]"),
                "lacks level 'expert'",
            ),
            (
                base.replacen("metric = \"attempts\"", "metric = \"atempts\"", 1),
                "unknown metric 'atempts'",
            ),
            (
                base.replacen("pass_score = 60.0", "pass_score = 160.0", 1),
                "pass_score",
            ),
            (
                base.replacen("redirection_mm = 5.0", "redirection_mm = -5.0", 1),
                "positive",
            ),
            (
                base.replacen("{ metric = \"risk_hits\", max = 0 }", "{ metric = \"risk_hits\" }", 1),
                "neither min nor max",
            ),
            (base.replacen("points = 10 }", "points = -10 }", 1), "negative points"),
            (format!("{base}\nsurprise = 1\n"), "surprise"),
            (
                base.replace("min_experts = 3", "min_experts = 1"),
                "min_experts must be 2",
            ),
            (base.replace("[benchmark]\nmin_experts = 3\n", ""), "need a [benchmark]"),
            (
                base.replacen("spreads = 2,", "spreads = -2,", 1),
                "negative points, spreads or max_points",
            ),
            ("name = ".to_string(), "line 1"),
            (
                base.replacen(
                    "[levels.expert]",
                    "[levels.wizard]\npass_score = 50.0\n\n[levels.expert]",
                    1,
                ),
                "unknown level 'wizard' (levels: beginner, advanced, expert)",
            ),
        ];
        for (text, want) in cases {
            let e = Rubric::parse(&text).unwrap_err().to_string();
            assert!(e.contains(want), "expected '{want}' in: {e}");
        }
    }
}
