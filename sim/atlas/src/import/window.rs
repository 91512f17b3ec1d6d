//! The intercostal window: a straight line from the skin to the target that crosses no bone and no
//! risk structure, named by the ribs that bound it where it crosses the chest wall, and ranked by a
//! clinical score (PTCD entry: thesis §2.1; docs/atlas.md "Intercostal window").
//!
//! - **Lines.** From a dozen points of the target and its centre, straight lines in 3000
//!   directions are walked out to the skin; a line is refused where it meets bone (a bone label or
//!   CT ≥ t_fat→bone), a risk structure (the lung among them), or leaves the CT before the skin.
//! - **Wall crossing.** A line's wall segment is its part between the skin and the last organ or
//!   target voxel on the way in; its crossing is the point of that segment nearest the rib cage
//!   (every rib label and the costal cartilage).
//! - **Name.** Near the crossing, each rib (or cartilage) is above or below the line by where its
//!   nearest voxel lies; the window is named by the nearest above and the nearest below, each
//!   within [`BOUND_NEAR_MM`] of the wall segment, else the line is not intercostal and is dropped.
//! - **Pleura.** A wall segment that comes within [`PLEURAL_RECESS_MM`] of the lung passes
//!   through the costophrenic recess, where the parietal pleura reaches below the lung's edge
//!   (Nichols et al., AJR 1984: to the 10th rib in the mid-axillary line): the window is marked
//!   transpleural and ranks after every window clear of it.
//! - **Score.** Then by [`WindowFound::penalty`]: points for vessels and bone near the line, for its
//!   length and for its cranio-caudal tilt. Each name's best line is its window.

use std::collections::{BTreeMap, HashMap};

use rayon::prelude::*;
use stylet_physics::distance::squared_edt;
use stylet_physics::glam::DVec3;
use stylet_physics::{Affine, Grid, LabelId, PunctureAtlas, Role};

use super::classes::{ClassTable, ordinal};
use crate::manifest::InsertionPath;

/// Step along candidate lines (mm).
const STEP_MM: f64 = 0.75;
/// Longest line tried (mm).
const MAX_LENGTH_MM: f64 = 250.0;
/// Directions tried per target point (Fibonacci sphere).
const DIRECTIONS: usize = 3000;
/// A rib (or cartilage) bounds a window when it lies within this distance of the line's wall
/// segment: half a typical lower intercostal space; a line farther from both ribs is not between
/// them.
pub const BOUND_NEAR_MM: f64 = 10.0;
/// How far below the lung's edge seen on CT the costophrenic recess (and so the parietal pleura)
/// is taken to reach: about one rib and space. The recess reaches two spaces below the lung in quiet
/// breathing (Nichols 1984); a planning CT is taken in inspiration, with the lung already down in
/// part of it.
pub const PLEURAL_RECESS_MM: f64 = 30.0;
/// Vessels and other risk structures closer than this to the line cost a point per mm.
pub const VESSEL_MARGIN_MM: f64 = 10.0;
/// Bone closer than this to the line costs a point per mm: a small aiming error meets the rib.
pub const BONE_MARGIN_MM: f64 = 5.0;
/// A point per this many mm of line: a longer path bends more and crosses more liver.
pub const LENGTH_MM_PER_POINT: f64 = 10.0;
/// A point per this many degrees out of the axial plane (the PTCD needle is advanced horizontally,
/// aimed under fluoroscopy at the 11th–12th thoracic vertebra), and per this many degrees the
/// approach turns further than [`LATERAL_FREE_DEG`] from the side.
pub const TILT_DEG_PER_POINT: f64 = 5.0;
/// How far (degrees, in the axial plane) the approach may turn from the patient's side — the
/// mid-axillary line — toward the front or back at no cost: the anterior axillary line.
pub const LATERAL_FREE_DEG: f64 = 45.0;

