//! Gradients of a volume's trilinear field by central differences, in one gather (thesis §3.6:
//! the directions v_s = −∇D_skin/‖·‖ and v_b = −∇D_bone/‖·‖ of eqs. 3.6.1 and 3.6.4).
//!
//! Along each index axis a the field is differenced at c ± δ_a e_a, δ_a being half the smallest
//! voxel size expressed in voxels of axis a (so every step is the same length in mm, at most half
//! a voxel), and the index gradient is turned into mm through the inverse affine:
//! ∇f = Σ_a (f(c + δ_a e_a) − f(c − δ_a e_a)) / (2 δ_a) · ∇index_a.
//!
//! Away from the grid's border the six samples lie in the 4 × 4 × 4 voxels around c, read once:
//! along axis a the trilinear field at fixed other coordinates is the bilinear blend (in those
//! coordinates) of four piecewise-linear lines along a, so each sample costs four line lerps. Near
//! the border the samples go through [`Volume::sample_index`] with its half-voxel margin and
//! `outside` value.

use glam::DVec3;

use crate::Volume;
use crate::lanes::{F4, LANES, Lane, V4, has_avx2};

/// Volumes on one grid prepared for values and gradients at shared points (the contact tools
/// read D_skin and D_bone at every node): the per-axis steps in voxels.
#[derive(Debug, Clone, Copy)]
pub struct GradientSampler<'a, const N: usize> {
    volumes: [&'a Volume<f32>; N],
    /// δ_a in voxels of axis a (≤ ½).
    delta: [f64; 3],
    /// 1/(2δ_a), the difference stencils' scale.
    inv_two_delta: [f64; 3],
}

/// A value and its gradient (value units per mm along the world axes).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ValueGradient {
    /// As [`Volume::sample_index`] gives it (the same bits).
    pub value: f64,
    pub gradient: DVec3,
}

/// The central difference (L(f + δ) − L(f − δ)) / 2δ of the line L through four samples
/// p₀ … p₃ at −1, 0, 1, 2 (relative to floor(c); f ∈ [0, 1), δ ≤ ½) as weights on the samples.
/// With the slopes s_i = p_{i+1} − p_i: L(f + δ) − L(f − δ) = a₀ s₀ + a₁ s₁ + a₂ s₂, where
/// a₀ = max(δ − f, 0) is the part of the step left of sample 0, a₂ = max(f + δ − 1, 0) the part
/// right of sample 1 and a₁ the rest.
#[inline]
/// `k` is 1/(2δ), worked out once per sampler.
fn difference_stencil(f: f64, delta: f64, k: f64) -> [f64; 4] {
    let (plus, minus) = (f + delta, f - delta);
    let a0 = -minus.min(0.0);
    let a1 = plus.min(1.0) - minus.max(0.0);
    let a2 = (plus - 1.0).max(0.0);
    [-a0 * k, (a0 - a1) * k, (a1 - a2) * k, a2 * k]
}

#[inline]
fn dot4(w: &[f64; 4], p: [f64; 4]) -> f64 {
    w[0] * p[0] + w[1] * p[1] + w[2] * p[2] + w[3] * p[3]
}

impl<'a> GradientSampler<'a, 1> {
    pub fn new(volume: &'a Volume<f32>) -> Self {
        Self::on_one_grid([volume]).expect("one volume is on its own grid")
    }

    /// The gradient at the continuous index `c`.
    #[inline]
    pub fn gradient_at_index(&self, c: DVec3, outside: f32) -> DVec3 {
        self.at_index(c, outside)[0].gradient
    }
}

