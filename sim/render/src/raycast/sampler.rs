//! The sampling function s(x) (docs/rendering.md "Sampling"; thesis eq. 3.1.1) in `f32`:
//! trilinear CT by eight loads with `stylet_physics::Volume::sample_index`'s inside rule, the
//! deformed sub-image J inside its grid Ω_J, labels by nearest neighbour, and the gradient by
//! central differences for shading.

use stylet_physics::LabelId;
use stylet_physics::atlas::AIR_HU;
use stylet_physics::glam::{Vec3, Vec4};

pub use super::cell::Cell;
use super::gradient_volume::GradientVolume;
use crate::volume::IndexMap;

/// A scalar grid as the ray loop reads it: data (x fastest) and its dimensions, with the
/// per-axis constants of the trilinear inside rule precomputed once per frame (the ray loop
/// reads seven trilinear values per visible sample).
#[derive(Clone, Copy)]
pub struct Grid3<'a> {
    pub data: &'a [f32],
    pub dims: [u32; 3],
    /// n_a − ½ (upper bound of the inside rule), n_a − 1 (clamp), n_a − 2 (last base voxel).
    hi: [f32; 3],
    top: [f32; 3],
    last_base: [u32; 3],
    /// Strides of y and z in `data`.
    sy: usize,
    sz: usize,
    /// Every axis has ≥ 2 voxels and `data` holds them all: the unchecked fast path applies.
    fast: bool,
}

impl<'a> Grid3<'a> {
    pub fn new(data: &'a [f32], dims: [u32; 3]) -> Self {
        let nf = dims.map(|n| n as f32);
        let (nx, ny, nz) = (dims[0] as usize, dims[1] as usize, dims[2] as usize);
        let len = nx.checked_mul(ny).and_then(|v| v.checked_mul(nz));
        Grid3 {
            data,
            dims,
            hi: nf.map(|n| n - 0.5),
            top: nf.map(|n| n - 1.0),
            last_base: dims.map(|n| n.saturating_sub(2)),
            sy: nx,
            sz: nx.saturating_mul(ny),
            fast: dims.iter().all(|&n| n >= 2) && len.is_some_and(|l| l <= data.len()),
        }
    }
}

