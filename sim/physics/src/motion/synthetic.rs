//! A synthetic breathing motion for atlases without a 4D CT (docs/breathing.md "Synthetic
//! motion"): the displacement a₁(X) at end-inspiration, relative to the CT (taken as the
//! end-expiration reference), built from the atlas' own maps, and driven by the breathing signal
//! through the surrogate model (eq. 5.3.6 with a₂ = a₃ = 0).
//!
//!   a₁(X) = A · w(z) · m(X) · (0, r_ap, −1)
//!
//! - A: the cranio-caudal amplitude of the liver (default 12 mm; Eccles et al. 2011 measured a
//!   mean of 11.7 mm, 4.8–23.3 mm, in 60 patients); r_ap: the anterior share (0.3).
//!   Inspiration moves the liver caudally (−z, RAS) and anteriorly (+y).
//! - w(z): the diaphragm as a piston. 1 from the liver's dome down to 150 mm below it, then
//!   falling linearly to 0.4 at 300 mm below (the lower abdomen moves less); above the dome the
//!   lungs follow, falling linearly to 0 at 150 mm above it (the apex hardly moves).
//! - m(X) ∈ [0, 1]: what may move, worked out once at the nodes of a grid aligned with the CT
//!   (every f-th voxel, f chosen for nodes about [`MOBILITY_SPACING_MM`] apart; a node keeps the
//!   least m of the voxels around it, so still voxels stay still) and read trilinearly between
//!   them: the haptics, the CPU views and the GPU all read the same map. 0 in the body wall (less than `wall_mm` under the skin), in
//!   bone and within `bone_margin_mm` of it, and outside the body; 1 deeper inside, reached over
//!   a ramp of [`RAMP_MM`]. Bone is the atlas' bone map (CT above the bone threshold) outside
//!   the segmented soft structures: a contrast-filled vessel is as dense as bone but moves with
//!   its organ, and an organ's voxel next to a rib moves fully. The step from the wall and the
//!   ribs to the cavity is the sliding interface: liver and lung slide along the inside of the
//!   ribs while the ribs stay.

use std::sync::Arc;

use glam::DVec3;
use rayon::prelude::*;

use super::BreathingError;
use super::field::{FactoredField, SpatialField};
use crate::labels::Role;
use crate::{Affine, Grid, PunctureAtlas, SettingsError, Volume};

/// Width of the transition from still to moving tissue (mm).
pub const RAMP_MM: f64 = 4.0;
/// Above the liver's dome, the motion falls to 0 over this height (mm).
pub const LUNG_FALL_MM: f64 = 150.0;
/// Below the dome, full motion over this height, then a fall to [`PELVIS_WEIGHT`] over as much again.
pub const ABDOMEN_FULL_MM: f64 = 150.0;
pub const PELVIS_WEIGHT: f64 = 0.4;
/// The mobility map's node spacing (mm), at least one CT voxel: fine enough for the
/// [`RAMP_MM`] transitions, a ninth of the chest CT's voxels.
pub const MOBILITY_SPACING_MM: f64 = 2.0;

/// The synthetic motion's parameters (part of the world model in the session header).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticMotion {
    /// Cranio-caudal displacement of the liver at an average end-inspiration (mm).
    pub amplitude_mm: f64,
    /// Anterior displacement as a share of the cranio-caudal one.
    pub anterior_ratio: f64,
    /// Depth under the skin that stays still: the body wall (mm).
    pub wall_mm: f64,
    /// Tissue this close to bone stays with it (mm).
    pub bone_margin_mm: f64,
}

impl Default for SyntheticMotion {
    fn default() -> Self {
        SyntheticMotion {
            amplitude_mm: 12.0,
            anterior_ratio: 0.3,
            wall_mm: 12.0,
            bone_margin_mm: 3.0,
        }
    }
}

impl SyntheticMotion {
    /// The documented ranges (docs/breathing.md).
    pub fn validate(&self) -> Result<(), SettingsError> {
        let check = |setting: &'static str, what: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(SettingsError::Breathing {
                    setting,
                    reason: format!("breathing {what} {v} must be {lo} … {hi}"),
                })
            }
        };
        check("amplitude_mm", "amplitude (mm)", self.amplitude_mm, 0.0, 50.0)?;
        check("anterior_ratio", "anterior ratio", self.anterior_ratio, 0.0, 1.0)?;
        check("wall_mm", "body wall (mm)", self.wall_mm, 0.0, 60.0)?;
        check("bone_margin_mm", "bone margin (mm)", self.bone_margin_mm, 0.0, 20.0)
    }
}

