//! The intercostal window: a straight line from the skin between two ribs to the target that
//! crosses no bone and no risk structure (the PTCD entry, usually between the right 10th and 11th
//! ribs: thesis §2.1). Straight lines from points of the target are cast in many directions; a line
//! counts as passing between two ribs where, at its point closest to both, each rib is within 20 mm
//! and the upper rib lies cranial and the lower rib caudal of it. Every neighbouring pair of the
//! rib sequence is searched and the windows found are ranked by clearance (the smaller of the
//! line's distances to bone and to risk structures, then the shorter line).

use std::collections::BTreeMap;

use rayon::prelude::*;
use stylet_physics::distance::squared_edt;
use stylet_physics::glam::DVec3;
use stylet_physics::{Affine, Grid, LabelId, PunctureAtlas, Role};

use super::classes::{ClassTable, intercostal_space};
use crate::manifest::InsertionPath;

/// Step along candidate lines (mm).
const STEP_MM: f64 = 0.75;
/// Longest line tried (mm).
const MAX_LENGTH_MM: f64 = 250.0;
/// How close both ribs must be to the crossing point (mm).
const RIB_NEAR_MM: f64 = 20.0;
/// Directions tried per target point (Fibonacci sphere).
const DIRECTIONS: usize = 3000;

/// The best window found for one rib pair.
#[derive(Debug, Clone)]
pub struct WindowFound {
    pub upper_rib: LabelId,
    pub lower_rib: LabelId,
    pub entry_mm: DVec3,
    pub target_mm: DVec3,
    pub length_mm: f64,
    /// Smallest distance between the line and bone (mm).
    pub bone_clearance_mm: f64,
    /// Smallest distance between the line (outside the target) and a risk structure (mm).
    pub risk_clearance_mm: f64,
}

impl WindowFound {
    /// The clearance windows are ranked by: the nearer of bone and risk structures (mm).
    pub fn clearance_mm(&self) -> f64 {
        self.bone_clearance_mm.min(self.risk_clearance_mm)
    }

    /// Ranking key: larger clearance first, then the shorter line.
    fn key(&self) -> (f64, f64) {
        (self.clearance_mm(), -self.length_mm)
    }
}

/// Result of the search: the chosen window (the requested pair's when it has one, else the
/// best-ranked) and every window found, ranked.
#[derive(Debug, Clone)]
pub struct WindowReport {
    pub requested: (LabelId, LabelId),
    pub found: Option<WindowFound>,
    /// Whether `found` is between the requested ribs.
    pub requested_found: bool,
    /// The best window of each rib pair that has one, best clearance first (`found` among them).
    pub ranked: Vec<WindowFound>,
}

impl WindowReport {
    /// The window as a planned path: named by the ribs' side and numbers when the class table
    /// knows them as ribs ("intercostal-right-10-11", described as the "right 10th–11th
    /// intercostal space"), else by their class numbers.
    pub fn path(&self, classes: &ClassTable) -> Option<InsertionPath> {
        self.found.as_ref().map(|f| window_path(classes, f, None))
    }

    /// Every window found as a planned path: the chosen one first, then the others by rank, each
    /// described with its rank.
    pub fn paths(&self, classes: &ClassTable) -> Vec<InsertionPath> {
        let Some(chosen) = &self.found else {
            return Vec::new();
        };
        let rank = |f: &WindowFound| {
            self.ranked
                .iter()
                .position(|r| (r.upper_rib, r.lower_rib) == (f.upper_rib, f.lower_rib))
                .map(|i| i + 1)
        };
        let others = self
            .ranked
            .iter()
            .filter(|f| (f.upper_rib, f.lower_rib) != (chosen.upper_rib, chosen.lower_rib));
        std::iter::once(chosen)
            .chain(others)
            .map(|f| window_path(classes, f, rank(f).map(|r| (r, self.ranked.len()))))
            .collect()
    }
}