impl Grid3<'_> {
    /// Trilinear value at continuous index `c`: inside when −½ ≤ c_k < n_k − ½ on every axis
    /// (then clamped to [0, n_k − 1]), else `None`. Same arithmetic order as
    /// `Volume::sample_index`, in `f32`.
    #[inline(always)]
    pub fn trilinear(&self, c: Vec3) -> Option<f32> {
        if self.fast {
            self.trilinear_fast(c)
        } else {
            self.trilinear_general(c)
        }
    }

    /// The same values as [`Self::trilinear_general`] for grids with ≥ 2 voxels per axis,
    /// without bounds checks: the hot path of the ray loop.
    #[inline(always)]
    fn trilinear_fast(&self, c: Vec3) -> Option<f32> {
        self.locate(c).map(|cell| self.interpolate(&cell))
    }

    /// The base voxel and fractions of a trilinear read at `c` (the inside rule, the clamp to
    /// [0, n_a − 1] and base ≤ n_a − 2), or `None` outside. Only for grids with ≥ 2 voxels per
    /// axis ([`Self::is_fast`]).
    #[inline(always)]
    pub fn locate(&self, c: Vec3) -> Option<Cell> {
        debug_assert!(self.fast);
        let (x, y, z) = (c.x, c.y, c.z);
        if !(x >= -0.5 && x < self.hi[0] && y >= -0.5 && y < self.hi[1] && z >= -0.5 && z < self.hi[2]) {
            return None;
        }
        let x = x.clamp(0.0, self.top[0]);
        let y = y.clamp(0.0, self.top[1]);
        let z = z.clamp(0.0, self.top[2]);
        let b = [
            trunc(x).min(self.last_base[0]),
            trunc(y).min(self.last_base[1]),
            trunc(z).min(self.last_base[2]),
        ];
        Some(Cell {
            f: [x - b[0] as f32, y - b[1] as f32, z - b[2] as f32],
            b,
        })
    }

    /// The trilinear value of a located read (`Volume::sample_index`'s order, in `f32`).
    #[inline(always)]
    pub fn interpolate(&self, cell: &Cell) -> f32 {
        let [bx, by, bz] = cell.b;
        let [fx, fy, fz] = cell.f;
        let (sy, sz) = (self.sy, self.sz);
        let o = bx as usize + sy * by as usize + sz * bz as usize;
        // SAFETY: `fast` means n_a ≥ 2 and nx·ny·nz ≤ data.len(), and `locate` keeps
        // b_a ≤ n_a − 2, so the largest index read, o + 1 + sy + sz, is at most
        // (nx − 1) + nx·(ny − 1) + nx·ny·(nz − 1) = nx·ny·nz − 1.
        let v = |i: usize| unsafe { *self.data.get_unchecked(i) };
        let c00 = v(o) * (1.0 - fx) + v(o + 1) * fx;
        let c10 = v(o + sy) * (1.0 - fx) + v(o + sy + 1) * fx;
        let c01 = v(o + sz) * (1.0 - fx) + v(o + sz + 1) * fx;
        let c11 = v(o + sz + sy) * (1.0 - fx) + v(o + sz + sy + 1) * fx;
        let c0 = c00 * (1.0 - fy) + c10 * fy;
        let c1 = c01 * (1.0 - fy) + c11 * fy;
        c0 * (1.0 - fz) + c1 * fz
    }

    /// [`Self::locate`]'s constants per axis: n_a − ½ (the inside rule's upper bound), n_a − 1
    /// (the clamp) and n_a − 2 (the last base voxel).
    pub fn locate_bounds(&self) -> ([f32; 3], [f32; 3], [u32; 3]) {
        (self.hi, self.top, self.last_base)
    }

    /// Whether every axis has ≥ 2 voxels and the data holds them all ([`Self::locate`] applies).
    pub fn is_fast(&self) -> bool {
        self.fast
    }

    /// The trilinear read's base voxel, fractions and steps (0 on an axis of one voxel, which
    /// does not interpolate) on any grid, or `None` outside the sampling domain.
    fn general_setup(&self, c: Vec3) -> Option<([u32; 3], [f32; 3], [u32; 3])> {
        let mut base = [0u32; 3];
        let mut frac = [0.0f32; 3];
        let mut step = [0u32; 3];
        for a in 0..3 {
            let n = self.dims[a];
            let nf = n as f32;
            let x = c[a];
            if !(x >= -0.5 && x < nf - 0.5) {
                return None;
            }
            let x = x.clamp(0.0, nf - 1.0);
            let b = (x as u32).min(n.saturating_sub(2));
            base[a] = b;
            frac[a] = if n == 1 { 0.0 } else { x - b as f32 };
            step[a] = u32::from(n > 1);
        }
        Some((base, frac, step))
    }

    /// Any grid, including axes of one voxel (then that axis does not interpolate).
    fn trilinear_general(&self, c: Vec3) -> Option<f32> {
        let (base, frac, step) = self.general_setup(c)?;
        let (nx, ny) = (self.dims[0] as usize, self.dims[1] as usize);
        let (i0, j0, k0) = (base[0] as usize, base[1] as usize, base[2] as usize);
        let (di, dj, dk) = (step[0] as usize, step[1] as usize * nx, step[2] as usize * nx * ny);
        let o = i0 + nx * (j0 + ny * k0);
        let d = self.data;
        let (fx, fy, fz) = (frac[0], frac[1], frac[2]);
        let c00 = d[o] * (1.0 - fx) + d[o + di] * fx;
        let c10 = d[o + dj] * (1.0 - fx) + d[o + dj + di] * fx;
        let c01 = d[o + dk] * (1.0 - fx) + d[o + dk + di] * fx;
        let c11 = d[o + dk + dj] * (1.0 - fx) + d[o + dk + dj + di] * fx;
        let c0 = c00 * (1.0 - fy) + c10 * fy;
        let c1 = c01 * (1.0 - fy) + c11 * fy;
        Some(c0 * (1.0 - fz) + c1 * fz)
    }

    /// The central differences (Δx, Δy, Δz) of the eight voxels a trilinear read at `c` uses,
    /// Δa = I(i + e_a) − I(i − e_a), blended in [`Self::trilinear`]'s order; neighbours outside
    /// the grid read air (`Edge::Air`, the CT: its box's faces are surfaces) or the nearest
    /// voxel (`Edge::Clamp`, a deformed region J, whose box is not a surface). `None` outside
    /// the sampling domain. Computed from the voxels on the fly: the CT's hot path reads the same
    /// numbers from its [`GradientVolume`].
    pub fn differences(&self, c: Vec3, edge: Edge) -> Option<Vec3> {
        let (base, frac, step) = self.general_setup(c)?;
        let dims = self.dims.map(|n| n as i64);
        let value = |p: [i64; 3]| -> f32 {
            let mut q = p;
            for a in 0..3 {
                if q[a] < 0 || q[a] >= dims[a] {
                    match edge {
                        Edge::Air => return AIR_HU,
                        Edge::Clamp => q[a] = q[a].clamp(0, dims[a] - 1),
                    }
                }
            }
            self.data[(q[0] + dims[0] * (q[1] + dims[1] * q[2])) as usize]
        };
        let diff = |i: u32, j: u32, k: u32| -> Vec3 {
            let p = [i as i64, j as i64, k as i64];
            let d = |a: usize| {
                let (mut hi, mut lo) = (p, p);
                hi[a] += 1;
                lo[a] -= 1;
                value(hi) - value(lo)
            };
            Vec3::new(d(0), d(1), d(2))
        };
        let [i0, j0, k0] = base;
        let [i1, j1, k1] = [i0 + step[0], j0 + step[1], k0 + step[2]];
        let [fx, fy, fz] = frac;
        let (gx, gy, gz) = (1.0 - fx, 1.0 - fy, 1.0 - fz);
        let c00 = diff(i0, j0, k0) * gx + diff(i1, j0, k0) * fx;
        let c10 = diff(i0, j1, k0) * gx + diff(i1, j1, k0) * fx;
        let c01 = diff(i0, j0, k1) * gx + diff(i1, j0, k1) * fx;
        let c11 = diff(i0, j1, k1) * gx + diff(i1, j1, k1) * fx;
        let c0 = c00 * gy + c10 * fy;
        let c1 = c01 * gy + c11 * fy;
        Some(c0 * gz + c1 * fz)
    }
}