impl<'a, const N: usize> GradientSampler<'a, N> {
    /// `None` unless all volumes share one grid.
    pub fn on_one_grid(volumes: [&'a Volume<f32>; N]) -> Option<Self> {
        let grid = volumes.first()?.grid();
        if volumes.iter().any(|v| v.grid() != grid) {
            return None;
        }
        let s = grid.spacing_mm();
        let h = 0.5 * s[0].min(s[1]).min(s[2]);
        let delta = [h / s[0], h / s[1], h / s[2]];
        Some(GradientSampler {
            volumes,
            delta,
            inv_two_delta: delta.map(|d| 1.0 / (2.0 * d)),
        })
    }

    /// Each volume's value and gradient at the continuous index `c` (`outside` beyond the grid).
    #[inline]
    pub fn at_index(&self, c: DVec3, outside: f32) -> [ValueGradient; N] {
        let grid = self.volumes[0].grid();
        let mut out = if self.is_interior(c) {
            self.interior(c)
        } else {
            self.volumes.map(|v| self.border(v, c, outside))
        };
        for o in &mut out {
            o.gradient = grid.index_gradient_to_world(o.gradient);
        }
        out
    }

    /// Value and index gradient near the border: trilinear samples with the volume's margin.
    fn border(&self, v: &Volume<f32>, c: DVec3, outside: f32) -> ValueGradient {
        let mut g = DVec3::ZERO;
        for a in 0..3 {
            let mut e = DVec3::ZERO;
            e[a] = self.delta[a];
            let fp = v.sample_index(c + e, outside) as f64;
            let fm = v.sample_index(c - e, outside) as f64;
            g[a] = (fp - fm) / (2.0 * self.delta[a]);
        }
        ValueGradient {
            value: v.sample_index(c, outside) as f64,
            gradient: g,
        }
    }

    /// [`Self::at_index`] when the first volume's value passes `wanted`, else that value alone
    /// (`Err`), having read only it: the contact tools skip the nodes off the skin after one
    /// trilinear read and take the value of the nodes on it from the gather (the same bits as
    /// [`Volume::sample_index`]).
    #[inline(always)]
    pub fn at_index_if(&self, c: DVec3, outside: f32, wanted: impl Fn(f64) -> bool) -> Result<[ValueGradient; N], f64> {
        let grid = self.volumes[0].grid();
        let mut out = if self.is_interior(c) {
            let cell = self.cell(c);
            let (d0, rows0) = self.rows(self.volumes[0], &cell);
            let value = cell.value(&rows0);
            if !wanted(value) {
                return Err(value);
            }
            let mut out = [ValueGradient {
                value,
                gradient: cell.gradient(d0, &rows0),
            }; N];
            for (o, v) in out.iter_mut().zip(&self.volumes).skip(1) {
                *o = self.gather(v, &cell);
            }
            out
        } else {
            let value = self.volumes[0].sample_index(c, outside) as f64;
            if !wanted(value) {
                return Err(value);
            }
            self.volumes.map(|v| self.border(v, c, outside))
        };
        for o in &mut out {
            o.gradient = grid.index_gradient_to_world(o.gradient);
        }
        Ok(out)
    }

    /// Whether `c` is interior: the 4 × 4 × 4 voxels from floor(c) − 1 to floor(c) + 2 lie in
    /// the grid (the gathers read there; elsewhere [`Self::at_index`] takes trilinear samples).
    #[inline(always)]
    pub(crate) fn is_interior(&self, c: DVec3) -> bool {
        let [nx, ny, nz] = self.volumes[0].grid().dims();
        // Written out (no iterator): the contact tools test every node every tick. `&` keeps it
        // free of branches; NaN fails every comparison.
        (c.x >= 1.0)
            & (c.x < nx as f64 - 2.0)
            & (c.y >= 1.0)
            & (c.y < ny as f64 - 2.0)
            & (c.z >= 1.0)
            & (c.z < nz as f64 - 2.0)
    }

    /// The first volume's value at four interior indices (each [`Self::is_interior`]): the bits
    /// of [`Self::at_index_if`]'s first value (and of `sample_index`), from the 2 × 2 × 2 voxels
    /// around each, blended four lanes wide (AVX2 where the CPU has it).
    #[inline]
    pub(crate) fn values4(&self, cs: &[DVec3; LANES]) -> [f64; LANES] {
        debug_assert!(cs.iter().all(|&c| self.is_interior(c)));
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            // SAFETY: the CPU has AVX2 (checked above).
            return unsafe { self.values4_avx2(cs) };
        }
        self.values4_in::<F4>(cs)
    }

