//! The minimisation of thesis §4.2.5 on one set of boundary conditions: explicit Euler steps in
//! pseudo-time u ← u + τ (A u − g) (eqs. 4.2.22–4.2.24, A = f_mat·L) that never change a
//! Dirichlet node, accelerated by multigrid over the levels 16³ → 32³ → 64³ (thesis §4.4.2) and,
//! for the diffusion operator, by Fast Explicit Diffusion cycles on the coarsest level. Lattices
//! have 2^k + 1 nodes per axis (65 → 33 → 17 → 9 by default), so the levels nest exactly.
//!
//! The multigrid is the full-approximation scheme (FAS): a coarse level solves
//! A_c u_c = A_c(R u) + R_fw(g − A u) from u_c = R u, where R injects (coarse node c is fine node
//! 2c, as in the thesis) and R_fw is full weighting of the residual; the fine field then gains the
//! trilinearly prolonged change P(u_c − R u). A converged field is a fixed point of every cycle,
//! so warm-started frames converge to the fully converged solve.
//!
//! Deterministic and independent of the number of threads: each sweep reads one buffer and
//! writes another, node by node, with no reduction; planes of the lattice go to rayon tasks.

use std::sync::Arc;

use glam::DVec3;
use rayon::prelude::*;

use super::lattice::Lattice;
use super::operator::Regulariser;

/// Below this many nodes per axis a sweep runs on the calling thread (tasks cost more).
const PARALLEL_FROM_N: usize = 32;

/// Safety factor on the Gershgorin step: τ = STEP_FACTOR / bound (stable for < 2).
pub const STEP_FACTOR: f64 = 1.2;

/// A vector field as three component arrays (x, y, z), node index as [`Lattice::index`]: rows of
/// one component are contiguous, so the stencil loops vectorise.
pub type Components = [Vec<f64>; 3];

/// The components of a field of vectors.
pub fn split(u: &[DVec3]) -> Components {
    [0, 1, 2].map(|a| u.iter().map(|v| v[a]).collect())
}

/// The vectors of a field of components.
pub fn join(c: &Components) -> Vec<DVec3> {
    (0..c[0].len()).map(|i| DVec3::new(c[0][i], c[1][i], c[2][i])).collect()
}

/// One multigrid level: its lattice, which nodes are Dirichlet nodes (border, hard tissue, tool
/// points), and f_mat at each node.
#[derive(Debug, Clone)]
pub struct Level {
    pub lattice: Lattice,
    pub fixed: Vec<bool>,
    /// Shared between solves on one placement of Ω_J (only the Dirichlet nodes change).
    pub f_mat: Arc<[f64]>,
}