/// A window as a planned path, named by the ribs' side and numbers when the class table knows
/// them as ribs, else by their class numbers; `rank`: (its rank, of how many).
pub(crate) fn window_path(classes: &ClassTable, f: &WindowFound, rank: Option<(usize, usize)>) -> InsertionPath {
    let r = |v: DVec3| {
        [
            (v.x * 10.0).round() / 10.0,
            (v.y * 10.0).round() / 10.0,
            (v.z * 10.0).round() / 10.0,
        ]
    };
    let name = match (classes.rib(f.upper_rib), classes.rib(f.lower_rib)) {
        (Some(a), Some(b)) if a.side == b.side => {
            format!("intercostal-{}-{}-{}", a.side.word(), a.number, b.number)
        }
        _ => format!("intercostal-{}-{}", f.upper_rib, f.lower_rib),
    };
    let ranked = rank
        .map(|(k, n)| format!(", window {k} of {n} by clearance"))
        .unwrap_or_default();
    InsertionPath {
        name,
        entry_mm: r(f.entry_mm),
        target_mm: r(f.target_mm),
        description: format!(
            "straight path through the {} to the target, {:.0} mm long, {:.1} mm from bone, {:.1} mm from risk structures{ranked}",
            space_name(classes, f.upper_rib, f.lower_rib),
            f.length_mm,
            f.bone_clearance_mm,
            f.risk_clearance_mm
        ),
    }
}

/// The space between source classes `upper` and `lower` in words: "right 10th–11th intercostal
/// space" when both are ribs, else "space between rib_x (n) and class m (…)".
pub fn space_name(classes: &ClassTable, upper: LabelId, lower: LabelId) -> String {
    match (classes.rib(upper), classes.rib(lower)) {
        (Some(a), Some(b)) => intercostal_space(a, b),
        _ => format!(
            "space between {} and {}",
            classes.describe(upper),
            classes.describe(lower)
        ),
    }
}

/// Searches the window between `upper`/`lower` and between every adjacent pair of `sequence`,
/// and ranks the windows found; the requested pair's is chosen when it has one.
pub fn find_window(
    atlas: &PunctureAtlas,
    source: &stylet_physics::Volume<LabelId>,
    upper: LabelId,
    lower: LabelId,
    sequence: &[LabelId],
    bone_labels: &[LabelId],
) -> WindowReport {
    let mut pairs = vec![(upper, lower)];
    for w in sequence.windows(2) {
        if !pairs.contains(&(w[0], w[1])) {
            pairs.push((w[0], w[1]));
        }
    }
    let search = Search::new(atlas, source, bone_labels);
    // Every rib's voxels in one pass over the label map (a rib belongs to two pairs).
    let mut wanted = vec![false; LabelId::MAX as usize + 1];
    for &(a, b) in &pairs {
        wanted[a as usize] = true;
        wanted[b as usize] = true;
    }
    let mut rib_voxels: BTreeMap<LabelId, Vec<usize>> = BTreeMap::new();
    for (idx, &l) in source.data().iter().enumerate() {
        if wanted[l as usize] {
            rib_voxels.entry(l).or_default().push(idx);
        }
    }
    let found: Vec<WindowFound> = pairs
        .iter()
        .filter_map(|&(a, b)| search.best_between(a, b, &rib_voxels))
        .collect();
    let requested = found
        .iter()
        .find(|f| (f.upper_rib, f.lower_rib) == (upper, lower))
        .cloned();
    let mut ranked = found;
    // Stable: equal keys keep the pairs' order (requested first, then cranial to caudal).
    ranked.sort_by(|a, b| b.key().partial_cmp(&a.key()).unwrap_or(std::cmp::Ordering::Equal));
    WindowReport {
        requested: (upper, lower),
        requested_found: requested.is_some(),
        found: requested.or_else(|| ranked.first().cloned()),
        ranked,
    }
}

struct Search<'a> {
    atlas: &'a PunctureAtlas,
    source: &'a stylet_physics::Volume<LabelId>,
    bone_labels: &'a [LabelId],
    targets: Vec<DVec3>,
    target_labels: Vec<LabelId>,
    risk_labels: Vec<LabelId>,
    /// Squared distance (mm²) of every voxel to the nearest risk voxel.
    risk_sq: Vec<f32>,
}

