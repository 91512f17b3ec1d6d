//! The breathing hook (thesis §5.4.3–5.4.4; docs/breathing.md "Haptics"): physics reads the
//! motion u(X, t) that moves the reference patient X to the world x = X + u(X, t) through
//! [`MotionModel`], and already uses it the way the thesis does, so a motion model only has to
//! supply displacement fields.
//!
//! - The device is mapped into reference space with one fixed-point step per tick,
//!   X⁺ = x − u(X, t), X being the previous tick's mapped position (a cheap inverse of u).
//! - The needle tip direction is corrected with R = ∂u/∂X + I by forward differences of 1 mm
//!   (eq. 5.4.3): d_l = R⁻¹ r_m / ‖R⁻¹ r_m‖.
//! - Forces are sent to the device without transforming back (the thesis neglects the small
//!   rotation of u near the skin).
//!
//! The models (§5.3) are in [`models`], driven by the seeded breathing signal of [`signal`]; an
//! atlas without a 4D CT gets the [`synthetic`] motion built from its own maps. What a session
//! breathes is part of its world model ([`BreathingSettings`], recorded in the session header).

pub mod field;
pub mod models;
pub mod sampled;
pub mod signal;
pub mod synthetic;

use std::sync::Arc;

use glam::{DMat3, DVec3};

pub use field::{FactoredField, GridField, GridFieldError, SpatialField, WeightedGrids};
pub use models::{FullCycle, HalfCycle, Surrogate, SurrogateSignal};
pub use sampled::{SampledSignal, SampledSignalError};
pub use signal::{BreathingSignal, SignalParams};
pub use synthetic::{InversionCheck, SyntheticField, SyntheticMotion};

use crate::{PunctureAtlas, SettingsError};

/// Why a session's breathing cannot be set up: settings out of range, an atlas without the
/// motion the session asks for, or a motion model without enough key frames.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum BreathingError {
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// Breathing is on and the atlas was built without a motion.
    #[error("breathing on: this atlas has no breathing motion (it was built with --no-breathing)")]
    NoMotion,
    /// The session breathes with measured fields the atlas does not have.
    #[error("the session breathes with measured fields, and this atlas has none")]
    NoMeasuredFields,
    /// An amplitude asked of measured fields, whose amplitude is their own.
    #[error("breathing amplitude: this atlas breathes with measured fields, whose amplitude is their own")]
    MeasuredAmplitude,
    /// The synthetic motion finds no organ to place the diaphragm at.
    #[error("the synthetic breathing motion needs an organ or target label (the liver) to place the diaphragm")]
    NoOrgan,
    /// A [`FullCycle`] with fewer than 2 key frames (the count given).
    #[error("a full cycle needs at least 2 key frames, got {0}")]
    FullCycleFrames(usize),
    /// A [`HalfCycle`] with fewer than 2 key frames (the count given).
    #[error("a half cycle needs at least 2 key frames (EE … EI), got {0}")]
    HalfCycleFrames(usize),
}

/// A displacement field over time. Implementations must be pure functions of (X, t).
pub trait MotionModel: Send + Sync {
    /// u(X, t) in mm at reference position `x_ref` (mm) and breathing time `t_s`.
    fn displacement(&self, x_ref: DVec3, t_s: f64) -> DVec3;

    /// A bound on |u| over all X and t (mm): renderers widen their box and their empty-space
    /// leaping by it. Infinite when unknown (then they visit every sample).
    fn max_displacement_mm(&self) -> f64 {
        f64::INFINITY
    }

    /// u(·, t) at one moment, for many points (a frame, a slice): the same values as
    /// [`Self::displacement`], bit for bit, with what depends on t alone worked out once.
    fn at_time(&self, t_s: f64) -> Box<dyn Fn(DVec3) -> DVec3 + Send + Sync + '_> {
        Box::new(move |x| self.displacement(x, t_s))
    }

    /// u(·, t) as one [`FactoredField`] (its direction scaled by the moment), when the model
    /// has that form: what the GPU renderers draw.
    fn factored_at(&self, _t_s: f64) -> Option<FactoredField<'_>> {
        None
    }

    /// u(·, t) as [`WeightedGrids`] (measured fields, their weights at the moment), when the
    /// model has that form: what the GPU renderers draw of a measured motion.
    fn weighted_grids_at(&self, _t_s: f64) -> Option<WeightedGrids<'_>> {
        None
    }
}

/// No motion: u = 0 (the model when breathing is off).
#[derive(Debug, Clone, Copy, Default)]
pub struct Static;