/// What a central difference reads beyond a grid's last voxel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Edge {
    /// Air (−1000 HU): the CT, outside which the patient ends.
    Air,
    /// The nearest voxel: a deformed region J, which continues into the CT around it.
    Clamp,
}

/// ⌊x⌋ of an `x` already known to lie in [0, 2³¹): one conversion instruction instead of the
/// saturating `as` cast's range checks (the ray loop converts ~13 coordinates per sample).
#[inline(always)]
fn trunc(x: f32) -> u32 {
    debug_assert!((0.0..2_147_483_648.0).contains(&x), "{x}");
    // SAFETY: callers pass finite x in [0, n_a − 1] (after the inside test and clamp) or
    // checked ≥ 0 and < n_a − 1, and grid sizes are < 2³¹ voxels per axis.
    unsafe { x.to_int_unchecked::<i32>() as u32 }
}

/// Linear index of the voxel nearest `c`, or `None` outside the voxels' boxes
/// (`Grid::nearest_voxel_of_index` in `f32`).
#[inline]
pub fn nearest_voxel(c: Vec3, dims: [u32; 3]) -> Option<usize> {
    let mut v = [0usize; 3];
    for a in 0..3 {
        let r = c[a] + 0.5;
        if !(r >= 0.0 && r < dims[a] as f32) {
            return None;
        }
        v[a] = r as usize;
    }
    Some(v[0] + dims[0] as usize * (v[1] + dims[1] as usize * v[2]))
}

/// ½ Σ_a Δ_a·r_a for index-space differences Δ and `half_rows` = ½ M⁻¹'s rows r_a: the world
/// gradient (∂s/∂c_a ≈ Δ_a/2, ∂c_a/∂x = r_a), summed in this order everywhere (the SIMD lanes of
/// `batch` too).
#[inline(always)]
pub fn world_gradient(half_rows: &[Vec3; 3], d: Vec3) -> Vec3 {
    half_rows[0] * d.x + half_rows[1] * d.y + half_rows[2] * d.z
}

