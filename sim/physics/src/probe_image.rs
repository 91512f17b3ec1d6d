//! The image field of the simulated ultrasound probes (docs/ultrasound.md "Geometry"): what the
//! renderer draws and what scoring calls "in the image", in one place. Probe frame as the contact
//! patterns' (thesis Fig. 3.8): the array along +x, the beam along +z, the image plane the x–z
//! plane. A linear array images a 40 mm wide strip; a convex one a 60° sector from the centre of
//! curvature of its 50 mm radius face.

use crate::events::ProbeKind;

/// Width of the linear array (mm): the linear contact pattern is 40 mm long.
pub const LINEAR_APERTURE_MM: f64 = 40.0;
/// Radius of the convex face and half the sector's angle.
pub const CONVEX_RADIUS_MM: f64 = 50.0;
pub const CONVEX_HALF_ANGLE_DEG: f64 = 30.0;
/// Half the beam's thickness across the image plane (mm) beyond a needle's radius: a shaft this
/// far out of the plane still echoes (a 3–5 MHz beam is 2–4 mm thick at its elevation focus).
pub const ELEVATION_HALF_MM: f64 = 1.0;

impl ProbeKind {
    /// The imaging depth of the probe's default settings (mm): a convex abdominal probe at
    /// 3.5 MHz to 150 mm, a linear one at 7.5 MHz to 60 mm.
    pub fn default_depth_mm(self) -> f64 {
        match self {
            ProbeKind::Convex => 150.0,
            ProbeKind::Linear => 60.0,
        }
    }
}

/// Whether the image-plane point (u lateral, v along the beam from the face centre, mm) lies in
/// the field of a `kind` probe imaging to `depth_mm`.
pub fn in_field(kind: ProbeKind, depth_mm: f64, u: f64, v: f64) -> bool {
    match kind {
        ProbeKind::Linear => u.abs() <= LINEAR_APERTURE_MM / 2.0 && (0.0..=depth_mm).contains(&v),
        ProbeKind::Convex => {
            let (du, dv) = (u, v + CONVEX_RADIUS_MM);
            let rho = libm::hypot(du, dv);
            libm::atan2(du, dv).abs() <= CONVEX_HALF_ANGLE_DEG.to_radians()
                && (CONVEX_RADIUS_MM..=CONVEX_RADIUS_MM + depth_mm).contains(&rho)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fields_are_a_strip_and_a_sector() {
        assert!(in_field(ProbeKind::Linear, 60.0, 19.9, 59.0));
        assert!(!in_field(ProbeKind::Linear, 60.0, 20.1, 10.0));
        assert!(!in_field(ProbeKind::Linear, 60.0, 0.0, 61.0));
        // Convex: 28.9 mm wide each side at the face's edge, 100 mm at the bottom.
        let half = CONVEX_HALF_ANGLE_DEG.to_radians();
        let edge = |rho: f64| {
            (
                rho * libm::sin(half) - 0.01,
                rho * libm::cos(half) - CONVEX_RADIUS_MM + 0.01,
            )
        };
        let (u, v) = edge(60.0);
        assert!(in_field(ProbeKind::Convex, 150.0, u, v));
        assert!(!in_field(ProbeKind::Convex, 150.0, u + 0.1, v - 0.1));
        // The sector's curved bottom: 140 mm deep on the axis is inside, 40 mm aside it is not.
        assert!(in_field(ProbeKind::Convex, 150.0, 0.0, 140.0));
        assert!(!in_field(ProbeKind::Convex, 150.0, 100.0, 140.0));
    }
}