impl MotionModel for Static {
    fn displacement(&self, _x_ref: DVec3, _t_s: f64) -> DVec3 {
        DVec3::ZERO
    }

    fn max_displacement_mm(&self) -> f64 {
        0.0
    }
}

/// Fields measured on a 4D CT (registered displacement fields of the surrogate model, thesis
/// eqs. 5.3.4–5.3.6) and, optionally, the surrogate signal recorded with them (docs/breathing.md
/// "Measured motion").
#[derive(Clone)]
pub struct MeasuredMotion {
    pub a1: Arc<GridField>,
    pub a2: Option<Arc<GridField>>,
    pub a3: Option<Arc<GridField>>,
    /// Without one, the session's seeded Lujan signal drives the fields.
    pub signal: Option<Arc<SampledSignal>>,
}

impl std::fmt::Debug for MeasuredMotion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MeasuredMotion")
            .field("a1", &self.a1.grid().dims())
            .field("a2", &self.a2.as_ref().map(|a| a.grid().dims()))
            .field("a3", &self.a3.as_ref().map(|a| a.grid().dims()))
            .field("signal_period_s", &self.signal.as_ref().map(|s| s.period_s()))
            .finish()
    }
}

/// The motion attached to an atlas ([`PunctureAtlas::breathing`]).
#[derive(Debug, Clone)]
pub enum AtlasMotion {
    /// Built from the atlas' own maps.
    Synthetic(SyntheticMotion),
    /// Read from files beside the atlas.
    Measured(Arc<MeasuredMotion>),
}

/// Whether and how the patient breathes in a session (part of the world model, recorded in the
/// session header): the atlas' synthetic motion with these parameters, or its measured motion
/// (`measured`), driven by the seeded breathing signal (or the measured signal, when the atlas
/// has one).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BreathingSettings {
    pub enabled: bool,
    pub motion: SyntheticMotion,
    pub signal: SignalParams,
    /// The atlas' measured fields instead of the synthetic motion (`motion` is then unused).
    pub measured: bool,
}

impl BreathingSettings {
    /// Breathing with the default motion and signal.
    pub fn on() -> BreathingSettings {
        BreathingSettings {
            enabled: true,
            ..Default::default()
        }
    }

    pub fn validate(&self) -> Result<(), SettingsError> {
        self.motion.validate()?;
        self.signal.validate()
    }

    /// The motion model of these settings on `atlas` ([`Static`] when breathing is off).
    pub fn build(&self, atlas: &Arc<PunctureAtlas>) -> Result<Arc<dyn MotionModel>, BreathingError> {
        self.validate()?;
        if !self.enabled {
            return Ok(Arc::new(Static));
        }
        let lujan = || BreathingSignal::new(self.signal).map(SurrogateSignal::Lujan);
        if self.measured {
            let Some(AtlasMotion::Measured(m)) = atlas.breathing() else {
                return Err(BreathingError::NoMeasuredFields);
            };
            let field = |a: &Arc<GridField>| -> Arc<dyn SpatialField> { a.clone() };
            return Ok(Arc::new(Surrogate {
                a1: field(&m.a1),
                a2: m.a2.as_ref().map(field),
                a3: m.a3.as_ref().map(field),
                signal: match &m.signal {
                    Some(s) => SurrogateSignal::Sampled(Arc::clone(s)),
                    None => lujan()?,
                },
            }));
        }
        let field = SyntheticField::new(Arc::clone(atlas), self.motion)?;
        Ok(Arc::new(Surrogate {
            a1: Arc::new(field),
            a2: None,
            a3: None,
            signal: lujan()?,
        }))
    }
}

/// What a script or a scenario asks for: breathing on or off, the amplitude if it sets one, and
/// the signal. The rest of the motion is the atlas' attached one
/// ([`PunctureAtlas::breathing`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BreathingRequest {
    pub enabled: bool,
    pub amplitude_mm: Option<f64>,
    pub signal: SignalParams,
}

impl BreathingRequest {
    /// Breathing with the atlas' motion and the default signal.
    pub fn on() -> BreathingRequest {
        BreathingRequest {
            enabled: true,
            ..Default::default()
        }
    }

