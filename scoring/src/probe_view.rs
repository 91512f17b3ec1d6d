//! What an ultrasound probe shows: a probe's frame in the world, the image the renderer draws
//! (the needle-in-plane share), and the survey's "in view" test of the target (PerkTutor's
//! TargetsScanned; docs/metrics.md "Ultrasound survey").
//!
//! The survey tests every target point on every tick the target is out of view (up to
//! `MAX_TARGET_POINTS` in `target.rs`). [`SurveyPoints`] keeps the points in blocks with a
//! bounding sphere, so a block that lies wholly off the view is passed after one test: the
//! decision is the one of testing every point (a block is passed only when no point in it can
//! pass), only the work differs.

use stylet_physics::ProbeKind;
use stylet_physics::glam::{DQuat, DVec3};

/// The image plane test of the ultrasound survey: a target within this distance of the plane
/// (mm), down to this depth (mm).
pub const VIEW_PLANE_MM: f64 = 5.0;
pub const VIEW_DEPTH_MM: f64 = 150.0;
/// Half the width of a linear array's survey strip (mm).
const LINEAR_HALF_WIDTH_MM: f64 = 20.0;
/// Half the width of a convex probe's sector at its face (mm): 60° of a 50 mm radius.
const CONVEX_HALF_WIDTH_MM: f64 = 25.0;

/// A probe's frame in the world: its position, the array (tool x), the beam (tool z) and the
/// image plane's normal (tool y). The axes are rotated once per pose, not once per point tested,
/// with the same bits as rotating them per point.
pub struct ProbeFrame {
    position: DVec3,
    array: DVec3,
    beam: DVec3,
    normal: DVec3,
    /// At least the longest axis' length (1 for a unit quaternion; a recorded orientation need
    /// not be one exactly): how far a coordinate can move per mm the point moves. max(1, ‖axis‖²)
    /// is such a bound without a square root.
    stretch: f64,
}

impl ProbeFrame {
    pub fn new(position: DVec3, orientation: DQuat) -> ProbeFrame {
        let q = orientation;
        let (array, beam, normal) = (q * DVec3::X, q * DVec3::Z, q * DVec3::Y);
        let longest_squared = array
            .length_squared()
            .max(beam.length_squared())
            .max(normal.length_squared());
        ProbeFrame {
            position,
            array,
            beam,
            normal,
            stretch: longest_squared.max(1.0) * (1.0 + 1e-9),
        }
    }

    /// A point in the probe's frame: (lateral along the array, depth along the beam, distance
    /// off the image plane), mm.
    pub fn coords(&self, point: DVec3) -> (f64, f64, f64) {
        let d = point - self.position;
        (d.dot(self.array), d.dot(self.beam), d.dot(self.normal))
    }
}

/// Whether `point` lies in the image the renderer draws for a probe in `frame` (its default
/// depth), within `plane_mm` of the image plane.
pub fn in_rendered_image(frame: &ProbeFrame, kind: ProbeKind, point: DVec3, plane_mm: f64) -> bool {
    let (u, v, off) = frame.coords(point);
    off.abs() <= plane_mm && stylet_physics::probe_image::in_field(kind, kind.default_depth_mm(), u, v)
}

/// tan 30°: how fast a convex probe's survey sector widens with depth (computed as the survey
/// always has, once per call instead of once per point).
fn convex_widening() -> f64 {
    libm::tan(30f64.to_radians())
}

/// The ultrasound survey's "in view" (grades were computed with it, so it stays): within
/// `plane_mm` of the image plane, down to [`VIEW_DEPTH_MM`] for both probes, a 40 mm strip or a
/// sector 25 mm + depth·tan 30° wide each side. A little looser than the image the renderer
/// draws (`stylet_physics::probe_image`), which the needle-in-plane share uses.
pub fn in_survey_view(frame: &ProbeFrame, kind: ProbeKind, point: DVec3, plane_mm: f64) -> bool {
    in_survey_view_widening(frame, kind, point, plane_mm, convex_widening())
}