/// One window: the best line between two bounds (ribs, or costal cartilage).
#[derive(Debug, Clone)]
pub struct WindowFound {
    /// The source class bounding the window above: a rib, or the costal cartilage.
    pub upper: LabelId,
    /// The source class bounding it below.
    pub lower: LabelId,
    /// Distance from the upper bound to the line's wall segment (mm).
    pub upper_distance_mm: f64,
    /// Distance from the lower bound to the line's wall segment (mm).
    pub lower_distance_mm: f64,
    /// Where the line crosses the rib cage (its wall point nearest a rib or cartilage).
    pub wall_mm: DVec3,
    pub entry_mm: DVec3,
    pub target_mm: DVec3,
    pub length_mm: f64,
    /// Smallest distance between the line and bone (mm).
    pub bone_clearance_mm: f64,
    /// Smallest distance between the line (outside the target) and a risk structure other than
    /// the lung: vessels, gallbladder, viscera (mm).
    pub vessel_clearance_mm: f64,
    /// Smallest distance between the line's wall segment and the lung (mm).
    pub lung_clearance_mm: f64,
    /// Angle between the line and the patient's axial plane (degrees).
    pub tilt_deg: f64,
    /// Angle in the axial plane between the line (target to skin) and the side of the space asked
    /// for (degrees): 0° from the mid-axillary line, 90° from straight in front; `None` when the
    /// space asked for names no side.
    pub lateral_deg: Option<f64>,
}

impl WindowFound {
    /// The nearer of bone and every risk structure, the lung included (mm).
    pub fn clearance_mm(&self) -> f64 {
        self.bone_clearance_mm
            .min(self.vessel_clearance_mm)
            .min(self.lung_clearance_mm)
    }

    /// Whether the wall segment passes through the costophrenic recess: the needle crosses the
    /// pleura there (pneumothorax, pleural effusion or empyema) though it touches no lung.
    pub fn transpleural(&self) -> bool {
        self.lung_clearance_mm < PLEURAL_RECESS_MM
    }

    /// The clinical penalty (points, lower is better):
    ///
    /// (VESSEL_MARGIN − d_vessel)⁺ + (BONE_MARGIN − d_bone)⁺ + length / 10 mm + tilt / 5°
    ///   + (lateral − 45°)⁺ / 5°
    ///
    /// so a 100 mm horizontal line from the side, clear of vessels and bone, costs 10 points, each
    /// mm closer than 10 mm to a vessel as much as 10 mm more path, and a straight anterior
    /// approach 9 points more than a mid-axillary one.
    pub fn penalty(&self) -> f64 {
        let over = |x: f64, free: f64| (x - free).max(0.0);
        over(VESSEL_MARGIN_MM, self.vessel_clearance_mm)
            + over(BONE_MARGIN_MM, self.bone_clearance_mm)
            + self.length_mm / LENGTH_MM_PER_POINT
            + self.tilt_deg / TILT_DEG_PER_POINT
            + over(self.lateral_deg.unwrap_or(0.0), LATERAL_FREE_DEG) / TILT_DEG_PER_POINT
    }

    /// Ranking: clear of the pleura first, then the lower penalty.
    fn better_than(&self, other: &WindowFound) -> std::cmp::Ordering {
        (self.transpleural(), self.penalty())
            .partial_cmp(&(other.transpleural(), other.penalty()))
            .unwrap_or(std::cmp::Ordering::Equal)
    }

    fn bounds(&self) -> (LabelId, LabelId) {
        (self.upper, self.lower)
    }
}

/// Result of the search: the chosen window and every window found, ranked.
#[derive(Debug, Clone)]
pub struct WindowReport {
    /// The bounds the recipe asked for (the standard space).
    pub requested: (LabelId, LabelId),
    /// The chosen window: the requested one when it exists and is clear of the pleura (or no
    /// window is), else the best ranked.
    pub found: Option<WindowFound>,
    /// Whether a window between the requested bounds exists.
    pub requested_found: bool,
    /// The best line of each pair of bounds that has one, best first ([`WindowFound::penalty`]
    /// after the pleura); `found` among them.
    pub ranked: Vec<WindowFound>,
}

impl WindowReport {
    /// The window between the requested bounds, if there is one.
    pub fn requested_window(&self) -> Option<&WindowFound> {
        self.ranked.iter().find(|f| f.bounds() == self.requested)
    }

