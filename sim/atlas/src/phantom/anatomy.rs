//! The phantom's body plan: an adult lower chest and upper abdomen in world mm (RAS: +x patient
//! right, +y anterior, +z superior), centred on the origin, about z = −150 … +150 mm.
//!
//! The body wall is described in a body frame (angle around the torso, depth under the skin) so
//! that skin, subcutaneous fat, muscle, ribs with their intercostal spaces and the intercostal
//! fascia follow the body contour. Organs are signed-distance shapes painted on top, clipped to
//! the body cavity. Numbers are typical adult dimensions; the right 10th/11th intercostal space at
//! the mid-axillary line gives a straight path into the right hepatic duct that avoids lung, ribs
//! and vessels (the PTCD entry of ALGORITHMS.md §7).

use std::f64::consts::{FRAC_PI_2, PI};

use libm::{atan2, cos, pow, sin, sqrt};
use stylet_physics::glam::DVec3;

use super::noise::Rng;
use super::shapes::{Aabb, Capsule, Ellipsoid, Tube, smoothstep};
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

fn sq(x: f64) -> f64 {
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

    /// Muscle outside the ribs: about 8 mm over the flanks and the front, the erector spinae
    /// (up to 40 mm) beside the spine, so the ribs dive towards the transverse processes.
    fn outer_muscle_mm(&self, phi: f64) -> f64 {
        8.0 + 32.0 * (1.0 - smoothstep(15.0_f64.to_radians(), 50.0_f64.to_radians(), phi))
    }

    /// Subcutaneous fat thickness: thicker in front than at the back, thinner over the chest.
    fn fat_mm(&self, phi: f64, z: f64) -> f64 {
        let base = 11.0 + 9.0 * (1.0 - cos(phi)) / 2.0;
        base * (1.0 - 0.25 * smoothstep(20.0, 90.0, z))
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

    /// All organs, vessels and ducts in painting order (later parts cover earlier ones).
    pub fn parts(&self) -> Vec<Part> {
        let mut parts: Vec<Part> = Vec::new();
        let me = self.clone();
        // Abdominal organs stay inside the cavity and below the diaphragm.
        let abdominal = |shape: Ellipsoid| {
            let a = me.clone();
            move |p: DVec3| {
                shape
                    .sdf(p)
                    .max(a.cavity_sdf(p))
                    .max(p.z - (a.diaphragm_z(p.x, p.y) - 4.0))
            }
        };
        let ell = |s: Structure, v: f64, c: [f64; 3], r: [f64; 3]| {
            let e = Ellipsoid::new(c, r);
            Part {
                structure: s,
                hu: v,
                aabb: e.aabb(),
                sdf: Box::new(abdominal(e)),
            }
        };
        let tube = |s: Structure, v: f64, pts: &[[f64; 3]], r: &[f64]| {
            let t = Tube::new(pts, r);
            Part {
                structure: s,
                hu: v,
                aabb: t.aabb(),
                sdf: Box::new(move |p| t.sdf(p)),
            }
        };

        // Psoas muscles first (organs may press on them); the erector spinae is part of the wall.
        for side in [-1.0, 1.0] {
            let psoas = Tube::new(
                &[[40.0 * side, -22.0, -10.0], [48.0 * side, -20.0, -160.0]],
                &[6.0, 20.0],
            );
            parts.push(Part {
                structure: Structure::Muscle,
                hu: hu::MUSCLE,
                aabb: psoas.aabb(),
                sdf: Box::new(move |p| psoas.sdf(p)),
            });
        }

        // Liver first among the abdominal organs: its neighbours carve into it.
        let a = self.clone();
        parts.push(Part {
            structure: Structure::Liver,
            hu: hu::LIVER,
            aabb: Aabb::new(DVec3::new(-80.0, -65.0, -75.0), DVec3::new(160.0, 120.0, 100.0)),
            sdf: Box::new(move |p| a.liver_sdf(p)),
        });
        // Gallbladder (wall, then bile) on the liver's inferior surface.
        parts.push(ell(
            Structure::Gallbladder,
            hu::GALLBLADDER_WALL,
            [52.0, 55.0, -35.0],
            [15.0, 18.0, 36.0],
        ));
        parts.push(ell(
            Structure::Gallbladder,
            hu::BILE,
            [52.0, 55.0, -35.0],
            [13.0, 16.0, 34.0],
        ));
        // Kidneys with renal sinus fat.
        for (x, z) in [(75.0, -45.0), (-75.0, -32.0)] {
            parts.push(ell(Structure::Kidney, hu::KIDNEY, [x, -42.0, z], [28.0, 24.0, 52.0]));
            parts.push(ell(
                Structure::Fat,
                hu::RENAL_SINUS,
                [x * 0.92, -38.0, z],
                [10.0, 9.0, 22.0],
            ));
        }
        parts.push(ell(
            Structure::Spleen,
            hu::SPLEEN,
            [-105.0, -35.0, 35.0],
            [28.0, 42.0, 50.0],
        ));
        // Stomach: wall, content, gas rising anteriorly in a supine patient.
        parts.push(ell(
            Structure::Stomach,
            hu::STOMACH_WALL,
            [-75.0, 20.0, 28.0],
            [38.0, 42.0, 50.0],
        ));
        parts.push(ell(
            Structure::Stomach,
            hu::STOMACH_CONTENT,
            [-75.0, 20.0, 28.0],
            [34.0, 38.0, 46.0],
        ));
        {
            let inner = Ellipsoid::new([-75.0, 20.0, 28.0], [34.0, 38.0, 46.0]);
            parts.push(Part {
                structure: Structure::Gas,
                hu: hu::AIR,
                aabb: inner.aabb(),
                sdf: Box::new(move |p| inner.sdf(p).max(40.0 - p.y)),
            });
        }
        // Pancreas with the lesion in its head, duodenal C-loop around it.
        parts.push(tube(
            Structure::Pancreas,
            hu::PANCREAS,
            &[[22.0, 34.0, -62.0], [-20.0, 30.0, -45.0], [-85.0, -5.0, -25.0]],
            &[17.0, 12.0, 10.0],
        ));
        parts.push(tube(
            Structure::Duodenum,
            hu::DUODENUM,
            &[
                [5.0, 58.0, -40.0],
                [48.0, 34.0, -52.0],
                [50.0, 28.0, -90.0],
                [5.0, 18.0, -98.0],
                [-22.0, 22.0, -82.0],
            ],
            &[11.0, 12.0, 12.0, 11.0, 10.0],
        ));
        // Colon: ascending, hepatic flexure, transverse, splenic flexure, descending; stool below,
        // gas above (anterior) the centre line.
        let colon_pts = [
            [95.0, -5.0, -160.0],
            [95.0, 5.0, -88.0],
            [70.0, 45.0, -82.0],
            [-70.0, 50.0, -92.0],
            [-100.0, 20.0, -62.0],
            [-100.0, -10.0, -160.0],
        ];
        let colon_r = [20.0, 22.0, 22.0, 21.0, 20.0, 19.0];
        parts.push(tube(Structure::Colon, hu::COLON_WALL, &colon_pts, &colon_r));
        let inner_r: Vec<f64> = colon_r.iter().map(|r| r - 3.0).collect();
        parts.push(tube(Structure::Colon, hu::STOOL, &colon_pts, &inner_r));
        {
            let t = Tube::new(&colon_pts, &inner_r);
            parts.push(Part {
                structure: Structure::Gas,
                hu: hu::AIR,
                aabb: t.aabb(),
                sdf: Box::new(move |p| {
                    let mut best = (f64::INFINITY, 0.0);
                    for c in &t.segments {
                        let (d, tt) = c.sdf_t(p);
                        if d < best.0 {
                            best = (d, c.a.y + tt * (c.b.y - c.a.y));
                        }
                    }
                    best.0.max(best.1 + 4.0 - p.y)
                }),
            });
        }
        // Small bowel loops in the lower abdomen.
        let mut rng = Rng::new(self.seed, 0xB0E1);
        for _ in 0..7 {
            let c = [rng.range(-70.0, 60.0), rng.range(0.0, 60.0), rng.range(-150.0, -105.0)];
            let pts = [
                [
                    c[0] - 30.0,
                    c[1] + rng.range(-10.0, 10.0),
                    c[2] + rng.range(-10.0, 10.0),
                ],
                c,
                [
                    c[0] + 30.0,
                    c[1] + rng.range(-10.0, 10.0),
                    c[2] + rng.range(-10.0, 10.0),
                ],
            ];
            let t = Tube::new(&pts, &[11.0, 11.0, 11.0]);
            let a = self.clone();
            parts.push(Part {
                structure: Structure::Bowel,
                hu: hu::BOWEL,
                aabb: t.aabb(),
                sdf: Box::new(move |p| t.sdf(p).max(a.cavity_sdf(p))),
            });
        }
        // Heart above the diaphragm's central part.
        {
            let e = Ellipsoid::new([-15.0, 35.0, 120.0], [55.0, 45.0, 55.0]);
            let a = self.clone();
            parts.push(Part {
                structure: Structure::Heart,
                hu: hu::HEART,
                aabb: e.aabb(),
                sdf: Box::new(move |p| e.sdf(p).max(a.cavity_sdf(p))),
            });
        }

        // The spine over the posterior organs, the great vessels in front of it.
        parts.extend(self.spine());
        // Great vessels.
        parts.push(tube(
            Structure::Aorta,
            hu::AORTA,
            &[
                [-15.0, 2.0, -160.0],
                [-18.0, 0.0, 40.0],
                [-25.0, -8.0, 80.0],
                [-26.0, -10.0, 160.0],
            ],
            &[11.0, 11.5, 12.0, 12.0],
        ));
        parts.push(tube(
            Structure::VenaCava,
            hu::VENA_CAVA,
            &[
                [22.0, 0.0, -160.0],
                [24.0, 2.0, 40.0],
                [22.0, -2.0, 95.0],
                [5.0, 25.0, 115.0],
            ],
            &[10.0, 10.0, 11.0, 12.0],
        ));
        // Lesion in the pancreatic head, obstructing the distal common bile duct.
        parts.push(ell(
            Structure::Lesion,
            hu::LESION,
            [20.0, 35.0, -60.0],
            [14.0, 13.0, 14.0],
        ));

        // Liver vessels and the dilated biliary tree.
        parts.extend(self.liver_trees());
        parts
    }

    /// Vertebrae (cortex, cancellous bone, processes), discs and the spinal canal.
    fn spine(&self) -> Vec<Part> {
        let mut parts = Vec::new();
        let pitch = 32.0;
        let body_h = 25.0;
        let mut zc = -160.0;
        while zc < 170.0 {
            let (z0, z1) = (zc - body_h / 2.0, zc + body_h / 2.0);
            let body = move |p: DVec3, inset: f64| {
                let radial = sqrt(sq(p.x / (22.0 - inset)) + sq((p.y + 30.0) / (17.0 - inset)));
                let r = (radial - 1.0) * (17.0 - inset);
                r.max(z0 + inset - p.z).max(p.z - z1 + inset)
            };
            let aabb = Aabb::new(DVec3::new(-23.0, -48.0, z0), DVec3::new(23.0, -12.0, z1));
            parts.push(Part {
                structure: Structure::Vertebra,
                hu: hu::VERTEBRA_CORTEX,
                aabb,
                sdf: Box::new(move |p| body(p, 0.0)),
            });
            parts.push(Part {
                structure: Structure::Vertebra,
                hu: hu::CANCELLOUS,
                aabb,
                sdf: Box::new(move |p| body(p, 1.8)),
            });
            let processes = [
                // pedicles, laminae, spinous process, transverse processes
                ([12.0, -40.0, zc], [12.0, -54.0, zc], 5.0),
                ([-12.0, -40.0, zc], [-12.0, -54.0, zc], 5.0),
                ([12.0, -56.0, zc], [0.0, -68.0, zc - 3.0], 4.0),
                ([-12.0, -56.0, zc], [0.0, -68.0, zc - 3.0], 4.0),
                ([0.0, -66.0, zc - 3.0], [0.0, -84.0, zc - 10.0], 5.0),
                ([14.0, -46.0, zc], [44.0, -50.0, zc + 2.0], 4.5),
                ([-14.0, -46.0, zc], [-44.0, -50.0, zc + 2.0], 4.5),
            ];
            for (a, b, r) in processes {
                let c = Capsule::new(DVec3::from_array(a), DVec3::from_array(b), r, r);
                parts.push(Part {
                    structure: Structure::Vertebra,
                    hu: hu::MARROW + 150.0,
                    aabb: c.aabb(),
                    sdf: Box::new(move |p| c.sdf(p)),
                });
            }
            let (d0, d1) = (z1, z1 + pitch - body_h);
            let disc = move |p: DVec3| {
                let radial = sqrt(sq(p.x / 21.0) + sq((p.y + 30.0) / 16.0));
                ((radial - 1.0) * 16.0).max(d0 - p.z).max(p.z - d1)
            };
            parts.push(Part {
                structure: Structure::Disc,
                hu: hu::DISC,
                aabb: Aabb::new(DVec3::new(-22.0, -47.0, d0), DVec3::new(22.0, -13.0, d1)),
                sdf: Box::new(disc),
            });
            zc += pitch;
        }
        let canal = Capsule::new(DVec3::new(0.0, -55.0, -200.0), DVec3::new(0.0, -55.0, 200.0), 9.0, 9.0);
        parts.push(Part {
            structure: Structure::SpinalCord,
            hu: hu::CSF,
            aabb: canal.aabb(),
            sdf: Box::new(move |p| canal.sdf(p)),
        });
        let cord = Capsule::new(DVec3::new(0.0, -55.0, -200.0), DVec3::new(0.0, -55.0, 200.0), 5.5, 5.5);
        parts.push(Part {
            structure: Structure::SpinalCord,
            hu: hu::CORD,
            aabb: cord.aabb(),
            sdf: Box::new(move |p| cord.sdf(p)),
        });
        parts
    }

    /// Portal and hepatic veins and the dilated biliary tree. Main trunks are fixed; peripheral
    /// branches are grown from the seed, inside the liver and clear of the planned insertion path.
    fn liver_trees(&self) -> Vec<Part> {
        let lm = self.landmarks();
        let path = Capsule::new(lm.target, lm.intercostal_10_11, 0.0, 0.0);
        let mut parts = Vec::new();
        let seg = |s: Structure, v: f64, c: Capsule| Part {
            structure: s,
            hu: v,
            aabb: c.aabb(),
            sdf: Box::new(move |p| c.sdf(p)),
        };
        let cap = |a: [f64; 3], b: [f64; 3], ra: f64, rb: f64| {
            Capsule::new(DVec3::from_array(a), DVec3::from_array(b), ra, rb)
        };

        // Portal vein: main trunk to the hilum, right and left branches, right anterior/posterior.
        let pv_main = [
            cap([0.0, 28.0, -52.0], [14.0, 26.0, -25.0], 7.5, 7.2),
            cap([14.0, 26.0, -25.0], [24.0, 20.0, -5.0], 7.2, 7.0),
        ];
        let rpv = cap([24.0, 20.0, -5.0], [68.0, 6.0, 4.0], 6.0, 5.5);
        let rpv_ant = cap([68.0, 6.0, 4.0], [92.0, 30.0, 0.0], 4.5, 4.0);
        let rpv_post = cap([68.0, 6.0, 4.0], [98.0, -20.0, 12.0], 4.5, 4.0);
        let lpv = [
            cap([24.0, 20.0, -5.0], [-5.0, 28.0, 5.0], 5.5, 5.0),
            cap([-5.0, 28.0, 5.0], [-30.0, 36.0, 12.0], 5.0, 4.5),
        ];
        let mut pv: Vec<Capsule> = pv_main.iter().chain(&lpv).copied().collect();
        pv.extend([rpv, rpv_ant, rpv_post]);

        // Bile duct trunks: common bile duct from the lesion up to the hilum, left hepatic duct and
        // the right hepatic duct's anterior and posterior segmental ducts (the target comes last).
        let cbd = [
            cap([20.0, 35.0, -47.0], [26.0, 36.0, -25.0], 6.0, 6.0),
            cap([26.0, 36.0, -25.0], [30.0, 35.0, -2.0], 6.0, 5.5),
        ];
        let lhd = [
            cap([29.0, 35.0, 1.0], [-2.0, 42.0, 9.0], 4.2, 4.0),
            cap([-2.0, 42.0, 9.0], [-28.0, 48.0, 15.0], 4.0, 3.2),
        ];
        let seg_ducts = [
            cap(RHD.1.to_array(), [93.0, 46.0, 8.0], 3.4, 3.0),
            cap(RHD.1.to_array(), [99.0, -4.0, 18.0], 3.4, 3.0),
        ];

        // Peripheral portal branches, each with a companion bile duct (portal triads) that starts
        // where its parent's companion ends, so the biliary tree stays one connected piece.
        let mut rng = Rng::new(self.seed, 0x7EE5);
        let inside = |p: DVec3| self.liver_sdf(p);
        let mut duct_branches = Vec::new();
        let mut pv_branches = Vec::new();
        for (root, duct_root) in [(rpv_ant, seg_ducts[0]), (rpv_post, seg_ducts[1]), (lpv[1], lhd[1])] {
            let dir = (root.b - root.a).normalize();
            let mut tree = Vec::new();
            grow(
                &mut rng,
                root.b,
                dir,
                28.0,
                root.rb * 0.8,
                2,
                &inside,
                &path,
                None,
                &mut tree,
            );
            let mut duct_end: Vec<Option<(DVec3, f64)>> = Vec::with_capacity(tree.len());
            for b in &tree {
                let c = b.capsule;
                let start = match b.parent {
                    None => Some((duct_root.b, duct_root.rb)),
                    Some(p) => duct_end[p],
                };
                let companion = start.and_then(|(a, ra)| {
                    let axis = (c.b - c.a).normalize();
                    let anterior = (DVec3::Y - axis * axis.y).normalize_or_zero();
                    let rb = (c.rb * 0.6).max(1.0);
                    let d = Capsule::new(a, c.b + anterior * (c.rb + rb + 1.5), ra.min((c.ra * 0.6).max(1.2)), rb);
                    let ok = inside(d.b) < -(d.rb + 1.0) && segment_distance(&d, &path) > 6.0;
                    ok.then_some(d)
                });
                duct_end.push(companion.map(|d| (d.b, d.rb)));
                duct_branches.extend(companion);
            }
            pv_branches.extend(tree.iter().map(|b| b.capsule));
        }
        pv.extend(pv_branches);

        // Hepatic veins into the IVC below the heart, with grown branches.
        let hv_trunks = [
            [
                cap([26.0, 0.0, 80.0], [70.0, -15.0, 55.0], 6.5, 5.5),
                cap([70.0, -15.0, 55.0], [112.0, -20.0, 25.0], 5.5, 4.0),
            ],
            [
                cap([20.0, 8.0, 82.0], [35.0, 40.0, 50.0], 6.0, 5.0),
                cap([35.0, 40.0, 50.0], [45.0, 65.0, 12.0], 5.0, 3.5),
            ],
            [
                cap([12.0, 8.0, 82.0], [-10.0, 30.0, 65.0], 5.5, 4.5),
                cap([-10.0, 30.0, 65.0], [-35.0, 45.0, 45.0], 4.5, 3.5),
            ],
        ];
        let mut hv: Vec<Capsule> = hv_trunks.iter().flatten().copied().collect();
        let mut hv_branches = Vec::new();
        for t in &hv_trunks {
            let root = t[1];
            grow(
                &mut rng,
                root.b,
                (root.b - root.a).normalize(),
                24.0,
                root.rb * 0.8,
                2,
                &inside,
                &path,
                None,
                &mut hv_branches,
            );
            let mid = (t[0].a + t[0].b) * 0.5;
            let side = (t[0].b - t[0].a).normalize().cross(DVec3::Z).normalize_or_zero();
            grow(
                &mut rng,
                mid,
                (side - DVec3::Z * 0.5).normalize(),
                22.0,
                3.0,
                1,
                &inside,
                &path,
                None,
                &mut hv_branches,
            );
        }
        hv.extend(hv_branches.iter().map(|b| b.capsule));

        let target = Capsule::new(RHD.0, RHD.1, 4.5, 4.5);

        for c in pv {
            parts.push(seg(Structure::PortalVein, hu::PORTAL_VEIN, c));
        }
        for c in hv {
            parts.push(seg(Structure::HepaticVein, hu::HEPATIC_VEIN, c));
        }
        for c in cbd.into_iter().chain(lhd).chain(seg_ducts).chain(duct_branches) {
            parts.push(seg(Structure::BileDuct, hu::BILE, c));
        }
        parts.push(seg(Structure::TargetDuct, hu::BILE, target));
        parts
    }
}

/// The right hepatic duct's axis: from the hilar confluence to its division (mm).
pub const RHD: (DVec3, DVec3) = (DVec3::new(31.0, 34.0, 3.0), DVec3::new(70.0, 26.0, 12.0));

/// Smallest distance between a capsule's axis and a segment (sampled, good to 0.5 mm).
fn segment_distance(c: &Capsule, path: &Capsule) -> f64 {
    let n = 24;
    (0..=n)
        .map(|i| {
            let p = c.a + (c.b - c.a) * (i as f64 / n as f64);
            path.sdf(p) - c.ra.max(c.rb)
        })
        .fold(f64::INFINITY, f64::min)
}

/// One grown vessel segment and the segment it branches from (`None` for a root).
#[derive(Debug, Clone, Copy)]
struct Branch {
    capsule: Capsule,
    parent: Option<usize>,
}

/// Grows a binary branching tree from `start` along `dir` inside the region where `inside` < 0,
/// keeping every branch at least 6 mm from the planned insertion path.
#[allow(clippy::too_many_arguments)]
fn grow(
    rng: &mut Rng,
    start: DVec3,
    dir: DVec3,
    len: f64,
    radius: f64,
    depth: u32,
    inside: &dyn Fn(DVec3) -> f64,
    path: &Capsule,
    parent: Option<usize>,
    out: &mut Vec<Branch>,
) {
    if radius < 1.2 {
        return;
    }
    let mut l = len;
    for _ in 0..3 {
        let end = start + dir * l;
        let c = Capsule::new(start, end, radius, radius * 0.85);
        if inside(end) < -(radius + 2.0) && segment_distance(&c, path) > 6.0 {
            out.push(Branch { capsule: c, parent });
            let me = Some(out.len() - 1);
            if depth > 0 {
                for k in 0..2 {
                    let angle = rng.range(0.4, 0.75) * if k == 0 { 1.0 } else { -1.0 };
                    let child = rotate_about_random_axis(rng, dir, angle);
                    let child_len = len * rng.range(0.6, 0.8);
                    grow(
                        rng,
                        end,
                        child,
                        child_len,
                        radius * 0.72,
                        depth - 1,
                        inside,
                        path,
                        me,
                        out,
                    );
                }
            }
            return;
        }
        l *= 0.6;
    }
}

/// Rotates `dir` by `angle` about an axis perpendicular to it, the axis chosen at random.
fn rotate_about_random_axis(rng: &mut Rng, dir: DVec3, angle: f64) -> DVec3 {
    let helper = if dir.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let u = dir.cross(helper).normalize();
    let w = dir.cross(u);
    let spin = rng.range(0.0, 2.0 * PI);
    let axis = u * cos(spin) + w * sin(spin);
    // Rodrigues' rotation of dir about an axis perpendicular to it.
    (dir * cos(angle) + axis.cross(dir) * sin(angle)).normalize()
}
