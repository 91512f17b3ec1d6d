//! Empty-space leaping (thesis §3.2.1; docs/rendering.md "One ray", step 8): an N³ grid of cells
//! over the CT's index box, each with the CT range of the voxels its trilinear samples can read
//! (widened by one voxel), and per transfer function one bit per cell: occupied when the
//! transfer function is visible anywhere in that range. A sample in an empty cell would have zero
//! opacity, so skipping it never changes the picture.

use rayon::prelude::*;
use stylet_physics::Volume;
use stylet_physics::glam::{DVec3, Vec3};

use crate::index_map::IndexMap;
use crate::transfer_table::TransferTable;

/// The CT value range of every cell of an N³ occupancy grid over the index box
/// [−½, n − ½)³: cell q on axis a covers index coordinates [q·n/N − ½, (q+1)·n/N − ½), and its
/// range spans the voxels a trilinear sample there reads, widened by one voxel on every side.
#[derive(Debug, Clone, PartialEq)]
pub struct CellRanges {
    pub cells: u32,
    /// Minimum and maximum HU per cell, x fastest.
    pub min_hu: Vec<f32>,
    pub max_hu: Vec<f32>,
}

/// First and last voxel (inclusive) whose values a sample in cell `q` of `cells` along an axis
/// of `n` voxels may read: cell q covers [q·n/N − ½, (q+1)·n/N − ½), a sample at c reads voxels
/// ⌊c⌋ and ⌊c⌋ + 1, widened by one voxel on each side, clamped to [0, n − 1].
pub fn cell_voxels(q: u32, cells: u32, n: u32) -> (usize, usize) {
    let (q, cells, n) = (q as i64, cells as i64, n as i64);
    // ⌊q·n/N − ½⌋ = ⌊(2qn − N) / 2N⌋ in exact integer arithmetic.
    let lo = (2 * q * n - cells).div_euclid(2 * cells) - 1;
    let hi = (2 * (q + 1) * n - cells).div_euclid(2 * cells) + 2;
    (lo.clamp(0, n - 1) as usize, hi.clamp(0, n - 1) as usize)
}

/// Per-cell CT minimum and maximum, by separable min/max passes (x, then y, then z).
pub fn cell_ranges(ct: &Volume<f32>, cells: u32) -> CellRanges {
    let [nx, ny, nz] = ct.grid().dims();
    let nc = cells as usize;
    let data = ct.data();
    let windows = |n: usize| -> Vec<(usize, usize)> { (0..cells).map(|q| cell_voxels(q, cells, n as u32)).collect() };
    let (wx, wy, wz) = (windows(nx), windows(ny), windows(nz));
    // Pass 1: along x, for every (cell x, j, k).
    let mut a_min = vec![0.0f32; nc * ny * nz];
    let mut a_max = vec![0.0f32; nc * ny * nz];
    a_min
        .par_chunks_mut(nc * ny)
        .zip(a_max.par_chunks_mut(nc * ny))
        .enumerate()
        .for_each(|(k, (mn, mx))| {
            for j in 0..ny {
                let row = &data[nx * (j + ny * k)..nx * (j + ny * k + 1)];
                for (q, &(lo, hi)) in wx.iter().enumerate() {
                    let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
                    for &v in &row[lo..=hi] {
                        a = a.min(v);
                        b = b.max(v);
                    }
                    mn[q + nc * j] = a;
                    mx[q + nc * j] = b;
                }
            }
        });
    // Pass 2: along y, for every (cell x, cell y, k).
    let mut b_min = vec![0.0f32; nc * nc * nz];
    let mut b_max = vec![0.0f32; nc * nc * nz];
    b_min
        .par_chunks_mut(nc * nc)
        .zip(b_max.par_chunks_mut(nc * nc))
        .enumerate()
        .for_each(|(k, (mn, mx))| {
            for (qy, &(lo, hi)) in wy.iter().enumerate() {
                for qx in 0..nc {
                    let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
                    for j in lo..=hi {
                        let i = qx + nc * (j + ny * k);
                        a = a.min(a_min[i]);
                        b = b.max(a_max[i]);
                    }
                    mn[qx + nc * qy] = a;
                    mx[qx + nc * qy] = b;
                }
            }
        });
    // Pass 3: along z.
    let mut min_hu = vec![0.0f32; nc * nc * nc];
    let mut max_hu = vec![0.0f32; nc * nc * nc];
    for (qz, &(lo, hi)) in wz.iter().enumerate() {
        for qxy in 0..nc * nc {
            let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
            for k in lo..=hi {
                a = a.min(b_min[qxy + nc * nc * k]);
                b = b.max(b_max[qxy + nc * nc * k]);
            }
            min_hu[qxy + nc * nc * qz] = a;
            max_hu[qxy + nc * nc * qz] = b;
        }
    }
    CellRanges { cells, min_hu, max_hu }
}