    /// Why the chosen window was chosen, in words.
    pub fn choice(&self) -> Choice {
        match (&self.found, self.requested_window()) {
            (None, _) => Choice::None,
            (Some(f), Some(r)) if f.bounds() == r.bounds() => Choice::Requested,
            (Some(_), Some(_)) => Choice::RequestedTranspleural,
            (Some(_), None) => Choice::RequestedMissing,
        }
    }

    /// The rank (1-based) of the window between `bounds`.
    pub fn rank_of(&self, bounds: (LabelId, LabelId)) -> Option<usize> {
        self.ranked.iter().position(|f| f.bounds() == bounds).map(|i| i + 1)
    }

    /// The chosen window as a planned path, named by its bounds.
    pub fn path(&self, classes: &ClassTable) -> Option<InsertionPath> {
        self.found.as_ref().map(|f| window_path(classes, f, None))
    }

    /// Every window found as a planned path: the chosen one first, then the others by rank, each
    /// described with its rank.
    pub fn paths(&self, classes: &ClassTable) -> Vec<InsertionPath> {
        let Some(chosen) = &self.found else {
            return Vec::new();
        };
        let n = self.ranked.len();
        let others = self.ranked.iter().filter(|f| f.bounds() != chosen.bounds());
        std::iter::once(chosen)
            .chain(others)
            .map(|f| window_path(classes, f, self.rank_of(f.bounds()).map(|r| (r, n))))
            .collect()
    }
}

/// How the chosen window relates to the one the recipe asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Choice {
    /// The space asked for.
    Requested,
    /// The space asked for passes through the pleural recess and another is clear of it: the best
    /// ranked.
    RequestedTranspleural,
    /// The space asked for has no line clear of bone and risk structures: the best ranked.
    RequestedMissing,
    /// No window at all.
    None,
}

/// A window as a planned path: named by its bounds ("intercostal-right-10-11",
/// "intercostal-right-7-cartilage"), described in words with its figures; `rank`: (its rank, of
/// how many).
pub(crate) fn window_path(classes: &ClassTable, f: &WindowFound, rank: Option<(usize, usize)>) -> InsertionPath {
    let r = |v: DVec3| {
        [
            (v.x * 10.0).round() / 10.0,
            (v.y * 10.0).round() / 10.0,
            (v.z * 10.0).round() / 10.0,
        ]
    };
    let ranked = rank
        .map(|(k, n)| format!(", window {k} of {n} by clinical score"))
        .unwrap_or_default();
    let pleura = if f.transpleural() {
        format!(
            ", through the pleural recess ({:.0} mm from the lung)",
            f.lung_clearance_mm
        )
    } else {
        String::new()
    };
    let lateral = f
        .lateral_deg
        .map(|a| format!(", {a:.0}° from the side"))
        .unwrap_or_default();
    InsertionPath {
        name: path_name(classes, f.upper, f.lower),
        entry_mm: r(f.entry_mm),
        target_mm: r(f.target_mm),
        description: format!(
            "straight path through the {} to the target, {:.0} mm long, {:.0}° out of the axial plane{lateral}, \
             {:.1} mm from bone, {:.1} mm from vessels{pleura}, penalty {:.1}{ranked}",
            space_name(classes, f.upper, f.lower),
            f.length_mm,
            f.tilt_deg,
            f.bone_clearance_mm,
            f.vessel_clearance_mm,
            f.penalty()
        ),
    }
}

/// What bounds a window, as the class table names it.
enum Bound {
    Rib(super::classes::Rib),
    Cartilage,
    Other,
}

fn bound(classes: &ClassTable, id: LabelId) -> Bound {
    match classes.rib(id) {
        Some(r) => Bound::Rib(r),
        None if classes.is_costal_cartilage(id) => Bound::Cartilage,
        None => Bound::Other,
    }
}

