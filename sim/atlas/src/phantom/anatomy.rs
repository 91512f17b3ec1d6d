//! The phantom's body plan: an adult lower chest and upper abdomen in world mm (RAS: +x patient
//! right, +y anterior, +z superior), centred on the origin, about z = −150 … +150 mm.
//!
//! The body wall is described in a body frame (angle around the torso, depth under the skin) so
//! that skin, subcutaneous fat, muscle, ribs with their intercostal spaces and the intercostal
//! fascia follow the body contour. Organs are signed-distance shapes painted on top, clipped to
//! the body cavity. Numbers are typical adult dimensions; the right 10th/11th intercostal space at
//! the mid-axillary line gives a straight path into the right hepatic duct that avoids lung, ribs
//! and vessels (the usual intercostal PTCD entry, thesis §2.1).

use std::f64::consts::{FRAC_PI_2, PI};

use libm::{atan2, cos, pow, sin, sqrt};
use stylet_physics::glam::DVec3;

use super::shapes::{Aabb, Ellipsoid, smoothstep};
use super::structures::{Structure, hu};

/// Body centre in the axial plane (mm).
const BODY_CENTER_Y: f64 = 8.0;
/// Superellipse exponent of the torso cross-section (a little boxier than an ellipse).
const BODY_EXPONENT: f64 = 2.5;
const SKIN_MM: f64 = 2.5;
const RIB_LAYER_MM: f64 = 10.0;
const FASCIA_MM: f64 = 2.0;
/// Rib cross-section half-axes: radial and cranio-caudal (mm).
const RIB_HALF_RADIAL: f64 = 4.5;
const RIB_HALF_HEIGHT: f64 = 6.0;
/// Cranio-caudal distance between neighbouring ribs at the mid-axillary line (mm).
const RIB_PITCH_MM: f64 = 28.0;
/// How much higher a rib is at the back than at the mid-axillary line (mm).
const RIB_SLOPE_MM: f64 = 30.0;
/// Ribs present: 6 … 12 (rib 5 lies above the default volume).
const RIBS: [u32; 7] = [6, 7, 8, 9, 10, 11, 12];

/// The frame of the body wall at a point.
#[derive(Debug, Clone, Copy)]
pub struct BodyFrame {
    /// Angle around the body from the back (0) over the flank (π/2) to the front (π), per side.
    pub phi: f64,
    /// Distance from the body axis in the axial plane (mm).
    pub rho: f64,
    /// Radial depth under the skin surface (mm, negative outside).
    pub depth: f64,
    /// Depths of the layer boundaries: skin|fat, fat|muscle, muscle+ribs|fascia, fascia|cavity.
    pub b_fat: f64,
    pub b_muscle: f64,
    /// Start of the rib layer (intercostal muscles and ribs).
    pub b_ribs: f64,
    pub b_fascia: f64,
    pub b_cavity: f64,
}

/// One painted organ or tube: a signed distance (mm), a value (HU) and the structure it is.
pub struct Part {
    pub structure: Structure,
    pub hu: f64,
    pub aabb: Aabb,
    pub sdf: Box<dyn Fn(DVec3) -> f64 + Send + Sync>,
}

/// Key points of the anatomy that other code needs (insertion path, tests).
#[derive(Debug, Clone, Copy)]
pub struct Landmarks {
    /// Centre of the right hepatic duct (the target).
    pub target: DVec3,
    /// A point in the right 10th/11th intercostal space at the mid-axillary line, in the rib layer.
    pub intercostal_10_11: DVec3,
}

/// The body plan; all methods are pure functions of position.
#[derive(Debug, Clone)]
pub struct Anatomy {
    pub seed: u64,
}

pub(super) fn sq(x: f64) -> f64 {
    x * x
}

/// Piecewise-linear interpolation through (x, y) knots, constant beyond the ends.
fn piecewise(x: f64, knots: &[(f64, f64)]) -> f64 {
    if x <= knots[0].0 {
        return knots[0].1;
    }
    for w in knots.windows(2) {
        if x <= w[1].0 {
            let t = (x - w[0].0) / (w[1].0 - w[0].0);
            return w[0].1 + t * (w[1].1 - w[0].1);
        }
    }
    knots[knots.len() - 1].1
}