/// The occupancy bits of one frame and the geometry to find a sample's cell and a ray's exit
/// from it.
pub struct Occupancy {
    pub cells: u32,
    /// 1 = occupied, x fastest.
    pub occupied: Vec<u8>,
    /// N / n_a: cell coordinate per index unit.
    pub scale: Vec3,
    /// n_a / N: a cell's size in index units.
    pub size: Vec3,
}

impl Occupancy {
    /// Bits for the transfer table `tf` over `ranges`; `deformed` (J's grid, in CT index space through `ct_map`)
    /// marks every cell its box touches as occupied (Ω_J counts as occupied).
    pub fn new(
        ranges: &CellRanges,
        tf: &TransferTable,
        dims: [u32; 3],
        deformed: Option<(&Volume<f32>, &IndexMap)>,
    ) -> Occupancy {
        let n = ranges.cells;
        let mut occupied: Vec<u8> = ranges
            .min_hu
            .iter()
            .zip(&ranges.max_hu)
            .map(|(&lo, &hi)| u8::from(tf.visible_in(lo, hi)))
            .collect();
        let nf = n as f32;
        let scale = Vec3::new(nf / dims[0] as f32, nf / dims[1] as f32, nf / dims[2] as f32);
        let size = Vec3::new(dims[0] as f32 / nf, dims[1] as f32 / nf, dims[2] as f32 / nf);
        if let Some((j, ct_map)) = deformed {
            let g = j.grid();
            let [jx, jy, jz] = g.dims();
            let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for cx in [-0.5, jx as f64 - 0.5] {
                for cy in [-0.5, jy as f64 - 0.5] {
                    for cz in [-0.5, jz as f64 - 0.5] {
                        let c = ct_map.point(g.affine().apply(DVec3::new(cx, cy, cz)).as_vec3());
                        lo = lo.min(c);
                        hi = hi.max(c);
                    }
                }
            }
            // One cell of margin against rounding at the box's faces.
            let cell = |c: f32, a: usize| ((c + 0.5) * scale[a]).floor() as i64;
            let range = |a: usize| {
                let q0 = (cell(lo[a], a) - 1).clamp(0, n as i64 - 1) as usize;
                let q1 = (cell(hi[a], a) + 1).clamp(0, n as i64 - 1) as usize;
                (q0, q1)
            };
            let (rx, ry, rz) = (range(0), range(1), range(2));
            let inside = hi.cmpge(Vec3::splat(-0.5)).all()
                && lo
                    .cmplt(Vec3::new(
                        dims[0] as f32 - 0.5,
                        dims[1] as f32 - 0.5,
                        dims[2] as f32 - 0.5,
                    ))
                    .all();
            if inside {
                let nn = n as usize;
                for qz in rz.0..=rz.1 {
                    for qy in ry.0..=ry.1 {
                        for qx in rx.0..=rx.1 {
                            occupied[qx + nn * (qy + nn * qz)] = 1;
                        }
                    }
                }
            }
        }
        Occupancy {
            cells: n,
            occupied,
            scale,
            size,
        }
    }

    /// These bits dilated by `margin` index units along every axis (a cell is occupied when any
    /// cell within the margin is): for the breathing motion, whose world point x samples the
    /// reference point X = x − u with |u| within the margin (thesis §5.4.1), so an empty dilated
    /// cell at x means an empty cell at X.
    pub fn dilated(&self, margin: Vec3) -> Occupancy {
        let n = self.cells as usize;
        let reach = |a: usize| ((margin[a] * self.scale[a]).ceil().max(0.0) as usize).min(n);
        let r = [reach(0), reach(1), reach(2)];
        let mut out = self.occupied.clone();
        // Separable: a running OR along x, then y, then z.
        for (a, stride) in [(0usize, 1usize), (1, n), (2, n * n)] {
            if r[a] == 0 {
                continue;
            }
            let src = out.clone();
            for (idx, o) in out.iter_mut().enumerate() {
                let q = (idx / stride) % n;
                let lo = q.saturating_sub(r[a]);
                let hi = (q + r[a]).min(n - 1);
                let base = idx - q * stride;
                *o = u8::from((lo..=hi).any(|p| src[base + p * stride] != 0));
            }
        }
        Occupancy {
            cells: self.cells,
            occupied: out,
            scale: self.scale,
            size: self.size,
        }
    }

