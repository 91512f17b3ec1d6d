//! The C-arm's cone-beam geometry (thesis §3.3; docs/xray.md "Geometry"): an X-ray source and a
//! flat detector on opposite sides of the isocentre, rotated LAO/RAO about the patient's long
//! axis and tilted cranial/caudal.
//!
//! World space is RAS+ (x to the patient's right, y anterior, z superior). At LAO 0°, cranial 0°
//! the beam is posterior-anterior: the tube under the table, the detector above the patient, the
//! image seen from the detector as the operator sees the monitor (the patient's right on the
//! image's left, superior up). LAO θ turns the detector toward the patient's left, cranial φ
//! toward the head: the unit vector from the isocentre to the detector is
//!
//!   d = (−sin θ·cos φ, cos θ·cos φ, sin φ).

use stylet_atlas::manifest::CArmToml;
use stylet_physics::glam::Vec3;

use super::XrayError;

/// Where the C-arm stands and what its detector covers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CArm {
    /// The point the beam's central ray passes through (mm).
    pub isocenter_mm: Vec3,
    /// Focal spot to detector plane (the SID), mm.
    pub source_to_detector_mm: f32,
    /// Focal spot to isocentre, mm (less than the SID: the patient lies between).
    pub source_to_isocenter_mm: f32,
    /// Detector width and height, mm.
    pub detector_mm: [f32; 2],
    /// Rotation about the patient's long axis: > 0 LAO, < 0 RAO (degrees).
    pub lao_deg: f32,
    /// Tilt toward the head: > 0 cranial, < 0 caudal (degrees).
    pub cranial_deg: f32,
}

impl CArm {
    /// A typical interventional C-arm at the given isocentre: SID 1000 mm, source 750 mm from
    /// the isocentre, a 300 × 300 mm flat detector, posterior-anterior beam.
    pub fn posterior_anterior(isocenter_mm: Vec3) -> CArm {
        CArm {
            isocenter_mm,
            source_to_detector_mm: 1000.0,
            source_to_isocenter_mm: 750.0,
            detector_mm: [300.0, 300.0],
            lao_deg: 0.0,
            cranial_deg: 0.0,
        }
    }

    /// The scenario's `[scenarios.c_arm]` (docs/atlas.md), centred on `default_isocenter_mm`
    /// unless it names its own isocentre.
    pub fn from_toml(t: &CArmToml, default_isocenter_mm: Vec3) -> CArm {
        CArm {
            isocenter_mm: t.isocenter_mm.map_or(default_isocenter_mm, |p| {
                Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32)
            }),
            source_to_detector_mm: t.source_to_detector_mm as f32,
            source_to_isocenter_mm: t.source_to_isocenter_mm as f32,
            detector_mm: t.detector_mm.map(|v| v as f32),
            lao_deg: t.lao_deg as f32,
            cranial_deg: t.cranial_deg as f32,
        }
    }

    /// Names the first value outside what a C-arm can be set to (the limits of the scenario
    /// format, `CArmToml::check`).
    pub fn validate(&self) -> Result<(), XrayError> {
        if !self.isocenter_mm.is_finite() {
            return Err(XrayError::Isocenter(self.isocenter_mm));
        }
        CArmToml {
            lao_deg: self.lao_deg as f64,
            cranial_deg: self.cranial_deg as f64,
            source_to_detector_mm: self.source_to_detector_mm as f64,
            source_to_isocenter_mm: self.source_to_isocenter_mm as f64,
            detector_mm: self.detector_mm.map(|v| v as f64),
            isocenter_mm: None,
            ..CArmToml::default()
        }
        .check()
        .map_err(XrayError::CArm)
    }

    /// Unit vector from the isocentre toward the detector (see the module doc).
    pub fn beam_direction(&self) -> Vec3 {
        let (t, p) = (self.lao_deg.to_radians(), self.cranial_deg.to_radians());
        Vec3::new(-t.sin() * p.cos(), t.cos() * p.cos(), p.sin())
    }

    /// The projection onto a `width` × `height` pixel image of the detector. Pixels are square:
    /// pitch = min(detector width / width, detector height / height), so an image of another
    /// aspect than the detector shows its centre.
    pub fn projection(&self, width: u32, height: u32) -> Projection {
        let d = self.beam_direction();
        // Image up: superior, made perpendicular to the beam (at 90° cranial, anterior).
        let up_hint = if d.z.abs() > 0.999 { Vec3::Y } else { Vec3::Z };
        let up = (up_hint - d * d.dot(up_hint)).normalize();
        // Columns run toward the patient's left at PA (−x): up × d.
        let right = up.cross(d);
        let source_mm = self.isocenter_mm - d * self.source_to_isocenter_mm;
        let detector_center_mm = source_mm + d * self.source_to_detector_mm;
        let (w, h) = (width.max(1) as f32, height.max(1) as f32);
        let pitch_mm = self.pixel_pitch_mm(width, height);
        let col_mm = right * pitch_mm;
        let row_mm = -up * pitch_mm;
        Projection {
            source_mm,
            pixel00_mm: detector_center_mm - col_mm * (0.5 * w - 0.5) - row_mm * (0.5 * h - 0.5),
            col_mm,
            row_mm,
            width,
            height,
        }
    }

    /// The detector pixel pitch of a `width` × `height` image (mm).
    pub fn pixel_pitch_mm(&self, width: u32, height: u32) -> f32 {
        (self.detector_mm[0] / width.max(1) as f32).min(self.detector_mm[1] / height.max(1) as f32)
    }

    /// The pixel pitch projected back to the isocentre (mm across the patient per pixel): the
    /// detector pitch × SOD / SID.
    pub fn pixel_at_isocenter_mm(&self, width: u32, height: u32) -> f32 {
        self.pixel_pitch_mm(width, height) * self.source_to_isocenter_mm / self.source_to_detector_mm
    }
}

