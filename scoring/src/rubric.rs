//! Rubrics (TOML, versioned; `scoring/rubrics/`): requirements and deductions per difficulty
//! level that turn [`Metrics`] into a [`Grade`]. docs/metrics.md "Rubrics" describes the format.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::metrics::{MetricParams, Metrics};

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

/// Metric names a rubric may use, with their meaning (docs/metrics.md).
pub const RUBRIC_METRICS: [&str; 19] = [
    "attempts",
    "redirections",
    "risk_hits",
    "risk_time_s",
    "bone_contacts",
    "target_not_reached",
    "target_not_confirmed",
    "time_total_s",
    "fluoro_time_s",
    "xray_shots",
    "max_force_n",
    "tissue_damage_mm2",
    "path_inefficiency",
    "target_distance_mm",
    "missing_palpation",
    "missing_ultrasound",
    "guided_entry_distance_mm",
    "guided_angle_error_deg",
    "guided_mean_deviation_mm",
];

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
        "time_total_s" => m.time_total_s,
        "fluoro_time_s" => m.fluoro_time_s,
        "xray_shots" => m.xray_shots as f64,
        "max_force_n" => m.max_force_n,
        "tissue_damage_mm2" => m.tissue_damage_mm2,
        "path_inefficiency" => m.path_inefficiency.unwrap_or(0.0),
        "target_distance_mm" => m.target_distance_mm.unwrap_or(0.0),
        "missing_palpation" => flag(!m.workflow.palpation_before_puncture),
        "missing_ultrasound" => flag(!m.workflow.ultrasound_before_puncture),
        "guided_entry_distance_mm" => m.guided.as_ref().map_or(0.0, |g| g.entry_distance_mm),
        "guided_angle_error_deg" => m.guided.as_ref().map_or(0.0, |g| g.angle_error_deg),
        "guided_mean_deviation_mm" => m.guided.as_ref().map_or(0.0, |g| g.mean_deviation_mm),
        _ => return None,
    })
}

/// One deduction applied to a grade.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Applied {
    pub metric: String,
    pub value: f64,
    pub points: f64,
}

/// A grade: what the rubric makes of the metrics at one difficulty.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Grade {
    pub score: f64,
    pub passed: bool,
    pub difficulty: String,
    pub rubric: String,
    pub rubric_version: u32,
    pub physics_version: u32,
    /// Requirements not met, in words.
    pub failed: Vec<String>,
    pub deductions: Vec<Applied>,
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
        for level in LEVELS {
            if !r.levels.contains_key(level) {
                return Err(format!("the rubric lacks level '{level}'"));
            }
        }
        for (name, l) in &r.levels {
            if !LEVELS.contains(&name.as_str()) {
                return Err(format!("unknown level '{name}' (levels: {})", LEVELS.join(", ")));
            }
            if !(0.0..=100.0).contains(&l.pass_score) {
                return Err(format!("levels.{name}.pass_score must lie in 0…100"));
            }
            let known = |m: &str| {
                if RUBRIC_METRICS.contains(&m) {
                    Ok(())
                } else {
                    Err(format!(
                        "levels.{name}: unknown metric '{m}' (known: {})",
                        RUBRIC_METRICS.join(", ")
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

    /// Whether `difficulty` is a level of this rubric (checked before a replay is spent on it).
    pub fn grade_check(&self, difficulty: &str) -> Result<(), String> {
        if self.levels.contains_key(difficulty) {
            Ok(())
        } else {
            Err(format!(
                "the session's difficulty '{difficulty}' is not a level of this rubric ({})",
                LEVELS.join(", ")
            ))
        }
    }

    /// Grades `m` at `difficulty`.
    pub fn grade(&self, m: &Metrics, difficulty: &str) -> Result<Grade, String> {
        self.grade_check(difficulty)?;
        let level = &self.levels[difficulty];
        let value = |name: &str| metric_value(m, name).expect("rubric metrics are checked at parse time");
        let mut failed = Vec::new();
        for q in &level.require {
            let v = value(&q.metric);
            if let Some(min) = q.min.filter(|&min| v < min) {
                failed.push(format!("{} = {v} is below {min}", q.metric));
            }
            if let Some(max) = q.max.filter(|&max| v > max) {
                failed.push(format!("{} = {v} is above {max}", q.metric));
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
                });
            }
        }
        let score = (100.0 - deductions.iter().map(|d| d.points).sum::<f64>()).clamp(0.0, 100.0);
        // Scores are reported to 0.01 points.
        let score = (score * 100.0).round() / 100.0;
        Ok(Grade {
            score,
            passed: failed.is_empty() && score >= level.pass_score,
            difficulty: difficulty.to_string(),
            rubric: self.name.clone(),
            rubric_version: self.version,
            physics_version: stylet_physics::PHYSICS_VERSION,
            failed,
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
            risk_hits: Vec::new(),
            bone_contacts: 0,
            target_reached: true,
            target_confirmed: true,
            stylet_removed_in_target: true,
            contrast_in_target: true,
            time_to_target_s: Some(20.0),
            time_total_s: 60.0,
            fluoro_time_s: 40.0,
            xray_shots: 2,
            ultrasound_time_s: 10.0,
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
                confirmed_before_withdrawal: true,
            },
            target_distance_mm: Some(0.0),
            target_distance_min_mm: Some(0.0),
            guided: None,
        }
    }

    /// The worked example of docs/metrics.md "Rubrics".
    #[test]
    fn the_shipped_rubric_grades_the_worked_example() {
        let r = Rubric::default_rubric();
        assert_eq!((r.name.as_str(), r.version), ("ptcd", 1));
        let g = r.grade(&metrics(), "beginner").unwrap();
        // attempts 2 (1 free) −10, redirections 3 (2 free) −3, fluoro 40 s (30 free) −5,
        // no palpation first −5: 100 − 23.
        assert_eq!(g.score, 77.0, "{:?}", g.deductions);
        assert!(g.passed && g.failed.is_empty());
        let g = r.grade(&metrics(), "expert").unwrap();
        assert!(!g.passed);
        assert!(
            g.failed.iter().any(|f| f.starts_with("attempts = 2 is above 1")),
            "{:?}",
            g.failed
        );
        assert!(
            g.failed.iter().any(|f| f.starts_with("fluoro_time_s = 40 is above 30")),
            "{:?}",
            g.failed
        );
        assert!(r.grade(&metrics(), "wizard").unwrap_err().contains("'wizard'"));
    }

    #[test]
    fn bad_rubrics_are_named() {
        let base = DEFAULT_RUBRIC;
        let cases = [
            (base.replace("version = 1", "version = 0"), "version"),
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