impl<'a> Search<'a> {
    fn new(atlas: &'a PunctureAtlas, source: &'a stylet_physics::Volume<LabelId>, bone_labels: &'a [LabelId]) -> Self {
        let table = atlas.label_table();
        let target_labels: Vec<LabelId> = table.with_role(Role::Target).map(|l| l.id).collect();
        let risk_labels: Vec<LabelId> = table.with_role(Role::Risk).map(|l| l.id).collect();
        let grid = atlas.ct().grid();
        let mut pts: Vec<DVec3> = atlas
            .partial_labels()
            .data()
            .iter()
            .enumerate()
            .filter(|(_, l)| target_labels.contains(l))
            .map(|(idx, _)| grid.linear_to_world(idx))
            .collect();
        // A dozen points spread over the target (sorted along x, then sampled evenly), plus its centre.
        pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)).then(a.z.total_cmp(&b.z)));
        let mut targets = Vec::new();
        if !pts.is_empty() {
            let centre = pts.iter().copied().sum::<DVec3>() / pts.len() as f64;
            let nearest = *pts
                .iter()
                .min_by(|a, b| a.distance_squared(centre).total_cmp(&b.distance_squared(centre)))
                .expect("non-empty");
            targets.push(nearest);
            for s in 0..12 {
                targets.push(pts[s * (pts.len() - 1) / 11]);
            }
        }
        let risk_mask: Vec<bool> = atlas
            .partial_labels()
            .data()
            .iter()
            .map(|l| risk_labels.contains(l))
            .collect();
        let risk_sq = squared_edt(grid, &risk_mask);
        Search {
            atlas,
            source,
            bone_labels,
            targets,
            target_labels,
            risk_labels,
            risk_sq,
        }
    }

    /// The best line between `upper` and `lower` (`rib_voxels`: each rib's voxels, linear
    /// indices).
    fn best_between(
        &self,
        upper: LabelId,
        lower: LabelId,
        rib_voxels: &BTreeMap<LabelId, Vec<usize>>,
    ) -> Option<WindowFound> {
        let grid = self.atlas.ct().grid();
        let (vu, vl) = (rib_voxels.get(&upper)?, rib_voxels.get(&lower)?);
        let rib_points = |v: &[usize]| -> Vec<DVec3> { v.iter().map(|&idx| grid.linear_to_world(idx)).collect() };
        let (pu, pl) = (rib_points(vu), rib_points(vl));
        // The ribs' distance maps on the box around both ribs (a crossing is within
        // RIB_NEAR_MM of both, so inside it); beyond the box the distance is infinite.
        let crop = Crop::around(grid, &[vu, vl], RIB_NEAR_MM + 5.0);
        let du = crop.squared_edt(self.source, upper);
        let dl = crop.squared_edt(self.source, lower);
        let dist = |d: &[f32], p: DVec3| {
            crop.grid
                .nearest_voxel(p)
                .map(|[i, j, k]| (d[crop.grid.linear(i, j, k)] as f64).sqrt())
                .unwrap_or(f64::INFINITY)
        };
        let thresholds = *self.atlas.thresholds();
        let candidate = |t: DVec3, n: usize| -> Option<WindowFound> {
            let dir = fibonacci(n, DIRECTIONS);
            let (entry, clearance, crossing) =
                self.cast(t, dir, &|p| dist(&du, p).max(dist(&dl, p)), thresholds.fat_bone_hu)?;
            let c = crossing?;
            // Upper rib cranial, lower rib caudal of the crossing, looking at the nearby parts.
            let local_z = |pts: &[DVec3]| {
                let near: Vec<f64> = pts
                    .iter()
                    .filter(|p| p.distance(c) <= RIB_NEAR_MM + 10.0)
                    .map(|p| p.z)
                    .collect();
                (!near.is_empty()).then(|| near.iter().sum::<f64>() / near.len() as f64)
            };
            let (zu, zl) = (local_z(&pu)?, local_z(&pl)?);
            if !(zu > c.z && c.z > zl) {
                return None;
            }
            Some(WindowFound {
                upper_rib: upper,
                lower_rib: lower,
                entry_mm: entry,
                target_mm: t,
                length_mm: entry.distance(t),
                bone_clearance_mm: clearance.bone_mm,
                risk_clearance_mm: clearance.risk_mm,
            })
        };
        // Every line in parallel; the best by key, ties to the first line tried (deterministic).
        let best = |a: (usize, WindowFound), b: (usize, WindowFound)| match b.1.key().partial_cmp(&a.1.key()) {
            Some(std::cmp::Ordering::Greater) => b,
            Some(std::cmp::Ordering::Less) => a,
            _ => {
                if b.0 < a.0 {
                    b
                } else {
                    a
                }
            }
        };
        (0..self.targets.len() * DIRECTIONS)
            .into_par_iter()
            .filter_map(|i| candidate(self.targets[i / DIRECTIONS], i % DIRECTIONS).map(|f| (i, f)))
            .reduce_with(best)
            .map(|(_, f)| f)
    }

    /// Walks from the target outward. Returns the skin entry, the clearances and the point
    /// where both ribs are nearest (if within reach), or `None` if the line hits bone or risk or
    /// leaves the CT through a face of its box before it reaches the skin.
    fn cast(
        &self,
        t: DVec3,
        dir: DVec3,
        rib_gap: &dyn Fn(DVec3) -> f64,
        fat_bone_hu: f64,
    ) -> Option<(DVec3, Clearance, Option<DVec3>)> {
        let a = self.atlas;
        let grid = a.ct().grid();
        let mut clearance = Clearance {
            bone_mm: f64::INFINITY,
            risk_mm: f64::INFINITY,
        };
        let mut crossing: Option<(f64, DVec3)> = None;
        let mut s = 0.0;
        while s <= MAX_LENGTH_MM {
            let p = t + dir * s;
            let skin = a.skin_distance().sample(p, f32::NAN);
            if skin.is_nan() {
                // The line leaves the CT before it leaves the body (through a face of the scan,
                // e.g. a liver cut off at the bottom slice): no skin entry, not a path.
                return None;
            }
            if skin < 0.0 {
                return Some((
                    p,
                    clearance,
                    crossing.filter(|(g, _)| *g <= RIB_NEAR_MM).map(|(_, c)| c),
                ));
            }
            let partial = a.partial_label_at(p);
            if a.hu_at(p) >= fat_bone_hu || self.bone_labels.contains(&self.source.nearest(p, 0)) {
                return None;
            }
            if self.risk_labels.contains(&partial) {
                return None;
            }
            if !self.target_labels.contains(&partial) {
                clearance.bone_mm = clearance.bone_mm.min(-a.bone_distance().sample(p, -1000.0) as f64);
                if let Some([i, j, k]) = grid.nearest_voxel(p) {
                    clearance.risk_mm = clearance
                        .risk_mm
                        .min((self.risk_sq[grid.linear(i, j, k)] as f64).sqrt());
                }
            }
            let g = rib_gap(p);
            if crossing.is_none_or(|(best, _)| g < best) {
                crossing = Some((g, p));
            }
            s += STEP_MM;
        }
        None
    }
}

