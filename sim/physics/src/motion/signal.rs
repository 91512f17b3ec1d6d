//! The breathing signal g(t) that drives a motion model (thesis §5.3; docs/breathing.md).
//!
//! Each breathing cycle k lasts T_k and reaches a depth a_k, both drawn once from a seeded
//! generator (the thesis re-draws the period of the sawtooth τ = f(t) after every cycle, eq.
//! 5.3.1), so no two cycles are alike and a replay with the same seed meets the same ones. Within
//! a cycle the phase φ = (t − t_k)/T_k runs from 0 to 1 and the signal is Lujan's waveform
//! (Lujan et al. 1999), shifted so a cycle starts and ends at end-expiration:
//!
//!   g(t) = a_k · sin²ⁿ(π φ),  g′(t) = a_k · 2n sin²ⁿ⁻¹(π φ) cos(π φ) · π / T_k,
//!
//! 0 at end-expiration, a_k at end-inspiration (φ = ½); the larger n, the longer the pause at
//! end-expiration. Sines come from `libm`, so the bits are the same on every platform.

use std::sync::Arc;

use crate::SettingsError;

/// Cycles drawn ahead; past them the sequence repeats (9 hours at 4 s a cycle).
pub const CYCLES: usize = 8192;

/// What shapes the signal (part of the world model in the session header).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignalParams {
    /// Mean cycle length T (s).
    pub period_s: f64,
    /// Each cycle's length is T·(1 + j·r), r uniform in [−1, 1].
    pub period_jitter: f64,
    /// Each cycle's depth is 1 + j·r, r uniform in [−1, 1] (a deep breath goes beyond the
    /// displacement of an average end-inspiration).
    pub depth_jitter: f64,
    /// The power n of sin²ⁿ.
    pub power: u32,
    pub seed: u64,
}

impl Default for SignalParams {
    fn default() -> Self {
        SignalParams {
            period_s: 4.0,
            period_jitter: 0.15,
            depth_jitter: 0.1,
            power: 2,
            seed: 1,
        }
    }
}

impl SignalParams {
    /// Refuses what would make no sense or no breathing: the ranges are in docs/breathing.md.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let bad = |setting: &'static str, reason: String| Err(SettingsError::Breathing { setting, reason });
        if !(self.period_s.is_finite() && (1.0..=20.0).contains(&self.period_s)) {
            return bad(
                "period_s",
                format!("breathing period {} s must be 1 … 20 s", self.period_s),
            );
        }
        if !(self.period_jitter.is_finite() && (0.0..=0.5).contains(&self.period_jitter)) {
            return bad(
                "period_jitter",
                format!("period jitter {} must be 0 … 0.5", self.period_jitter),
            );
        }
        if !(self.depth_jitter.is_finite() && (0.0..=0.5).contains(&self.depth_jitter)) {
            return bad(
                "depth_jitter",
                format!("depth jitter {} must be 0 … 0.5", self.depth_jitter),
            );
        }
        if !(1..=5).contains(&self.power) {
            return bad("power", format!("waveform power n = {} must be 1 … 5", self.power));
        }
        Ok(())
    }
}

/// One breathing cycle: its start (s from the session's start), length and depth.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Cycle {
    start_s: f64,
    period_s: f64,
    depth: f64,
}

/// Where in its cycle a moment falls.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Phase {
    /// Index of the cycle (counting from 0 at t = 0, the repeats included).
    pub cycle: u64,
    /// Normalised time within the cycle, 0 … 1 (the thesis' τ).
    pub tau: f64,
    /// The cycle's length (s) and depth.
    pub period_s: f64,
    pub depth: f64,
}

/// g(t) and g′(t) over a session (the cycles are drawn once, at construction).
#[derive(Debug, Clone)]
pub struct BreathingSignal {
    params: SignalParams,
    cycles: Arc<[Cycle]>,
    /// The length of all drawn cycles together (the repeat period).
    total_s: f64,
}

impl BreathingSignal {
    /// The signal of `params`, refused when a parameter is out of range.
    pub fn new(params: SignalParams) -> Result<BreathingSignal, SettingsError> {
        params.validate()?;
        let mut cycles = Vec::with_capacity(CYCLES);
        let mut start_s = 0.0;
        for k in 0..CYCLES as u64 {
            let period_s = params.period_s * (1.0 + params.period_jitter * symmetric(params.seed, 1, k));
            let depth = 1.0 + params.depth_jitter * symmetric(params.seed, 2, k);
            cycles.push(Cycle {
                start_s,
                period_s,
                depth,
            });
            start_s += period_s;
        }
        Ok(BreathingSignal {
            params,
            cycles: cycles.into(),
            total_s: start_s,
        })
    }

    pub fn params(&self) -> &SignalParams {
        &self.params
    }

    /// The cycle and normalised time of `t_s` (negative times read as 0).
    pub fn phase(&self, t_s: f64) -> Phase {
        let t = if t_s.is_finite() { t_s.max(0.0) } else { 0.0 };
        let repeat = (t / self.total_s).floor();
        let t_in = t - repeat * self.total_s;
        // The last cycle starting at or before t_in (binary search on the starts).
        let k = self.cycles.partition_point(|c| c.start_s <= t_in).saturating_sub(1);
        let c = self.cycles[k];
        let tau = ((t_in - c.start_s) / c.period_s).clamp(0.0, 1.0);
        Phase {
            cycle: repeat as u64 * CYCLES as u64 + k as u64,
            tau,
            period_s: c.period_s,
            depth: c.depth,
        }
    }