/// a₁(X) of the synthetic motion on one atlas.
pub struct SyntheticField {
    params: SyntheticMotion,
    /// The liver's dome: the highest z of an organ or target voxel (mm).
    dome_z_mm: f64,
    /// m at the nodes of a coarse grid aligned with the CT ([`mobility_grid`]).
    mobility: Volume<f32>,
}

impl SyntheticField {
    /// Needs an organ (the liver) in the atlas' labels to place the diaphragm. Works out the
    /// mobility map (about 0.1 s on two cores for the 512 × 512 × 133 chest CT).
    pub fn new(atlas: Arc<PunctureAtlas>, params: SyntheticMotion) -> Result<SyntheticField, BreathingError> {
        params.validate()?;
        let dome_z_mm = dome_z_mm(&atlas).ok_or(BreathingError::NoOrgan)?;
        let mobility = mobility_map(&atlas, params);
        Ok(SyntheticField {
            params,
            dome_z_mm,
            mobility,
        })
    }

    /// The z of the liver's dome (mm).
    pub fn dome_z_mm(&self) -> f64 {
        self.dome_z_mm
    }

    /// w(z) as knots (z mm, w) ascending in z, constant beyond the first and the last.
    pub fn profile(&self) -> [(f64, f64); 4] {
        let d = self.dome_z_mm;
        [
            (d - 2.0 * ABDOMEN_FULL_MM, PELVIS_WEIGHT),
            (d - ABDOMEN_FULL_MM, 1.0),
            (d, 1.0),
            (d + LUNG_FALL_MM, 0.0),
        ]
    }

    /// w(z): the share of the full motion at height z.
    pub fn weight(&self, z_mm: f64) -> f64 {
        piecewise_linear(&self.profile(), z_mm)
    }

    /// m(X): 0 in the body wall, bone and its margin and outside the body; 1 deep inside
    /// (trilinear in the mobility map).
    pub fn mobility(&self, x_ref: DVec3) -> f64 {
        let c = self.mobility.grid().world_to_index(x_ref);
        crate::volume::trilinear(c, self.mobility.grid().dims(), |i, j, k| {
            self.mobility.get(i, j, k) as f64
        })
        .unwrap_or(0.0)
    }

    /// The mobility map (m at its nodes).
    pub fn mobility_map(&self) -> &Volume<f32> {
        &self.mobility
    }

    /// d = A·(0, r_ap, −1): the displacement where w = m = 1 (mm).
    pub fn direction_mm(&self) -> DVec3 {
        DVec3::new(0.0, self.params.anterior_ratio, -1.0) * self.params.amplitude_mm
    }
}

/// How well the fixed point inverts a field (thesis §5.4.1): reported when an atlas' motion is
/// loaded (docs/breathing.md "Atlases").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InversionCheck {
    /// The breathing depth g the field was scaled by (the deepest breath of the signal).
    pub depth: f64,
    /// Fixed-point steps from X = x.
    pub iterations: u32,
    /// Points checked: moving nodes of the mobility map whose way to their moved position lies
    /// in fully moving tissue.
    pub points: usize,
    /// Moving nodes in a ramp of m or whose way crosses one (the sliding interface): there u
    /// changes faster than the fixed point contracts, and a world point that the motion reaches
    /// from two places rightly belongs to the still side.
    pub sliding: usize,
    /// The largest |X̂ − X| over the points (mm).
    pub worst_mm: f64,
    /// The largest |X̂ − X| over the sliding nodes too (mm).
    pub worst_all_mm: f64,
}

impl SyntheticField {
    /// The inversion error of g·a₁ at depth `depth` over up to `max_points` nodes of the mobility
    /// map (evenly strided), after `iterations` steps.
    pub fn inversion_check(&self, depth: f64, iterations: u32, max_points: usize) -> InversionCheck {
        let grid = *self.mobility.grid();
        let moving: Vec<usize> = (0..grid.len()).filter(|&i| self.mobility.data()[i] > 0.0).collect();
        let stride = moving.len().div_ceil(max_points.max(1)).max(1);
        let around = [
            DVec3::ZERO,
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            -DVec3::X,
            -DVec3::Y,
            -DVec3::Z,
        ];
        let (inside, sliding): (Vec<DVec3>, Vec<DVec3>) = moving
            .iter()
            .step_by(stride)
            .map(|&i| grid.linear_to_world(i))
            .partition(|&x| {
                let u = self.at(x) * depth;
                (0..=12).all(|k| {
                    let p = x + u * (k as f64 * 0.1);
                    around.iter().all(|&e| self.mobility(p + e) == 1.0)
                })
            });
        let worst = |points: &[DVec3]| super::field_inversion_error_mm(self, points, depth, iterations);
        let worst_mm = worst(&inside);
        InversionCheck {
            depth,
            iterations,
            points: inside.len(),
            sliding: sliding.len(),
            worst_mm,
            worst_all_mm: worst_mm.max(worst(&sliding)),
        }
    }
}