/// A line's smallest distances to bone and to risk structures (mm).
#[derive(Debug, Clone, Copy)]
struct Clearance {
    bone_mm: f64,
    risk_mm: f64,
}

/// A box of the CT's grid (as a grid of its own) around some labels, with a margin.
struct Crop {
    grid: Grid,
    offset: [usize; 3],
}

impl Crop {
    /// The box around `voxels` (linear indices, at least one) widened by `margin_mm`.
    fn around(grid: &Grid, voxels: &[&Vec<usize>], margin_mm: f64) -> Crop {
        let dims = grid.dims();
        let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
        for &idx in voxels.iter().copied().flatten() {
            let v = grid.unlinear(idx);
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
        let s = grid.spacing_mm();
        let mut size = [0usize; 3];
        for a in 0..3 {
            let m = (margin_mm / s[a]).ceil() as usize;
            lo[a] = lo[a].saturating_sub(m);
            hi[a] = (hi[a] + m).min(dims[a] - 1);
            size[a] = hi[a] + 1 - lo[a];
        }
        let o = grid.voxel_to_world(lo[0], lo[1], lo[2]);
        let rows = grid.affine().rows();
        let shifted = Affine::from_rows([
            [rows[0][0], rows[0][1], rows[0][2], o.x],
            [rows[1][0], rows[1][1], rows[1][2], o.y],
            [rows[2][0], rows[2][1], rows[2][2], o.z],
        ]);
        Crop {
            grid: Grid::new(size, shifted).expect("a box inside a valid grid is valid"),
            offset: lo,
        }
    }

    /// Squared distance (mm²) within the box to the nearest voxel labelled `id`.
    fn squared_edt(&self, source: &stylet_physics::Volume<LabelId>, id: LabelId) -> Vec<f32> {
        let [nx, ny, nz] = self.grid.dims();
        let full = source.grid();
        let mut mask = Vec::with_capacity(nx * ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let [a, b, c] = [i + self.offset[0], j + self.offset[1], k + self.offset[2]];
                    mask.push(source.data()[full.linear(a, b, c)] == id);
                }
            }
        }
        squared_edt(&self.grid, &mask)
    }
}

/// The n-th of `count` directions spread evenly over the sphere.
fn fibonacci(n: usize, count: usize) -> DVec3 {
    let golden = std::f64::consts::PI * (3.0 - 5.0f64.sqrt());
    let z = 1.0 - 2.0 * (n as f64 + 0.5) / count as f64;
    let r = (1.0 - z * z).sqrt();
    let phi = golden * n as f64;
    DVec3::new(r * libm::cos(phi), r * libm::sin(phi), z)
}
