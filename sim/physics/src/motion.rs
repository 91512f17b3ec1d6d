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

use glam::{DMat3, DVec3};

/// A displacement field over time. Implementations must be pure functions of (X, t).
pub trait MotionModel: Send + Sync {
    /// u(X, t) in mm at reference position `x_ref` (mm) and breathing time `t_s`.
    fn displacement(&self, x_ref: DVec3, t_s: f64) -> DVec3;
}

/// No motion: u = 0 (the default until the motion-model issue supplies fields).
#[derive(Debug, Clone, Copy, Default)]
pub struct Static;

impl MotionModel for Static {
    fn displacement(&self, _x_ref: DVec3, _t_s: f64) -> DVec3 {
        DVec3::ZERO
    }
}

/// One fixed-point step of the inverse: X⁺ = x − u(X, t).
pub fn to_reference(model: &dyn MotionModel, x_world: DVec3, x_ref_prev: DVec3, t_s: f64) -> DVec3 {
    x_world - model.displacement(x_ref_prev, t_s)
}

/// R = ∂u/∂X + I at `x_ref` by forward differences of 1 mm (eq. 5.4.3).
pub fn deformation_gradient(model: &dyn MotionModel, x_ref: DVec3, t_s: f64) -> DMat3 {
    let u0 = model.displacement(x_ref, t_s);
    let col = |e: DVec3| model.displacement(x_ref + e, t_s) - u0;
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
