//! The breathing hook (thesis §5.4.3–5.4.4, ALGORITHMS.md §2 "Breathing"): physics reads the
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
pub mod signal;
pub mod synthetic;

use std::sync::Arc;

use glam::{DMat3, DVec3};

pub use field::{FactoredField, GridField, SpatialField};
pub use models::{FullCycle, HalfCycle, Surrogate};
pub use signal::{BreathingSignal, SignalParams};
pub use synthetic::{InversionCheck, SyntheticField, SyntheticMotion};

use crate::PunctureAtlas;

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
}

/// No motion: u = 0 (the default until the motion-model issue supplies fields).
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

/// Whether and how the patient breathes in a session (part of the world model, recorded in the
/// session header): the synthetic motion of the atlas driven by the seeded breathing signal.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BreathingSettings {
    pub enabled: bool,
    pub motion: SyntheticMotion,
    pub signal: SignalParams,
}

impl BreathingSettings {
    /// Breathing with the default motion and signal.
    pub fn on() -> BreathingSettings {
        BreathingSettings {
            enabled: true,
            ..Default::default()
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        self.motion.validate()?;
        self.signal.validate()
    }

    /// The motion model of these settings on `atlas` ([`Static`] when breathing is off).
    pub fn build(&self, atlas: &Arc<PunctureAtlas>) -> Result<Arc<dyn MotionModel>, String> {
        self.validate()?;
        if !self.enabled {
            return Ok(Arc::new(Static));
        }
        let field = SyntheticField::new(Arc::clone(atlas), self.motion)?;
        Ok(Arc::new(Surrogate {
            a1: Arc::new(field),
            a2: None,
            a3: None,
            signal: BreathingSignal::new(self.signal)?,
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
    pub fn resolve(&self, atlas: &PunctureAtlas) -> Result<BreathingSettings, String> {
        if !self.enabled {
            return Ok(BreathingSettings {
                signal: self.signal,
                ..Default::default()
            });
        }
        let mut motion = atlas
            .breathing()
            .ok_or("breathing on: this atlas has no breathing motion (it was built with --no-breathing)")?;
        if let Some(a) = self.amplitude_mm {
            motion.amplitude_mm = a;
        }
        let settings = BreathingSettings {
            enabled: true,
            motion,
            signal: self.signal,
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

/// One fixed-point step of the inverse: X⁺ = x − u(X, t).
pub fn to_reference(model: &dyn MotionModel, x_world: DVec3, x_ref_prev: DVec3, t_s: f64) -> DVec3 {
    x_world - model.displacement(x_ref_prev, t_s)
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
}