/// The planned path's name: "intercostal-right-10-11", "intercostal-right-7-cartilage",
/// "intercostal-cartilage-right-8", "intercostal-cartilage", else by class numbers
/// ("intercostal-<upper>-<lower>").
fn path_name(classes: &ClassTable, upper: LabelId, lower: LabelId) -> String {
    match (bound(classes, upper), bound(classes, lower)) {
        (Bound::Rib(a), Bound::Rib(b)) if a.side == b.side => {
            format!("intercostal-{}-{}-{}", a.side.word(), a.number, b.number)
        }
        (Bound::Rib(a), Bound::Cartilage) => format!("intercostal-{}-{}-cartilage", a.side.word(), a.number),
        (Bound::Cartilage, Bound::Rib(b)) => format!("intercostal-cartilage-{}-{}", b.side.word(), b.number),
        (Bound::Cartilage, Bound::Cartilage) => "intercostal-cartilage".into(),
        _ => format!("intercostal-{upper}-{lower}"),
    }
}

/// The space between source classes `upper` and `lower` in words: "right 10th–11th intercostal
/// space", "right intercostal space below the 7th rib, at the costal cartilage", else "space
/// between rib_x (n) and class m (…)".
pub fn space_name(classes: &ClassTable, upper: LabelId, lower: LabelId) -> String {
    match (bound(classes, upper), bound(classes, lower)) {
        (Bound::Rib(a), Bound::Rib(b)) => super::classes::intercostal_space(a, b),
        (Bound::Rib(a), Bound::Cartilage) => format!(
            "{} intercostal space below the {} rib, above costal cartilage",
            a.side.word(),
            ordinal(a.number as u32)
        ),
        (Bound::Cartilage, Bound::Rib(b)) => format!(
            "{} intercostal space above the {} rib, below costal cartilage",
            b.side.word(),
            ordinal(b.number as u32)
        ),
        (Bound::Cartilage, Bound::Cartilage) => "anterior intercostal space between costal cartilages".into(),
        (Bound::Other, _) | (_, Bound::Other) => format!(
            "space between {} and {}",
            classes.describe(upper),
            classes.describe(lower)
        ),
    }
}

