//! The expert benchmark of a scenario (docs/metrics.md "Expert benchmark"): for every rubric
//! metric of its exercise, the mean and the spread of the sessions instructors marked as expert
//! references. As in proficiency-based training, the expert mean is the proficiency level a
//! trainee works toward; the spread says how far from it experts themselves lie.
//!
//! mean = Σ vᵢ / n, spread = √(Σ (vᵢ − mean)² / (n − 1)) (the sample standard deviation; 0 for a
//! single expert). The sums run over the experts in the order of their session ids, so the same
//! references give bit-identical figures whatever order they come in.

use serde::{Deserialize, Serialize};
use stylet_atlas::Exercise;

use crate::metrics::Metrics;
use crate::rubric_metrics::{HIGHER_IS_BETTER, exercise_metrics, metric_value};

/// The most expert references a scenario may have: a benchmark is computed from their stored
/// reports whenever a session of the scenario is scored, so their number is bounded.
pub const MAX_EXPERTS: usize = 50;

/// One metric's expert figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricBenchmark {
    pub metric: String,
    pub mean: f64,
    /// Sample standard deviation over the experts (0 with one expert).
    pub spread: f64,
}

/// The benchmark of one scenario: the expert sessions it comes from and the figures per metric.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Benchmark {
    pub scenario: String,
    pub exercise: Exercise,
    /// The expert sessions (ids), sorted.
    pub experts: Vec<String>,
    /// One entry per rubric metric of the exercise, in the rubric's metric order.
    pub metrics: Vec<MetricBenchmark>,
}

/// A trainee's value of one metric beside the expert figures.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    pub metric: String,
    pub value: f64,
    pub mean: f64,
    pub spread: f64,
}

impl Comparison {
    /// How many expert spreads the value lies above (+) or below (−) the expert mean; `None`
    /// when the experts all had the same value (no spread to measure by; a spread below a
    /// millionth of the mean is rounding, not disagreement).
    pub fn spreads_from_mean(&self) -> Option<f64> {
        (self.spread > 1e-6 * self.mean.abs().max(1.0)).then(|| (self.value - self.mean) / self.spread)
    }
}

impl Benchmark {
    /// The benchmark of `scenario` from its expert sessions (`(session id, metrics)`; any order).
    pub fn from_sessions(scenario: &str, exercise: Exercise, sessions: &[(String, &Metrics)]) -> Benchmark {
        let mut sorted: Vec<&(String, &Metrics)> = sessions.iter().collect();
        sorted.sort_by(|a, b| a.0.cmp(&b.0));
        let metrics = exercise_metrics(exercise)
            .iter()
            .filter_map(|name| {
                let values: Vec<f64> = sorted.iter().filter_map(|(_, m)| metric_value(m, name)).collect();
                let (mean, spread) = mean_and_spread(&values)?;
                Some(MetricBenchmark {
                    metric: name.to_string(),
                    mean,
                    spread,
                })
            })
            .collect();
        Benchmark {
            scenario: scenario.to_string(),
            exercise,
            experts: sorted.iter().map(|(id, _)| id.clone()).collect(),
            metrics,
        }
    }

    /// The figures of `metric`, if the benchmark has them.
    pub fn figure(&self, metric: &str) -> Option<&MetricBenchmark> {
        self.metrics.iter().find(|f| f.metric == metric)
    }

    /// The trainee's `m` beside every metric of the benchmark.
    pub fn compare(&self, m: &Metrics) -> Vec<Comparison> {
        self.metrics
            .iter()
            .filter_map(|f| {
                Some(Comparison {
                    metric: f.metric.clone(),
                    value: metric_value(m, &f.metric)?,
                    mean: f.mean,
                    spread: f.spread,
                })
            })
            .collect()
    }
}

/// One metric's part of a [`SkillEstimate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricZ {
    pub metric: String,
    /// Spreads from the expert mean, + when worse than it (a metric where more is better has
    /// its sign turned).
    pub z: f64,
}

/// An overall skill estimate against the experts (docs/metrics.md "Skill estimate"): PerkTutor's
/// linear combination (its `SkillAssessment` module, method `LinearCombination`: z-score
/// scaling, mean aggregation, every weight 1) over the metrics the experts differ on. 0 is the
/// experts' mean; +1 one expert spread worse on average. Beside the rubric grade, never instead
/// of it: the rubric passes or fails a session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SkillEstimate {
    /// Expert references the benchmark came from.
    pub experts: u32,
    /// z̄ = Σ zₘ / M over the metrics below.
    pub z_mean: f64,
    /// The metrics combined, in the rubric's order: those with an expert spread.
    pub metrics: Vec<MetricZ>,
}

impl Benchmark {
    /// The skill estimate of `m` against this benchmark; `None` below two experts (no spread)
    /// or when the experts agree on every metric.
    pub fn skill_estimate(&self, m: &Metrics) -> Option<SkillEstimate> {
        if self.experts.len() < 2 {
            return None;
        }
        let metrics: Vec<MetricZ> = self
            .compare(m)
            .iter()
            .filter_map(|c| {
                let z = c.spreads_from_mean()?;
                let worse = if HIGHER_IS_BETTER.contains(&c.metric.as_str()) {
                    -z
                } else {
                    z
                };
                Some(MetricZ {
                    metric: c.metric.clone(),
                    z: worse,
                })
            })
            .collect();
        if metrics.is_empty() {
            return None;
        }
        let z_mean = metrics.iter().map(|z| z.z).sum::<f64>() / metrics.len() as f64;
        Some(SkillEstimate {
            experts: self.experts.len() as u32,
            z_mean,
            metrics,
        })
    }
}