/// w at z of a piecewise-linear profile (knots ascending in z, constant beyond the ends).
pub fn piecewise_linear(knots: &[(f64, f64)], z: f64) -> f64 {
    let (first, last) = (knots[0], knots[knots.len() - 1]);
    if z <= first.0 {
        return first.1;
    }
    if z >= last.0 {
        return last.1;
    }
    for w in knots.windows(2) {
        let ((z0, w0), (z1, w1)) = (w[0], w[1]);
        if z <= z1 {
            return w0 + (w1 - w0) * (z - z0) / (z1 - z0);
        }
    }
    last.1
}

/// The thinning of [`mobility_grid`]: every f-th CT voxel per axis, f = max(1,
/// round(MOBILITY_SPACING_MM / spacing)).
fn thinning(ct: &Grid) -> [usize; 3] {
    let spacing = ct.spacing_mm();
    std::array::from_fn(|a| ((MOBILITY_SPACING_MM / spacing[a]).round() as usize).max(1))
}

/// The CT grid thinned to every f-th voxel per axis (`thinning`), one node more where needed
/// so the nodes reach the CT's last voxel.
pub fn mobility_grid(ct: &Grid) -> Grid {
    let f = thinning(ct);
    let dims = ct.dims();
    let n: [usize; 3] = std::array::from_fn(|a| dims[a].saturating_sub(1).div_ceil(f[a]) + 1);
    let mut rows = ct.affine().rows();
    for row in &mut rows {
        for (a, fa) in f.iter().enumerate() {
            row[a] *= *fa as f64;
        }
    }
    Grid::new(n, Affine::from_rows(rows)).expect("a thinned grid of a valid grid is valid")
}

/// m at the nodes of [`mobility_grid`]: the least m of the CT voxels within f − 1 voxels of the
/// node on each axis. Trilinear reads between the nodes are then 0 at every voxel centre the
/// rule makes still (a rib's voxel next to the liver stays): each node of the cell around a
/// voxel centre sees that voxel. The mobile side of an interface loses up to one node spacing.
fn mobility_map(atlas: &PunctureAtlas, params: SyntheticMotion) -> Volume<f32> {
    let ct = *atlas.ct().grid();
    let grid = mobility_grid(&ct);
    let f = thinning(&ct);
    let [nx, ny, nz] = ct.dims();
    let [mx, my, mz] = grid.dims();
    let rule = MobilityRule::new(atlas, params);
    if f == [1, 1, 1] {
        // Every voxel a node (voxels of 2.5 mm or more): the rule itself, in one pass.
        let values = (0..ct.len())
            .into_par_iter()
            .map(|i| {
                let [x, y, z] = ct.unlinear(i);
                rule.at_voxel(x, y, z) as f32
            })
            .collect();
        return Volume::new(grid, values).expect("one value per node");
    }
    // CT voxels within f − 1 of node n (clipped to the grid; never empty, see mobility_grid).
    let window = |n: usize, f: usize, len: usize| (n * f).saturating_sub(f - 1)..=(n * f + f - 1).min(len - 1);
    let planes: Vec<Vec<f32>> = (0..mz)
        .into_par_iter()
        .map(|kn| {
            let mut over_z = vec![1.0f32; nx * ny];
            for k in window(kn, f[2], nz) {
                for j in 0..ny {
                    for i in 0..nx {
                        let v = &mut over_z[i + nx * j];
                        *v = v.min(rule.at_voxel(i, j, k) as f32);
                    }
                }
            }
            let mut over_x = vec![1.0f32; mx * ny];
            for j in 0..ny {
                for in_ in 0..mx {
                    over_x[in_ + mx * j] = window(in_, f[0], nx).map(|i| over_z[i + nx * j]).fold(1.0, f32::min);
                }
            }
            let mut plane = vec![1.0f32; mx * my];
            for jn in 0..my {
                for in_ in 0..mx {
                    plane[in_ + mx * jn] = window(jn, f[1], ny).map(|j| over_x[in_ + mx * j]).fold(1.0, f32::min);
                }
            }
            plane
        })
        .collect();
    Volume::new(grid, planes.concat()).expect("one value per node")
}