/// Where each detector pixel is: rays go from `source_mm` to the pixel's centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    pub source_mm: Vec3,
    /// Centre of pixel (0, 0), the top-left one.
    pub pixel00_mm: Vec3,
    /// Step to the next column and to the next row (mm).
    pub col_mm: Vec3,
    pub row_mm: Vec3,
    pub width: u32,
    pub height: u32,
}

impl Projection {
    /// Centre of pixel (`col`, `row`) on the detector: p₀₀ + col·Δc + row·Δr.
    #[inline]
    pub fn pixel_mm(&self, col: u32, row: u32) -> Vec3 {
        self.pixel00_mm + self.col_mm * col as f32 + self.row_mm * row as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).length() < 1e-3
    }

    #[test]
    fn posterior_anterior_beam_puts_the_patients_right_on_the_left_and_superior_up() {
        let arm = CArm::posterior_anterior(Vec3::new(10.0, 20.0, 30.0));
        assert!(close(arm.beam_direction(), Vec3::Y));
        let p = arm.projection(3, 3);
        assert!(close(p.source_mm, Vec3::new(10.0, -730.0, 30.0)));
        // The centre pixel lies on the central ray, at the detector.
        assert!(close(p.pixel_mm(1, 1), Vec3::new(10.0, 270.0, 30.0)));
        // Column 0 toward the patient's right (+x), row 0 superior (+z).
        assert!(p.pixel_mm(0, 1).x > p.pixel_mm(2, 1).x);
        assert!(p.pixel_mm(1, 0).z > p.pixel_mm(1, 2).z);
        assert!(((p.pixel_mm(0, 1) - p.pixel_mm(2, 1)).length() - 200.0).abs() < 1e-3);
    }

    #[test]
    fn lao_turns_the_detector_to_the_patients_left_and_cranial_to_the_head() {
        let mut arm = CArm::posterior_anterior(Vec3::ZERO);
        arm.lao_deg = 90.0;
        assert!(close(arm.beam_direction(), Vec3::new(-1.0, 0.0, 0.0)));
        arm.lao_deg = -30.0; // RAO 30
        assert!(arm.beam_direction().x > 0.4);
        arm.lao_deg = 0.0;
        arm.cranial_deg = 20.0;
        let d = arm.beam_direction();
        assert!(d.z > 0.3 && d.y > 0.9);
        // The detector's axes stay perpendicular to the beam.
        let p = arm.projection(4, 4);
        assert!(p.col_mm.dot(d).abs() < 1e-5 && p.row_mm.dot(d).abs() < 1e-5);
    }

    #[test]
    fn settings_outside_a_c_arms_range_are_named() {
        let ok = CArm::posterior_anterior(Vec3::ZERO);
        assert!(ok.validate().is_ok());
        let bad = |f: fn(&mut CArm)| {
            let mut a = ok;
            f(&mut a);
            a.validate().unwrap_err().to_string()
        };
        assert!(bad(|a| a.lao_deg = 200.0).contains("lao_deg"));
        assert!(bad(|a| a.cranial_deg = f32::NAN).contains("cranial_deg"));
        assert!(bad(|a| a.source_to_isocenter_mm = 990.0).contains("source_to_isocenter_mm"));
        assert!(bad(|a| a.source_to_detector_mm = 0.0).contains("source_to_detector_mm"));
        assert!(bad(|a| a.detector_mm[1] = 1e6).contains("height"));
        assert!(bad(|a| a.isocenter_mm.x = f32::INFINITY).contains("isocenter"));
    }
}
