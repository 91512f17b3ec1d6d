//! Rubrics (TOML, versioned; `scoring/rubrics/`): requirements and deductions per difficulty
//! level that turn [`Metrics`] into a [`Grade`]. docs/metrics.md "Rubrics" describes the format.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::metrics::{MetricParams, Metrics};
use stylet_atlas::Exercise;

/// The rubric shipped with Stylet (`scoring/rubrics/ptcd.toml`).
pub const DEFAULT_RUBRIC: &str = include_str!("../rubrics/ptcd.toml");

/// The difficulty levels, in order.
pub const LEVELS: [&str; 3] = ["beginner", "advanced", "expert"];

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rubric {
    pub name: String,
    pub version: u32,
    pub metrics: RubricMetrics,
    /// The puncture exercise's levels (kept at the top for rubrics written before exercises).
    pub levels: BTreeMap<String, Level>,
    /// The levels of the other exercises (`[exercises.palpation.levels.beginner]`, …).
    #[serde(default)]
    pub exercises: BTreeMap<Exercise, ExerciseRubric>,
}

/// The levels of one exercise.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExerciseRubric {
    pub levels: BTreeMap<String, Level>,
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

/// Metric names a puncture rubric may use, with their meaning (docs/metrics.md).
pub const PUNCTURE_METRICS: &[&str] = &[
    "attempts",
    "redirections",
    "risk_hits",
    "risk_time_s",
    "bone_contacts",
    "target_not_reached",
    "target_not_confirmed",
    "extravasated_ml",
    "time_total_s",
    "fluoro_time_s",
    "xray_shots",
    "dose_area_product_gy_cm2",
    "max_force_n",
    "tissue_damage_mm2",
    "path_inefficiency",
    "target_distance_mm",
    "missing_palpation",
    "missing_ultrasound",
    "missing_target_scan",
    "guided_entry_distance_mm",
    "guided_angle_error_deg",
    "guided_mean_deviation_mm",
];

/// Metric names a palpation rubric may use.
pub const PALPATION_METRICS: &[&str] = &[
    "intercostal_spaces_found",
    "intercostal_spaces_missed",
    "palpation_coverage",
    "palpation_time_s",
    "time_total_s",
    "max_force_n",
];

/// Metric names an ultrasound-survey rubric may use.
pub const ULTRASOUND_METRICS: &[&str] = &[
    "target_not_scanned",
    "time_to_target_view_s",
    "good_contact_time_s",
    "poor_contact_share",
    "time_total_s",
    "max_force_n",
];

/// Every metric name a rubric may use, over all exercises (a name two exercises share, like
/// `time_total_s`, comes once per exercise).
pub fn rubric_metrics() -> impl Iterator<Item = &'static str> {
    PUNCTURE_METRICS
        .iter()
        .chain(PALPATION_METRICS)
        .chain(ULTRASOUND_METRICS)
        .copied()
}

/// The metric names a rubric may use for `exercise`.
pub fn exercise_metrics(exercise: Exercise) -> &'static [&'static str] {
    match exercise {
        Exercise::Puncture => PUNCTURE_METRICS,
        Exercise::Palpation => PALPATION_METRICS,
        Exercise::UltrasoundSurvey => ULTRASOUND_METRICS,
    }
}