/// Signed distance to an axis-aligned 2-D box [x0, x1] × [y0, y1] in the axial plane.
fn box2(x: f64, y: f64, x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
    let dx = (x0 - x).max(x - x1);
    let dy = (y0 - y).max(y - y1);
    let out = sqrt(sq(dx.max(0.0)) + sq(dy.max(0.0)));
    out + dx.max(dy).min(0.0)
}

impl Anatomy {
    pub fn new(seed: u64) -> Self {
        Anatomy { seed }
    }

    /// Radius of the skin surface in direction θ of the axial plane at height z (superellipse).
    fn surface_radius(&self, theta: f64, z: f64) -> f64 {
        let a = 152.0 + 0.04 * z;
        let b = if sin(theta) >= 0.0 { 112.0 - 0.02 * z } else { 98.0 };
        let c = cos(theta).abs() / a;
        let s = sin(theta).abs() / b;
        1.0 / pow(pow(c, BODY_EXPONENT) + pow(s, BODY_EXPONENT), 1.0 / BODY_EXPONENT)
    }

    /// Muscle outside the ribs: about 6 mm over the flanks and the front, the erector spinae
    /// (up to 40 mm) beside the spine, so the ribs dive towards the transverse processes.
    fn outer_muscle_mm(&self, phi: f64) -> f64 {
        6.0 + 34.0 * (1.0 - smoothstep(15.0_f64.to_radians(), 50.0_f64.to_radians(), phi))
    }

    /// Subcutaneous fat thickness: thicker in front than at the back, thinner over the chest.
    /// Over the lower chest the fat thins to about 8 mm at the flank, so the ribs lie some 15 mm
    /// under the skin there and can be palpated, as in a slim adult.
    fn fat_mm(&self, phi: f64, z: f64) -> f64 {
        let base = 11.0 + 9.0 * (1.0 - cos(phi)) / 2.0;
        base * (1.0 - 0.45 * smoothstep(-30.0, 30.0, z))
    }

    pub fn frame(&self, p: DVec3) -> BodyFrame {
        let (x, y) = (p.x, p.y - BODY_CENTER_Y);
        let theta = atan2(y, x);
        let phi = if x >= 0.0 {
            theta + FRAC_PI_2
        } else if theta > 0.0 {
            1.5 * PI - theta
        } else {
            -FRAC_PI_2 - theta
        };
        let rho = sqrt(x * x + y * y);
        let depth = self.surface_radius(theta, p.z) - rho;
        let b_fat = SKIN_MM;
        let b_muscle = b_fat + self.fat_mm(phi, p.z);
        let b_ribs = b_muscle + self.outer_muscle_mm(phi);
        let b_fascia = b_ribs + RIB_LAYER_MM;
        let b_cavity = b_fascia + FASCIA_MM;
        BodyFrame {
            phi,
            rho,
            depth,
            b_fat,
            b_muscle,
            b_ribs,
            b_fascia,
            b_cavity,
        }
    }

    /// Signed distance to the skin (negative inside the body).
    pub fn body_sdf(&self, p: DVec3) -> f64 {
        -self.frame(p).depth
    }

    /// Signed distance to the body cavity inside the chest/abdominal wall.
    pub fn cavity_sdf(&self, p: DVec3) -> f64 {
        let f = self.frame(p);
        f.b_cavity - f.depth
    }

    /// Height of the rib's centre line at angle φ (ribs slope down from back to front).
    fn rib_z(&self, rib: u32, phi: f64) -> f64 {
        RIB_PITCH_MM * (11.0 - rib as f64) + RIB_SLOPE_MM * cos(phi)
    }

    /// Angular extent of a rib's bone and of its costal cartilage (radians of φ).
    fn rib_extent(&self, rib: u32) -> ((f64, f64), Option<(f64, f64)>) {
        let d = PI / 180.0;
        match rib {
            11 => ((12.0 * d, 112.0 * d), None),
            12 => ((12.0 * d, 72.0 * d), None),
            _ => ((12.0 * d, 150.0 * d), Some((150.0 * d, 172.0 * d))),
        }
    }