/// Searches every line from the target to the skin, names each by the ribs (or costal cartilage)
/// that bound it at the chest wall, keeps the best line of each pair of bounds, and ranks them.
/// `upper`/`lower`: the space asked for (chosen when it exists and is clear of the pleura);
/// `bone_labels`: source classes a needle must not cross. Every class of `source` that `classes`
/// names as a rib or as the costal cartilage can bound a window.
pub fn find_window(
    atlas: &PunctureAtlas,
    source: &stylet_physics::Volume<LabelId>,
    classes: &ClassTable,
    requested: (LabelId, LabelId),
    bone_labels: &[LabelId],
) -> WindowReport {
    // The patient's side of the space asked for (world RAS: +x is the patient's right).
    let side = classes.rib(requested.0).map(|r| match r.side {
        super::classes::Side::Right => DVec3::X,
        super::classes::Side::Left => DVec3::NEG_X,
    });
    let search = Search::new(atlas, source, classes, bone_labels, side);
    // Every line in parallel; the best of each pair of bounds, ties to the first line tried (the
    // same result on any number of threads).
    let lines: Vec<(usize, WindowFound)> = (0..search.targets.len() * DIRECTIONS)
        .into_par_iter()
        .filter_map(|i| {
            search
                .window(search.targets[i / DIRECTIONS], fibonacci(i % DIRECTIONS, DIRECTIONS))
                .map(|f| (i, f))
        })
        .collect();
    let mut best: BTreeMap<(LabelId, LabelId), (usize, WindowFound)> = BTreeMap::new();
    for (i, f) in lines {
        match best.get(&f.bounds()) {
            Some((j, g)) if g.better_than(&f).then(j.cmp(&i)).is_le() => {}
            _ => {
                best.insert(f.bounds(), (i, f));
            }
        }
    }
    let mut ranked: Vec<WindowFound> = best.into_values().map(|(_, f)| f).collect();
    // Stable: equal keys keep the bounds' order.
    ranked.sort_by(|a, b| a.better_than(b));
    let requested_window = ranked.iter().find(|f| f.bounds() == requested).cloned();
    let found = match requested_window {
        Some(r) if !r.transpleural() || ranked.first().is_none_or(|b| b.transpleural()) => Some(r),
        _ => ranked.first().cloned(),
    };
    WindowReport {
        requested,
        requested_found: ranked.iter().any(|f| f.bounds() == requested),
        found,
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
    /// Labels the needle passes through on its way to the target (organs, the target): the wall
    /// segment starts outside the outermost of them.
    inner_labels: Vec<LabelId>,
    /// Squared distance (mm²) of every voxel to the nearest risk voxel that is not lung.
    vessel_sq: Vec<f32>,
    /// Squared distance (mm²) of every voxel to the nearest lung voxel.
    lung_sq: Vec<f32>,
    /// The rib cage: squared distance to the nearest rib or cartilage voxel, on the box around
    /// them (beyond it, farther than any bound that counts).
    cage: Option<(Crop, Vec<f32>)>,
    /// Every rib and cartilage voxel, by cell.
    bounds: BoundVoxels,
    /// The patient's side the approach should come from (a unit vector), if known.
    side: Option<DVec3>,
}

impl<'a> Search<'a> {
    fn new(
        atlas: &'a PunctureAtlas,
        source: &'a stylet_physics::Volume<LabelId>,
        classes: &ClassTable,
        bone_labels: &'a [LabelId],
        side: Option<DVec3>,
    ) -> Self {
        let table = atlas.label_table();
        let ids = |role: Role| -> Vec<LabelId> { table.with_role(role).map(|l| l.id).collect() };
        let target_labels = ids(Role::Target);
        let risk_labels = ids(Role::Risk);
        let inner_labels: Vec<LabelId> = ids(Role::Organ)
            .into_iter()
            .chain(target_labels.iter().copied())
            .collect();
        let lung_labels: Vec<LabelId> = table
            .with_role(Role::Risk)
            .filter(|l| l.tissue == "lung")
            .map(|l| l.id)
            .collect();
        let grid = atlas.ct().grid();
        let partial = atlas.partial_labels().data();
        let mut pts: Vec<DVec3> = partial
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
        let (vessel_sq, lung_sq) = rayon::join(
            || {
                let mask: Vec<bool> = partial
                    .iter()
                    .map(|l| risk_labels.contains(l) && !lung_labels.contains(l))
                    .collect();
                squared_edt(grid, &mask)
            },
            || {
                let mask: Vec<bool> = partial.iter().map(|l| lung_labels.contains(l)).collect();
                squared_edt(grid, &mask)
            },
        );
        let is_bound = |l: LabelId| l != 0 && (classes.rib(l).is_some() || classes.is_costal_cartilage(l));
        let mut wanted = vec![false; LabelId::MAX as usize + 1];
        for (id, w) in wanted.iter_mut().enumerate() {
            *w = is_bound(id as LabelId);
        }
        let cage_voxels: Vec<usize> = source
            .data()
            .iter()
            .enumerate()
            .filter(|(_, l)| wanted[**l as usize])
            .map(|(idx, _)| idx)
            .collect();
        let cage = (!cage_voxels.is_empty()).then(|| {
            let crop = Crop::around(grid, &cage_voxels, 2.0 * BOUND_NEAR_MM);
            let sq = crop.squared_edt(source, |l| wanted[l as usize]);
            (crop, sq)
        });
        let bounds = BoundVoxels::new(
            cage_voxels
                .iter()
                .map(|&idx| (grid.linear_to_world(idx), source.data()[idx])),
            classes,
        );
        Search {
            atlas,
            source,
            bone_labels,
            targets,
            target_labels,
            risk_labels,
            inner_labels,
            vessel_sq,
            lung_sq,
            cage,
            bounds,
            side,
        }
    }

    /// The line from target point `t` along `dir` as a window, if it reaches the skin clear of
    /// bone and risk structures between two bounds.
    fn window(&self, t: DVec3, dir: DVec3) -> Option<WindowFound> {
        let line = self.cast(t, dir)?;
        let (wall_s, _) = line.wall_crossing?;
        let wall_mm = t + dir * wall_s;
        let b = self
            .bounds
            .nearest_above_and_below(t, dir, line.wall_from_s, line.length_mm, wall_mm)?;
        Some(WindowFound {
            upper: b.upper,
            lower: b.lower,
            upper_distance_mm: b.upper_mm,
            lower_distance_mm: b.lower_mm,
            wall_mm,
            entry_mm: t + dir * line.length_mm,
            target_mm: t,
            length_mm: line.length_mm,
            bone_clearance_mm: line.bone_mm,
            vessel_clearance_mm: line.vessel_mm,
            lung_clearance_mm: line.wall_lung_mm,
            tilt_deg: libm::asin(dir.z.abs().min(1.0)).to_degrees(),
            lateral_deg: self.side.map(|side| {
                let axial = DVec3::new(dir.x, dir.y, 0.0).normalize_or_zero();
                libm::acos(axial.dot(side).clamp(-1.0, 1.0)).to_degrees()
            }),
        })
    }

    /// Walks from the target outward to the skin; `None` if the line meets bone or a risk
    /// structure, or leaves the CT through a face of its box before it reaches the skin.
    fn cast(&self, t: DVec3, dir: DVec3) -> Option<Line> {
        let a = self.atlas;
        let grid = a.ct().grid();
        let fat_bone_hu = a.thresholds().fat_bone_hu;
        let mut line = Line {
            length_mm: 0.0,
            bone_mm: f64::INFINITY,
            vessel_mm: f64::INFINITY,
            wall_from_s: 0.0,
            wall_lung_mm: f64::INFINITY,
            wall_crossing: None,
        };
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
                line.length_mm = s;
                return Some(line);
            }
            let partial = a.partial_label_at(p);
            if a.hu_at(p) >= fat_bone_hu || self.bone_labels.contains(&self.source.nearest(p, 0)) {
                return None;
            }
            if self.risk_labels.contains(&partial) {
                return None;
            }
            let voxel = grid.nearest_voxel(p).map(|[i, j, k]| grid.linear(i, j, k));
            let at = |sq: &[f32]| voxel.map_or(f64::INFINITY, |v| (sq[v] as f64).sqrt());
            if !self.target_labels.contains(&partial) {
                line.bone_mm = line.bone_mm.min(-a.bone_distance().sample(p, -1000.0) as f64);
                line.vessel_mm = line.vessel_mm.min(at(&self.vessel_sq));
            }
            if self.inner_labels.contains(&partial) {
                // Still inside: the wall segment starts further out.
                line.wall_from_s = s + STEP_MM;
                line.wall_lung_mm = f64::INFINITY;
                line.wall_crossing = None;
            } else {
                line.wall_lung_mm = line.wall_lung_mm.min(at(&self.lung_sq));
                if let Some(g) = self.cage_distance_mm(p)
                    && line.wall_crossing.is_none_or(|(_, best)| g < best)
                {
                    line.wall_crossing = Some((s, g));
                }
            }
            s += STEP_MM;
        }
        None
    }

    /// Distance (mm) from `p` to the nearest rib or cartilage voxel, if within the cage's box.
    fn cage_distance_mm(&self, p: DVec3) -> Option<f64> {
        let (crop, sq) = self.cage.as_ref()?;
        let [i, j, k] = crop.grid.nearest_voxel(p)?;
        Some((sq[crop.grid.linear(i, j, k)] as f64).sqrt())
    }
}

