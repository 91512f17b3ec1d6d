//! The sampling function s(x) (docs/rendering.md "Sampling"; thesis eq. 3.1.1) in `f32`:
//! trilinear CT by eight loads with `stylet_physics::Volume::sample_index`'s inside rule, the
//! deformed sub-image J inside its grid Ω_J, labels by nearest neighbour, and the gradient by
//! central differences for shading.

use stylet_physics::LabelId;
use stylet_physics::atlas::AIR_HU;
use stylet_physics::glam::Vec3;

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

    /// Whether every axis has ≥ 2 voxels and the data holds them all ([`Self::locate`] applies).
    pub fn is_fast(&self) -> bool {
        self.fast
    }

    /// ∇s of [`Sampler::gradient`] when the three offsets lie along the index axes (`d`: the
    /// signed index offset of each, |d_a| ≤ ½) and all seven positions are interior
    /// (0 ≤ c_a ± d_a < n_a − 1, so the clamp and the last-base `min` are no-ops): the six
    /// trilinear reads then share their set-up and most of their x-interpolated rows. Every
    /// value is the same formula on the same voxels in the same order as six
    /// [`Self::trilinear`] calls, so the result is bit-identical. `None`: use those calls.
    #[inline(always)]
    fn gradient_aligned(&self, c: Vec3, d: [f32; 3], inv_2h: f32) -> Option<Vec3> {
        if !self.fast {
            return None;
        }
        let cc = [c.x, c.y, c.z];
        // The same sums as `at.ct ± grad_ct[a]` (the other components add ±0).
        let p = [cc[0] + d[0], cc[1] + d[1], cc[2] + d[2]];
        let m = [cc[0] - d[0], cc[1] - d[1], cc[2] - d[2]];
        for a in 0..3 {
            if !(p[a].min(m[a]) >= 0.0 && p[a].max(m[a]) < self.top[a]) {
                return None;
            }
        }
        // Interior and ≥ 0: truncation is the floor, and ≤ n_a − 2.
        let split = |x: f32| {
            let b = trunc(x);
            (b, x - b as f32)
        };
        let ((bx, fx), (by, fy), (bz, fz)) = (split(cc[0]), split(cc[1]), split(cc[2]));
        // Window of rows j ∈ y0 … y0 + 2, k ∈ z0 … z0 + 2 (|d| ≤ ½: bases differ by ≤ 1).
        let y0 = trunc(p[1].min(m[1]));
        let z0 = trunc(p[2].min(m[2]));
        let (ny1, nz1) = (self.dims[1] - 1, self.dims[2] - 1);
        // `row_x`'s bounds: i ≤ n_x − 2 (interior), j ≤ n_y − 1, k ≤ n_z − 1 (clamped below, and
        // by + 1, bz + 1 ≤ n − 1 for the interior centre).
        let row = |i: u32, f: f32, j: u32, k: u32| self.row_x(i, f, j, k);
        // Rows at the centre's x (bx, fx). Rows past the grid (clamped index) are never used:
        // every sample's rows lie in [base, base + 1] ⊂ window, and base + 1 ≤ n − 1.
        let mut r = [[0.0f32; 3]; 3];
        for (kk, rk) in r.iter_mut().enumerate() {
            let k = (z0 + kk as u32).min(nz1);
            for (jj, v) in rk.iter_mut().enumerate() {
                *v = row(bx, fx, (y0 + jj as u32).min(ny1), k);
            }
        }
        // One trilinear value from the window: y base jb with fraction fy_, z base kb with fz_.
        let yz = |jb: u32, fy_: f32, kb: u32, fz_: f32| window_yz(&r, jb - y0, fy_, kb - z0, fz_);
        // ±x: own x base and fraction, the centre's rows j = by, by + 1 and k = bz, bz + 1.
        let along_x = |x: f32| {
            let (bxs, fxs) = split(x);
            let c0 = row(bxs, fxs, by, bz) * (1.0 - fy) + row(bxs, fxs, by + 1, bz) * fy;
            let c1 = row(bxs, fxs, by, bz + 1) * (1.0 - fy) + row(bxs, fxs, by + 1, bz + 1) * fy;
            c0 * (1.0 - fz) + c1 * fz
        };
        let gx = (along_x(p[0]) - along_x(m[0])) * inv_2h;
        let ((pyb, pyf), (myb, myf)) = (split(p[1]), split(m[1]));
        let gy = (yz(pyb, pyf, bz, fz) - yz(myb, myf, bz, fz)) * inv_2h;
        let ((pzb, pzf), (mzb, mzf)) = (split(p[2]), split(m[2]));
        let gz = (yz(by, fy, pzb, pzf) - yz(by, fy, mzb, mzf)) * inv_2h;
        Some(Vec3::new(gx, gy, gz))
    }

    /// The x-interpolated row value v(i, j, k)·(1 − f) + v(i + 1, j, k)·f.
    ///
    /// Callers (`gradient_aligned`, with `fast`) keep i ≤ n_x − 2, j ≤ n_y − 1, k ≤ n_z − 1,
    /// so the largest index read is ≤ nx·ny·nz − 1 < data.len().
    #[inline(always)]
    fn row_x(&self, i: u32, f: f32, j: u32, k: u32) -> f32 {
        let o = i as usize + self.sy * j as usize + self.sz * k as usize;
        debug_assert!(self.fast && o + 1 < self.data.len());
        // SAFETY: see above.
        let (a, b) = unsafe { (*self.data.get_unchecked(o), *self.data.get_unchecked(o + 1)) };
        a * (1.0 - f) + b * f
    }

    /// Any grid, including axes of one voxel (then that axis does not interpolate).
    fn trilinear_general(&self, c: Vec3) -> Option<f32> {
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

/// Where a trilinear read lands: base voxel b (each ≤ n_a − 2) and fractions f ∈ [0, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    pub b: [u32; 3],
    pub f: [f32; 3],
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

/// Where one sample is read: the continuous index in the CT grid and, with a deformed region,
/// in J's grid. Both are stepped along the ray in index space (c = c_e + t·M⁻¹r), so a J on the
/// CT's own grid reads exactly the CT's values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct At {
    pub ct: Vec3,
    pub j: Vec3,
}

