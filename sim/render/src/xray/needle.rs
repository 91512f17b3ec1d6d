//! The needle in the X-ray (docs/xray.md "Needle"): each shaft segment is a solid steel cylinder
//! of the needle's diameter, and a ray's attenuation through it is μ_steel × the chord length.
//! The chord is closed-form (ray against a finite cylinder without caps, so consecutive
//! segments do not count their joints twice); the GPU shader runs the same formula.

use stylet_physics::glam::Vec3;

/// Length (mm) of the ray `origin + t·dir` (dir a unit vector, t ∈ [0, t_max]) inside the
/// cylinder of `radius_mm` around the segment a–b.
///
/// Solved relative to the ray's point nearest `a`, so the f32 arithmetic stays well
/// conditioned with the source a metre away: with p = that point, w = b − a, o = p − a,
/// |(o + s·d) × w|² = r²|w|² is a quadratic in s whose roots bound the infinite cylinder, and
/// 0 ≤ (o + s·d)·w ≤ |w|² the slab between the end planes.
#[inline]
pub fn chord_mm(origin: Vec3, dir: Vec3, t_max: f32, a: Vec3, b: Vec3, radius_mm: f32) -> f32 {
    let t_near = (a - origin).dot(dir);
    let p = origin + dir * t_near;
    let w = b - a;
    let ww = w.dot(w);
    if ww <= 0.0 {
        return 0.0;
    }
    let o = p - a;
    let (wd, wo) = (w.dot(dir), w.dot(o));
    let k2 = ww - wd * wd;
    let k1 = ww * o.dot(dir) - wo * wd;
    let k0 = ww * o.dot(o) - wo * wo - radius_mm * radius_mm * ww;
    // The slab 0 ≤ wo + s·wd ≤ ww.
    let (mut s_lo, mut s_hi) = if wd.abs() > 1e-12 {
        let (s1, s2) = (-wo / wd, (ww - wo) / wd);
        (s1.min(s2), s1.max(s2))
    } else if (0.0..=ww).contains(&wo) {
        (f32::NEG_INFINITY, f32::INFINITY)
    } else {
        return 0.0;
    };
    if k2 > 1e-9 * ww {
        let h = k1 * k1 - k2 * k0;
        if h <= 0.0 {
            return 0.0;
        }
        let h = h.sqrt();
        s_lo = s_lo.max((-k1 - h) / k2);
        s_hi = s_hi.min((-k1 + h) / k2);
    } else if k0 > 0.0 {
        // Parallel to the axis and outside the radius.
        return 0.0;
    }
    // The part of the ray that exists: t = t_near + s ∈ [0, t_max].
    s_lo = s_lo.max(-t_near);
    s_hi = s_hi.min(t_max - t_near);
    (s_hi - s_lo).max(0.0)
}

/// The needle as the detector resolves it: a shaft thinner than a pixel's footprint at the
/// isocentre is drawn with radius r' = max(r, ½ footprint) and μ' = μ_steel (r/r')², which keeps
/// ∫ μ·chord across the shaft (μπr², the steel per mm of shaft) and so each pixel's mean, while a
/// shaft hit only between pixel centres would otherwise break into dots. Returns (r', μ').
pub fn resolved_radius_and_mu(diameter_mm: f32, pixel_at_isocenter_mm: f32, mu_per_mm: f32) -> (f32, f32) {
    let r = 0.5 * diameter_mm;
    let r_eff = r.max(0.5 * pixel_at_isocenter_mm);
    (r_eff, mu_per_mm * (r / r_eff) * (r / r_eff))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chords_of_a_perpendicular_ray_are_those_of_a_circle() {
        let (a, b) = (Vec3::new(0.0, 0.0, -5.0), Vec3::new(0.0, 0.0, 5.0));
        let origin = Vec3::new(-800.0, 0.3, 0.0);
        let c = chord_mm(origin, Vec3::X, 2000.0, a, b, 0.5);
        let expected = 2.0 * (0.25f32 - 0.09).sqrt();
        assert!((c - expected).abs() < 1e-3, "{c} vs {expected}");
        // Missing the radius, beyond the end plane, or stopping before it: nothing.
        assert_eq!(chord_mm(Vec3::new(-800.0, 0.6, 0.0), Vec3::X, 2000.0, a, b, 0.5), 0.0);
        assert_eq!(chord_mm(Vec3::new(-800.0, 0.0, 6.0), Vec3::X, 2000.0, a, b, 0.5), 0.0);
        assert_eq!(chord_mm(origin, Vec3::X, 700.0, a, b, 0.5), 0.0);
    }

    #[test]
    fn a_thin_needle_keeps_its_steel_when_widened_to_a_pixel() {
        let (r, mu) = resolved_radius_and_mu(0.7, 0.44, 0.294);
        assert_eq!((r, mu), (0.35, 0.294));
        let (r, mu) = resolved_radius_and_mu(0.7, 1.76, 0.294);
        assert_eq!(r, 0.88);
        assert!((mu * r * r - 0.294 * 0.35 * 0.35).abs() < 1e-7);
    }

    #[test]
    fn oblique_and_axial_rays() {
        let (a, b) = (Vec3::ZERO, Vec3::new(0.0, 0.0, 10.0));
        // 45° through the axis: the chord is 2r/sin 45°.
        let d = Vec3::new(1.0, 0.0, 1.0).normalize();
        let c = chord_mm(Vec3::new(0.0, 0.0, 5.0) - d * 500.0, d, 1000.0, a, b, 0.5);
        assert!((c - 2.0 * 0.5 * 2f32.sqrt()).abs() < 2e-3, "{c}");
        // Along the axis: the whole segment.
        let c = chord_mm(Vec3::new(0.1, 0.0, -300.0), Vec3::Z, 1000.0, a, b, 0.5);
        assert!((c - 10.0).abs() < 1e-3, "{c}");
    }
}