#[inline(always)]
fn in_survey_view_widening(frame: &ProbeFrame, kind: ProbeKind, point: DVec3, plane_mm: f64, widening: f64) -> bool {
    let (u, depth, off) = frame.coords(point);
    if off.abs() > plane_mm || !(0.0..=VIEW_DEPTH_MM).contains(&depth) {
        return false;
    }
    let half_width = match kind {
        ProbeKind::Linear => LINEAR_HALF_WIDTH_MM,
        ProbeKind::Convex => CONVEX_HALF_WIDTH_MM + depth * widening,
    };
    u.abs() <= half_width
}

/// Points per block: 4096 target points are 128 blocks.
const BLOCK_POINTS: usize = 32;
/// Added to every block's reach (mm): far more than the rounding of any coordinate, radius or
/// sector width within a kilometre of the probe, so a block is never passed by a rounding error.
const ROUNDING_MARGIN_MM: f64 = 1e-6;

/// Consecutive target points and the sphere that holds them.
#[derive(Debug, Clone, Copy)]
struct Block {
    centre: DVec3,
    radius_mm: f64,
    start: usize,
    end: usize,
}

/// Target points for the survey test, in blocks of `BLOCK_POINTS` consecutive points (the
/// points come in voxel order, so a block is a few neighbouring rows of the target).
#[derive(Debug, Clone, Default)]
pub struct SurveyPoints {
    points: Vec<DVec3>,
    blocks: Vec<Block>,
}

impl SurveyPoints {
    pub fn new(points: Vec<DVec3>) -> Self {
        let blocks = (0..points.len())
            .step_by(BLOCK_POINTS)
            .map(|start| {
                let end = (start + BLOCK_POINTS).min(points.len());
                let run = &points[start..end];
                let (lo, hi) = run.iter().fold((run[0], run[0]), |(lo, hi), &p| (lo.min(p), hi.max(p)));
                let centre = (lo + hi) * 0.5;
                let radius_mm = run.iter().map(|&p| p.distance(centre)).fold(0.0, f64::max);
                Block {
                    centre,
                    radius_mm,
                    start,
                    end,
                }
            })
            .collect();
        SurveyPoints { points, blocks }
    }

    /// Whether any point is in the survey view of a probe in `frame` ([`in_survey_view`] with
    /// [`VIEW_PLANE_MM`]): exactly `points().iter().any(…)`, with the blocks that cannot hold
    /// such a point passed after one test of their sphere.
    pub fn any_in_survey_view(&self, frame: &ProbeFrame, kind: ProbeKind) -> bool {
        let widening = convex_widening();
        self.blocks.iter().any(|b| {
            block_may_be_in_view(frame, kind, b, widening)
                && self.points[b.start..b.end]
                    .iter()
                    .any(|&p| in_survey_view_widening(frame, kind, p, VIEW_PLANE_MM, widening))
        })
    }
}

