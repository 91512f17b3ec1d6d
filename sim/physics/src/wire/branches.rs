//! Which way along the bile ducts the wire goes: the distance from the hilum measured through the
//! ducts' lumen, and the wire's advances away from it (docs/seldinger.md "Wrong branches").
//!
//! A PTCD wire is steered centrally, from the punctured peripheral duct toward the hilum and the
//! common bile duct, where the drain will sit. The hilum is taken as the widest point of the duct
//! tree (the largest distance to a wall: in an obstructed, dilated tree the common duct or the
//! confluence); the distance from it is geodesic — a shortest path through duct voxels — so that a
//! branch that lies close to the hilum in space but leads away from it along the ducts counts as
//! leading away. A wire tip that runs [`WRONG_BRANCH_MM`] farther from the hilum than the nearest
//! it has been went into a wrong branch (a peripheral one, or up the punctured duct the wrong way);
//! it may go wrong again once it has come back to within [`REARM_MM`] of that nearest point.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use glam::DVec3;

use crate::grid::Grid;
use crate::volume::Volume;

/// How far the tip runs away from the hilum, past the nearest it has been, to count as one
/// wrong-branch entry (mm): the length of a segmental duct's first stretch, beyond the wobble of
/// a tip turning at a junction.
pub const WRONG_BRANCH_MM: f64 = 10.0;
/// How close to its nearest point the tip must come back before it can go wrong again (mm).
pub const REARM_MM: f64 = 3.0;

/// Geodesic distance from the hilum through the ducts' voxels (mm; negative outside the ducts
/// and in duct voxels cut off from the hilum).
#[derive(Debug, Clone)]
pub struct HilumDistance {
    along_ducts_mm: Volume<f32>,
    hilum: usize,
}

/// Value of voxels the distance does not reach.
const UNREACHED: f32 = -1.0;

impl HilumDistance {
    /// The distance from the widest lumen voxel (`depth`: distance to the wall, positive inside;
    /// the lowest index among equals, so the choice is reproducible).
    pub fn from_widest(grid: &Grid, lumen: &[bool], depth: &Volume<f32>) -> HilumDistance {
        let hilum = (0..grid.len())
            .filter(|&i| lumen[i])
            .fold(None, |best: Option<usize>, i| match best {
                Some(b) if depth.data()[b] >= depth.data()[i] => Some(b),
                _ => Some(i),
            })
            .unwrap_or(0);
        HilumDistance::from_voxel(grid, lumen, hilum)
    }

    /// The distance from the lumen voxel `hilum` (linear index): Dijkstra over the 26 neighbours,
    /// each step as long as the line between the voxels' centres.
    pub fn from_voxel(grid: &Grid, lumen: &[bool], hilum: usize) -> HilumDistance {
        // The best distance found so far per voxel, kept in f32 (the map's own precision; one
        // array of the grid's size): the queue carries the exact f64 sums.
        let mut best = vec![f32::INFINITY; grid.len()];
        let [nx, ny, nz] = grid.dims();
        let steps = neighbour_steps(grid);
        let mut queue = BinaryHeap::new();
        if lumen.get(hilum).copied().unwrap_or(false) {
            best[hilum] = 0.0;
            queue.push(Entry { mm: 0.0, voxel: hilum });
        }
        while let Some(Entry { mm, voxel }) = queue.pop() {
            if mm as f32 > best[voxel] {
                continue;
            }
            let [i, j, k] = grid.unlinear(voxel);
            for &([di, dj, dk], step_mm) in &steps {
                let (Some(a), Some(b), Some(c)) = (
                    i.checked_add_signed(di).filter(|&a| a < nx),
                    j.checked_add_signed(dj).filter(|&b| b < ny),
                    k.checked_add_signed(dk).filter(|&c| c < nz),
                ) else {
                    continue;
                };
                let n = grid.linear(a, b, c);
                let to_mm = mm + step_mm;
                if lumen[n] && (to_mm as f32) < best[n] {
                    best[n] = to_mm as f32;
                    queue.push(Entry { mm: to_mm, voxel: n });
                }
            }
        }
        for b in &mut best {
            if !b.is_finite() {
                *b = UNREACHED;
            }
        }
        let along_ducts_mm = Volume::new(*grid, best).expect("one value per voxel of the grid");
        HilumDistance { along_ducts_mm, hilum }
    }

    /// The distance from the hilum at the duct voxel nearest `x` (mm), `None` outside the ducts.
    pub fn at(&self, x: DVec3) -> Option<f64> {
        let v = self.along_ducts_mm.nearest(x, UNREACHED);
        (v >= 0.0).then_some(f64::from(v))
    }

    /// The hilum (world, mm).
    pub fn hilum_mm(&self) -> DVec3 {
        self.along_ducts_mm.grid().linear_to_world(self.hilum)
    }
}

