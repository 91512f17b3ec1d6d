//! A measured breathing signal (docs/breathing.md "Measured motion"): the surrogate recorded
//! with a 4D CT (a belt's stretch, a marker's height) as g at sample times, linear between
//! them and repeated after the last sample, to drive the surrogate model u = a₁g + a₂g′ + a₃
//! (thesis eqs. 5.3.4–5.3.6) with measured fields.

/// Most samples a signal may have (a day at 10 Hz).
pub const MAX_SAMPLES: usize = 1_000_000;
/// The largest |g| accepted: g is 0 at end-expiration and about 1 at an average end-inspiration.
pub const MAX_ABS_G: f64 = 10.0;

/// Why samples do not make a [`SampledSignal`] (`sample` counts from 1); the importer adds which
/// file and line they came from.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SampledSignalError {
    #[error("{times} times for {values} values of g")]
    Lengths { times: usize, values: usize },
    #[error("{0} samples: a breathing signal needs 2 … {max}", max = MAX_SAMPLES)]
    SampleCount(usize),
    /// A time that is negative or not finite.
    #[error("sample {sample}: time {time_s} s must be finite and ≥ 0")]
    Time { sample: usize, time_s: f64 },
    /// A time not after the one before it.
    #[error("sample {sample}: time {time_s} s does not follow {previous_s} s")]
    NotIncreasing {
        sample: usize,
        time_s: f64,
        previous_s: f64,
    },
    /// A value of g that is not finite or beyond ±[`MAX_ABS_G`].
    #[error("sample {sample}: g = {g} must be finite within ±{}", MAX_ABS_G)]
    Value { sample: usize, g: f64 },
}

/// g(t) from samples.
#[derive(Debug, Clone, PartialEq)]
pub struct SampledSignal {
    times_s: Vec<f64>,
    g: Vec<f64>,
    max_g: f64,
    max_rate: f64,
}

impl SampledSignal {
    /// At least two samples, times finite and strictly increasing from t ≥ 0, g finite within
    /// ±[`MAX_ABS_G`]; the message names the first bad row (1-based).
    pub fn new(times_s: Vec<f64>, g: Vec<f64>) -> Result<SampledSignal, SampledSignalError> {
        if times_s.len() != g.len() {
            return Err(SampledSignalError::Lengths {
                times: times_s.len(),
                values: g.len(),
            });
        }
        if !(2..=MAX_SAMPLES).contains(&times_s.len()) {
            return Err(SampledSignalError::SampleCount(times_s.len()));
        }
        for (k, (&t, &v)) in times_s.iter().zip(&g).enumerate() {
            if !(t.is_finite() && t >= 0.0) {
                return Err(SampledSignalError::Time {
                    sample: k + 1,
                    time_s: t,
                });
            }
            if k > 0 && t <= times_s[k - 1] {
                return Err(SampledSignalError::NotIncreasing {
                    sample: k + 1,
                    time_s: t,
                    previous_s: times_s[k - 1],
                });
            }
            if !(v.is_finite() && v.abs() <= MAX_ABS_G) {
                return Err(SampledSignalError::Value { sample: k + 1, g: v });
            }
        }
        let max_g = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let max_rate = times_s
            .windows(2)
            .zip(g.windows(2))
            .map(|(t, v)| ((v[1] - v[0]) / (t[1] - t[0])).abs())
            .fold(0.0, f64::max);
        Ok(SampledSignal {
            times_s,
            g,
            max_g,
            max_rate,
        })
    }

    /// The recording's length (s): the signal repeats with this period.
    pub fn period_s(&self) -> f64 {
        self.times_s[self.times_s.len() - 1] - self.times_s[0]
    }

    /// The segment holding `t_s` (folded into the recording) and the fraction along it.
    fn locate(&self, t_s: f64) -> (usize, f64) {
        let t0 = self.times_s[0];
        let t = if t_s.is_finite() {
            t0 + (t_s - t0).rem_euclid(self.period_s())
        } else {
            t0
        };
        let k = self
            .times_s
            .partition_point(|&s| s <= t)
            .clamp(1, self.times_s.len() - 1)
            - 1;
        let (a, b) = (self.times_s[k], self.times_s[k + 1]);
        (k, ((t - a) / (b - a)).clamp(0.0, 1.0))
    }

    pub fn g(&self, t_s: f64) -> f64 {
        let (k, f) = self.locate(t_s);
        self.g[k] + (self.g[k + 1] - self.g[k]) * f
    }

    /// g and its rate g′ (the segment's slope, per s).
    pub fn g_and_rate(&self, t_s: f64) -> (f64, f64) {
        let (k, f) = self.locate(t_s);
        let dg = self.g[k + 1] - self.g[k];
        (self.g[k] + dg * f, dg / (self.times_s[k + 1] - self.times_s[k]))
    }

    pub fn max_g(&self) -> f64 {
        self.max_g
    }

    pub fn max_rate(&self) -> f64 {
        self.max_rate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_joined_linearly_and_repeat_and_bad_ones_are_named() {
        let s = SampledSignal::new(vec![0.0, 1.0, 3.0, 4.0], vec![0.0, 1.0, 0.5, 0.0]).unwrap();
        assert_eq!(s.period_s(), 4.0);
        for (t, g) in [
            (0.0, 0.0),
            (0.5, 0.5),
            (2.0, 0.75),
            (3.5, 0.25),
            (4.5, 0.5),
            (-3.5, 0.5),
        ] {
            assert!((s.g(t) - g).abs() < 1e-12, "g({t}) = {}", s.g(t));
        }
        assert_eq!(s.g_and_rate(2.0), (0.75, -0.25));
        assert_eq!((s.max_g(), s.max_rate()), (1.0, 1.0));
        let e = SampledSignal::new(vec![0.0, 1.0, 1.0], vec![0.0; 3])
            .unwrap_err()
            .to_string();
        assert!(e.contains("sample 3") && e.contains("does not follow"), "{e}");
        let e = SampledSignal::new(vec![0.0, 1.0], vec![0.0, f64::NAN])
            .unwrap_err()
            .to_string();
        assert!(e.contains("sample 2"), "{e}");
        assert!(SampledSignal::new(vec![0.0], vec![0.0]).is_err());
        assert!(SampledSignal::new(vec![-1.0, 1.0], vec![0.0, 0.0]).is_err());
    }
}