    /// [`Self::at_index`] at four interior indices at once (each [`Self::is_interior`]), with
    /// the same bits per lane: the voxels are read one by one; the blends, differences and the
    /// turn into world units run four lanes wide (AVX2 where the CPU has it).
    #[inline]
    pub(crate) fn at_interior4(&self, cs: &[DVec3; LANES]) -> [[ValueGradient; N]; LANES] {
        debug_assert!(cs.iter().all(|&c| self.is_interior(c)));
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            // SAFETY: the CPU has AVX2 (checked above).
            return unsafe { self.at_interior4_avx2(cs) };
        }
        self.at_interior4_in::<F4>(cs)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn values4_avx2(&self, cs: &[DVec3; LANES]) -> [f64; LANES] {
        self.values4_in::<crate::lanes::avx::Avx>(cs)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn at_interior4_avx2(&self, cs: &[DVec3; LANES]) -> [[ValueGradient; N]; LANES] {
        self.at_interior4_in::<crate::lanes::avx::Avx>(cs)
    }

    #[inline(always)]
    fn values4_in<L: Lane>(&self, cs: &[DVec3; LANES]) -> [f64; LANES] {
        let cells = [self.cell(cs[0]), self.cell(cs[1]), self.cell(cs[2]), self.cell(cs[3])];
        let lanes = Cells4::<L>::new(&cells);
        lanes.value_only(self.volumes[0], &cells).store()
    }

    #[inline(always)]
    fn at_interior4_in<L: Lane>(&self, cs: &[DVec3; LANES]) -> [[ValueGradient; N]; LANES] {
        let zero = ValueGradient {
            value: 0.0,
            gradient: DVec3::ZERO,
        };
        let mut out = [[zero; N]; LANES];
        for (n, (value, gradient)) in self.at_interior4_lanes::<L>(cs).into_iter().enumerate() {
            let values = value.store();
            let g = gradient.store();
            for (lane, o) in out.iter_mut().enumerate() {
                o[n] = ValueGradient {
                    value: values[lane],
                    gradient: g.get(lane),
                };
            }
        }
        out
    }

    /// [`Self::at_interior4`] as lanes: each volume's values and world gradients at the four
    /// interior indices, kept in registers for a caller compiled with the same lanes (the contact
    /// tools pass them straight to their force law).
    #[inline(always)]
    pub(crate) fn at_interior4_lanes<L: Lane>(&self, cs: &[DVec3; LANES]) -> [(L, V4<L>); N] {
        debug_assert!(cs.iter().all(|&c| self.is_interior(c)));
        let cells = [self.cell(cs[0]), self.cell(cs[1]), self.cell(cs[2]), self.cell(cs[3])];
        let lanes = Cells4::<L>::new(&cells);
        let rows = self.volumes[0].grid().index_gradient_rows();
        // A loop, not `map` with a closure (see `crate::lanes`).
        let zero = L::splat(0.0);
        let mut out = [(
            zero,
            V4 {
                x: zero,
                y: zero,
                z: zero,
            },
        ); N];
        for (o, v) in out.iter_mut().zip(&self.volumes) {
            let (value, gradient) = lanes.value_gradient(v, &cells);
            *o = (value, world_gradient(rows, gradient));
        }
        out
    }

    /// Value and index gradient from the 32 voxels the six samples and the value touch: the
    /// 2 × 2 rows of four along x through the cell, and the ends of the columns along y and z.
    /// Along each axis the difference is a four-tap stencil ([`difference_stencil`]) on the
    /// lines through the cell, blended bilinearly across them as the trilinear field is.
    fn interior(&self, c: DVec3) -> [ValueGradient; N] {
        let cell = self.cell(c);
        self.volumes.map(|v| self.gather(v, &cell))
    }

    /// What every volume's gather at an interior index `c` shares.
    #[inline(always)]
    fn cell(&self, c: DVec3) -> Cell {
        let [nx, ny, _] = self.volumes[0].grid().dims();
        // c ≥ 1 on every axis, so truncation is floor.
        let b = [c.x as usize, c.y as usize, c.z as usize];
        let f = [c.x - b[0] as f64, c.y - b[1] as f64, c.z - b[2] as f64];
        let w = |t: f64| [1.0 - t, t];
        Cell {
            // Offset of voxel floor(c) − 1 + (i, j, k).
            base: (b[0] - 1) + nx * ((b[1] - 1) + ny * (b[2] - 1)),
            sj: nx,
            sk: nx * ny,
            f,
            stencil: [
                difference_stencil(f[0], self.delta[0], self.inv_two_delta[0]),
                difference_stencil(f[1], self.delta[1], self.inv_two_delta[1]),
                difference_stencil(f[2], self.delta[2], self.inv_two_delta[2]),
            ],
            wx: w(f[0]),
            wy: w(f[1]),
            wz: w(f[2]),
        }
    }

    /// The voxels of `v` around the cell and its 2 × 2 rows of four along x
    /// (rows[k − 1][j − 1]: voxels i = 0 … 3 at j, k ∈ {1, 2}).
    #[inline(always)]
    fn rows<'v>(&self, v: &'v Volume<f32>, cell: &Cell) -> (&'v [f32], [[[f64; 4]; 2]; 2]) {
        let (sj, sk) = (cell.sj, cell.sk);
        let d = &v.data()[cell.base..=cell.base + 3 + 3 * sj + 3 * sk];
        let get = |i: usize, j: usize, k: usize| voxel(d, i + j * sj + k * sk);
        let row = |j, k| [get(0, j, k), get(1, j, k), get(2, j, k), get(3, j, k)];
        (d, [[row(1, 1), row(2, 1)], [row(1, 2), row(2, 2)]])
    }

