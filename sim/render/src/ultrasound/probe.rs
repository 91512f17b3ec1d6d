//! Scan geometry of the two probes (thesis §3.4; docs/ultrasound.md "Geometry"): where each
//! scan line starts and points, and the inverse map from a point of the image plane to its
//! (line, sample) position, which scan conversion reads. The probe frame is the physics' contact
//! pattern's (thesis Fig. 3.8): the array along +x, the beam along +z (the pressing direction),
//! the elevation (slice thickness) along +y.

use stylet_physics::glam::{DVec3, Mat3, Quat, Vec3};
use stylet_physics::{ProbeKind, PunctureAtlas};

use crate::tools::{CONVEX_HALF_ANGLE_DEG, CONVEX_RADIUS_MM, ProbeShape};

/// Width of the linear array (mm): physics' linear contact pattern is 40 mm long.
pub const LINEAR_APERTURE_MM: f32 = stylet_physics::probe_image::LINEAR_APERTURE_MM as f32;

/// The lines and samples of one frame, in world space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanGeometry {
    pub kind: ProbeKind,
    /// Centre of the transducer face (mm, world).
    pub face_mm: Vec3,
    /// Unit axes: array (lateral), elevation (the image plane's normal), beam.
    pub lateral: Vec3,
    pub elevation: Vec3,
    pub beam: Vec3,
    pub lines: u32,
    pub samples: u32,
    /// Imaging depth from the face along each line (mm).
    pub depth_mm: f32,
}

impl ScanGeometry {
    pub fn new(probe: &ProbeShape, lines: u32, samples: u32, depth_mm: f32) -> ScanGeometry {
        let [lateral, elevation, beam] = probe.axes();
        ScanGeometry {
            kind: probe.kind,
            face_mm: probe.position_mm,
            lateral,
            elevation,
            beam,
            lines,
            samples,
            depth_mm,
        }
    }

    /// Distance between samples along a line (mm).
    pub fn sample_mm(&self) -> f32 {
        self.depth_mm / self.samples as f32
    }

    /// How much air at the start of line `i` the coupling gel bridges (mm along the line): the
    /// gel layer [`super::GEL_MAX_MM`] beyond the plane tangent to the face's centre, plus, on a
    /// convex array, the line's own recess behind that plane, R(1/cos θ − 1) (7.7 mm at ±30°).
    /// Measured from the curved face itself, the outer lines spent the layer on the face's own
    /// curvature and went black on any flank that curves away.
    pub fn gel_allowance_mm(&self, i: u32) -> f32 {
        match self.kind {
            ProbeKind::Linear => super::GEL_MAX_MM,
            ProbeKind::Convex => {
                let f = (i as f32 + 0.5) / self.lines as f32;
                let theta = (2.0 * f - 1.0) * CONVEX_HALF_ANGLE_DEG.to_radians();
                super::GEL_MAX_MM + CONVEX_RADIUS_MM * (1.0 / theta.cos() - 1.0)
            }
        }
    }

    /// Line `i`'s start on the transducer face and its unit direction (world). Linear: parallel
    /// lines spread evenly over the aperture; convex: a fan from the face's centre of curvature,
    /// evenly in angle over ±30°.
    pub fn line(&self, i: u32) -> (Vec3, Vec3) {
        let f = (i as f32 + 0.5) / self.lines as f32;
        match self.kind {
            ProbeKind::Linear => (
                self.face_mm + self.lateral * ((f - 0.5) * LINEAR_APERTURE_MM),
                self.beam,
            ),
            ProbeKind::Convex => {
                let half = CONVEX_HALF_ANGLE_DEG.to_radians();
                let theta = (2.0 * f - 1.0) * half;
                let dir = self.beam * theta.cos() + self.lateral * theta.sin();
                (self.apex_mm() + dir * CONVEX_RADIUS_MM, dir)
            }
        }
    }

    /// The convex array's centre of curvature (behind the face).
    fn apex_mm(&self) -> Vec3 {
        self.face_mm - self.beam * CONVEX_RADIUS_MM
    }

    /// World point of sample `j` on line `i`: the middle of its depth interval.
    pub fn sample_point(&self, i: u32, j: u32) -> Vec3 {
        let (o, d) = self.line(i);
        o + d * ((j as f32 + 0.5) * self.sample_mm())
    }

    /// A world point's coordinates in the probe frame: (lateral, along the beam from the face,
    /// off the image plane), mm.
    pub fn plane_coords(&self, x: Vec3) -> (f32, f32, f32) {
        let d = x - self.face_mm;
        (d.dot(self.lateral), d.dot(self.beam), d.dot(self.elevation))
    }

    /// The continuous (line, sample) index of the image-plane point (u lateral, v along the
    /// beam from the face), sample centres at integers; `None` outside the imaged sector.
    pub fn index_at(&self, u: f32, v: f32) -> Option<(f32, f32)> {
        let (fi, fj) = match self.kind {
            ProbeKind::Linear => (
                (u / LINEAR_APERTURE_MM + 0.5) * self.lines as f32 - 0.5,
                v / self.sample_mm() - 0.5,
            ),
            ProbeKind::Convex => {
                let (du, dv) = (u, v + CONVEX_RADIUS_MM);
                let half = CONVEX_HALF_ANGLE_DEG.to_radians();
                let theta = du.atan2(dv);
                let rho = (du * du + dv * dv).sqrt();
                (
                    (theta / half + 1.0) * 0.5 * self.lines as f32 - 0.5,
                    (rho - CONVEX_RADIUS_MM) / self.sample_mm() - 0.5,
                )
            }
        };
        let inside = (-0.5..=self.lines as f32 - 0.5).contains(&fi) && (-0.5..=self.samples as f32 - 0.5).contains(&fj);
        inside.then_some((fi, fj))
    }

