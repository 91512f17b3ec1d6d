//! The minimisation of thesis §4.2.5 on one set of boundary conditions: explicit Euler steps in
//! pseudo-time u ← u + τ (A u − g) (eqs. 4.2.22–4.2.24, A = f_mat·L) that never change a
//! Dirichlet node, accelerated by multigrid over the levels 16³ → 32³ → 64³ (thesis §4.4.2) and,
//! for the diffusion operator, by Fast Explicit Diffusion cycles on the coarsest level. Lattices
//! have 2^k + 1 nodes per axis (65 → 33 → 17 by default), so the levels nest exactly.
//!
//! The multigrid is the full-approximation scheme (FAS): a coarse level solves
//! A_c u_c = A_c(R u) + R_fw(g − A u) from u_c = R u, where R injects (coarse node c is fine node
//! 2c, as in the thesis) and R_fw is full weighting of the residual; the fine field then gains the
//! trilinearly prolonged change P(u_c − R u). A converged field is a fixed point of every cycle,
//! so warm-started frames converge to the fully converged solve.
//!
//! Deterministic and independent of the number of threads: each sweep reads one buffer and
//! writes another, node by node, with no reduction; planes of the lattice go to rayon tasks.

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
    pub f_mat: Vec<f64>,
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
        Level { lattice, fixed, f_mat }
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
    /// g − f_mat·L u (the residual).
    Residual,
}