    #[inline(always)]
    fn gather(&self, v: &Volume<f32>, cell: &Cell) -> ValueGradient {
        let (d, rows) = self.rows(v, cell);
        ValueGradient {
            value: cell.value(&rows),
            gradient: cell.gradient(d, &rows),
        }
    }
}

/// Voxel `o` of a gather's voxels `d` (the 4 × 4 × 4 block from the cell's base: `o` = i + j·sj +
/// k·sk with i, j, k ≤ 3), as f64, without a bounds check in the hot loop.
#[inline(always)]
fn voxel(d: &[f32], o: usize) -> f64 {
    debug_assert!(o < d.len());
    // SAFETY: `d` is the slice base ..= base + 3 + 3·sj + 3·sk (checked when it was cut), and
    // every caller's offset i + j·sj + k·sk has i, j, k ∈ 0 … 3, so o ≤ 3 + 3·sj + 3·sk < d.len().
    unsafe { *d.get_unchecked(o) as f64 }
}

/// The `K` voxels from offset `o` of a gather's voxels `d` (a run along x: `o` = i + j·sj + k·sk
/// with i + K ≤ 4 and j, k ≤ 3), without a bounds check in the hot loop.
#[inline(always)]
fn run<const K: usize>(d: &[f32], o: usize) -> &[f32; K] {
    debug_assert!(o + K <= d.len());
    // SAFETY: as in `voxel`: the run's last offset is at most 3 + 3·sj + 3·sk < d.len(), and
    // `[f32; K]` has the alignment of `f32`.
    unsafe { &*d.as_ptr().add(o).cast::<[f32; K]>() }
}

/// The shared part of an interior gather: the offset of its first voxel, the strides, the
/// fractions, the difference stencils and the blend weights.
struct Cell {
    base: usize,
    sj: usize,
    sk: usize,
    f: [f64; 3],
    stencil: [[f64; 4]; 3],
    wx: [f64; 2],
    wy: [f64; 2],
    wz: [f64; 2],
}

impl Cell {
    /// The value, blended along x, then y, then z as `trilinear` does (the same bits).
    #[inline(always)]
    fn value(&self, rows: &[[[f64; 4]; 2]; 2]) -> f64 {
        let f = self.f;
        let fx = f[0];
        let c00 = rows[0][0][1] * (1.0 - fx) + rows[0][0][2] * fx;
        let c10 = rows[0][1][1] * (1.0 - fx) + rows[0][1][2] * fx;
        let c01 = rows[1][0][1] * (1.0 - fx) + rows[1][0][2] * fx;
        let c11 = rows[1][1][1] * (1.0 - fx) + rows[1][1][2] * fx;
        let c0 = c00 * (1.0 - f[1]) + c10 * f[1];
        let c1 = c01 * (1.0 - f[1]) + c11 * f[1];
        (c0 * (1.0 - f[2]) + c1 * f[2]) as f32 as f64
    }