    /// The settings on `atlas`: off stays off; on needs an atlas that breathes.
    pub fn resolve(&self, atlas: &PunctureAtlas) -> Result<BreathingSettings, BreathingError> {
        if !self.enabled {
            return Ok(BreathingSettings {
                signal: self.signal,
                ..Default::default()
            });
        }
        let attached = atlas.breathing().ok_or(BreathingError::NoMotion)?;
        let settings = match attached {
            AtlasMotion::Synthetic(m) => {
                let mut motion = *m;
                if let Some(a) = self.amplitude_mm {
                    motion.amplitude_mm = a;
                }
                BreathingSettings {
                    enabled: true,
                    motion,
                    signal: self.signal,
                    measured: false,
                }
            }
            AtlasMotion::Measured(_) if self.amplitude_mm.is_some() => {
                return Err(BreathingError::MeasuredAmplitude);
            }
            AtlasMotion::Measured(_) => BreathingSettings {
                enabled: true,
                signal: self.signal,
                measured: true,
                ..Default::default()
            },
        };
        settings.validate()?;
        Ok(settings)
    }
}

/// The reference position of world point `x_world` after `iterations` fixed-point steps from
/// X = x (the inversion every view and the haptics use, thesis §5.4.1).
pub fn invert(model: &dyn MotionModel, x_world: DVec3, t_s: f64, iterations: u32) -> DVec3 {
    let mut x_ref = x_world;
    for _ in 0..iterations {
        x_ref = to_reference(model, x_world, x_ref, t_s);
    }
    x_ref
}

/// How far the inverse misses: for each reference point X, x = X + u(X, t) is inverted by
/// [`invert`] and the largest |X̂ − X| (mm) is returned.
pub fn inversion_error_mm(model: &dyn MotionModel, points: &[DVec3], t_s: f64, iterations: u32) -> f64 {
    points
        .iter()
        .map(|&x_ref| {
            let x_world = x_ref + model.displacement(x_ref, t_s);
            (invert(model, x_world, t_s, iterations) - x_ref).length()
        })
        .fold(0.0, f64::max)
}

/// How far the inverse of d·v misses (mm): for each reference point X, x = X + d·v(X) is
/// inverted by `iterations` fixed-point steps from X = x; the largest |X̂ − X|. A field's check
/// at a breathing depth d (docs/breathing.md "Atlases").
pub fn field_inversion_error_mm(field: &dyn SpatialField, points: &[DVec3], depth: f64, iterations: u32) -> f64 {
    use rayon::prelude::*;
    points
        .par_iter()
        .map(|&x_ref| {
            let x_world = x_ref + field.at(x_ref) * depth;
            let mut x = x_world;
            for _ in 0..iterations {
                x = x_world - field.at(x) * depth;
            }
            (x - x_ref).length()
        })
        .reduce(|| 0.0, f64::max)
}

/// One fixed-point step of the inverse: X⁺ = x − u(X, t).
pub fn to_reference(model: &dyn MotionModel, x_world: DVec3, x_ref_prev: DVec3, t_s: f64) -> DVec3 {
    x_world - model.displacement(x_ref_prev, t_s)
}

/// Above this steepness L (how much u changes along the step per mm of step) the device's step
/// to reference space is relaxed ([`device_step`]); below it the plain step contracts by L or
/// better.
pub const RELAX_ABOVE: f64 = 0.5;

/// The device's reference position this tick (thesis §5.4.3): one fixed-point step from last
/// tick's X, X⁺ = x − u(X), with u(·, t) of this tick.
///
/// Where u changes faster than the step contracts (the ramps of the sliding interface: 12 mm
/// over 4 mm for the default synthetic motion), the plain step overshoots and can alternate
/// between two points tick after tick — a period-2 oscillation the hand would feel as a buzz of
/// several newtons. So the step's steepness is measured along the step itself,
/// L = |u(X⁺) − u(X)| / |X⁺ − X| (one more read of u), and above [`RELAX_ABOVE`] the step is
/// relaxed,
///
///   X⁺ = X + (x − u(X) − X) / (1 + L),
///
/// which lands on the root of a linear ramp that rises along the step, and moves away without
/// overshoot from a fold (a world point the motion reaches from two places) to one of its sides.
/// Elsewhere the plain step is kept bit for bit.
pub fn device_step(u: &dyn Fn(DVec3) -> DVec3, x_world: DVec3, x_ref_prev: DVec3) -> DVec3 {
    let u0 = u(x_ref_prev);
    let plain = x_world - u0;
    let step = plain - x_ref_prev;
    let step_mm = step.length();
    if step_mm == 0.0 {
        return plain;
    }
    let steepness = (u(plain) - u0).length() / step_mm;
    if !(steepness > RELAX_ABOVE) {
        return plain;
    }
    x_ref_prev + step / (1.0 + steepness)
}