/// The value of a rubric metric (absent guided or distance metrics count as 0: nothing to judge).
pub fn metric_value(m: &Metrics, name: &str) -> Option<f64> {
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    Some(match name {
        "attempts" => m.attempts as f64,
        "redirections" => m.redirections as f64,
        "risk_hits" => m.risk_hits.len() as f64,
        "risk_time_s" => m.risk_hits.iter().map(|h| h.duration_s).sum(),
        "bone_contacts" => m.bone_contacts as f64,
        "target_not_reached" => flag(!m.target_reached),
        "target_not_confirmed" => flag(!m.target_confirmed),
        "extravasated_ml" => m.extravasated_ml,
        "time_total_s" => m.time_total_s,
        "fluoro_time_s" => m.fluoro_time_s,
        "xray_shots" => m.xray_shots as f64,
        "dose_area_product_gy_cm2" => m.dose_area_product_gy_cm2,
        "max_force_n" => m.max_force_n,
        "tissue_damage_mm2" => m.tissue_damage_mm2,
        "path_inefficiency" => m.path_inefficiency.unwrap_or(0.0),
        "target_distance_mm" => m.target_distance_mm.unwrap_or(0.0),
        "missing_palpation" => flag(!m.workflow.palpation_before_puncture),
        "missing_ultrasound" => flag(!m.workflow.ultrasound_before_puncture),
        "missing_target_scan" => flag(!m.workflow.target_scanned_before_puncture),
        "guided_entry_distance_mm" => m.guided.as_ref().map_or(0.0, |g| g.entry_distance_mm),
        "guided_angle_error_deg" => m.guided.as_ref().map_or(0.0, |g| g.angle_error_deg),
        "guided_mean_deviation_mm" => m.guided.as_ref().map_or(0.0, |g| g.mean_deviation_mm),
        // Palpation (0 when the finger never touched the skin).
        "intercostal_spaces_found" => m.palpation.as_ref().map_or(0.0, |p| p.spaces_found as f64),
        "intercostal_spaces_missed" => m
            .palpation
            .as_ref()
            .map_or(0.0, |p| p.spaces_crossed.saturating_sub(p.spaces_found) as f64),
        "palpation_coverage" => m.palpation.as_ref().map_or(0.0, |p| p.coverage),
        "palpation_time_s" => m.palpation_time_s,
        // Ultrasound survey (a target never shown takes the whole session to its first view).
        "target_not_scanned" => flag(!m.ultrasound.as_ref().is_some_and(|u| u.target_scanned)),
        "time_to_target_view_s" => m
            .ultrasound
            .as_ref()
            .and_then(|u| u.time_to_target_view_s)
            .unwrap_or(m.time_total_s),
        "good_contact_time_s" => m.ultrasound.as_ref().map_or(0.0, |u| u.good_contact_time_s),
        "poor_contact_share" => m.ultrasound.as_ref().map_or(1.0, |u| {
            if m.ultrasound_time_s > 0.0 {
                (1.0 - u.good_contact_time_s / m.ultrasound_time_s).clamp(0.0, 1.0)
            } else {
                1.0
            }
        }),
        _ => return None,
    })
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
    pub difficulty: String,
    /// The level's pass mark (absent in grades stored before it was kept).
    #[serde(default)]
    pub pass_score: Option<f64>,
    pub rubric: String,
    pub rubric_version: u32,
    pub physics_version: u32,
    /// Requirements not met, in words (from the table of `reasons`).
    pub failed: Vec<String>,
    /// The same requirements, as numbers.
    #[serde(default)]
    pub unmet: Vec<Unmet>,
    pub deductions: Vec<Applied>,
}