    /// The index gradient from the rows and the ends of the columns along y and z (read from
    /// `d`, the voxels from the cell's base).
    #[inline(always)]
    fn gradient(&self, d: &[f32], rows: &[[[f64; 4]; 2]; 2]) -> DVec3 {
        let (sj, sk) = (self.sj, self.sk);
        let get = |i: usize, j: usize, k: usize| voxel(d, i + j * sj + k * sk);
        let (stencil, wx, wy, wz) = (&self.stencil, self.wx, self.wy, self.wz);
        let mut g = DVec3::ZERO;
        for kk in 0..2 {
            for jj in 0..2 {
                g.x += wy[jj] * wz[kk] * dot4(&stencil[0], rows[kk][jj]);
            }
            for ii in 0..2 {
                let (i, k) = (ii + 1, kk + 1);
                let col = [get(i, 0, k), rows[kk][0][i], rows[kk][1][i], get(i, 3, k)];
                g.y += wx[ii] * wz[kk] * dot4(&stencil[1], col);
            }
        }
        for jj in 0..2 {
            for ii in 0..2 {
                let (i, j) = (ii + 1, jj + 1);
                let pillar = [get(i, j, 0), rows[0][jj][i], rows[1][jj][i], get(i, j, 3)];
                g.z += wx[ii] * wy[jj] * dot4(&stencil[2], pillar);
            }
        }
        g
    }
}

/// Four interior cells' fractions, blend weights and difference stencils as lanes.
struct Cells4<L> {
    f: [L; 3],
    /// (1 − f_a, f_a) per axis.
    w: [[L; 2]; 3],
    stencil: [[L; 4]; 3],
    sj: usize,
    sk: usize,
}

impl<L: Lane> Cells4<L> {
    #[inline(always)]
    fn new(cells: &[Cell; LANES]) -> Self {
        let mut f = [[0.0; LANES]; 3];
        let mut w = [[[0.0; LANES]; 2]; 3];
        let mut stencil = [[[0.0; LANES]; 4]; 3];
        for (lane, c) in cells.iter().enumerate() {
            for a in 0..3 {
                f[a][lane] = c.f[a];
                for t in 0..4 {
                    stencil[a][t][lane] = c.stencil[a][t];
                }
            }
            for e in 0..2 {
                w[0][e][lane] = c.wx[e];
                w[1][e][lane] = c.wy[e];
                w[2][e][lane] = c.wz[e];
            }
        }
        let zero = L::splat(0.0);
        let mut lanes = Cells4 {
            f: [zero; 3],
            w: [[zero; 2]; 3],
            stencil: [[zero; 4]; 3],
            sj: cells[0].sj,
            sk: cells[0].sk,
        };
        for a in 0..3 {
            lanes.f[a] = L::load(f[a]);
            for e in 0..2 {
                lanes.w[a][e] = L::load(w[a][e]);
            }
            for t in 0..4 {
                lanes.stencil[a][t] = L::load(stencil[a][t]);
            }
        }
        lanes
    }