/// Where one sample is read: the continuous index in the CT grid and, with a deformed region,
/// in J's grid. Both are stepped along the ray in index space (c = c_e + t·M⁻¹r), so a J on the
/// CT's own grid reads exactly the CT's values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct At {
    pub ct: Vec3,
    pub j: Vec3,
}

/// s(x), ∇s and l(x) for one frame.
#[derive(Clone, Copy)]
pub struct Sampler<'a> {
    pub ct: Grid3<'a>,
    pub ct_map: IndexMap,
    /// The CT's value and central differences per voxel: the hot path's one read per sample.
    pub grads: &'a GradientVolume,
    /// J of eq. 3.1.1 on its own grid, when the scene carries one.
    pub deformed: Option<(Grid3<'a>, IndexMap)>,
    pub labels: &'a [LabelId],
    /// ½ M⁻¹'s rows of the CT and of J: ∇s = Σ_a Δ_a·half_rows[a] (world, HU/mm) for the
    /// interpolated index-space differences Δ.
    half_rows_ct: [Vec3; 3],
    half_rows_j: [Vec3; 3],
    /// The CT and its records have ≥ 2 voxels per axis and the records are 16-bit: lattice
    /// samples read the CT from the records ([`Self::lattice_read`]). Decided once, not per sample.
    lattice_from_records: bool,
}

/// A lattice sample's value and, when it was blended from the CT's records, the record blend
/// itself (Δx, Δy, Δz, s): its gradient then needs no second read ([`Sampler::lattice_gradient`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatticeRead {
    pub value: f32,
    records: Option<Vec4>,
}