/// Checks the levels of one exercise: all three present, pass marks in 0…100, known metrics,
/// finite numbers, no negative points. `at` names the table in messages.
fn check_levels(levels: &BTreeMap<String, Level>, exercise: Exercise, at: &str) -> Result<(), String> {
    let finite = |v: f64, what: &str| {
        if v.is_finite() {
            Ok(())
        } else {
            Err(format!("{what} is not a finite number"))
        }
    };
    let allowed = exercise_metrics(exercise);
    for level in LEVELS {
        if !levels.contains_key(level) {
            if exercise == Exercise::Puncture {
                return Err(format!("the rubric lacks level '{level}'"));
            }
            return Err(format!("{at}: the rubric lacks level '{level}'"));
        }
    }
    for (name, l) in levels {
        let name = if exercise == Exercise::Puncture {
            name.clone()
        } else {
            format!("{}.{name}", exercise.as_str())
        };
        let bare = name.rsplit('.').next().unwrap_or(&name);
        if !LEVELS.contains(&bare) {
            return Err(format!("unknown level '{bare}' (levels: {})", LEVELS.join(", ")));
        }
        if !(0.0..=100.0).contains(&l.pass_score) {
            return Err(format!("levels.{name}.pass_score must lie in 0…100"));
        }
        let known = |m: &str| {
            if allowed.contains(&m) {
                Ok(())
            } else {
                Err(format!(
                    "levels.{name}: unknown metric '{m}' for the {} exercise (known: {})",
                    exercise.label(),
                    allowed.join(", ")
                ))
            }
        };
        for q in &l.require {
            known(&q.metric)?;
            if q.min.is_none() && q.max.is_none() {
                return Err(format!(
                    "levels.{name}: requirement on '{}' has neither min nor max",
                    q.metric
                ));
            }
            for v in q.min.iter().chain(&q.max) {
                finite(*v, &format!("levels.{name}: requirement on '{}'", q.metric))?;
            }
        }
        for d in &l.deduct {
            known(&d.metric)?;
            for v in [d.free, d.points].iter().chain(&d.max_points) {
                finite(*v, &format!("levels.{name}: deduction on '{}'", d.metric))?;
            }
            if d.points < 0.0 {
                return Err(format!(
                    "levels.{name}: deduction on '{}' has negative points",
                    d.metric
                ));
            }
        }
    }
    Ok(())
}