/// What a walk from the target to the skin found.
struct Line {
    length_mm: f64,
    /// Smallest distances to bone and to risk structures other than lung, outside the target.
    bone_mm: f64,
    vessel_mm: f64,
    /// Where the wall segment starts (distance from the target, mm).
    wall_from_s: f64,
    /// Smallest distance between the wall segment and the lung.
    wall_lung_mm: f64,
    /// The wall segment's point nearest the rib cage: (distance from the target, its distance to
    /// the cage), both mm.
    wall_crossing: Option<(f64, f64)>,
}

/// The bounds of a window and their distances to the line's wall segment (mm).
struct Bounds {
    upper: LabelId,
    upper_mm: f64,
    lower: LabelId,
    lower_mm: f64,
}

/// Rib and cartilage voxels (world positions) bucketed in cubes of [`BOUND_NEAR_MM`], for the
/// ones near a wall crossing.
struct BoundVoxels {
    cells: HashMap<[i64; 3], Vec<(DVec3, LabelId)>>,
    /// Classes that bound on either side (the costal cartilage: one class for every rib's).
    either_side: Vec<LabelId>,
}

impl BoundVoxels {
    fn new(voxels: impl Iterator<Item = (DVec3, LabelId)>, classes: &ClassTable) -> Self {
        let mut cells: HashMap<[i64; 3], Vec<(DVec3, LabelId)>> = HashMap::new();
        let mut either_side = Vec::new();
        for (p, l) in voxels {
            cells.entry(Self::cell(p)).or_default().push((p, l));
            if classes.is_costal_cartilage(l) && !either_side.contains(&l) {
                either_side.push(l);
            }
        }
        BoundVoxels { cells, either_side }
    }