    /// Each lane's 4 × 4 × 4 block of `v`, bounds-checked once (as `GradientSampler::rows`).
    #[inline(always)]
    fn blocks<'v>(&self, v: &'v Volume<f32>, cells: &[Cell; LANES]) -> [&'v [f32]; LANES] {
        let span = 3 + 3 * self.sj + 3 * self.sk;
        let d = v.data();
        [
            &d[cells[0].base..=cells[0].base + span],
            &d[cells[1].base..=cells[1].base + span],
            &d[cells[2].base..=cells[2].base + span],
            &d[cells[3].base..=cells[3].base + span],
        ]
    }

    /// Every lane's run of `K` voxels from (i, j, k) of its block.
    #[inline(always)]
    fn runs<'v, const K: usize>(&self, d: &[&'v [f32]; LANES], i: usize, j: usize, k: usize) -> [&'v [f32; K]; LANES] {
        let o = i + j * self.sj + k * self.sk;
        [run(d[0], o), run(d[1], o), run(d[2], o), run(d[3], o)]
    }

    /// [`Self::value_gradient`]'s value alone, reading only the 2 × 2 × 2 voxels it blends.
    #[inline(always)]
    fn value_only(&self, v: &Volume<f32>, cells: &[Cell; LANES]) -> L {
        let d = self.blocks(v, cells);
        let mut mid = [[[L::splat(0.0); 2]; 2]; 2];
        for (kk, plane) in mid.iter_mut().enumerate() {
            for (jj, m) in plane.iter_mut().enumerate() {
                *m = L::runs2(self.runs(&d, 1, jj + 1, kk + 1));
            }
        }
        self.value(&mid)
    }

    /// `Cell::value` lane by lane from the voxels i = 1, 2 of the rows (mid[k − 1][j − 1][i − 1]),
    /// rounded through f32 as `sample_index`.
    #[inline(always)]
    fn value(&self, mid: &[[[L; 2]; 2]; 2]) -> L {
        let one = L::splat(1.0);
        let [fx, fy, fz] = self.f;
        let c00 = mid[0][0][0] * (one - fx) + mid[0][0][1] * fx;
        let c10 = mid[0][1][0] * (one - fx) + mid[0][1][1] * fx;
        let c01 = mid[1][0][0] * (one - fx) + mid[1][0][1] * fx;
        let c11 = mid[1][1][0] * (one - fx) + mid[1][1][1] * fx;
        let c0 = c00 * (one - fy) + c10 * fy;
        let c1 = c01 * (one - fy) + c11 * fy;
        (c0 * (one - fz) + c1 * fz).round_f32()
    }

    /// `Cell::value` and `Cell::gradient` lane by lane: the same products, summed in the same
    /// order. One plane k of rows at a time (the rows along x give g_x, with the ends of the
    /// columns along y they give g_y), keeping only the rows' middle voxels for the value and
    /// the pillars along z: fewer values live at once than all 32 voxels.
    #[inline(always)]
    fn value_gradient(&self, v: &Volume<f32>, cells: &[Cell; LANES]) -> (L, V4<L>) {
        let d = self.blocks(v, cells);
        let [wx, wy, wz] = self.w;
        let [sx, sy, sz] = &self.stencil;
        let zero = L::splat(0.0);
        let mut g = V4 {
            x: zero,
            y: zero,
            z: zero,
        };
        let mut mid = [[[zero; 2]; 2]; 2];
        for kk in 0..2 {
            let k = kk + 1;
            let rows = [L::runs4(self.runs(&d, 0, 1, k)), L::runs4(self.runs(&d, 0, 2, k))];
            for jj in 0..2 {
                g.x = g.x + wy[jj] * wz[kk] * dot4_lanes(sx, rows[jj]);
            }
            // The ends of the columns along y (j = 0 and 3) at i = 1, 2.
            let (low, high) = (L::runs2(self.runs(&d, 1, 0, k)), L::runs2(self.runs(&d, 1, 3, k)));
            for ii in 0..2 {
                let i = ii + 1;
                let col = [low[ii], rows[0][i], rows[1][i], high[ii]];
                g.y = g.y + wx[ii] * wz[kk] * dot4_lanes(sy, col);
            }
            mid[kk] = [[rows[0][1], rows[0][2]], [rows[1][1], rows[1][2]]];
        }
        for jj in 0..2 {
            let j = jj + 1;
            // The ends of the pillars along z (k = 0 and 3) at i = 1, 2.
            let (low, high) = (L::runs2(self.runs(&d, 1, j, 0)), L::runs2(self.runs(&d, 1, j, 3)));
            for ii in 0..2 {
                let pillar = [low[ii], mid[0][jj][ii], mid[1][jj][ii], high[ii]];
                g.z = g.z + wx[ii] * wy[jj] * dot4_lanes(sz, pillar);
            }
        }
        (self.value(&mid), g)
    }
}