    /// The largest g can be: the deepest drawn cycle's depth.
    pub fn max_g(&self) -> f64 {
        1.0 + self.params.depth_jitter
    }

    /// A bound on |g′(t)| (1/s): depth · 2n · π / (shortest period), as sin, cos ≤ 1.
    pub fn max_rate(&self) -> f64 {
        let shortest_s = self.params.period_s * (1.0 - self.params.period_jitter);
        self.max_g() * 2.0 * self.params.power as f64 * std::f64::consts::PI / shortest_s
    }

    /// g(t): 0 at end-expiration, the cycle's depth (about 1) at end-inspiration.
    pub fn g(&self, t_s: f64) -> f64 {
        let p = self.phase(t_s);
        p.depth * libm::pow(libm::sin(std::f64::consts::PI * p.tau), 2.0 * self.params.power as f64)
    }

    /// g(t) and its time derivative g′(t) (1/s).
    pub fn g_and_rate(&self, t_s: f64) -> (f64, f64) {
        let p = self.phase(t_s);
        let n = self.params.power as f64;
        let (s, c) = (
            libm::sin(std::f64::consts::PI * p.tau),
            libm::cos(std::f64::consts::PI * p.tau),
        );
        let g = p.depth * libm::pow(s, 2.0 * n);
        let rate = p.depth * 2.0 * n * libm::pow(s, 2.0 * n - 1.0) * c * std::f64::consts::PI / p.period_s;
        (g, rate)
    }
}

/// A uniform number in [−1, 1) for (seed, stream, index): SplitMix64 mixing, no floating point
/// beyond one exact conversion, so it is the same on every platform.
fn symmetric(seed: u64, stream: u64, index: u64) -> f64 {
    let h = mix64(seed ^ mix64(stream.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ mix64(index)));
    (h >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0
}

/// SplitMix64's output function (Steele, Lea & Flood 2014).
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn signal(seed: u64) -> BreathingSignal {
        BreathingSignal::new(SignalParams {
            seed,
            ..Default::default()
        })
        .unwrap()
    }

    #[test]
    fn cycles_start_and_end_at_end_expiration_and_peak_at_the_cycles_depth() {
        let s = signal(7);
        assert_eq!(s.g(0.0), 0.0);
        for k in [0usize, 1, 5, 100] {
            let c = s.cycles[k];
            assert!(s.g(c.start_s).abs() < 1e-12, "cycle {k} starts at end-expiration");
            let peak = s.g(c.start_s + 0.5 * c.period_s);
            assert!(
                (peak - c.depth).abs() < 1e-12,
                "cycle {k}: peak {peak} vs depth {}",
                c.depth
            );
            // Within the drawn ranges.
            assert!((c.period_s - 4.0).abs() <= 0.6 + 1e-12 && (c.depth - 1.0).abs() <= 0.1 + 1e-12);
        }
    }

    #[test]
    fn the_same_seed_gives_the_same_bits_and_another_seed_other_cycles() {
        let (a, b, c) = (signal(7), signal(7), signal(8));
        let ts: Vec<f64> = (0..2000).map(|i| i as f64 * 0.137).collect();
        assert!(ts.iter().all(|&t| a.g(t).to_bits() == b.g(t).to_bits()));
        assert!(ts.iter().any(|&t| a.g(t) != c.g(t)));
        // Cycles differ from each other (the period is re-drawn every cycle).
        let periods: Vec<f64> = a.cycles[..20].iter().map(|c| c.period_s).collect();
        assert!(periods.windows(2).all(|w| w[0] != w[1]));
    }

    #[test]
    fn the_rate_is_the_derivative_of_the_signal() {
        let s = signal(3);
        let h = 1e-6;
        for i in 1..400 {
            let t = i as f64 * 0.0731;
            let (_, rate) = s.g_and_rate(t);
            let numeric = (s.g(t + h) - s.g(t - h)) / (2.0 * h);
            assert!(
                (rate - numeric).abs() < 1e-4 * (1.0 + rate.abs()),
                "t {t}: {rate} vs {numeric}"
            );
        }
    }

    #[test]
    fn the_sequence_repeats_after_the_drawn_cycles_and_bad_params_are_refused() {
        let s = signal(5);
        let t = 1.234;
        assert!((s.g(t + s.total_s) - s.g(t)).abs() < 1e-9);
        assert_eq!(s.phase(s.total_s + 0.1).cycle, CYCLES as u64);
        assert_eq!(s.g(-3.0), 0.0);
        assert_eq!(s.g(f64::NAN), 0.0);
        for bad in [
            SignalParams {
                period_s: 0.0,
                ..Default::default()
            },
            SignalParams {
                period_s: f64::NAN,
                ..Default::default()
            },
            SignalParams {
                period_jitter: 0.9,
                ..Default::default()
            },
            SignalParams {
                depth_jitter: -0.1,
                ..Default::default()
            },
            SignalParams {
                power: 0,
                ..Default::default()
            },
        ] {
            assert!(BreathingSignal::new(bad).is_err(), "{bad:?}");
        }
    }
}