    fn cell(p: DVec3) -> [i64; 3] {
        let c = |x: f64| libm::floor(x / BOUND_NEAR_MM) as i64;
        [c(p.x), c(p.y), c(p.z)]
    }

    /// The nearest bound above and the nearest below the line `t + s·dir`, measured to its wall
    /// segment `s ∈ [from_s, to_s]` among the voxels within 2·[`BOUND_NEAR_MM`] of the crossing
    /// `wall`; each must be within [`BOUND_NEAR_MM`]. A rib is above or below by its nearest
    /// voxel; the cartilage counts on each side by its nearest voxel there.
    fn nearest_above_and_below(&self, t: DVec3, dir: DVec3, from_s: f64, to_s: f64, wall: DVec3) -> Option<Bounds> {
        let reach = 2.0 * BOUND_NEAR_MM;
        let [ci, cj, ck] = Self::cell(wall);
        // Per class: nearest voxel (distance, above?), and for either-side classes the nearest
        // above and below.
        let mut nearest: BTreeMap<LabelId, (f64, bool)> = BTreeMap::new();
        let mut sided: BTreeMap<(LabelId, bool), f64> = BTreeMap::new();
        for di in -2..=2 {
            for dj in -2..=2 {
                for dk in -2..=2 {
                    let Some(cell) = self.cells.get(&[ci + di, cj + dj, ck + dk]) else {
                        continue;
                    };
                    for &(q, l) in cell {
                        if q.distance_squared(wall) > reach * reach {
                            continue;
                        }
                        let foot = t + dir * (q - t).dot(dir).clamp(from_s, to_s);
                        let d = q.distance(foot);
                        let above = q.z > foot.z;
                        if self.either_side.contains(&l) {
                            let e = sided.entry((l, above)).or_insert(f64::INFINITY);
                            *e = e.min(d);
                        } else {
                            let e = nearest.entry(l).or_insert((f64::INFINITY, above));
                            if d < e.0 {
                                *e = (d, above);
                            }
                        }
                    }
                }
            }
        }
        let side = |want_above: bool| -> Option<(LabelId, f64)> {
            nearest
                .iter()
                .filter(|(_, (_, above))| *above == want_above)
                .map(|(&l, &(d, _))| (l, d))
                .chain(
                    sided
                        .iter()
                        .filter(|((_, above), _)| *above == want_above)
                        .map(|(&(l, _), &d)| (l, d)),
                )
                .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
                .filter(|(_, d)| *d <= BOUND_NEAR_MM)
        };
        let (upper, upper_mm) = side(true)?;
        let (lower, lower_mm) = side(false)?;
        Some(Bounds {
            upper,
            upper_mm,
            lower,
            lower_mm,
        })
    }
}

/// A box of the CT's grid (as a grid of its own) around some voxels, with a margin.
struct Crop {
    grid: Grid,
    offset: [usize; 3],
}

impl Crop {
    /// The box around `voxels` (linear indices, at least one) widened by `margin_mm`.
    fn around(grid: &Grid, voxels: &[usize], margin_mm: f64) -> Crop {
        let dims = grid.dims();
        let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
        for &idx in voxels {
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

    /// Squared distance (mm²) within the box to the nearest voxel whose label is `wanted`.
    fn squared_edt(&self, source: &stylet_physics::Volume<LabelId>, wanted: impl Fn(LabelId) -> bool) -> Vec<f32> {
        let [nx, ny, nz] = self.grid.dims();
        let full = source.grid();
        let mut mask = Vec::with_capacity(nx * ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let [a, b, c] = [i + self.offset[0], j + self.offset[1], k + self.offset[2]];
                    mask.push(wanted(source.data()[full.linear(a, b, c)]));
                }
            }
        }
        squared_edt(&self.grid, &mask)
    }
}