/// [`dot4`] lane by lane.
#[inline(always)]
fn dot4_lanes<L: Lane>(w: &[L; 4], p: [L; 4]) -> L {
    w[0] * p[0] + w[1] * p[1] + w[2] * p[2] + w[3] * p[3]
}

/// `Grid::index_gradient_to_world` lane by lane: r₀·g_x + r₁·g_y + r₂·g_z per component.
#[inline(always)]
fn world_gradient<L: Lane>(r: [DVec3; 3], g: V4<L>) -> V4<L> {
    V4 {
        x: L::splat(r[0].x) * g.x + L::splat(r[1].x) * g.y + L::splat(r[2].x) * g.z,
        y: L::splat(r[0].y) * g.x + L::splat(r[1].y) * g.y + L::splat(r[2].y) * g.z,
        z: L::splat(r[0].z) * g.x + L::splat(r[1].z) * g.y + L::splat(r[2].z) * g.z,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Affine, Grid};

    /// A smooth, curved field on an anisotropic grid.
    fn field() -> Volume<f32> {
        let g = Grid::new(
            [12, 10, 9],
            Affine::from_spacing([1.5, 2.0, 3.0], DVec3::new(-5.0, 2.0, 1.0)),
        )
        .unwrap();
        let mut data = Vec::new();
        for k in 0..9 {
            for j in 0..10 {
                for i in 0..12 {
                    let p = g.voxel_to_world(i, j, k);
                    data.push((0.3 * p.x + 0.02 * p.y * p.y - 0.5 * libm::sin(0.2 * p.z) + 0.01 * p.x * p.z) as f32);
                }
            }
        }
        Volume::new(g, data).unwrap()
    }

    /// The interior gather gives what six trilinear samples give, everywhere it applies.
    #[test]
    fn the_interior_gather_equals_six_trilinear_samples() {
        let v = field();
        let s = GradientSampler::new(&v);
        let mut checked = 0;
        for n in 0..2000 {
            let t = n as f64;
            // Interior points of the 12 × 10 × 9 grid: 1 ≤ c < n − 2.
            let c = DVec3::new(
                1.0 + (t * 0.7371).fract() * 8.999,
                1.0 + (t * 0.3119 + 0.1).fract() * 6.999,
                1.0 + (t * 0.5813 + 0.2).fract() * 5.999,
            );
            let [fast] = s.interior(c);
            assert_eq!(
                fast.value.to_bits(),
                (v.sample_index(c, -1.0) as f64).to_bits(),
                "value at {c}"
            );
            let fast = fast.gradient;
            let mut slow = DVec3::ZERO;
            for a in 0..3 {
                let mut e = DVec3::ZERO;
                e[a] = s.delta[a];
                let fp = trilinear_f64(&v, c + e);
                let fm = trilinear_f64(&v, c - e);
                slow[a] = (fp - fm) / (2.0 * s.delta[a]);
            }
            // Each difference of a sum of lerps, regrouped: equal up to rounding.
            assert!(
                (fast - slow).length() < 1e-9 * (1.0 + slow.length()),
                "at {c}: {fast} vs {slow}"
            );
            checked += 1;
        }
        assert_eq!(checked, 2000);
    }

    /// `at_index_if` reads the first volume's value (the same bits as `sample_index`) and gives
    /// either it alone or exactly what `at_index` gives, inside and at the border.
    #[test]
    fn at_index_if_is_the_first_value_or_everything() {
        let v = field();
        let w = Volume::new(*v.grid(), v.data().iter().map(|x| 3.0 - 0.5 * x).collect()).unwrap();
        let s = GradientSampler::on_one_grid([&v, &w]).unwrap();
        let (mut inside, mut border) = (0, 0);
        for n in 0..3000 {
            let t = n as f64;
            // Over the whole sampling domain and a little beyond it.
            let c = DVec3::new(
                -1.0 + (t * 0.7371).fract() * 13.5,
                -1.0 + (t * 0.3119 + 0.1).fract() * 11.5,
                -1.0 + (t * 0.5813 + 0.2).fract() * 10.5,
            );
            let first = v.sample_index(c, -7.0) as f64;
            let all = s.at_index(c, -7.0);
            assert_eq!(all[0].value.to_bits(), first.to_bits(), "at {c}");
            assert_eq!(s.at_index_if(c, -7.0, |d| d == first), Ok(all), "at {c}");
            let skipped = s.at_index_if(c, -7.0, |_| false).unwrap_err();
            assert_eq!(skipped.to_bits(), first.to_bits(), "at {c}");
            if (0..3).all(|a| c[a] >= 1.0 && c[a] < v.grid().dims()[a] as f64 - 2.0) {
                inside += 1;
            } else {
                border += 1;
            }
        }
        assert!(inside > 300 && border > 300, "{inside} inside, {border} at the border");
    }

    /// The batched reads give, lane by lane, the bits of one read at a time (with and without
    /// AVX2): the first value as `at_index_if` and `sample_index` give it, everything as
    /// `at_index` gives it.
    #[test]
    fn four_interior_reads_at_once_give_the_bits_of_one_at_a_time() {
        let v = field();
        let w = Volume::new(*v.grid(), v.data().iter().map(|x| 3.0 - 0.5 * x * x).collect()).unwrap();
        let s = GradientSampler::on_one_grid([&v, &w]).unwrap();
        let dims = v.grid().dims();
        let bits = |g: &ValueGradient| (g.value.to_bits(), g.gradient.to_array().map(f64::to_bits));
        for n in 0..2000 {
            let t = n as f64;
            let cs: [DVec3; LANES] = std::array::from_fn(|lane| {
                let u = t * 4.0 + lane as f64;
                // Over the interior: 1 ≤ c_a < n_a − 2.
                DVec3::new(
                    1.0 + (u * 0.7371).fract() * (dims[0] as f64 - 3.0),
                    1.0 + (u * 0.3119 + 0.1).fract() * (dims[1] as f64 - 3.0),
                    1.0 + (u * 0.5813 + 0.2).fract() * (dims[2] as f64 - 3.0),
                )
            });
            assert!(cs.iter().all(|&c| s.is_interior(c)));
            let values = [s.values4(&cs), s.values4_in::<F4>(&cs)];
            let reads = [s.at_interior4(&cs), s.at_interior4_in::<F4>(&cs)];
            for (lane, &c) in cs.iter().enumerate() {
                let first = s.at_index_if(c, -7.0, |_| false).unwrap_err();
                assert_eq!(first.to_bits(), (v.sample_index(c, -7.0) as f64).to_bits());
                let one = s.at_index(c, -7.0);
                for (vs, rs) in values.iter().zip(&reads) {
                    assert_eq!(vs[lane].to_bits(), first.to_bits(), "at {c}");
                    for (a, e) in rs[lane].iter().zip(&one) {
                        assert_eq!(bits(a), bits(e), "at {c}");
                    }
                }
            }
        }
    }

    fn trilinear_f64(v: &Volume<f32>, c: DVec3) -> f64 {
        crate::volume::trilinear(c, v.grid().dims(), |i, j, k| v.get(i, j, k) as f64).unwrap()
    }

    #[test]
    fn a_linear_field_has_its_exact_gradient_inside_and_at_the_border() {
        let g = Grid::new(
            [8, 7, 6],
            Affine::from_spacing([2.0, 1.0, 3.0], DVec3::new(10.0, 0.0, 0.0)),
        )
        .unwrap();
        let mut data = Vec::new();
        for k in 0..6 {
            for j in 0..7 {
                for i in 0..8 {
                    let p = g.voxel_to_world(i, j, k);
                    data.push((0.5 * p.x + 10.0 * p.y + 4.0 * p.z) as f32);
                }
            }
        }
        let v = Volume::new(g, data).unwrap();
        let s = GradientSampler::new(&v);
        for c in [
            DVec3::new(3.3, 2.7, 2.5),
            DVec3::new(0.6, 0.6, 0.6),
            DVec3::new(6.2, 5.1, 4.2),
        ] {
            let grad = s.gradient_at_index(c, -1.0);
            assert!((grad - DVec3::new(0.5, 10.0, 4.0)).length() < 1e-4, "at {c}: {grad}");
        }
    }
}