/// The 26 neighbour offsets and their lengths (mm).
fn neighbour_steps(grid: &Grid) -> Vec<([isize; 3], f64)> {
    let mut steps = Vec::with_capacity(26);
    for di in -1..=1isize {
        for dj in -1..=1isize {
            for dk in -1..=1isize {
                if (di, dj, dk) != (0, 0, 0) {
                    let d = grid.affine().apply(DVec3::new(di as f64, dj as f64, dk as f64))
                        - grid.affine().apply(DVec3::ZERO);
                    steps.push(([di, dj, dk], d.length()));
                }
            }
        }
    }
    steps
}

/// A voxel in Dijkstra's queue, nearest first (ties: lowest index, for a reproducible order).
#[derive(Debug, PartialEq)]
struct Entry {
    mm: f64,
    voxel: usize,
}

impl Eq for Entry {}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        other.mm.total_cmp(&self.mm).then_with(|| other.voxel.cmp(&self.voxel))
    }
}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Counts the wire tip's runs away from the hilum (see the module's doc).
#[derive(Debug, Clone, Default)]
pub struct WrongBranchWatch {
    /// The nearest to the hilum the tip has been (mm along the ducts).
    nearest_mm: Option<f64>,
    /// In a wrong branch now: waiting for the tip to come back.
    astray: bool,
    entries: u32,
}

impl WrongBranchWatch {
    /// Observes the tip's distance from the hilum (`None`: the tip is not in the ducts).
    pub fn observe(&mut self, from_hilum_mm: Option<f64>) {
        let Some(d) = from_hilum_mm else { return };
        let nearest = self.nearest_mm.map_or(d, |n| n.min(d));
        self.nearest_mm = Some(nearest);
        if self.astray {
            self.astray = d > nearest + REARM_MM;
        } else if d >= nearest + WRONG_BRANCH_MM {
            self.astray = true;
            self.entries += 1;
        }
    }

    /// Wrong branches entered so far.
    pub fn entries(&self) -> u32 {
        self.entries
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Affine;

    #[test]
    fn a_run_away_from_the_hilum_counts_once_until_the_tip_comes_back() {
        let mut w = WrongBranchWatch::default();
        // Toward the hilum: nothing.
        for d in [60.0, 55.0, 50.0, 45.0] {
            w.observe(Some(d));
        }
        assert_eq!(w.entries(), 0);
        // Out of the ducts: ignored.
        w.observe(None);
        // 9 mm back: still the junction's wobble.
        w.observe(Some(54.0));
        assert_eq!(w.entries(), 0);
        // On into the branch: one entry, however far it goes.
        for d in [55.0, 60.0, 70.0] {
            w.observe(Some(d));
        }
        assert_eq!(w.entries(), 1);
        // Drawn back to the junction and into the branch again: a second entry.
        w.observe(Some(47.0));
        w.observe(Some(58.0));
        assert_eq!(w.entries(), 2);
        // Back, then on toward the hilum: no more.
        for d in [46.0, 40.0, 30.0, 20.0] {
            w.observe(Some(d));
        }
        assert_eq!(w.entries(), 2);
    }

    #[test]
    fn the_distance_runs_through_the_ducts_not_across_them() {
        // A U of 1 mm voxels: up x = 0, across y = 20, down x = 10; the hilum at the first
        // arm's foot. The second arm's foot is 10 mm away in space, 50 mm along the ducts.
        let grid = Grid::new([12, 22, 1], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let lumen: Vec<bool> = (0..grid.len())
            .map(|n| {
                let [i, j, _] = grid.unlinear(n);
                ((i == 0 || i == 10) && j <= 20) || (j == 20 && i <= 10)
            })
            .collect();
        let h = HilumDistance::from_voxel(&grid, &lumen, grid.linear(0, 0, 0));
        assert_eq!(h.at(DVec3::ZERO), Some(0.0));
        let foot = h.at(DVec3::new(10.0, 0.0, 0.0)).unwrap();
        // 19 straight, 2 diagonal (corners cut), 8 across, 19 down: 46 + 2√2.
        assert!((foot - (46.0 + 2.0 * std::f64::consts::SQRT_2)).abs() < 1e-4, "{foot}");
        assert_eq!(h.at(DVec3::new(5.0, 5.0, 0.0)), None);
        assert_eq!(h.hilum_mm(), DVec3::ZERO);
    }

    #[test]
    fn the_widest_voxel_is_the_hilum() {
        let grid = Grid::new([5, 1, 1], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let depth = Volume::new(grid, vec![0.5, 1.0, 2.0, 2.0, 0.5]).unwrap();
        let h = HilumDistance::from_widest(&grid, &[true; 5], &depth);
        assert_eq!(h.hilum_mm(), DVec3::new(2.0, 0.0, 0.0));
        assert_eq!(h.at(DVec3::new(4.0, 0.0, 0.0)), Some(2.0));
    }
}
