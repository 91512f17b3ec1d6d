//! The intercostal window: a straight line from the skin between two ribs to the target that
//! crosses no bone and no risk structure (ALGORITHMS.md §7, PTCD entry between the right 10th and
//! 11th ribs). Straight lines from points of the target are cast in many directions; a line counts
//! as passing between two ribs where, at its point closest to both, each rib is within 20 mm and
//! the upper rib lies cranial and the lower rib caudal of it.

use stylet_physics::distance::squared_edt;
use stylet_physics::glam::DVec3;
use stylet_physics::{LabelId, PunctureAtlas, Role};

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
}

/// Result of the search: the requested pair, or the best fall-back pair.
#[derive(Debug, Clone)]
pub struct WindowReport {
    pub requested: (LabelId, LabelId),
    pub found: Option<WindowFound>,
    /// Whether `found` is between the requested ribs.
    pub requested_found: bool,
}

impl WindowReport {
    /// The window as a planned path: named by the ribs' side and numbers when the class table
    /// knows them as ribs ("intercostal-right-10-11", described as the "right 10th–11th
    /// intercostal space"), else by their class numbers.
    pub fn path(&self, classes: &ClassTable) -> Option<InsertionPath> {
        let f = self.found.as_ref()?;
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
        Some(InsertionPath {
            name,
            entry_mm: r(f.entry_mm),
            target_mm: r(f.target_mm),
            description: format!(
                "straight path through the {} to the target, {:.0} mm long, {:.1} mm from bone",
                space_name(classes, f.upper_rib, f.lower_rib),
                f.length_mm,
                f.bone_clearance_mm
            ),
        })
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

/// Searches the window between `upper`/`lower`, then between the adjacent pairs of `sequence`.
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
        if (w[0], w[1]) != (upper, lower) {
            pairs.push((w[0], w[1]));
        }
    }
    let search = Search::new(atlas, source, bone_labels);
    let mut best_fallback: Option<WindowFound> = None;
    for (n, &(a, b)) in pairs.iter().enumerate() {
        let Some(found) = search.best_between(a, b) else {
            continue;
        };
        if n == 0 {
            return WindowReport {
                requested: (upper, lower),
                found: Some(found),
                requested_found: true,
            };
        }
        if best_fallback
            .as_ref()
            .is_none_or(|f| found.bone_clearance_mm > f.bone_clearance_mm)
        {
            best_fallback = Some(found);
        }
    }
    WindowReport {
        requested: (upper, lower),
        found: best_fallback,
        requested_found: false,
    }
}

struct Search<'a> {
    atlas: &'a PunctureAtlas,
    source: &'a stylet_physics::Volume<LabelId>,
    bone_labels: &'a [LabelId],
    targets: Vec<DVec3>,
    target_labels: Vec<LabelId>,
    risk_labels: Vec<LabelId>,
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
        Search {
            atlas,
            source,
            bone_labels,
            targets,
            target_labels,
            risk_labels,
        }
    }

    fn best_between(&self, upper: LabelId, lower: LabelId) -> Option<WindowFound> {
        let grid = self.atlas.ct().grid();
        let mask = |id: LabelId| -> Vec<bool> { self.source.data().iter().map(|&l| l == id).collect() };
        let (mu, ml) = (mask(upper), mask(lower));
        if !mu.contains(&true) || !ml.contains(&true) {
            return None;
        }
        let du = squared_edt(grid, &mu);
        let dl = squared_edt(grid, &ml);
        let dist = |d: &[f32], p: DVec3| {
            grid.nearest_voxel(p)
                .map(|[i, j, k]| (d[grid.linear(i, j, k)] as f64).sqrt())
                .unwrap_or(f64::INFINITY)
        };
        let rib_points = |m: &[bool]| -> Vec<DVec3> {
            m.iter()
                .enumerate()
                .filter(|(_, b)| **b)
                .map(|(idx, _)| grid.linear_to_world(idx))
                .collect()
        };
        let (pu, pl) = (rib_points(&mu), rib_points(&ml));
        let thresholds = *self.atlas.thresholds();
        let mut best: Option<WindowFound> = None;
        for &t in &self.targets {
            for n in 0..DIRECTIONS {
                let dir = fibonacci(n, DIRECTIONS);
                let Some((entry, clearance, crossing)) =
                    self.cast(t, dir, &|p| dist(&du, p).max(dist(&dl, p)), thresholds.fat_bone_hu)
                else {
                    continue;
                };
                let Some(c) = crossing else { continue };
                // Upper rib cranial, lower rib caudal of the crossing, looking at the nearby parts.
                let local_z = |pts: &[DVec3]| {
                    let near: Vec<f64> = pts
                        .iter()
                        .filter(|p| p.distance(c) <= RIB_NEAR_MM + 10.0)
                        .map(|p| p.z)
                        .collect();
                    (!near.is_empty()).then(|| near.iter().sum::<f64>() / near.len() as f64)
                };
                let (Some(zu), Some(zl)) = (local_z(&pu), local_z(&pl)) else {
                    continue;
                };
                if !(zu > c.z && c.z > zl) {
                    continue;
                }
                let found = WindowFound {
                    upper_rib: upper,
                    lower_rib: lower,
                    entry_mm: entry,
                    target_mm: t,
                    length_mm: entry.distance(t),
                    bone_clearance_mm: clearance,
                };
                let better = best
                    .as_ref()
                    .is_none_or(|b| (found.bone_clearance_mm, -found.length_mm) > (b.bone_clearance_mm, -b.length_mm));
                if better {
                    best = Some(found);
                }
            }
        }
        best
    }

    /// Walks from the target outward. Returns the skin entry, the bone clearance and the point
    /// where both ribs are nearest (if within reach), or `None` if the line hits bone or risk or
    /// leaves the CT through a face of its box before it reaches the skin.
    fn cast(
        &self,
        t: DVec3,
        dir: DVec3,
        rib_gap: &dyn Fn(DVec3) -> f64,
        fat_bone_hu: f64,
    ) -> Option<(DVec3, f64, Option<DVec3>)> {
        let a = self.atlas;
        let mut clearance = f64::INFINITY;
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
                clearance = clearance.min(-a.bone_distance().sample(p, -1000.0) as f64);
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

/// The n-th of `count` directions spread evenly over the sphere.
fn fibonacci(n: usize, count: usize) -> DVec3 {
    let golden = std::f64::consts::PI * (3.0 - 5.0f64.sqrt());
    let z = 1.0 - 2.0 * (n as f64 + 0.5) / count as f64;
    let r = (1.0 - z * z).sqrt();
    let phi = golden * n as f64;
    DVec3::new(r * libm::cos(phi), r * libm::sin(phi), z)
}