impl Level {
    /// The next coarser level by injection: coarse node c takes fine node 2c's f_mat, and is fixed
    /// on its own border and wherever a fine node of its restriction stencil (2c ± 1 on each
    /// axis) is fixed: the coarse correction then never works against a fine condition it cannot
    /// see (with injection alone, a face of sparse contact patches made the cycle diverge).
    pub fn coarsen(&self) -> Level {
        let fine = &self.lattice;
        let lattice = fine.coarse();
        let n = lattice.n;
        let mut fixed = vec![false; lattice.len()];
        let mut f_mat = vec![0.0; lattice.len()];
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let c = lattice.index(i, j, k);
                    let f = fine.index(2 * i, 2 * j, 2 * k);
                    fixed[c] = lattice.is_border(i, j, k) || self.stencil_fixed(2 * i, 2 * j, 2 * k);
                    f_mat[c] = self.f_mat[f];
                }
            }
        }
        Level {
            lattice,
            fixed,
            f_mat: f_mat.into(),
        }
    }

    /// Fixes the nodes `new` of this level and returns the nodes of the next coarser level
    /// that this newly fixes: those whose restriction stencil (2c ± 1 on each axis) holds one of
    /// them and that were free. Marking level by level gives exactly the levels [`Level::coarsen`]
    /// builds from the marked finest level, at the cost of the new nodes only.
    fn fix_and_coarsen(&mut self, new: &[usize], coarse: &Level) -> Vec<usize> {
        let mut out = Vec::new();
        let cl = &coarse.lattice;
        // Coarse coordinates c with |2c − f| ≤ 1: f/2 for even f, (f ± 1)/2 for odd f (⌊f/2⌋ … ⌈f/2⌉).
        let span = |f: usize| f / 2..=f.div_ceil(2);
        for &f in new {
            self.fixed[f] = true;
            let [i, j, k] = self.lattice.ijk(f);
            for kc in span(k) {
                for jc in span(j) {
                    for ic in span(i) {
                        let c = cl.index(ic, jc, kc);
                        if !coarse.fixed[c] {
                            out.push(c);
                        }
                    }
                }
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// Whether a fine node within one node of (i, j, k) on every axis is fixed.
    fn stencil_fixed(&self, i: usize, j: usize, k: usize) -> bool {
        let n = self.lattice.n;
        let span = |c: usize| c.saturating_sub(1)..=(c + 1).min(n - 1);
        span(k).any(|kk| span(j).any(|jj| span(i).any(|ii| self.fixed[self.lattice.index(ii, jj, kk)])))
    }
}

/// How much work one solve does (a fixed amount: no convergence test, thesis §4.3.1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Schedule {
    /// Multigrid levels (1 = the thesis' plain explicit iteration on the finest lattice).
    pub levels: u32,
    /// V-cycles per solve.
    pub cycles: u32,
    /// Steps on each level before and after its coarse correction.
    pub pre_steps: u32,
    pub post_steps: u32,
    /// Steps on the coarsest level.
    pub coarsest_steps: u32,
    /// Fast Explicit Diffusion: steps per FED cycle on the coarsest level (diffusion only;
    /// 0 = plain steps).
    pub fed_cycle_steps: u32,
}

/// What a sweep writes at a free node.
#[derive(Clone, Copy)]
enum Sweep {
    /// u + τ (f_mat·L u − g).
    Step(f64),
    /// f_mat·L u − g: the residual's negative, which both FAS transfers use (−0 at Dirichlet
    /// and border nodes: the bits of negating a zero residual).
    Defect,
}

/// What every row of one sweep shares.
#[derive(Clone, Copy)]
struct SweepJob<'a> {
    u: &'a Components,
    g: Option<&'a Components>,
    level: &'a Level,
    /// (μ, λ + μ, 1/h²).
    coef: (f64, f64, f64),
    sweep: Sweep,
}

/// Partial sums of one row, reused from row to row of a plane.
struct RowScratch {
    lap: [f64; MAX_ROW],
    d: [f64; MAX_ROW],
}

impl RowScratch {
    fn new() -> Self {
        RowScratch {
            lap: [0.0; MAX_ROW],
            d: [0.0; MAX_ROW],
        }
    }
}

/// One row of free-node candidates: nodes `c0 .. c0 + m` (an interior row without its two border
/// nodes). Writes `out[a][0..m]` for the three components. The arithmetic is that of
/// [`super::operator::apply`] (second differences, then the mixed ones), in component form.
#[inline(always)]
fn row(job: &SweepJob, c0: usize, m: usize, out: [&mut [f64]; 3], scratch: &mut RowScratch) {
    let SweepJob {
        u,
        g,
        level,
        coef,
        sweep,
    } = *job;
    let n = level.lattice.n;
    let lm = coef.1;
    let s = [1usize, n, n * n];
    // The slice of component `a` shifted by `plus − minus` nodes (all offsets stay inside u for
    // an interior row).
    let sl = |a: usize, plus: usize, minus: usize| &u[a][c0 + plus - minus..][..m];
    let fixed = &level.fixed[c0..][..m];
    let f_mat = &level.f_mat[c0..][..m];
    const ZEROS: [f64; MAX_ROW] = [0.0; MAX_ROW];
    for (a, out) in out.into_iter().enumerate() {
        let (b1, b2) = ((a + 1) % 3, (a + 2) % 3);
        // The two other components b and the offsets of ∂²u_b/∂x_a∂x_b.
        let mix = |b: usize| {
            [
                sl(b, s[a] + s[b], 0),
                sl(b, s[a], s[b]),
                sl(b, s[b], s[a]),
                sl(b, 0, s[a] + s[b]),
            ]
        };
        let nb = Neighbours {
            c: sl(a, 0, 0),
            faces: [
                sl(a, s[0], 0),
                sl(a, 0, s[0]),
                sl(a, s[1], 0),
                sl(a, 0, s[1]),
                sl(a, s[2], 0),
                sl(a, 0, s[2]),
            ],
            along: [sl(a, s[a], 0), sl(a, 0, s[a])],
            mixed: [mix(b1), mix(b2)],
        };
        let g = g.map_or(&ZEROS[..m], |g| &g[a][c0..][..m]);
        let out = &mut out[..m];
        let rows = (g, fixed, f_mat, out);
        match (lm == 0.0, sweep) {
            (true, Sweep::Step(tau)) => kernel::<false, false>(&nb, rows, coef, tau, scratch),
            (true, Sweep::Defect) => kernel::<false, true>(&nb, rows, coef, 0.0, scratch),
            (false, Sweep::Step(tau)) => kernel::<true, false>(&nb, rows, coef, tau, scratch),
            (false, Sweep::Defect) => kernel::<true, true>(&nb, rows, coef, 0.0, scratch),
        }
    }
}

