//! The thesis' three motion models (§5.3), each u(X, t) from displacement fields and the
//! breathing signal ([`BreathingSignal`]).

use std::sync::Arc;

use glam::DVec3;

use super::field::{FactoredField, GridField, SpatialField, WeightedGrids};
use super::sampled::SampledSignal;
use super::signal::BreathingSignal;
use super::{BreathingError, MotionModel};

/// Key frames over one full cycle (thesis §5.3.1): n fields u_j at τ_j = j/n on the cycle's
/// normalised time τ = f(t) (a sawtooth whose period is re-drawn every cycle, eq. 5.3.2), the
/// last followed by the first; between neighbours
///
///   b(X, τ) = (1 − α) u_j(X) + α u_{j+1}(X),  α = (τ − τ_j)/(τ_{j+1} − τ_j)  (eq. 5.3.1).
///
/// Frame 0 is the phase at which a cycle starts (end-expiration for [`BreathingSignal`]).
pub struct FullCycle {
    frames: Vec<Arc<dyn SpatialField>>,
    signal: BreathingSignal,
}

impl FullCycle {
    pub fn new(frames: Vec<Arc<dyn SpatialField>>, signal: BreathingSignal) -> Result<FullCycle, BreathingError> {
        if frames.len() < 2 {
            return Err(BreathingError::FullCycleFrames(frames.len()));
        }
        Ok(FullCycle { frames, signal })
    }
}

impl MotionModel for FullCycle {
    fn max_displacement_mm(&self) -> f64 {
        self.frames.iter().map(|f| f.max_length_mm()).fold(0.0, f64::max)
    }

    fn displacement(&self, x_ref: DVec3, t_s: f64) -> DVec3 {
        let n = self.frames.len();
        let s = self.signal.phase(t_s).tau * n as f64;
        let j = (s as usize).min(n - 1);
        let alpha = s - j as f64;
        let next = (j + 1) % n;
        (1.0 - alpha) * self.frames[j].at(x_ref) + alpha * self.frames[next].at(x_ref)
    }
}

/// Key frames over half a cycle (thesis §5.3.2): m fields from end-expiration (s = 0) to
/// end-inspiration (s = 1) at s_j = j/(m − 1), driven by s = g(t). Within [0, 1] neighbours are
/// interpolated (eq. 5.3.1); beyond (a breath deeper than the recorded end-inspiration, g > 1)
/// the displacement is extrapolated along u_EE → u_EI (eq. 5.3.3):
///
///   b_oos(X, s) = (1 − s) u_EE(X) + s u_EI(X).
///
/// Inspiration and expiration follow the same path (no hysteresis).
pub struct HalfCycle {
    frames: Vec<Arc<dyn SpatialField>>,
    signal: BreathingSignal,
}

impl HalfCycle {
    pub fn new(frames: Vec<Arc<dyn SpatialField>>, signal: BreathingSignal) -> Result<HalfCycle, BreathingError> {
        if frames.len() < 2 {
            return Err(BreathingError::HalfCycleFrames(frames.len()));
        }
        Ok(HalfCycle { frames, signal })
    }
}

impl MotionModel for HalfCycle {
    /// Within [0, 1] a blend of two frames; beyond, |(1 − s) u_EE + s u_EI| with s ≤ max g.
    fn max_displacement_mm(&self) -> f64 {
        let frames = self.frames.iter().map(|f| f.max_length_mm()).fold(0.0, f64::max);
        let s = self.signal.max_g();
        let (ee, ei) = (
            self.frames[0].max_length_mm(),
            self.frames[self.frames.len() - 1].max_length_mm(),
        );
        frames.max((s - 1.0).abs() * ee + s * ei)
    }

    fn displacement(&self, x_ref: DVec3, t_s: f64) -> DVec3 {
        let m = self.frames.len();
        let s = self.signal.g(t_s);
        if !(0.0..=1.0).contains(&s) {
            let (ee, ei) = (&self.frames[0], &self.frames[m - 1]);
            return (1.0 - s) * ee.at(x_ref) + s * ei.at(x_ref);
        }
        let pos = s * (m - 1) as f64;
        let j = (pos as usize).min(m - 2);
        let alpha = pos - j as f64;
        (1.0 - alpha) * self.frames[j].at(x_ref) + alpha * self.frames[j + 1].at(x_ref)
    }
}

/// The surrogate-driven linear model (thesis §5.3.3, eqs. 5.3.4–5.3.6):
///
///   u(X, t) = a₁(X) g(t) + a₂(X) g′(t) + a₃(X),
///
/// g the breathing signal, g′ its rate (which separates inspiration from expiration: hysteresis).
/// a₂ and a₃ may be absent (zero).
pub struct Surrogate {
    pub a1: Arc<dyn SpatialField>,
    pub a2: Option<Arc<dyn SpatialField>>,
    pub a3: Option<Arc<dyn SpatialField>>,
    pub signal: SurrogateSignal,
}

/// What drives a surrogate model: the seeded Lujan waveform, or a measured signal.
#[derive(Debug, Clone)]
pub enum SurrogateSignal {
    Lujan(BreathingSignal),
    Sampled(Arc<SampledSignal>),
}