impl<'a> Sampler<'a> {
    /// `grads` must be the records of `ct` ([`GradientVolume::new`] of the same data).
    pub fn new(
        ct: Grid3<'a>,
        ct_map: IndexMap,
        grads: &'a GradientVolume,
        deformed: Option<(Grid3<'a>, IndexMap)>,
        labels: &'a [LabelId],
    ) -> Self {
        debug_assert_eq!(grads.dims(), ct.dims);
        let half = |m: &IndexMap| m.rows.map(|r| r * 0.5);
        Sampler {
            ct,
            ct_map,
            grads,
            half_rows_ct: half(&ct_map),
            half_rows_j: deformed.as_ref().map_or([Vec3::ZERO; 3], |(_, m)| half(m)),
            deformed,
            labels,
            lattice_from_records: ct.is_fast() && grads.is_fast() && grads.is_int16(),
        }
    }

    /// Index coordinates of a world point in both grids (used with the motion warp).
    #[inline]
    pub fn at_world(&self, x: Vec3) -> At {
        At {
            ct: self.ct_map.point(x),
            j: match &self.deformed {
                Some((_, m)) => m.point(x),
                None => Vec3::ZERO,
            },
        }
    }

    /// s(x): J inside Ω_J, else the CT, else air.
    #[inline(always)]
    pub fn s(&self, at: At) -> f32 {
        self.deformed_value(at)
            .unwrap_or_else(|| self.ct.trilinear(at.ct).unwrap_or(AIR_HU))
    }

    /// A lattice sample: s(x), with the CT read from its records where they are 16-bit
    /// (`GradientVolume::interpolate`'s fixed-point blend, as the batches read them), so every
    /// path of the ray caster composites the same values. The GPU's `sample` does the same.
    #[inline(always)]
    pub fn lattice_read(&self, at: At) -> LatticeRead {
        if let Some(value) = self.deformed_value(at) {
            return LatticeRead { value, records: None };
        }
        if self.lattice_from_records {
            // Outside the records' domain the CT reads air, without a second look through
            // `trilinear` (which would find the same: most of a naive frame's samples lie there).
            return match self.ct.locate(at.ct) {
                Some(cell) => {
                    let r = self.grads.interpolate(&cell);
                    LatticeRead {
                        value: r.w,
                        records: Some(r),
                    }
                }
                None => LatticeRead {
                    value: AIR_HU,
                    records: None,
                },
            };
        }
        LatticeRead {
            value: self.ct.trilinear(at.ct).unwrap_or(AIR_HU),
            records: None,
        }
    }

    /// ∇s of a lattice sample ([`Self::gradient`]): from the records `read` blended, when it
    /// did (then it lies outside Ω_J and inside the CT, where `gradient` reads those same
    /// records), else read anew.
    #[inline(always)]
    pub fn lattice_gradient(&self, at: At, read: &LatticeRead) -> Vec3 {
        match read.records {
            Some(r) => self.world_gradient_ct(r.truncate()),
            None => self.gradient(at),
        }
    }

    /// J's value inside Ω_J, when the scene carries J.
    #[inline(always)]
    fn deformed_value(&self, at: At) -> Option<f32> {
        self.deformed.as_ref().and_then(|(j, _)| j.trilinear(at.j))
    }

    /// ½ M⁻¹'s rows of the CT ([`Self::world_gradient_ct`]'s factors).
    pub fn half_rows_ct(&self) -> [Vec3; 3] {
        self.half_rows_ct
    }

    /// The world gradient of index-space differences Δ: ½ Σ_a Δ_a·r_a with r_a the rows of M⁻¹
    /// (∂s/∂c_a ≈ Δ_a/2, ∂c_a/∂x = r_a).
    #[inline(always)]
    pub fn world_gradient_ct(&self, d: Vec3) -> Vec3 {
        world_gradient(&self.half_rows_ct, d)
    }

    /// ∇s (HU/mm, docs/rendering.md "Gradient"): the trilinear blend of the central differences
    /// of the eight voxels s reads, in J inside Ω_J, else in the CT, else 0 (unshaded).
    #[inline]
    pub fn gradient(&self, at: At) -> Vec3 {
        if let Some((j, _)) = &self.deformed
            && let Some(d) = j.differences(at.j, Edge::Clamp)
        {
            return world_gradient(&self.half_rows_j, d);
        }
        let d = if self.ct.is_fast() && self.grads.is_fast() {
            match self.ct.locate(at.ct) {
                Some(cell) => self.grads.interpolate(&cell).truncate(),
                None => return Vec3::ZERO,
            }
        } else {
            match self.ct.differences(at.ct, Edge::Air) {
                Some(d) => d,
                None => return Vec3::ZERO,
            }
        };
        self.world_gradient_ct(d)
    }

    /// l(x): the label of the CT voxel nearest the sample, 0 outside.
    #[inline]
    pub fn label(&self, at: At) -> LabelId {
        match nearest_voxel(at.ct, self.ct.dims) {
            Some(i) => self.labels[i],
            None => 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_physics::glam::DVec3;
    use stylet_physics::{Affine, Grid, Volume};

    #[test]
    fn trilinear_matches_the_physics_sampler() {
        let g = Grid::new(
            [5, 4, 3],
            Affine::from_spacing([1.0, 2.0, 3.0], DVec3::new(-2.0, 1.0, 0.5)),
        )
        .unwrap();
        let data: Vec<f32> = (0..g.len()).map(|i| ((i * 37) % 23) as f32 * 10.0 - 100.0).collect();
        let vol = Volume::new(g, data.clone()).unwrap();
        let grid = Grid3::new(&data, [5, 4, 3]);
        for i in 0..400 {
            let f = i as f64;
            let c = DVec3::new(
                (f * 0.37).sin() * 3.5 + 2.0,
                (f * 0.11).cos() * 3.0 + 1.5,
                (f * 0.23).sin() * 2.0 + 1.0,
            );
            let want = vol.sample_index(c, AIR_HU);
            let got = grid.trilinear(c.as_vec3()).unwrap_or(AIR_HU);
            assert!((want - got).abs() < 0.05, "{c:?}: {want} vs {got}");
        }
        assert_eq!(grid.trilinear(Vec3::new(-0.51, 0.0, 0.0)), None);
        assert_eq!(grid.trilinear(Vec3::new(4.5, 0.0, 0.0)), None);
        assert_eq!(grid.trilinear(Vec3::new(4.49, 3.0, 2.0)), Some(data[data.len() - 1]));
        assert_eq!(
            nearest_voxel(Vec3::new(4.49, 3.0, 2.0), [5, 4, 3]),
            Some(data.len() - 1)
        );
        assert_eq!(nearest_voxel(Vec3::new(4.5, 3.0, 2.0), [5, 4, 3]), None);
    }
}