/// One row of free-node candidates: nodes `c0 .. c0 + m` (an interior row without its two border
/// nodes). Writes `out[a][0..m]` for the three components. The arithmetic is that of
/// [`super::operator::apply`] (second differences, then the mixed ones), in component form.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn row(
    u: &Components,
    g: Option<&Components>,
    level: &Level,
    c0: usize,
    m: usize,
    n: usize,
    (mu, lm, inv_h2): (f64, f64, f64),
    sweep: Sweep,
    out: [&mut [f64]; 3],
) {
    let s = [1usize, n, n * n];
    // The slice of component `a` shifted by `plus − minus` nodes (all offsets stay inside u for
    // an interior row).
    let sl = |a: usize, plus: usize, minus: usize| &u[a][c0 + plus - minus..][..m];
    let fixed = &level.fixed[c0..][..m];
    let f_mat = &level.f_mat[c0..][..m];
    const ZEROS: [f64; 256] = [0.0; 256];
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
        let coef = (mu, lm, inv_h2);
        match (lm == 0.0, sweep) {
            (true, Sweep::Step(tau)) => kernel::<false, false>(&nb, g, fixed, f_mat, out, coef, tau),
            (true, Sweep::Residual) => kernel::<false, true>(&nb, g, fixed, f_mat, out, coef, 0.0),
            (false, Sweep::Step(tau)) => kernel::<true, false>(&nb, g, fixed, f_mat, out, coef, tau),
            (false, Sweep::Residual) => kernel::<true, true>(&nb, g, fixed, f_mat, out, coef, 0.0),
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

/// The branch-free inner loop (equal lengths asserted once, so it vectorises).
#[inline(always)]
fn kernel<const ELASTIC: bool, const RESIDUAL: bool>(
    nb: &Neighbours,
    g: &[f64],
    fixed: &[bool],
    f_mat: &[f64],
    out: &mut [f64],
    (mu, lm, inv_h2): (f64, f64, f64),
    tau: f64,
) {
    let m = out.len();
    let uc = &nb.c[..m];
    let [xp, xm, yp, ym, zp, zm] = nb.faces.map(|f| &f[..m]);
    let [ap, am] = nb.along.map(|f| &f[..m]);
    let [[p1, q1, r1, t1], [p2, q2, r2, t2]] = nb.mixed.map(|q| q.map(|f| &f[..m]));
    let (g, fixed, f_mat) = (&g[..m], &fixed[..m], &f_mat[..m]);
    for i in 0..m {
        let two_c = uc[i] + uc[i];
        let lap = (xp[i] + xm[i] - two_c) + (yp[i] + ym[i] - two_c) + (zp[i] + zm[i] - two_c);
        let l = if ELASTIC {
            let daa = ap[i] + am[i] - two_c;
            let d1 = ((p1[i] - q1[i]) - (r1[i] - t1[i])) * 0.25;
            let d2 = ((p2[i] - q2[i]) - (r2[i] - t2[i])) * 0.25;
            (lap * mu + (daa + d1 + d2) * lm) * inv_h2
        } else {
            lap * (mu * inv_h2)
        };
        let rhs = l * f_mat[i] - g[i];
        out[i] = if RESIDUAL {
            if fixed[i] { 0.0 } else { -rhs }
        } else if fixed[i] {
            uc[i]
        } else {
            uc[i] + rhs * tau
        };
    }
}

/// One sweep over the lattice: every free node by [`row`]; Dirichlet and border nodes keep their
/// value (a step) or get a zero residual.
fn sweep(level: &Level, reg: Regulariser, sweep: Sweep, u: &Components, g: Option<&Components>, out: &mut Components) {
    let n = level.lattice.n;
    let h = level.lattice.h_mm;
    let (mu, lm) = reg.lame();
    let coef = (mu, lm, 1.0 / (h * h));
    let plane = |k: usize, o: [&mut [f64]; 3]| {
        let base = k * n * n;
        let [ox, oy, oz] = o;
        let border = |o: &mut [f64], a: usize, lo: usize, hi: usize| match sweep {
            Sweep::Step(_) => o[lo..hi].copy_from_slice(&u[a][base + lo..base + hi]),
            Sweep::Residual => o[lo..hi].fill(0.0),
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
            row(
                u,
                g,
                level,
                base + r + 1,
                n - 2,
                n,
                coef,
                sweep,
                [&mut ox[r + 1..], &mut oy[r + 1..], &mut oz[r + 1..]],
            );
        }
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
/// fine nodes around 2c.
fn subtract_restricted(fine: &Lattice, coarse: &Lattice, r: &Components, out: &mut Components) {
    const W: [f64; 3] = [0.25, 0.5, 0.25];
    let nc = coarse.n;
    per_coarse_plane(nc, out, |k, o| {
        if k == 0 || k == nc - 1 {
            return;
        }
        for (a, o) in o.into_iter().enumerate() {
            for j in 1..nc - 1 {
                for i in 1..nc - 1 {
                    let mut s = 0.0;
                    for (dk, wk) in W.iter().enumerate() {
                        for (dj, wj) in W.iter().enumerate() {
                            let base = fine.index(2 * i - 1, 2 * j + dj - 1, 2 * k + dk - 1);
                            let rr = &r[a][base..base + 3];
                            s += (rr[0] * W[0] + rr[1] * W[1] + rr[2] * W[2]) * (wj * wk);
                        }
                    }
                    o[i + nc * j] -= s;
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

/// u += P e at free fine nodes, P trilinear (fine node f at coarse coordinate f/2).
fn prolong_add(level: &Level, coarse: &Lattice, e: &Components, u: &mut Components) {
    let fine = &level.lattice;
    let n = fine.n;
    let m = coarse.n - 1;
    let fixed = &level.fixed;
    let plane = |k: usize, o: [&mut [f64]; 3]| {
        let (k0, k1, wk) = weights(k, m);
        for (a, o) in o.into_iter().enumerate() {
            let e = &e[a];
            let v = |i: usize, j: usize, kk: usize| e[coarse.index(i, j, kk)];
            for j in 0..n {
                let (j0, j1, wj) = weights(j, m);
                for i in 0..n {
                    if fixed[fine.index(i, j, k)] {
                        continue;
                    }
                    let (i0, i1, wi) = weights(i, m);
                    let x0 = (v(i0, j0, k0) * (1.0 - wi) + v(i1, j0, k0) * wi) * (1.0 - wj)
                        + (v(i0, j1, k0) * (1.0 - wi) + v(i1, j1, k0) * wi) * wj;
                    let x1 = (v(i0, j0, k1) * (1.0 - wi) + v(i1, j0, k1) * wi) * (1.0 - wj)
                        + (v(i0, j1, k1) * (1.0 - wi) + v(i1, j1, k1) * wi) * wj;
                    o[i + n * j] += x0 * (1.0 - wk) + x1 * wk;
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
    sweep(level, reg, Sweep::Residual, u, g, r);
    let u_c0 = sized(&mut b.u_c0, nc);
    inject(&level.lattice, &coarse.lattice, u, u_c0);
    // g_c = A_c(R u) + R_fw(r): the coarse right-hand side of FAS (A_c u = −residual with g = 0).
    let g_c = sized(&mut b.g_c, nc);
    sweep(coarse, reg, Sweep::Residual, u_c0, None, g_c);
    g_c.iter_mut().for_each(|c| c.iter_mut().for_each(|v| *v = -*v));
    r.iter_mut().for_each(|c| c.iter_mut().for_each(|v| *v = -*v));
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deform::operator;

    /// The vectorised rows compute the reference operator: one step from a random field equals
    /// u + τ·f_mat·apply(u) node by node.
    #[test]
    fn the_row_kernel_is_the_reference_operator() {
        let lattice = Lattice {
            n: 9,
            h_mm: 1.5,
            origin_mm: DVec3::ZERO,
        };
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
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
            f_mat: f_mat.clone(),
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