/// R = ∂u/∂X + I at `x_ref` by forward differences of 1 mm (eq. 5.4.3).
pub fn deformation_gradient(model: &dyn MotionModel, x_ref: DVec3, t_s: f64) -> DMat3 {
    gradient_of(&*model.at_time(t_s), x_ref)
}

/// R = ∂u/∂X + I of u(·, t) at one moment ([`MotionModel::at_time`]), by forward differences of
/// 1 mm (eq. 5.4.3).
pub fn gradient_of(u: &dyn Fn(DVec3) -> DVec3, x_ref: DVec3) -> DMat3 {
    let u0 = u(x_ref);
    let col = |e: DVec3| u(x_ref + e) - u0;
    DMat3::from_cols(col(DVec3::X), col(DVec3::Y), col(DVec3::Z)) + DMat3::IDENTITY
}

/// d_l = R⁻¹ r / ‖R⁻¹ r‖; `r` unchanged when R is singular.
pub fn correct_direction(r_mat: &DMat3, r: DVec3) -> DVec3 {
    let det = r_mat.determinant();
    if !det.is_finite() || det.abs() < 1e-9 {
        return r;
    }
    (r_mat.inverse() * r).normalize_or(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A uniform shear u = (0.1·z, 0, 0) and a translation: the fixed point converges to the
    /// inverse and R corrects directions.
    struct Shear;
    impl MotionModel for Shear {
        fn displacement(&self, x: DVec3, _t: f64) -> DVec3 {
            DVec3::new(0.1 * x.z + 3.0, 0.0, 0.0)
        }
    }

    #[test]
    fn static_model_is_the_identity() {
        let r = deformation_gradient(&Static, DVec3::new(1.0, 2.0, 3.0), 0.5);
        assert_eq!(r, DMat3::IDENTITY);
        let d = DVec3::new(0.0, 0.6, 0.8);
        assert_eq!(correct_direction(&r, d), d);
        assert_eq!(to_reference(&Static, d, DVec3::ZERO, 0.0), d);
    }

    #[test]
    fn fixed_point_tracks_the_inverse_and_directions_are_corrected() {
        let target_ref = DVec3::new(10.0, 0.0, 20.0);
        let x_world = target_ref + Shear.displacement(target_ref, 0.0);
        let mut x_ref = x_world;
        for _ in 0..5 {
            x_ref = to_reference(&Shear, x_world, x_ref, 0.0);
        }
        assert!((x_ref - target_ref).length() < 1e-9, "{x_ref}");
        // A world direction along the sheared z axis maps back to the reference z axis.
        let r = deformation_gradient(&Shear, x_ref, 0.0);
        let d_world = (r * DVec3::Z).normalize();
        assert!((correct_direction(&r, d_world) - DVec3::Z).length() < 1e-12);
    }

    /// A cranio-caudal motion of 12 mm below z = 0 that falls to 0 over 4 mm of z (the
    /// steepness of a sliding interface's ramp): the plain step alternates between the two
    /// plateaus for ever; the relaxed step settles on X with X + u(X) = x, as it does on the
    /// mirrored ramp (12 mm above z = 4).
    #[test]
    fn the_device_step_settles_where_u_is_steep() {
        let rising = |x: DVec3| DVec3::new(0.0, 0.0, -12.0 * (1.0 - (x.z / 4.0).clamp(0.0, 1.0)));
        let falling = |x: DVec3| DVec3::new(0.0, 0.0, -12.0 * (x.z / 4.0).clamp(0.0, 1.0));
        for (name, u, x) in [
            ("rising", &rising as &dyn Fn(DVec3) -> DVec3, DVec3::new(5.0, 0.0, -4.0)),
            ("falling", &falling, DVec3::new(5.0, 0.0, 3.0)),
        ] {
            let (mut plain, mut relaxed) = (x, x);
            let mut plain_moves = Vec::new();
            for _ in 0..200 {
                let next = x - u(plain);
                plain_moves.push((next - plain).length());
                plain = next;
                relaxed = device_step(u, x, relaxed);
            }
            if name == "rising" {
                assert!(plain_moves[190..].iter().all(|&d| d > 1.0), "{plain_moves:?}");
            }
            assert!((relaxed + u(relaxed) - x).length() < 1e-9, "{name}: {relaxed}");
        }
        // Where u is gentle the step is the plain one, bit for bit.
        let gentle = |x: DVec3| DVec3::new(0.0, 0.1 * x.y, -0.2 * x.z);
        let (x, p) = (DVec3::new(5.0, 0.0, -4.0), DVec3::new(1.0, 2.0, 3.0));
        assert_eq!(device_step(&gentle, x, p), x - gentle(p));
    }
}