/// s(x) and l(x) for one frame.
#[derive(Clone, Copy)]
pub struct Sampler<'a> {
    pub ct: Grid3<'a>,
    pub ct_map: IndexMap,
    /// J of eq. 3.1.1 on its own grid, when the scene carries one.
    pub deformed: Option<(Grid3<'a>, IndexMap)>,
    pub labels: &'a [LabelId],
    /// Index-space offsets of ±h along the world axes (h = ½·min CT spacing), CT and J grids.
    pub grad_ct: [Vec3; 3],
    pub grad_j: [Vec3; 3],
    /// 1 / (2h), per mm.
    pub inv_2h: f32,
    /// The CT offsets' index components when each lies along its own index axis with
    /// |d| ≤ ½ (axis-aligned affines): the shared-read gradient applies.
    grad_axis: Option<[f32; 3]>,
}

impl<'a> Sampler<'a> {
    pub fn new(
        ct: Grid3<'a>,
        ct_map: IndexMap,
        deformed: Option<(Grid3<'a>, IndexMap)>,
        labels: &'a [LabelId],
        h_mm: f32,
    ) -> Self {
        let axis = |m: &IndexMap, a: usize| {
            let mut e = Vec3::ZERO;
            e[a] = h_mm;
            m.vector(e)
        };
        let grad_ct = [axis(&ct_map, 0), axis(&ct_map, 1), axis(&ct_map, 2)];
        let grad_j = match &deformed {
            Some((_, m)) => [axis(m, 0), axis(m, 1), axis(m, 2)],
            None => [Vec3::ZERO; 3],
        };
        let aligned = (0..3).all(|a| (0..3).all(|b| a == b || grad_ct[a][b] == 0.0) && grad_ct[a][a].abs() <= 0.5);
        Sampler {
            ct,
            ct_map,
            deformed,
            labels,
            grad_ct,
            grad_j,
            inv_2h: 1.0 / (2.0 * h_mm),
            grad_axis: aligned.then(|| [grad_ct[0].x, grad_ct[1].y, grad_ct[2].z]),
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
        if let Some((j, _)) = &self.deformed
            && let Some(v) = j.trilinear(at.j)
        {
            return v;
        }
        self.ct.trilinear(at.ct).unwrap_or(AIR_HU)
    }

    /// ∇s by central differences at ±h along the world axes (HU/mm).
    #[inline]
    pub fn gradient(&self, at: At) -> Vec3 {
        let mut g = Vec3::ZERO;
        if self.deformed.is_none() {
            // The same values as below without J's bookkeeping (the common case).
            if let Some(d) = self.grad_axis
                && let Some(g) = self.ct.gradient_aligned(at.ct, d, self.inv_2h)
            {
                return g;
            }
            for a in 0..3 {
                let plus = self.ct.trilinear(at.ct + self.grad_ct[a]).unwrap_or(AIR_HU);
                let minus = self.ct.trilinear(at.ct - self.grad_ct[a]).unwrap_or(AIR_HU);
                g[a] = (plus - minus) * self.inv_2h;
            }
            return g;
        }
        for a in 0..3 {
            let plus = At {
                ct: at.ct + self.grad_ct[a],
                j: at.j + self.grad_j[a],
            };
            let minus = At {
                ct: at.ct - self.grad_ct[a],
                j: at.j - self.grad_j[a],
            };
            g[a] = (self.s(plus) - self.s(minus)) * self.inv_2h;
        }
        g
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

/// One trilinear value from a 3 × 3 window of x-interpolated rows `r[k][j]`: y row `j` (0 or 1)
/// with fraction `fy`, z row `k` (0 or 1) with fraction `fz`; `Grid3::trilinear`'s order.
#[inline(always)]
fn window_yz(r: &[[f32; 3]; 3], j: u32, fy: f32, k: u32, fz: f32) -> f32 {
    let (j, k) = (j as usize, k as usize);
    let c0 = r[k][j] * (1.0 - fy) + r[k][j + 1] * fy;
    let c1 = r[k + 1][j] * (1.0 - fy) + r[k + 1][j + 1] * fy;
    c0 * (1.0 - fz) + c1 * fz
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