    /// Signed distance to a rib segment in the wall frame (ellipse cross-section, flat ends).
    fn rib_sdf(&self, f: &BodyFrame, z: f64, rib: u32, range: (f64, f64), half_r: f64, half_h: f64) -> f64 {
        let dr = f.depth - (f.b_ribs + 0.5 * RIB_LAYER_MM);
        let dz = z - self.rib_z(rib, f.phi);
        let q0 = sqrt(sq(dr / half_r) + sq(dz / half_h));
        let q1 = sqrt(sq(dr / (half_r * half_r)) + sq(dz / (half_h * half_h)));
        let ellipse = if q1 > 0.0 { q0 * (q0 - 1.0) / q1 } else { -half_r };
        let arc = (range.0 - f.phi).max(f.phi - range.1) * f.rho;
        ellipse.max(arc)
    }

    /// Lowest edge of the rib cage at angle φ (below it the wall is abdominal: no intercostal fascia).
    fn costal_margin_z(&self, phi: f64) -> f64 {
        let mut low = f64::INFINITY;
        for rib in RIBS {
            let (bone, cart) = self.rib_extent(rib);
            let within = (phi >= bone.0 && phi <= bone.1) || cart.is_some_and(|c| phi >= c.0 && phi <= c.1);
            if within {
                low = low.min(self.rib_z(rib, phi) - RIB_HALF_HEIGHT - 4.0);
            }
        }
        low
    }

    /// Height of the diaphragm's upper surface: two domes, the right one higher (§6 of the digest:
    /// the liver lies under the right dome).
    pub fn diaphragm_z(&self, x: f64, y: f64) -> f64 {
        let right = 95.0 - 0.01 * (sq(x - 60.0) + sq(y - 5.0));
        let left = 85.0 - 0.01 * (sq(x + 65.0) + sq(y - 5.0));
        right.max(left)
    }

    /// Mediastinum and posterior midline, where there is no lung (signed distance).
    fn mediastinum_sdf(&self, x: f64, y: f64) -> f64 {
        box2(x, y, -55.0, 35.0, -15.0, 200.0).min(box2(x, y, -30.0, 30.0, -200.0, 0.0))
    }

    /// The liver: under the right dome, inside the cavity, above an inferior border that rises
    /// from the right lobe to the left lobe, anterior to the posterior abdominal wall.
    pub fn liver_sdf(&self, p: DVec3) -> f64 {
        let (x, y, z) = (p.x, p.y, p.z);
        let under_diaphragm = z - (self.diaphragm_z(x, y) - 4.0);
        let z_inf = -70.0 + (100.0 - x).max(0.0) * (65.0 / 140.0) + (y - 30.0).max(0.0) * 0.5;
        let above_border = z_inf - z;
        // Posterior limit: the bare area reaches back beside the spine on the right; medially the
        // liver stays in front of the vena cava, the aorta and the vertebrae.
        let y_post = piecewise(x, &[(-75.0, 20.0), (-30.0, 14.0), (38.0, 14.0), (58.0, -60.0)]);
        let anterior = y_post - y;
        let left_tip = -75.0 - x;
        let envelope = Ellipsoid::new([35.0, 15.0, 15.0], [125.0, 95.0, 105.0]).sdf(p);
        self.cavity_sdf(p)
            .max(under_diaphragm)
            .max(above_border)
            .max(anterior)
            .max(left_tip)
            .max(envelope)
    }

    pub fn landmarks(&self) -> Landmarks {
        let target = (RHD.0 + RHD.1) * 0.5;
        // Mid-axillary line (φ = π/2, θ = 0), halfway between ribs 10 and 11, in the rib layer.
        let z = 0.5 * (self.rib_z(10, FRAC_PI_2) + self.rib_z(11, FRAC_PI_2));
        let theta = 0.0;
        let phi = FRAC_PI_2;
        let depth = SKIN_MM + self.fat_mm(phi, z) + self.outer_muscle_mm(phi) + 0.5 * RIB_LAYER_MM;
        let r = self.surface_radius(theta, z) - depth;
        Landmarks {
            target,
            intercostal_10_11: DVec3::new(r, BODY_CENTER_Y, z),
        }
    }