/// The rows one component's operator reads: the node, its six face neighbours (+x, −x, +y, −y,
/// +z, −z), its two neighbours along its own axis, and for each other component the four edge
/// neighbours of the mixed difference (++, +−, −+, −−).
struct Neighbours<'a> {
    c: &'a [f64],
    faces: [&'a [f64]; 6],
    along: [&'a [f64]; 2],
    mixed: [[&'a [f64]; 4]; 2],
}

/// Longest interior row a sweep handles (`cells` ≤ 128 leaves 127).
const MAX_ROW: usize = 256;

/// The inner loops, in passes of at most eleven streams each so that every pointer stays in a
/// register and each loop vectorises (one loop over all nineteen neighbour rows spilled its
/// pointers and ran scalar). The arithmetic and its order per node are those of
/// [`super::operator::apply`]: the passes only split where partial sums are kept.
#[inline(always)]
fn kernel<const ELASTIC: bool, const DEFECT: bool>(
    nb: &Neighbours,
    (g, fixed, f_mat, out): (&[f64], &[bool], &[f64], &mut [f64]),
    (mu, lm, inv_h2): (f64, f64, f64),
    tau: f64,
    scratch: &mut RowScratch,
) {
    let m = out.len();
    let (lap, d) = (&mut scratch.lap[..m], &mut scratch.d[..m]);
    let uc = &nb.c[..m];
    // Pass 1: the Laplacian and the second difference along the component's own axis.
    {
        let [xp, xm, yp, ym, zp, zm] = nb.faces.map(|f| &f[..m]);
        for i in 0..m {
            let two_c = uc[i] + uc[i];
            lap[i] = (xp[i] + xm[i] - two_c) + (yp[i] + ym[i] - two_c) + (zp[i] + zm[i] - two_c);
        }
        if ELASTIC {
            let [ap, am] = nb.along.map(|f| &f[..m]);
            for i in 0..m {
                let two_c = uc[i] + uc[i];
                d[i] = ap[i] + am[i] - two_c;
            }
        }
    }
    // Passes 2–3: the mixed differences of the two other components, (daa + d1) + d2.
    if ELASTIC {
        for q in &nb.mixed {
            let [p, q_, r, t] = q.map(|f| &f[..m]);
            for i in 0..m {
                d[i] += ((p[i] - q_[i]) - (r[i] - t[i])) * 0.25;
            }
        }
    }
    // Pass 4: f_mat, the right-hand side, and the step or the residual (Dirichlet nodes kept).
    let (g, fixed, f_mat) = (&g[..m], &fixed[..m], &f_mat[..m]);
    for i in 0..m {
        let l = if ELASTIC {
            (lap[i] * mu + d[i] * lm) * inv_h2
        } else {
            lap[i] * (mu * inv_h2)
        };
        let rhs = l * f_mat[i] - g[i];
        out[i] = if DEFECT {
            if fixed[i] { -0.0 } else { rhs }
        } else if fixed[i] {
            uc[i]
        } else {
            uc[i] + rhs * tau
        };
    }
}

/// The interior rows 1 … n−2 of plane `k` (`out`: that plane of each component).
#[inline(always)]
fn interior_rows(job: &SweepJob, k: usize, out: [&mut [f64]; 3]) {
    let n = job.level.lattice.n;
    let mut scratch = RowScratch::new();
    let [ox, oy, oz] = out;
    for j in 1..n - 1 {
        let r = j * n + 1;
        row(
            job,
            k * n * n + r,
            n - 2,
            [&mut ox[r..], &mut oy[r..], &mut oz[r..]],
            &mut scratch,
        );
    }
}

/// [`interior_rows`] compiled for AVX2 (four lanes): the same IEEE operations per node, so the
/// same bits (no fused multiply–add: Rust never contracts). Chosen at run time where the CPU
/// has it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn interior_rows_avx2(job: &SweepJob, k: usize, out: [&mut [f64]; 3]) {
    interior_rows(job, k, out)
}

/// The interior rows of a plane by the widest kernel this CPU runs.
fn interior_rows_dispatch(job: &SweepJob, k: usize, out: [&mut [f64]; 3]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        return unsafe { interior_rows_avx2(job, k, out) };
    }
    interior_rows(job, k, out)
}

/// One sweep over the lattice: every free node by [`row`]; Dirichlet and border nodes keep their
/// value (a step) or get a zero residual.
fn sweep(level: &Level, reg: Regulariser, sweep: Sweep, u: &Components, g: Option<&Components>, out: &mut Components) {
    let n = level.lattice.n;
    let h = level.lattice.h_mm;
    let (mu, lm) = reg.lame();
    let job = SweepJob {
        u,
        g,
        level,
        coef: (mu, lm, 1.0 / (h * h)),
        sweep,
    };
    let plane = |k: usize, o: [&mut [f64]; 3]| {
        let base = k * n * n;
        let [ox, oy, oz] = o;
        let border = |o: &mut [f64], a: usize, lo: usize, hi: usize| match sweep {
            Sweep::Step(_) => o[lo..hi].copy_from_slice(&u[a][base + lo..base + hi]),
            Sweep::Defect => o[lo..hi].fill(-0.0),
        };
        if k == 0 || k == n - 1 {
            // A border plane: u = 0 (eq. 4.2.5).
            for (a, o) in [ox, oy, oz].into_iter().enumerate() {
                border(o, a, 0, n * n);
            }
            return;
        }
        for (a, o) in [&mut *ox, &mut *oy, &mut *oz].into_iter().enumerate() {
            border(o, a, 0, n);
            border(o, a, n * (n - 1), n * n);
        }
        for j in 1..n - 1 {
            let r = j * n;
            for (a, o) in [&mut *ox, &mut *oy, &mut *oz].into_iter().enumerate() {
                border(o, a, r, r + 1);
                border(o, a, r + n - 1, r + n);
            }
        }
        interior_rows_dispatch(&job, k, [ox, oy, oz]);
    };
    let [ox, oy, oz] = out;
    if n >= PARALLEL_FROM_N {
        ox.par_chunks_mut(n * n)
            .zip(oy.par_chunks_mut(n * n))
            .zip(oz.par_chunks_mut(n * n))
            .enumerate()
            .for_each(|(k, ((x, y), z))| plane(k, [x, y, z]));
    } else {
        ox.chunks_mut(n * n)
            .zip(oy.chunks_mut(n * n))
            .zip(oz.chunks_mut(n * n))
            .enumerate()
            .for_each(|(k, ((x, y), z))| plane(k, [x, y, z]));
    }
}

/// Explicit steps of the sizes `taus`, ping-ponging with `scratch`; the result ends in `u`.
fn steps(
    level: &Level,
    reg: Regulariser,
    taus: &[f64],
    u: &mut Components,
    g: Option<&Components>,
    scratch: &mut Components,
) {
    for &tau in taus {
        sweep(level, reg, Sweep::Step(tau), u, g, scratch);
        std::mem::swap(u, scratch);
    }
}

/// The stable plain step on a lattice of spacing `h_mm`.
pub fn plain_tau(reg: Regulariser, h_mm: f64) -> f64 {
    STEP_FACTOR / reg.gershgorin(h_mm)
}

/// Step sizes of one Fast Explicit Diffusion cycle of `m` steps (Grewenig, Weickert & Bruhn
/// 2010): τ_i = τ_max / (2 cos²(π (2i + 1) / (4m + 2))), τ_max = 2 / ρ. Single steps exceed the
/// stability limit; the cycle as a whole is stable and covers the pseudo-time τ_max·(m² + m)/3.
pub fn fed_taus(m: u32, tau_max: f64) -> Vec<f64> {
    (0..m)
        .map(|i| {
            let c = libm::cos(std::f64::consts::PI * f64::from(2 * i + 1) / f64::from(4 * m + 2));
            tau_max / (2.0 * c * c)
        })
        .collect()
}

/// Per plane of the coarse lattice, in parallel when it is large enough.
fn per_coarse_plane(nc: usize, out: &mut Components, f: impl Fn(usize, [&mut [f64]; 3]) + Sync) {
    let [ox, oy, oz] = out;
    if nc >= PARALLEL_FROM_N / 2 {
        ox.par_chunks_mut(nc * nc)
            .zip(oy.par_chunks_mut(nc * nc))
            .zip(oz.par_chunks_mut(nc * nc))
            .enumerate()
            .for_each(|(k, ((x, y), z))| f(k, [x, y, z]));
    } else {
        ox.chunks_mut(nc * nc)
            .zip(oy.chunks_mut(nc * nc))
            .zip(oz.chunks_mut(nc * nc))
            .enumerate()
            .for_each(|(k, ((x, y), z))| f(k, [x, y, z]));
    }
}

/// `out −= R_fw r` at interior coarse nodes: full weighting, the (¼, ½, ¼)³-weighted mean of the
/// fine nodes around 2c. Separable: each fine row of the three fine planes around a coarse
/// plane is first weighted along i, then nine such values are summed per coarse node in the
/// order of the full stencil (k outer, j inner), so the bits are those of the direct sum.
fn subtract_restricted(fine: &Lattice, coarse: &Lattice, r: &Components, out: &mut Components) {
    const W: [f64; 3] = [0.25, 0.5, 0.25];
    let (n, nc) = (fine.n, coarse.n);
    per_coarse_plane(nc, out, |k, o| {
        if k == 0 || k == nc - 1 {
            return;
        }
        // rows[dk][jf * nc + i]: fine row jf of fine plane 2k + dk − 1, weighted along i.
        let mut rows = [vec![0.0; n * nc], vec![0.0; n * nc], vec![0.0; n * nc]];
        for (a, o) in o.into_iter().enumerate() {
            for (dk, rows) in rows.iter_mut().enumerate() {
                for jf in 0..n {
                    let src = &r[a][fine.index(0, jf, 2 * k + dk - 1)..][..n];
                    let dst = &mut rows[jf * nc..][..nc];
                    for i in 1..nc - 1 {
                        dst[i] = src[2 * i - 1] * W[0] + src[2 * i] * W[1] + src[2 * i + 1] * W[2];
                    }
                }
            }
            let mut s = vec![0.0; nc];
            for j in 1..nc - 1 {
                let out = &mut o[nc * j..][..nc];
                s.fill(0.0);
                for (dk, wk) in W.iter().enumerate() {
                    for (dj, wj) in W.iter().enumerate() {
                        let w = wj * wk;
                        let row = &rows[dk][(2 * j + dj - 1) * nc..][..nc];
                        for i in 1..nc - 1 {
                            s[i] += row[i] * w;
                        }
                    }
                }
                for i in 1..nc - 1 {
                    out[i] -= s[i];
                }
            }
        }
    });
}

/// Coarse node c gets fine node 2c.
fn inject(fine: &Lattice, coarse: &Lattice, u: &Components, out: &mut Components) {
    let nc = coarse.n;
    per_coarse_plane(nc, out, |k, o| {
        for (a, o) in o.into_iter().enumerate() {
            for j in 0..nc {
                for i in 0..nc {
                    o[i + nc * j] = u[a][fine.index(2 * i, 2 * j, 2 * k)];
                }
            }
        }
    });
}

/// u += P e at free fine nodes, P trilinear (fine node f at coarse coordinate f/2). Separable:
/// per fine plane, the coarse rows of its two coarse planes are first interpolated along i to
/// fine rows, then each fine row mixes two of them along j and the two planes along k; the
/// products and sums per node are those of the trilinear formula, in its order.
fn prolong_add(level: &Level, coarse: &Lattice, e: &Components, u: &mut Components) {
    let fine = &level.lattice;
    let n = fine.n;
    let nc = coarse.n;
    let m = nc - 1;
    let fixed = &level.fixed;
    let plane = |k: usize, o: [&mut [f64]; 3]| {
        let (k0, k1, wk) = weights(k, m);
        // Fine-resolution rows of the coarse planes k0 and k1: rows[p][jc * n + i].
        let mut rows = [vec![0.0; nc * n], vec![0.0; nc * n]];
        let fixed = &fixed[k * n * n..][..n * n];
        for (a, o) in o.into_iter().enumerate() {
            let e = &e[a];
            for (rows, kc) in rows.iter_mut().zip([k0, k1]) {
                for jc in 0..nc {
                    let src = &e[coarse.index(0, jc, kc)..][..nc];
                    let dst = &mut rows[jc * n..][..n];
                    // Even fine nodes sit on coarse nodes (weight 0), odd ones halfway (½):
                    // the formula's products, without its index look-ups.
                    for c in 0..m {
                        dst[2 * c] = src[c] * (1.0 - 0.0) + src[c] * 0.0;
                        dst[2 * c + 1] = src[c] * (1.0 - 0.5) + src[c + 1] * 0.5;
                    }
                    dst[2 * m] = src[m] * (1.0 - 0.0) + src[m] * 0.0;
                }
            }
            for j in 0..n {
                let (j0, j1, wj) = weights(j, m);
                let [r00, r10] = [&rows[0][j0 * n..][..n], &rows[0][j1 * n..][..n]];
                let [r01, r11] = [&rows[1][j0 * n..][..n], &rows[1][j1 * n..][..n]];
                let (out, fx) = (&mut o[j * n..][..n], &fixed[j * n..][..n]);
                for i in 0..n {
                    let x0 = r00[i] * (1.0 - wj) + r10[i] * wj;
                    let x1 = r01[i] * (1.0 - wj) + r11[i] * wj;
                    let v = x0 * (1.0 - wk) + x1 * wk;
                    out[i] = if fx[i] { out[i] } else { out[i] + v };
                }
            }
        }
    };
    let [ux, uy, uz] = u;
    if n >= PARALLEL_FROM_N {
        ux.par_chunks_mut(n * n)
            .zip(uy.par_chunks_mut(n * n))
            .zip(uz.par_chunks_mut(n * n))
            .enumerate()
            .for_each(|(k, ((x, y), z))| plane(k, [x, y, z]));
    } else {
        ux.chunks_mut(n * n)
            .zip(uy.chunks_mut(n * n))
            .zip(uz.chunks_mut(n * n))
            .enumerate()
            .for_each(|(k, ((x, y), z))| plane(k, [x, y, z]));
    }
}

/// Coarse neighbours and weight of fine index `f` (coarse coordinate f/2, clamped to `m`).
#[inline]
fn weights(f: usize, m: usize) -> (usize, usize, f64) {
    let c0 = (f / 2).min(m);
    if f % 2 == 1 && c0 < m {
        (c0, c0 + 1, 0.5)
    } else {
        (c0, c0, 0.0)
    }
}

/// Buffers of one level, reused from solve to solve (each is fully written before it is read,
/// so what an earlier solve left in them never reaches a result).
#[derive(Default)]
struct Buffers {
    scratch: Components,
    residual: Components,
    /// Coarse: R u, the coarse right-hand side, the coarse solution, its change.
    u_c0: Components,
    g_c: Components,
    u_c: Components,
    e: Components,
}

fn sized(v: &mut Components, len: usize) -> &mut Components {
    for c in v.iter_mut() {
        c.resize(len, 0.0);
    }
    v
}

thread_local! {
    static BUFFERS: std::cell::RefCell<Vec<Buffers>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// One FAS V-cycle from `levels[l]` down, solving A u = g (`g` None = 0) in place.
fn v_cycle(
    levels: &[Level],
    l: usize,
    reg: Regulariser,
    s: &Schedule,
    u: &mut Components,
    g: Option<&Components>,
    bufs: &mut [Buffers],
) {
    let level = &levels[l];
    let len = level.lattice.len();
    let tau = plain_tau(reg, level.lattice.h_mm);
    let (b, below) = bufs.split_first_mut().expect("a buffer per level");
    if l + 1 == levels.len() {
        let taus = match reg {
            Regulariser::Diffusion if s.fed_cycle_steps > 0 => {
                let cycle = fed_taus(s.fed_cycle_steps, 2.0 / reg.gershgorin(level.lattice.h_mm));
                let cycles = s.coarsest_steps.div_ceil(s.fed_cycle_steps) as usize;
                cycle.repeat(cycles)
            }
            _ => vec![tau; s.coarsest_steps as usize],
        };
        steps(level, reg, &taus, u, g, sized(&mut b.scratch, len));
        return;
    }
    steps(
        level,
        reg,
        &vec![tau; s.pre_steps as usize],
        u,
        g,
        sized(&mut b.scratch, len),
    );
    let coarse = &levels[l + 1];
    let nc = coarse.lattice.len();
    let r = sized(&mut b.residual, len);
    sweep(level, reg, Sweep::Defect, u, g, r);
    let u_c0 = sized(&mut b.u_c0, nc);
    inject(&level.lattice, &coarse.lattice, u, u_c0);
    // g_c = A_c(R u) + R_fw(g − A u) = A_c(R u) − R_fw(defect): the coarse right-hand side
    // of FAS (A_c u is the defect with g = 0).
    let g_c = sized(&mut b.g_c, nc);
    sweep(coarse, reg, Sweep::Defect, u_c0, None, g_c);
    subtract_restricted(&level.lattice, &coarse.lattice, r, g_c);
    let u_c = sized(&mut b.u_c, nc);
    for a in 0..3 {
        u_c[a].copy_from_slice(&u_c0[a]);
    }
    v_cycle(levels, l + 1, reg, s, u_c, Some(g_c), below);
    let e = sized(&mut b.e, nc);
    for a in 0..3 {
        e[a].iter_mut()
            .zip(u_c[a].iter().zip(u_c0[a].iter()))
            .for_each(|(e, (x, y))| *e = *x - *y);
    }
    prolong_add(level, &coarse.lattice, e, u);
    steps(
        level,
        reg,
        &vec![tau; s.post_steps as usize],
        u,
        g,
        sized(&mut b.scratch, len),
    );
}

/// Runs the schedule on `u` (Dirichlet values already in place) over `levels` (finest first).
/// `g` is the right-hand side on the finest level (None for the deformation itself; the
/// manufactured-solution tests pass one).
pub fn solve(levels: &[Level], reg: Regulariser, s: &Schedule, u: &mut Components, g: Option<&Components>) {
    BUFFERS.with(|b| {
        let mut bufs = b.borrow_mut();
        if bufs.len() < levels.len() {
            bufs.resize_with(levels.len(), Buffers::default);
        }
        for _ in 0..s.cycles {
            v_cycle(levels, 0, reg, s, u, g, &mut bufs[..levels.len()]);
        }
    });
}

/// The levels below `finest` by injection, finest first (`levels` in all while the coarsest
/// keeps ≥ 9 nodes per axis).
pub fn hierarchy(finest: Level, levels: u32) -> Vec<Level> {
    let mut out = vec![finest];
    while out.len() < levels as usize && out.last().is_some_and(|l| l.lattice.n >= 9) {
        let next = out.last().expect("non-empty").coarsen();
        out.push(next);
    }
    out
}

/// The levels of `base` (a [`hierarchy`]) with the finest-level nodes `new` fixed as well, and
/// every coarse node that fixes in turn: equal to the hierarchy of the marked finest level.
pub fn with_fixed(base: &[Level], new: &[usize]) -> Vec<Level> {
    let mut levels = base.to_vec();
    let mut new = new.to_vec();
    for l in 0..levels.len() {
        let (this, below) = levels.split_at_mut(l + 1);
        match below.first() {
            Some(coarse) => new = this[l].fix_and_coarsen(&new, coarse),
            None => new.iter().for_each(|&f| this[l].fixed[f] = true),
        }
    }
    levels
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deform::operator;

    /// A cube lattice of `n` nodes per axis at spacing `h_mm`, origin at zero.
    fn cube(n: usize, h_mm: f64) -> Lattice {
        Lattice {
            n,
            h_mm,
            origin_mm: DVec3::ZERO,
        }
    }

    /// Seeded uniform numbers in [−½, ½) (a 64-bit LCG: the same sequence on every machine).
    fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// Fixing tool nodes on a cached hierarchy gives the levels built from scratch.
    #[test]
    fn marking_a_cached_hierarchy_equals_coarsening_the_marked_lattice() {
        let lattice = cube(33, 1.0);
        let len = lattice.len();
        let base_fixed: Vec<bool> = (0..len)
            .map(|i| {
                let [a, b, c] = lattice.ijk(i);
                lattice.is_border(a, b, c) || (a > 20 && b < 9)
            })
            .collect();
        let f_mat: Arc<[f64]> = (0..len).map(|i| (i % 13) as f64 / 13.0).collect();
        let base = hierarchy(
            Level {
                lattice,
                fixed: base_fixed.clone(),
                f_mat: Arc::clone(&f_mat),
            },
            4,
        );
        assert_eq!(base.len(), 4);
        // Tool nodes on even and odd coordinates, some already fixed, one twice.
        let new: Vec<usize> = [[5, 5, 5], [6, 7, 8], [21, 3, 4], [30, 30, 1], [5, 5, 5], [15, 16, 17]]
            .iter()
            .map(|&[i, j, k]| lattice.index(i, j, k))
            .collect();
        let mut marked = base_fixed;
        new.iter().for_each(|&i| marked[i] = true);
        let want = hierarchy(
            Level {
                lattice,
                fixed: marked,
                f_mat,
            },
            4,
        );
        let got = with_fixed(&base, &new);
        for (l, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!(g.fixed, w.fixed, "level {l}");
            assert_eq!(g.f_mat, w.f_mat, "level {l}");
        }
        assert!(got[1].fixed.iter().filter(|&&f| f).count() > base[1].fixed.iter().filter(|&&f| f).count());
    }

    /// The rows compiled for AVX2 give the bits of the plain rows (no FMA, same order per node),
    /// so a session replays alike on any x86-64.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_avx2_rows_give_the_bits_of_the_plain_rows() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            // Not skipped silently: without AVX2 the plain rows are the only ones that run.
            eprintln!("this CPU has no AVX2: only the plain rows run on it");
            return;
        }
        let lattice = cube(21, 0.7);
        let mut rnd = uniform(99);
        let len = lattice.len();
        let u: Components = [0, 1, 2].map(|_| (0..len).map(|_| rnd()).collect());
        let g: Components = [0, 1, 2].map(|_| (0..len).map(|_| rnd()).collect());
        let level = Level {
            lattice,
            fixed: (0..len).map(|i| i % 5 == 0).collect(),
            f_mat: (0..len).map(|_| 0.5 + rnd()).collect(),
        };
        let n = lattice.n;
        for reg in [
            Regulariser::Diffusion,
            Regulariser::LinearElastic { poisson_ratio: 0.45 },
        ] {
            let (mu, lm) = reg.lame();
            for sweep in [Sweep::Step(0.07), Sweep::Defect] {
                let job = SweepJob {
                    u: &u,
                    g: Some(&g),
                    level: &level,
                    coef: (mu, lm, 1.0 / 0.49),
                    sweep,
                };
                let run = |avx2: bool| {
                    let mut out: Components = [vec![0.0; n * n], vec![0.0; n * n], vec![0.0; n * n]];
                    let [x, y, z] = &mut out;
                    let o = [&mut x[..], &mut y[..], &mut z[..]];
                    if avx2 {
                        // SAFETY: AVX2 checked above.
                        unsafe { interior_rows_avx2(&job, 9, o) }
                    } else {
                        interior_rows(&job, 9, o)
                    }
                    out.map(|c| c.into_iter().map(f64::to_bits).collect::<Vec<_>>())
                };
                assert_eq!(run(true), run(false), "{reg:?}");
            }
        }
    }

    /// The vectorised rows compute the reference operator: one step from a random field equals
    /// u + τ·f_mat·apply(u) node by node.
    #[test]
    fn the_row_kernel_is_the_reference_operator() {
        let lattice = cube(9, 1.5);
        let mut rnd = uniform(12345);
        let u: Vec<DVec3> = (0..lattice.len()).map(|_| DVec3::new(rnd(), rnd(), rnd())).collect();
        let f_mat: Vec<f64> = (0..lattice.len()).map(|_| 0.5 + rnd()).collect();
        let fixed: Vec<bool> = (0..lattice.len())
            .map(|i| {
                let [a, b, c] = lattice.ijk(i);
                lattice.is_border(a, b, c) || i % 7 == 0
            })
            .collect();
        let level = Level {
            lattice,
            fixed: fixed.clone(),
            f_mat: f_mat.clone().into(),
        };
        for reg in [
            Regulariser::Diffusion,
            Regulariser::LinearElastic { poisson_ratio: 0.3 },
        ] {
            let (mu, lm) = reg.lame();
            let tau = 0.1;
            let mut out: Components = [
                vec![0.0; lattice.len()],
                vec![0.0; lattice.len()],
                vec![0.0; lattice.len()],
            ];
            sweep(&level, reg, Sweep::Step(tau), &split(&u), None, &mut out);
            let got = join(&out);
            for c in 0..lattice.len() {
                let want = if fixed[c] {
                    u[c]
                } else {
                    u[c] + operator::apply(&u, lattice.n, c, 1.0 / (1.5 * 1.5), mu, lm) * f_mat[c] * tau
                };
                assert!(
                    (got[c] - want).length() < 1e-12,
                    "{reg:?} node {c}: {} vs {}",
                    got[c],
                    want
                );
            }
        }
    }
}