/// The n-th of `count` directions spread evenly over the sphere.
fn fibonacci(n: usize, count: usize) -> DVec3 {
    let golden = std::f64::consts::PI * (3.0 - libm::sqrt(5.0));
    let z = 1.0 - 2.0 * (n as f64 + 0.5) / count as f64;
    let r = libm::sqrt(1.0 - z * z);
    let phi = golden * n as f64;
    DVec3::new(r * libm::cos(phi), r * libm::sin(phi), z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn window(upper: LabelId, lower: LabelId) -> WindowFound {
        WindowFound {
            upper,
            lower,
            upper_distance_mm: 5.0,
            lower_distance_mm: 5.0,
            wall_mm: DVec3::ZERO,
            entry_mm: DVec3::new(100.0, 0.0, 0.0),
            target_mm: DVec3::ZERO,
            length_mm: 100.0,
            bone_clearance_mm: 8.0,
            vessel_clearance_mm: 15.0,
            lung_clearance_mm: 45.0,
            tilt_deg: 0.0,
            lateral_deg: Some(0.0),
        }
    }

    /// The penalty by hand: 100 mm horizontal from the side, clear of vessels and bone: 10
    /// points; then each term on its own.
    #[test]
    fn the_penalty_adds_its_terms_as_documented() {
        let w = window(113, 114);
        assert_eq!(w.penalty(), 10.0);
        let with = |f: &dyn Fn(&mut WindowFound)| {
            let mut w = window(113, 114);
            f(&mut w);
            w.penalty()
        };
        assert_eq!(with(&|w| w.vessel_clearance_mm = 7.0), 13.0);
        assert_eq!(with(&|w| w.bone_clearance_mm = 2.0), 13.0);
        assert_eq!(with(&|w| w.length_mm = 150.0), 15.0);
        assert_eq!(with(&|w| w.tilt_deg = 20.0), 14.0);
        assert_eq!(
            with(&|w| w.lateral_deg = Some(40.0)),
            10.0,
            "the anterior axillary line is free"
        );
        assert_eq!(
            with(&|w| w.lateral_deg = Some(90.0)),
            19.0,
            "straight in front: 9 points"
        );
        assert_eq!(with(&|w| w.lateral_deg = None), 10.0);
    }

    /// Clear of the pleura beats any penalty; the mark sits at 30 mm from the lung.
    #[test]
    fn transpleural_windows_rank_after_every_clear_one() {
        let mut near_lung = window(111, 112);
        near_lung.lung_clearance_mm = 29.9;
        let mut long = window(113, 114);
        long.length_mm = 250.0;
        long.lung_clearance_mm = PLEURAL_RECESS_MM;
        assert!(near_lung.transpleural() && !long.transpleural());
        assert!(long.penalty() > near_lung.penalty());
        assert_eq!(long.better_than(&near_lung), std::cmp::Ordering::Less);
    }

    #[test]
    fn windows_are_named_by_their_ribs_or_the_cartilage() {
        let ts = ClassTable::totalsegmentator();
        let cartilage = ts.id_of("costal_cartilages").unwrap();
        let name = |u, l| (path_name(&ts, u, l), space_name(&ts, u, l));
        assert_eq!(
            name(113, 114),
            (
                "intercostal-right-10-11".into(),
                "right 10th–11th intercostal space".into()
            )
        );
        assert_eq!(
            name(110, cartilage),
            (
                "intercostal-right-7-cartilage".into(),
                "right intercostal space below the 7th rib, above costal cartilage".into()
            )
        );
        assert_eq!(
            name(cartilage, 111),
            (
                "intercostal-cartilage-right-8".into(),
                "right intercostal space above the 8th rib, below costal cartilage".into()
            )
        );
        assert_eq!(
            name(cartilage, cartilage),
            (
                "intercostal-cartilage".into(),
                "anterior intercostal space between costal cartilages".into()
            )
        );
        assert_eq!(name(5, 113).0, "intercostal-5-113");
        assert!(
            name(5, 113)
                .1
                .starts_with("space between liver (5) and rib_right_10 (113)")
        );
    }
}
