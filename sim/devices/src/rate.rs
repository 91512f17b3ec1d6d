//! Rate control: a six-axis deflection (a SpaceMouse cap, held keys) moves the tool at a speed
//! proportional to it, integrated tick by tick into the pose the simulation receives.
//!
//! The pose, not the deflection, is what the session records, so this mapping may change
//! without touching replay. Deflections are in the device frame (x right, y away from the user,
//! z up) and act in the view: `view` turns the device frame into world space, so pushing the cap
//! away moves the tool away from the viewer whatever the camera.

use stylet_physics::glam::{DQuat, DVec3};

/// How fast full deflection moves the tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateSettings {
    /// Deflection that counts as full (SpaceMouse: about 350 counts).
    pub full_scale: f64,
    /// Deflection below this fraction of full scale is ignored (the cap's rest noise).
    pub deadzone: f64,
    /// Translation speed at full deflection (mm/s).
    pub speed_mm_per_s: f64,
    /// Rotation speed at full deflection (degrees/s).
    pub turn_deg_per_s: f64,
}

impl RateSettings {
    /// A SpaceMouse: ±350 counts, 5 % dead zone, 40 mm/s and 45°/s at full deflection (slow
    /// enough to place a needle to a millimetre).
    pub const SPACEMOUSE: RateSettings = RateSettings {
        full_scale: 350.0,
        deadzone: 0.05,
        speed_mm_per_s: 40.0,
        turn_deg_per_s: 45.0,
    };

    /// Deflection as a fraction of full scale, with the dead zone removed and the rest rescaled
    /// so speed starts from zero at its edge; clamped to [−1, 1].
    fn shaped(&self, v: f64) -> f64 {
        let x = (v / self.full_scale).clamp(-1.0, 1.0);
        let d = self.deadzone.clamp(0.0, 0.99);
        if x.abs() <= d {
            0.0
        } else {
            x.signum() * (x.abs() - d) / (1.0 - d)
        }
    }
}

/// The tool pose moved by rate control (default: at the origin, tool axis along +z).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RatePose {
    pub position_mm: DVec3,
    pub orientation: DQuat,
}

impl RatePose {
    /// Moves the pose by one tick of `dt_s` seconds at deflection (`translation`, `rotation`),
    /// both in the device frame, with `view` the device frame's orientation in the world. The
    /// tool turns about its own position (the needle tip, the probe face).
    pub fn step(&mut self, settings: &RateSettings, view: DQuat, translation: DVec3, rotation: DVec3, dt_s: f64) {
        let shape = |v: DVec3| DVec3::new(settings.shaped(v.x), settings.shaped(v.y), settings.shaped(v.z));
        let v_mm_per_s = view * (shape(translation) * settings.speed_mm_per_s);
        let w_rad_per_s = view * (shape(rotation) * settings.turn_deg_per_s.to_radians());
        self.position_mm += v_mm_per_s * dt_s;
        let angle = w_rad_per_s.length() * dt_s;
        if angle > 0.0 {
            let turn = DQuat::from_axis_angle(w_rad_per_s.normalize(), angle);
            self.orientation = (turn * self.orientation).normalize();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_deflection_moves_at_the_set_speed_and_rest_noise_does_not() {
        let s = RateSettings::SPACEMOUSE;
        let mut p = RatePose::default();
        for _ in 0..1000 {
            p.step(&s, DQuat::IDENTITY, DVec3::new(350.0, 0.0, 10.0), DVec3::ZERO, 1e-3);
        }
        assert!((p.position_mm.x - 40.0).abs() < 1e-9, "{:?}", p.position_mm);
        assert_eq!(p.position_mm.z, 0.0, "10 counts is inside the dead zone");
        // Over-deflection is clamped to full speed.
        let mut q = RatePose::default();
        q.step(&s, DQuat::IDENTITY, DVec3::new(0.0, 900.0, 0.0), DVec3::ZERO, 1.0);
        assert!((q.position_mm.y - 40.0).abs() < 1e-9);
    }

    #[test]
    fn motion_follows_the_view_and_rotation_turns_the_tool_axis() {
        let s = RateSettings::SPACEMOUSE;
        // A view turned 90° about z: the device's "right" is the world's +y.
        let view = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2);
        let mut p = RatePose::default();
        p.step(&s, view, DVec3::new(350.0, 0.0, 0.0), DVec3::ZERO, 0.5);
        assert!((p.position_mm - DVec3::new(0.0, 20.0, 0.0)).length() < 1e-9);
        // Full rotation about x for 1 s: 45°.
        let mut r = RatePose::default();
        for _ in 0..1000 {
            r.step(&s, DQuat::IDENTITY, DVec3::ZERO, DVec3::new(350.0, 0.0, 0.0), 1e-3);
        }
        let axis = r.orientation * DVec3::Z;
        let angle = axis.angle_between(DVec3::Z).to_degrees();
        assert!((angle - 45.0).abs() < 1e-6, "{angle}");
        assert_eq!(r.position_mm, DVec3::ZERO);
    }
}