impl SurrogateSignal {
    pub fn g(&self, t_s: f64) -> f64 {
        match self {
            SurrogateSignal::Lujan(s) => s.g(t_s),
            SurrogateSignal::Sampled(s) => s.g(t_s),
        }
    }

    pub fn g_and_rate(&self, t_s: f64) -> (f64, f64) {
        match self {
            SurrogateSignal::Lujan(s) => s.g_and_rate(t_s),
            SurrogateSignal::Sampled(s) => s.g_and_rate(t_s),
        }
    }

    pub fn max_g(&self) -> f64 {
        match self {
            SurrogateSignal::Lujan(s) => s.max_g(),
            SurrogateSignal::Sampled(s) => s.max_g(),
        }
    }

    pub fn max_rate(&self) -> f64 {
        match self {
            SurrogateSignal::Lujan(s) => s.max_rate(),
            SurrogateSignal::Sampled(s) => s.max_rate(),
        }
    }
}

impl From<BreathingSignal> for SurrogateSignal {
    fn from(s: BreathingSignal) -> SurrogateSignal {
        SurrogateSignal::Lujan(s)
    }
}

impl Surrogate {
    /// g and g′ at `t_s` (g′ only when a₂ needs it).
    fn signal_at(&self, t_s: f64) -> (f64, f64) {
        match self.a2 {
            Some(_) => self.signal.g_and_rate(t_s),
            None => (self.signal.g(t_s), 0.0),
        }
    }

    fn combine(&self, x_ref: DVec3, (g, rate): (f64, f64)) -> DVec3 {
        let mut u = self.a1.at(x_ref) * g;
        if let Some(a2) = &self.a2 {
            u += a2.at(x_ref) * rate;
        }
        if let Some(a3) = &self.a3 {
            u += a3.at(x_ref);
        }
        u
    }
}

impl MotionModel for Surrogate {
    fn displacement(&self, x_ref: DVec3, t_s: f64) -> DVec3 {
        self.combine(x_ref, self.signal_at(t_s))
    }

    fn max_displacement_mm(&self) -> f64 {
        self.a1.max_length_mm() * self.signal.max_g()
            + self
                .a2
                .as_ref()
                .map_or(0.0, |a| a.max_length_mm() * self.signal.max_rate())
            + self.a3.as_ref().map_or(0.0, |a| a.max_length_mm())
    }

    /// The signal once per moment, then three field reads per point.
    fn at_time(&self, t_s: f64) -> Box<dyn Fn(DVec3) -> DVec3 + Send + Sync + '_> {
        let signal = self.signal_at(t_s);
        Box::new(move |x| self.combine(x, signal))
    }

    /// g(t)·a₁ + g′(t)·a₂ + a₃ when every field present is a grid field.
    fn weighted_grids_at(&self, t_s: f64) -> Option<WeightedGrids<'_>> {
        let (g, rate) = self.signal_at(t_s);
        fn term(f: &Option<Arc<dyn SpatialField>>, w: f64) -> Option<Option<(&GridField, f64)>> {
            match f {
                None => Some(None),
                Some(f) => Some(Some((f.as_grid()?, w))),
            }
        }
        Some(WeightedGrids {
            terms: [
                Some((self.a1.as_grid()?, g)),
                term(&self.a2, rate)?,
                term(&self.a3, 1.0)?,
            ],
        })
    }

    /// g(t)·a₁ when a₁ is factored and there is no a₂ or a₃.
    fn factored_at(&self, t_s: f64) -> Option<FactoredField<'_>> {
        if self.a2.is_some() || self.a3.is_some() {
            return None;
        }
        let mut f = self.a1.factored()?;
        f.direction_mm *= self.signal.g(t_s);
        Some(f)
    }
}

#[cfg(test)]
mod tests {
    use super::super::signal::SignalParams;
    use super::*;

    /// A uniform displacement.
    struct Uniform(DVec3);
    impl SpatialField for Uniform {
        fn at(&self, _x: DVec3) -> DVec3 {
            self.0
        }
        fn max_length_mm(&self) -> f64 {
            self.0.length()
        }
    }

    fn uniform(v: DVec3) -> Arc<dyn SpatialField> {
        Arc::new(Uniform(v))
    }

    fn signal() -> BreathingSignal {
        BreathingSignal::new(SignalParams {
            seed: 11,
            ..Default::default()
        })
        .unwrap()
    }

    #[test]
    fn a_full_cycle_interpolates_neighbouring_frames_and_wraps_to_the_first() {
        let s = signal();
        let frames: Vec<_> = (0..4).map(|j| uniform(DVec3::new(j as f64 * 10.0, 0.0, 0.0))).collect();
        let m = FullCycle::new(frames, s.clone()).unwrap();
        for i in 0..500 {
            let t = i as f64 * 0.0371;
            let tau = s.phase(t).tau;
            let u = m.displacement(DVec3::ZERO, t).x;
            // Piecewise linear through 0, 10, 20, 30 and back to 0 over τ ∈ [0, 1).
            let expected = if tau < 0.75 {
                40.0 * tau
            } else {
                30.0 * (1.0 - tau) / 0.25
            };
            assert!((u - expected).abs() < 1e-9, "t {t} τ {tau}: {u} vs {expected}");
        }
        assert!(FullCycle::new(vec![uniform(DVec3::ZERO)], s).is_err());
    }