    /// The cell of CT index `c`: q_a = ⌊(c_a + ½)·N/n_a⌋ clamped to [0, N − 1].
    #[inline]
    pub fn cell(&self, c: Vec3) -> [u32; 3] {
        // ⌊v⌋ clamped to [0, N − 1] as max(v, 0) truncated then `min`: the same cell for every
        // v (truncation is the floor for v ≥ 0) without a libm `floorf` call per sample.
        let last = self.cells - 1;
        let q = (c + Vec3::splat(0.5)) * self.scale;
        let cell = |v: f32| (v.max(0.0) as u32).min(last);
        [cell(q.x), cell(q.y), cell(q.z)]
    }

    #[inline]
    pub fn is_occupied(&self, q: [u32; 3]) -> bool {
        let n = self.cells as usize;
        self.occupied[q[0] as usize + n * (q[1] as usize + n * q[2] as usize)] != 0
    }

    /// Ray parameter where the ray c(t) = `ce` + t·`dc` (index space) leaves cell `q`:
    /// the nearest of the three exit faces; +∞ if the ray is parallel to all of them.
    #[inline]
    pub fn exit_t(&self, q: [u32; 3], ce: Vec3, dc: Vec3) -> f32 {
        let mut t = f32::INFINITY;
        for a in 0..3 {
            let d = dc[a];
            if d != 0.0 {
                let face = if d > 0.0 { q[a] + 1 } else { q[a] };
                let bound = face as f32 * self.size[a] - 0.5;
                t = t.min((bound - ce[a]) / d);
            }
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_physics::{Affine, Grid};

    /// The separable dilation equals the brute-force one: a cell is occupied when any cell within
    /// ⌈margin·N/n⌉ cells per axis (a box) is.
    #[test]
    fn dilation_marks_every_cell_within_the_margin() {
        let n = 12u32;
        let occupied: Vec<u8> = (0..n.pow(3) as usize)
            .map(|i| u8::from((i * 2_654_435_761) % 97 == 0))
            .collect();
        let occ = Occupancy {
            cells: n,
            occupied,
            scale: Vec3::new(0.25, 0.5, 0.125),
            size: Vec3::new(4.0, 2.0, 8.0),
        };
        let margin = Vec3::new(5.0, 1.5, 20.0);
        let d = occ.dilated(margin);
        let r = [2i64, 1, 3]; // ⌈5·0.25⌉, ⌈1.5·0.5⌉, ⌈20·0.125⌉
        let n = n as i64;
        let at = |v: &[u8], x: i64, y: i64, z: i64| v[(x + n * (y + n * z)) as usize] != 0;
        for (z, y, x) in (0..n).flat_map(|z| (0..n).flat_map(move |y| (0..n).map(move |x| (z, y, x)))) {
            let mut any = false;
            for dz in -r[2]..=r[2] {
                for dy in -r[1]..=r[1] {
                    for dx in -r[0]..=r[0] {
                        let (a, b, c) = (x + dx, y + dy, z + dz);
                        if (0..n).contains(&a) && (0..n).contains(&b) && (0..n).contains(&c) {
                            any |= at(&occ.occupied, a, b, c);
                        }
                    }
                }
            }
            assert_eq!(at(&d.occupied, x, y, z), any, "cell ({x}, {y}, {z})");
        }
    }

    #[test]
    fn cell_windows_cover_every_voxel_a_sample_reads() {
        for (cells, n) in [(16u32, 64u32), (64, 50), (128, 40), (16, 17)] {
            for q in 0..cells {
                let (lo, hi) = cell_voxels(q, cells, n);
                // Sample positions spanning the cell: every voxel read must be in the window.
                let c0 = q as f64 * n as f64 / cells as f64 - 0.5;
                let c1 = (q + 1) as f64 * n as f64 / cells as f64 - 0.5;
                for s in 0..=20 {
                    let c = (c0 + (c1 - c0) * s as f64 / 20.0).clamp(0.0, n as f64 - 1.0);
                    let b = (c as usize).min(n as usize - 2);
                    assert!(lo <= b && b < hi, "cells {cells} n {n} q {q}: {lo}..{hi} vs {b}");
                }
            }
        }
    }

    #[test]
    fn ranges_bound_the_voxels_of_each_cell() {
        let g = Grid::new([40, 33, 20], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let data: Vec<f32> = (0..g.len()).map(|i| ((i * 7919) % 1000) as f32 - 500.0).collect();
        let v = Volume::new(g, data).unwrap();
        let r = cell_ranges(&v, 16);
        let (lx, hx) = cell_voxels(3, 16, 40);
        let (ly, hy) = cell_voxels(5, 16, 33);
        let (lz, hz) = cell_voxels(15, 16, 20);
        let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
        for k in lz..=hz {
            for j in ly..=hy {
                for i in lx..=hx {
                    a = a.min(v.get(i, j, k));
                    b = b.max(v.get(i, j, k));
                }
            }
        }
        let idx = 3 + 16 * (5 + 16 * 15);
        assert_eq!((r.min_hu[idx], r.max_hu[idx]), (a, b));
    }
}