/// False only when no point within the block's sphere passes [`in_survey_view`]: each of the
/// point's frame coordinates lies within `reach` of the centre's (the sphere's radius times the
/// frame's stretch, plus a margin for rounding), so each bound below is the test's, loosened by
/// `reach`. NaN coordinates fail every comparison and leave the block to the points' own test.
#[inline(always)]
fn block_may_be_in_view(frame: &ProbeFrame, kind: ProbeKind, block: &Block, widening: f64) -> bool {
    let (u, depth, off) = frame.coords(block.centre);
    let reach = block.radius_mm * frame.stretch + ROUNDING_MARGIN_MM;
    if off.abs() > VIEW_PLANE_MM + reach || depth < -reach || depth > VIEW_DEPTH_MM + reach {
        return false;
    }
    let widest_mm = match kind {
        ProbeKind::Linear => LINEAR_HALF_WIDTH_MM,
        // The sector is widest at the deepest the block's points can be (depth ≥ −reach here).
        ProbeKind::Convex => CONVEX_HALF_WIDTH_MM + (depth + reach) * widening,
    };
    // Written so that NaN keeps the block (`<=` would pass it).
    u.abs().partial_cmp(&(widest_mm + reach)) != Some(std::cmp::Ordering::Greater)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seeded uniform generator in [0, 1).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// The frame's coordinates are those of rotating the axes for every point, as the survey
    /// computed them before the axes were rotated once per pose: the same bits, so the same
    /// in-view decisions.
    #[test]
    fn a_probe_frame_gives_the_coordinates_of_rotating_the_axes_per_point() {
        let mut unit = uniform(0x5EED);
        for _ in 0..5_000 {
            let position = DVec3::new(unit() * 400.0 - 200.0, unit() * 400.0 - 200.0, unit() * 400.0 - 200.0);
            let axis = DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5).normalize_or(DVec3::Z);
            let q = DQuat::from_axis_angle(axis, unit() * 6.3);
            let point = position + DVec3::new(unit() * 100.0 - 50.0, unit() * 100.0 - 50.0, unit() * 160.0 - 10.0);
            let d = point - position;
            let per_point = (d.dot(q * DVec3::X), d.dot(q * DVec3::Z), d.dot(q * DVec3::Y));
            let got = ProbeFrame::new(position, q).coords(point);
            assert_eq!(
                [got.0, got.1, got.2].map(f64::to_bits),
                [per_point.0, per_point.1, per_point.2].map(f64::to_bits)
            );
        }
    }

    /// A target like an atlas gives one: the voxel centres of a blob (an ellipsoid of 2 mm
    /// voxels), in voxel order.
    fn blob_points() -> Vec<DVec3> {
        let centre = DVec3::new(40.0, -20.0, 60.0);
        let mut points = Vec::new();
        for k in -12..=12 {
            for j in -9..=9 {
                for i in -15..=15 {
                    let p = DVec3::new(i as f64, j as f64, k as f64) * 2.0;
                    if (p / DVec3::new(30.0, 18.0, 24.0)).length_squared() <= 1.0 {
                        points.push(centre + p);
                    }
                }
            }
        }
        points
    }

    /// The blocks decide as testing every point does, for both probes and for poses all around
    /// the target (many on the edge of the view, where a block's bound matters), with unit and
    /// slightly stretched orientations; both answers occur often, and blocks are passed.
    #[test]
    fn the_blocks_decide_as_testing_every_point() {
        let points = blob_points();
        assert!(points.len() > 20 * BLOCK_POINTS);
        let survey = SurveyPoints::new(points.clone());
        let target_centre = DVec3::new(40.0, -20.0, 60.0);
        let mut unit = uniform(0xB10C);
        let mut seen = [0usize; 2];
        let mut passed_blocks = 0usize;
        for n in 0..20_000 {
            let kind = if n % 2 == 0 {
                ProbeKind::Linear
            } else {
                ProbeKind::Convex
            };
            let axis = DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5).normalize_or(DVec3::Z);
            let mut q = DQuat::from_axis_angle(axis, unit() * 6.3);
            if n % 5 == 0 {
                // A recorded orientation a little off unit length.
                q *= 1.0 + (unit() - 0.5) * 1e-3;
            }
            // The beam aimed near the target from up to 180 mm away, shifted sideways so the
            // image plane often grazes it.
            let depth = unit() * 180.0;
            let side = (q * DVec3::Y) * ((unit() - 0.5) * 60.0) + (q * DVec3::X) * ((unit() - 0.5) * 120.0);
            let position = target_centre - (q * DVec3::Z) * depth + side;
            let frame = ProbeFrame::new(position, q);
            let every_point = points.iter().any(|&p| in_survey_view(&frame, kind, p, VIEW_PLANE_MM));
            assert_eq!(survey.any_in_survey_view(&frame, kind), every_point, "pose {n}");
            seen[every_point as usize] += 1;
            passed_blocks += survey
                .blocks
                .iter()
                .filter(|b| !block_may_be_in_view(&frame, kind, b, convex_widening()))
                .count();
        }
        assert!(seen.iter().all(|&s| s > 2_000), "in view / not: {seen:?}");
        // Aimed at the target, about a third of the blocks are still passed.
        assert!(
            passed_blocks > 20_000 * survey.blocks.len() / 4,
            "passed {passed_blocks}"
        );
    }

    /// A point just inside each edge of the view is found, and one just outside is not: the
    /// blocks' margins never pass a point the test takes.
    #[test]
    fn points_on_the_edges_of_the_view_decide_as_the_test() {
        let q = DQuat::from_rotation_x(0.3) * DQuat::from_rotation_z(1.1);
        let frame = ProbeFrame::new(DVec3::new(10.0, 20.0, 30.0), q);
        let mut seen = [0usize; 2];
        let at =
            |u: f64, depth: f64, off: f64| frame.position + frame.array * u + frame.beam * depth + frame.normal * off;
        for kind in [ProbeKind::Linear, ProbeKind::Convex] {
            let half = |depth: f64| match kind {
                ProbeKind::Linear => LINEAR_HALF_WIDTH_MM,
                ProbeKind::Convex => CONVEX_HALF_WIDTH_MM + depth * convex_widening(),
            };
            for (u, depth, off) in [
                (0.0, 50.0, VIEW_PLANE_MM),
                (0.0, VIEW_DEPTH_MM, 0.0),
                (0.0, 0.0, 0.0),
                (half(140.0), 140.0, 0.0),
                (-half(140.0), 140.0, -VIEW_PLANE_MM),
            ] {
                for nudge in [-1e-9, 0.0, 1e-9] {
                    let p = at(u * (1.0 + nudge), depth * (1.0 + nudge), off * (1.0 + nudge));
                    let expected = in_survey_view(&frame, kind, p, VIEW_PLANE_MM);
                    // Alone (a block as small as a point), and in a block of points all off the
                    // image plane.
                    assert_eq!(SurveyPoints::new(vec![p]).any_in_survey_view(&frame, kind), expected);
                    let mut points = vec![p];
                    points.extend((1..40).map(|k| p + frame.normal * (2.0 * VIEW_PLANE_MM + k as f64)));
                    assert_eq!(SurveyPoints::new(points).any_in_survey_view(&frame, kind), expected);
                    seen[expected as usize] += 1;
                }
            }
        }
        assert!(seen.iter().all(|&s| s > 0), "in view / not: {seen:?}");
        // A convex probe's sector is wider deeper down: a block whose point just inside the edge
        // lies deeper than the block's centre (and to its side, 30° from the array's axis, where
        // a bound taken at the centre's depth would pass it). Its partner is far off the sector.
        let widening = convex_widening();
        let p = at((CONVEX_HALF_WIDTH_MM + 140.0 * widening) * 0.999, 140.0, 0.0);
        let away = frame.array * libm::cos(30f64.to_radians()) - frame.beam * libm::sin(30f64.to_radians());
        let points = vec![p, p + away * 20.0];
        assert!(in_survey_view(&frame, ProbeKind::Convex, p, VIEW_PLANE_MM));
        assert!(SurveyPoints::new(points).any_in_survey_view(&frame, ProbeKind::Convex));
        // A recorded quaternion 0.1 % longer than unit stretches every coordinate by 0.2 %: a
        // point 4.99 mm off the plane, in view, and a partner 40 mm farther off put the block's
        // centre 25.03 mm off, beyond 5 mm + its 20 mm radius; only the stretch keeps the block.
        let stretched = ProbeFrame::new(frame.position, q * 1.001);
        let (normal, beam) = (stretched.normal.normalize(), stretched.beam.normalize());
        let p =
            stretched.position + normal * (4.99 / stretched.normal.length()) + beam * (50.0 / stretched.beam.length());
        for kind in [ProbeKind::Linear, ProbeKind::Convex] {
            assert!(in_survey_view(&stretched, kind, p, VIEW_PLANE_MM));
            assert!(SurveyPoints::new(vec![p, p + normal * 40.0]).any_in_survey_view(&stretched, kind));
        }
    }
}