    #[test]
    fn a_half_cycle_follows_g_and_extrapolates_beyond_end_inspiration() {
        // Deep breaths (depth up to 1.5) go past the recorded end-inspiration.
        let s = BreathingSignal::new(SignalParams {
            depth_jitter: 0.5,
            seed: 2,
            ..Default::default()
        })
        .unwrap();
        let ee = DVec3::new(0.0, 0.0, 0.0);
        let mid = DVec3::new(0.0, 1.0, -5.0);
        let ei = DVec3::new(0.0, 3.0, -12.0);
        let m = HalfCycle::new(vec![uniform(ee), uniform(mid), uniform(ei)], s.clone()).unwrap();
        let mut beyond = 0;
        for i in 0..4000 {
            let t = i as f64 * 0.0113;
            let g = s.g(t);
            let u = m.displacement(DVec3::ZERO, t);
            let expected = if g > 1.0 {
                beyond += 1;
                (1.0 - g) * ee + g * ei
            } else if g <= 0.5 {
                ee + (mid - ee) * (g / 0.5)
            } else {
                mid + (ei - mid) * ((g - 0.5) / 0.5)
            };
            assert!((u - expected).length() < 1e-9, "t {t} g {g}: {u} vs {expected}");
        }
        assert!(beyond > 0, "no breath went beyond end-inspiration");
    }

    #[test]
    fn the_surrogate_model_sums_its_three_terms() {
        let s = signal();
        let (a1, a2, a3) = (
            DVec3::new(0.0, 3.0, -12.0),
            DVec3::new(0.0, 0.5, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
        );
        let m = Surrogate {
            a1: uniform(a1),
            a2: Some(uniform(a2)),
            a3: Some(uniform(a3)),
            signal: s.clone().into(),
        };
        for i in 0..300 {
            let t = i as f64 * 0.05;
            let (g, rate) = s.g_and_rate(t);
            let expected = a1 * g + a2 * rate + a3;
            assert_eq!(m.displacement(DVec3::ONE, t), expected);
        }
        // Hysteresis: the same g on the way in and out gives different displacements.
        let c = s.phase(0.0);
        let (t_in, t_out) = (0.3 * c.period_s, 0.7 * c.period_s);
        assert!((s.g(t_in) - s.g(t_out)).abs() < 1e-12);
        assert!((m.displacement(DVec3::ZERO, t_in) - m.displacement(DVec3::ZERO, t_out)).length() > 0.1);
        // One moment for many points: the same bits; and the bound holds at every time.
        let bound = m.max_displacement_mm();
        for i in 0..2000 {
            let t = i as f64 * 0.0123;
            let at = m.at_time(t);
            let x = DVec3::new(i as f64, 1.0, 2.0);
            assert_eq!(
                at(x).to_array().map(f64::to_bits),
                m.displacement(x, t).to_array().map(f64::to_bits)
            );
            assert!(at(x).length() <= bound, "t {t}: |u| {} > {bound}", at(x).length());
        }
    }

    /// The weighted grids of a measured surrogate model are its displacement at that moment,
    /// bit for bit; a field that is not a grid has no such form.
    #[test]
    fn a_surrogate_of_grid_fields_is_weighted_grids() {
        let grid = crate::Grid::new(
            [6, 5, 4],
            crate::Affine::from_spacing([4.0; 3], DVec3::new(-10.0, -8.0, -6.0)),
        )
        .unwrap();
        let field = |k: f64| {
            Arc::new(GridField::sample(grid, move |x| {
                DVec3::new(0.1 * x.y, k, -0.2 * x.z + k)
            })) as Arc<dyn SpatialField>
        };
        let signal = BreathingSignal::new(SignalParams::default()).unwrap();
        let model = Surrogate {
            a1: field(1.0),
            a2: Some(field(-0.5)),
            a3: Some(field(0.25)),
            signal: signal.clone().into(),
        };
        for t in [0.0, 0.7, 2.3, 4.1] {
            let w = model.weighted_grids_at(t).expect("grid fields");
            for x in [
                DVec3::new(1.0, 2.0, 3.0),
                DVec3::new(-7.5, 4.0, 0.2),
                DVec3::new(50.0, 0.0, 0.0),
            ] {
                let mut u = DVec3::ZERO;
                for (f, weight) in w.terms.iter().flatten() {
                    u += f.at(x) * *weight;
                }
                assert_eq!(u, model.displacement(x, t), "{x} at {t}");
            }
        }
        let uniform = Surrogate {
            a1: Arc::new(Uniform(DVec3::X)),
            a2: None,
            a3: None,
            signal: signal.into(),
        };
        assert!(uniform.weighted_grids_at(1.0).is_none());
    }
}