    /// The body wall and cavity background at p: HU with partial-volume ramps (over `h` mm) and the
    /// ground-truth structure at p. This initialises every voxel before organs are painted.
    pub fn wall(&self, p: DVec3, h: f64) -> (f64, Structure) {
        let f = self.frame(p);
        let ramp = |d: f64| (d / h + 0.5).clamp(0.0, 1.0);
        let thorax = p.z > self.costal_margin_z(f.phi);
        let inner_wall = if thorax { hu::FASCIA } else { hu::MUSCLE };
        let (cavity_hu, cavity_s) = self.cavity_background(p, h);
        let mut v = hu::AIR;
        v += (hu::SKIN - v) * ramp(f.depth);
        v += (hu::FAT - hu::SKIN) * ramp(f.depth - f.b_fat);
        v += (hu::MUSCLE - hu::FAT) * ramp(f.depth - f.b_muscle);
        v += (inner_wall - hu::MUSCLE) * ramp(f.depth - f.b_fascia);
        v += (cavity_hu - inner_wall) * ramp(f.depth - f.b_cavity);
        let mut s = if f.depth < 0.0 {
            Structure::Air
        } else if f.depth < f.b_fat {
            Structure::Skin
        } else if f.depth < f.b_muscle {
            Structure::Fat
        } else if f.depth < f.b_fascia {
            Structure::Muscle
        } else if f.depth < f.b_cavity {
            if thorax { Structure::Fascia } else { Structure::Muscle }
        } else {
            cavity_s
        };
        // Ribs (cortex, marrow) and costal cartilage in the rib layer.
        if f.depth > f.b_ribs - h && f.depth < f.b_fascia + h {
            for rib in RIBS {
                let (bone, cart) = self.rib_extent(rib);
                let dz = p.z - self.rib_z(rib, f.phi);
                if dz.abs() > RIB_HALF_HEIGHT + h {
                    continue;
                }
                let outer = self.rib_sdf(&f, p.z, rib, bone, RIB_HALF_RADIAL, RIB_HALF_HEIGHT);
                let inner = self.rib_sdf(&f, p.z, rib, bone, RIB_HALF_RADIAL - 1.5, RIB_HALF_HEIGHT - 1.5);
                v += (hu::RIB_CORTEX - v) * ramp(-outer);
                v += (hu::MARROW - v) * ramp(-inner);
                if outer < 0.0 {
                    s = Structure::Rib;
                }
                if let Some(c) = cart {
                    let cs = self.rib_sdf(&f, p.z, rib, c, RIB_HALF_RADIAL - 0.5, RIB_HALF_HEIGHT - 1.0);
                    v += (hu::CARTILAGE - v) * ramp(-cs);
                    if cs < 0.0 {
                        s = Structure::Cartilage;
                    }
                }
            }
        }
        (v, s)
    }

    /// Inside the cavity before organs: lung above the diaphragm (except the mediastinum), the
    /// diaphragm muscle, and visceral fat below it.
    fn cavity_background(&self, p: DVec3, h: f64) -> (f64, Structure) {
        let ramp = |d: f64| (d / h + 0.5).clamp(0.0, 1.0);
        let zd = self.diaphragm_z(p.x, p.y);
        let med = self.mediastinum_sdf(p.x, p.y);
        let above_hu = hu::LUNG + (hu::VISCERAL_FAT - hu::LUNG) * ramp(-med);
        let mut v = hu::VISCERAL_FAT;
        v += (hu::DIAPHRAGM - v) * ramp(p.z - (zd - 4.0));
        v += (above_hu - hu::DIAPHRAGM) * ramp(p.z - zd);
        let s = if p.z >= zd {
            if med < 0.0 {
                Structure::Fat
            } else if p.x >= 0.0 {
                Structure::LungRight
            } else {
                Structure::LungLeft
            }
        } else if p.z >= zd - 4.0 {
            Structure::Diaphragm
        } else {
            Structure::Fat
        };
        (v, s)
    }
}

/// The right hepatic duct's axis: from the hilar confluence to its division (mm).
pub const RHD: (DVec3, DVec3) = (DVec3::new(31.0, 34.0, 3.0), DVec3::new(70.0, 26.0, 12.0));