/// m of one CT voxel from the atlas' maps (all on the CT's grid).
struct MobilityRule<'a> {
    atlas: &'a PunctureAtlas,
    params: SyntheticMotion,
    /// By label id: a segmented soft structure (organ, target or risk), never bone.
    soft: Vec<bool>,
}

impl<'a> MobilityRule<'a> {
    fn new(atlas: &'a PunctureAtlas, params: SyntheticMotion) -> MobilityRule<'a> {
        let table = atlas.label_table();
        let max_id = table.labels().iter().map(|l| l.id as usize).max().unwrap_or(0);
        let mut soft = vec![false; max_id + 1];
        for l in table.labels() {
            soft[l.id as usize] = matches!(l.role, Role::Organ | Role::Target | Role::Risk);
        }
        MobilityRule { atlas, params, soft }
    }

    fn at_voxel(&self, i: usize, j: usize, k: usize) -> f64 {
        let ramp = |d: f64| (d / RAMP_MM).clamp(0.0, 1.0);
        let depth = self.atlas.skin_distance().get(i, j, k) as f64;
        if depth <= self.params.wall_mm {
            return 0.0;
        }
        let wall = ramp(depth - self.params.wall_mm);
        let label = self.atlas.partial_labels().get(i, j, k) as usize;
        if self.soft.get(label).copied().unwrap_or(false) {
            return wall;
        }
        // Positive inside bone.
        let bone = self.atlas.bone_distance().get(i, j, k) as f64;
        wall * ramp(-bone - self.params.bone_margin_mm)
    }
}

impl SpatialField for SyntheticField {
    /// A · |(0, r_ap, −1)|: w and m never exceed 1.
    fn max_length_mm(&self) -> f64 {
        self.params.amplitude_mm * (1.0 + self.params.anterior_ratio * self.params.anterior_ratio).sqrt()
    }

    fn at(&self, x_ref: DVec3) -> DVec3 {
        let m = self.mobility(x_ref);
        if m == 0.0 {
            return DVec3::ZERO;
        }
        self.direction_mm() * (self.weight(x_ref.z) * m)
    }

    fn factored(&self) -> Option<FactoredField<'_>> {
        Some(FactoredField {
            direction_mm: self.direction_mm(),
            profile: self.profile(),
            map: &self.mobility,
        })
    }
}

/// The highest world z of a voxel labelled with an organ or target role (the liver's dome).
fn dome_z_mm(atlas: &PunctureAtlas) -> Option<f64> {
    let table = atlas.label_table();
    let moving = |id: u16| {
        id != 0
            && table
                .get(id)
                .is_some_and(|l| matches!(l.role, Role::Organ | Role::Target))
    };
    let labels = atlas.partial_labels();
    let grid = labels.grid();
    labels
        .data()
        .iter()
        .enumerate()
        .filter(|&(_, &id)| moving(id))
        .map(|(i, _)| grid.linear_to_world(i).z)
        .fold(None, |m: Option<f64>, z| Some(m.map_or(z, |m| m.max(z))))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_profile_is_the_piston_and_the_thinned_grid_reaches_the_last_voxel() {
        let knots = [(-300.0, 0.4), (-150.0, 1.0), (0.0, 1.0), (150.0, 0.0)];
        for (z, w) in [
            (-500.0, 0.4),
            (-225.0, 0.7),
            (-150.0, 1.0),
            (-10.0, 1.0),
            (75.0, 0.5),
            (400.0, 0.0),
        ] {
            assert!((piecewise_linear(&knots, z) - w).abs() < 1e-12, "w({z})");
        }
        let ct = Grid::new([512, 512, 133], Affine::from_spacing([0.7, 0.7, 2.5], DVec3::ZERO)).unwrap();
        let g = mobility_grid(&ct);
        assert_eq!(g.dims(), [172, 172, 133]);
        assert_eq!(g.spacing_mm().map(|s| (s * 10.0).round() / 10.0), [2.1, 2.1, 2.5]);
        assert!(g.voxel_to_world(171, 0, 0).x >= ct.voxel_to_world(511, 0, 0).x);
        let odd = Grid::new([10, 1, 12], Affine::from_spacing([1.0, 1.0, 0.5], DVec3::ZERO)).unwrap();
        assert_eq!(mobility_grid(&odd).dims(), [6, 1, 4]);
    }
}