impl Rubric {
    /// Parses and checks a rubric; the error names the problem.
    pub fn parse(text: &str) -> Result<Rubric, String> {
        let r: Rubric = toml::from_str(text).map_err(|e| e.to_string())?;
        if r.version == 0 {
            return Err("rubric version must be 1 or more".into());
        }
        let finite = |v: f64, what: &str| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(format!("{what} is not a finite number"))
            }
        };
        finite(r.metrics.redirection_mm, "metrics.redirection_mm")?;
        finite(r.metrics.readvance_mm, "metrics.readvance_mm")?;
        if r.metrics.redirection_mm <= 0.0 || r.metrics.readvance_mm <= 0.0 {
            return Err("metrics.redirection_mm and readvance_mm must be positive".into());
        }
        check_levels(&r.levels, Exercise::Puncture, "levels")?;
        for (exercise, e) in &r.exercises {
            if *exercise == Exercise::Puncture {
                return Err("the puncture's levels are the top-level [levels], not [exercises.puncture]".into());
            }
            check_levels(&e.levels, *exercise, &format!("exercises.{}.levels", exercise.as_str()))?;
        }
        Ok(r)
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
    pub fn levels_for(&self, exercise: Exercise) -> Option<&BTreeMap<String, Level>> {
        match exercise {
            Exercise::Puncture => Some(&self.levels),
            other => self.exercises.get(&other).map(|e| &e.levels),
        }
    }

    /// The level `difficulty` of `exercise`, if this rubric has it.
    pub fn level(&self, exercise: Exercise, difficulty: &str) -> Option<&Level> {
        self.levels_for(exercise)?.get(difficulty)
    }

    /// Whether this rubric grades `exercise` at `difficulty` (checked before a replay is spent
    /// on it).
    pub fn grade_check(&self, exercise: Exercise, difficulty: &str) -> Result<(), String> {
        let Some(levels) = self.levels_for(exercise) else {
            return Err(format!(
                "rubric {} v{} has no levels for the {} exercise",
                self.name,
                self.version,
                exercise.label()
            ));
        };
        if levels.contains_key(difficulty) {
            Ok(())
        } else {
            Err(format!(
                "the session's difficulty '{difficulty}' is not a level of this rubric ({})",
                LEVELS.join(", ")
            ))
        }
    }

    /// Grades `m` as `exercise` at `difficulty`.
    pub fn grade(&self, m: &Metrics, exercise: Exercise, difficulty: &str) -> Result<Grade, String> {
        self.grade_check(exercise, difficulty)?;
        let level = self.level(exercise, difficulty).expect("checked above");
        let value = |name: &str| metric_value(m, name).expect("rubric metrics are checked at parse time");
        let mut failed = Vec::new();
        let mut unmet = Vec::new();
        for q in &level.require {
            let v = value(&q.metric);
            let below = q.min.is_some_and(|min| v < min);
            let above = q.max.is_some_and(|max| v > max);
            if below || above {
                let info = crate::reasons::metric_info(&q.metric).expect("every rubric metric has words (tested)");
                failed.push(info.unmet(v, q.min, q.max));
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
            let mut points = (v - d.free).max(0.0) * d.points;
            if let Some(cap) = d.max_points {
                points = points.min(cap);
            }
            if points > 0.0 {
                deductions.push(Applied {
                    metric: d.metric.clone(),
                    value: v,
                    points,
                    free: Some(d.free),
                });
            }
        }
        let score = (100.0 - deductions.iter().map(|d| d.points).sum::<f64>()).clamp(0.0, 100.0);
        // Scores are reported to 0.01 points.
        let score = (score * 100.0).round() / 100.0;
        Ok(Grade {
            score,
            passed: failed.is_empty() && score >= level.pass_score,
            exercise,
            difficulty: difficulty.to_string(),
            pass_score: Some(level.pass_score),
            rubric: self.name.clone(),
            rubric_version: self.version,
            physics_version: stylet_physics::PHYSICS_VERSION,
            failed,
            unmet,
            deductions,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::{Metrics, Workflow};

    fn metrics() -> Metrics {
        Metrics {
            attempts: 2,
            redirections: 3,
            redirection_times_s: vec![4.0, 9.0, 15.0],
            risk_hits: Vec::new(),
            bone_contacts: 0,
            target_reached: true,
            target_confirmed: true,
            stylet_removed_in_target: true,
            contrast_in_target: true,
            contrast_in_ducts_ml: 2.0,
            extravasated_ml: 0.0,
            contrast_extent_mm: 30.0,
            time_to_target_s: Some(20.0),
            time_total_s: 60.0,
            fluoro_time_s: 40.0,
            xray_shots: 2,
            dose_area_product_gy_cm2: 1.7,
            ultrasound_time_s: 10.0,
            needle_in_plane_share: None,
            palpation_time_s: 0.0,
            path_length_mm: 100.0,
            path_inefficiency: Some(1.1),
            max_force_n: 3.0,
            rms_force_n: 1.0,
            max_bending_mm: 1.0,
            tissue_damage_mm2: 0.0,
            workflow: Workflow {
                palpation_before_puncture: false,
                ultrasound_before_puncture: true,
                target_scanned_before_puncture: true,
                confirmed_before_withdrawal: true,
            },
            target_distance_mm: Some(0.0),
            target_distance_min_mm: Some(0.0),
            guided: None,
            palpation: None,
            ultrasound: None,
        }
    }

    /// The worked example of docs/metrics.md "Rubrics".
    #[test]
    fn the_shipped_rubric_grades_the_worked_example() {
        let r = Rubric::default_rubric();
        assert_eq!((r.name.as_str(), r.version), ("ptcd", 3));
        let g = r.grade(&metrics(), Exercise::Puncture, "beginner").unwrap();
        // attempts 2 (1 free) −10, redirections 3 (2 free) −3, fluoro 40 s (30 free) −5,
        // no palpation first −5: 100 − 23.
        assert_eq!(g.score, 77.0, "{:?}", g.deductions);
        assert!(g.passed && g.failed.is_empty());
        let g = r.grade(&metrics(), Exercise::Puncture, "expert").unwrap();
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
        assert!(
            r.grade(&metrics(), Exercise::Puncture, "wizard")
                .unwrap_err()
                .contains("'wizard'")
        );
    }

    #[test]
    fn bad_rubrics_are_named() {
        let base = DEFAULT_RUBRIC;
        let cases = [
            (base.replace("version = 3", "version = 0"), "version"),
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
            ("name = ".to_string(), "line 1"),
        ];
        for (text, want) in cases {
            let e = Rubric::parse(&text).unwrap_err();
            assert!(e.contains(want), "expected '{want}' in: {e}");
        }
    }
}
