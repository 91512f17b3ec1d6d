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
use crate::rubric_metrics::{exercise_metrics, metric_value};

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
    }
}