/// Mean and sample standard deviation (two passes, in the order given); `None` for no values.
pub fn mean_and_spread(values: &[f64]) -> Option<(f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let spread = if values.len() < 2 {
        0.0
    } else {
        (values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0)).sqrt()
    };
    Some((mean, spread))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::tests_support::metrics_with;

    #[test]
    fn mean_and_spread_of_known_values() {
        assert_eq!(mean_and_spread(&[]), None);
        assert_eq!(mean_and_spread(&[7.0]), Some((7.0, 0.0)));
        // 2, 4, 4, 4, 5, 5, 7, 9: mean 5, Σ(v − 5)² = 32, sample variance 32/7.
        let (mean, spread) = mean_and_spread(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]).unwrap();
        assert_eq!(mean, 5.0);
        assert!((spread - (32.0f64 / 7.0).sqrt()).abs() < 1e-12, "{spread}");
    }

    #[test]
    fn the_benchmark_of_three_experts() {
        let a = metrics_with(|m| {
            m.time_total_s = 100.0;
            m.attempts = 1;
            m.fluoro_time_s = 10.0;
        });
        let b = metrics_with(|m| {
            m.time_total_s = 120.0;
            m.attempts = 1;
            m.fluoro_time_s = 20.0;
        });
        let c = metrics_with(|m| {
            m.time_total_s = 140.0;
            m.attempts = 2;
            m.fluoro_time_s = 30.0;
        });
        let sessions = vec![("c".to_string(), &c), ("a".to_string(), &a), ("b".to_string(), &b)];
        let bench = Benchmark::from_sessions("right-duct", Exercise::Puncture, &sessions);
        assert_eq!(bench.experts, ["a", "b", "c"]);
        let time = bench.figure("time_total_s").unwrap();
        assert_eq!((time.mean, time.spread), (120.0, 20.0));
        let fluoro = bench.figure("fluoro_time_s").unwrap();
        assert_eq!((fluoro.mean, fluoro.spread), (20.0, 10.0));
        let attempts = bench.figure("attempts").unwrap();
        assert!((attempts.mean - 4.0 / 3.0).abs() < 1e-12);
        assert!((attempts.spread - (1.0f64 / 3.0).sqrt()).abs() < 1e-12);
        // Every puncture metric has figures, in the rubric's order.
        let names: Vec<&str> = bench.metrics.iter().map(|f| f.metric.as_str()).collect();
        assert_eq!(names, exercise_metrics(Exercise::Puncture));
        // The order the sessions come in does not change a bit.
        let reversed: Vec<_> = sessions.iter().rev().cloned().collect();
        assert_eq!(
            Benchmark::from_sessions("right-duct", Exercise::Puncture, &reversed),
            bench
        );

        let trainee = metrics_with(|m| m.time_total_s = 180.0);
        let cmp = bench.compare(&trainee);
        let t = cmp.iter().find(|c| c.metric == "time_total_s").unwrap();
        assert_eq!((t.value, t.mean, t.spread), (180.0, 120.0, 20.0));
        assert_eq!(t.spreads_from_mean(), Some(3.0));
        let risk = cmp.iter().find(|c| c.metric == "risk_hits").unwrap();
        assert_eq!(risk.spreads_from_mean(), None, "every expert hit nothing");

        // The skill estimate: the metrics the experts differ on are time (mean 120, spread
        // 20), fluoroscopy (20, 10) and attempts (4/3, √(1/3)). The trainee: 180 s (+3),
        // 40 s of fluoroscopy (+2), 2 attempts ((2 − 4/3)/√(1/3) = +1.1547): mean +2.0516.
        let trainee = metrics_with(|m| {
            m.time_total_s = 180.0;
            m.fluoro_time_s = 40.0;
            m.attempts = 2;
        });
        let skill = bench.skill_estimate(&trainee).unwrap();
        let names: Vec<&str> = skill.metrics.iter().map(|z| z.metric.as_str()).collect();
        assert_eq!(names, ["attempts", "time_total_s", "fluoro_time_s"]);
        let attempts_z = (2.0 - 4.0 / 3.0) / (1.0f64 / 3.0).sqrt();
        assert!(
            (skill.z_mean - (3.0 + 2.0 + attempts_z) / 3.0).abs() < 1e-12,
            "{skill:?}"
        );
        assert_eq!(skill.experts, 3);
        // An expert's own metrics lie about 0; one expert alone gives no estimate.
        let own = bench.skill_estimate(&b).unwrap();
        assert!(own.z_mean.abs() < 1.0, "{own:?}");
        let alone = Benchmark::from_sessions("right-duct", Exercise::Puncture, &sessions[..1]);
        assert_eq!(alone.skill_estimate(&trainee), None);
    }

    #[test]
    fn more_is_better_metrics_count_with_their_sign_turned() {
        let with = |found: u32| {
            metrics_with(|m| {
                m.palpation = Some(crate::metrics::PalpationMetrics {
                    spaces_crossed: 4,
                    spaces_found: found,
                    coverage: found as f64 / 4.0,
                    ribs_crossed: 5,
                });
            })
        };
        let (a, b, c) = (with(2), with(3), with(4));
        let sessions = vec![("a".to_string(), &a), ("b".to_string(), &b), ("c".to_string(), &c)];
        let bench = Benchmark::from_sessions("sweep", Exercise::Palpation, &sessions);
        // Finding 1 space of 4 is worse than the experts: + on both "more is better" metrics and
        // on the missed spaces.
        let skill = bench.skill_estimate(&with(1)).unwrap();
        for z in &skill.metrics {
            assert!(z.z > 0.0, "{z:?}");
        }
    }
}