    /// The image's bounding box in the plane: (u_min, u_max, v_min, v_max), mm.
    pub fn bounds(&self) -> (f32, f32, f32, f32) {
        match self.kind {
            ProbeKind::Linear => (-LINEAR_APERTURE_MM / 2.0, LINEAR_APERTURE_MM / 2.0, 0.0, self.depth_mm),
            ProbeKind::Convex => {
                let half = CONVEX_HALF_ANGLE_DEG.to_radians();
                let r = CONVEX_RADIUS_MM;
                let u = (r + self.depth_mm) * half.sin();
                (-u, u, r * half.cos() - r, self.depth_mm)
            }
        }
    }
}

/// How far from the path's skin entry the probe may sit (mm), nearest first, so that the needle
/// crosses the image rather than running down its middle line.
pub const PATH_VIEW_OFFSETS_MM: [f64; 5] = [50.0, 40.0, 60.0, 30.0, 20.0];
/// CT values above this block the view (bone).
const BONE_HU: f64 = 250.0;

/// A probe on the skin that images an insertion path in plane, as for an in-plane puncture
/// (thesis Fig. 2.1): the image plane holds the path (entry → target) and the patient's
/// left–right direction; the probe sits beside the entry, anterior or posterior, at the first of
/// [`PATH_VIEW_OFFSETS_MM`] from which the target is seen through no bone (an acoustic window
/// between the ribs), else the one with the least bone in the way; on the skin, its beam aimed
/// at the target. `None` when entry and target coincide.
pub fn facing_path(atlas: &PunctureAtlas, kind: ProbeKind, entry_mm: DVec3, target_mm: DVec3) -> Option<ProbeShape> {
    let d = (target_mm - entry_mm).try_normalize()?;
    // Across the path, in the axial plane when possible; anterior (+y) first.
    let mut across = DVec3::Z.cross(d).try_normalize().unwrap_or(DVec3::X);
    if across.y < 0.0 {
        across = -across;
    }
    let normal = across.cross(d).try_normalize()?;
    let mut best: Option<(usize, ProbeShape)> = None;
    for side in [1.0, -1.0] {
        for offset in PATH_VIEW_OFFSETS_MM {
            let Some((probe, bone)) = on_skin(atlas, kind, entry_mm + across * (side * offset), target_mm, normal)
            else {
                continue;
            };
            if bone == 0 {
                return Some(probe);
            }
            if best.as_ref().is_none_or(|(b, _)| bone < *b) {
                best = Some((bone, probe));
            }
        }
    }
    best.map(|(_, p)| p)
}

/// The probe that looks from near `start` at `target` in the plane of `normal`, placed 0.5 mm
/// under the skin, and how many 1 mm steps of bone lie between its face and the target.
fn on_skin(
    atlas: &PunctureAtlas,
    kind: ProbeKind,
    start: DVec3,
    target_mm: DVec3,
    normal: DVec3,
) -> Option<(ProbeShape, usize)> {
    let beam = (target_mm - start).try_normalize()?;
    let skin = atlas.skin_distance();
    let face = (0..320)
        .map(|k| start - beam * (80.0 - 0.5 * k as f64))
        .find(|&x| skin.sample(x, -1.0e3) >= 0.5)?;
    let reach = (target_mm - face).length();
    let bone = (0..reach as usize)
        .filter(|&k| atlas.hu_at(face + beam * k as f64) > BONE_HU)
        .count();
    let lateral = normal.cross(beam);
    let orientation =
        Quat::from_mat3(&Mat3::from_cols(lateral.as_vec3(), normal.as_vec3(), beam.as_vec3())).normalize();
    Some((
        ProbeShape {
            kind,
            position_mm: face.as_vec3(),
            orientation,
        },
        bone,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry(kind: ProbeKind) -> ScanGeometry {
        let probe = ProbeShape {
            kind,
            position_mm: Vec3::new(3.0, -2.0, 5.0),
            orientation: Quat::from_rotation_x(0.4) * Quat::from_rotation_z(0.3),
        };
        ScanGeometry::new(&probe, 64, 128, 120.0)
    }

    #[test]
    fn every_sample_maps_back_to_its_own_index() {
        for kind in [ProbeKind::Linear, ProbeKind::Convex] {
            let g = geometry(kind);
            for (i, j) in [(0, 0), (10, 77), (63, 127), (31, 64)] {
                let (u, v, e) = g.plane_coords(g.sample_point(i, j));
                assert!(e.abs() < 1e-3, "{kind:?}: off the plane by {e}");
                let (fi, fj) = g.index_at(u, v).expect("inside");
                assert!(
                    (fi - i as f32).abs() < 1e-3 && (fj - j as f32).abs() < 1e-3,
                    "{kind:?} {i} {j}: {fi} {fj}"
                );
            }
            let (u0, u1, v0, v1) = g.bounds();
            assert!(g.index_at(u1 + 1.0, v1 / 2.0).is_none() && g.index_at(0.0, v1 + 1.0).is_none());
            assert!(u0 < 0.0 && v0 <= 0.0);
        }
    }

    #[test]
    fn the_convex_fan_spans_sixty_degrees_and_the_linear_array_forty_mm() {
        let g = geometry(ProbeKind::Convex);
        let (_, first) = g.line(0);
        let (_, last) = g.line(g.lines - 1);
        let spread = first.angle_between(last).to_degrees();
        assert!((spread - 60.0 * 63.0 / 64.0).abs() < 0.01, "{spread}");
        let g = geometry(ProbeKind::Linear);
        let (a, _) = g.line(0);
        let (b, _) = g.line(g.lines - 1);
        assert!((a.distance(b) - 40.0 * 63.0 / 64.0).abs() < 1e-3);
    }
}
