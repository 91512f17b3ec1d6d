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
use super::operator::{self, Regulariser};

/// Below this many nodes per axis a sweep runs on the calling thread (tasks cost more).
const PARALLEL_FROM_N: usize = 32;

/// Safety factor on the Gershgorin step: τ = STEP_FACTOR / bound (stable for < 2).
pub const STEP_FACTOR: f64 = 1.2;

/// One multigrid level: its lattice, which nodes are Dirichlet nodes (border, hard tissue, tool
/// points), and f_mat at each node.
#[derive(Debug, Clone)]
pub struct Level {
    pub lattice: Lattice,
    pub fixed: Vec<bool>,
    pub f_mat: Vec<f64>,
}

impl Level {
    /// The next coarser level by injection: coarse node c takes fine node 2c's f_mat and is fixed
    /// where fine node 2c is (and on its own border).
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
                    fixed[c] = lattice.is_border(i, j, k) || self.fixed[f];
                    f_mat[c] = self.f_mat[f];
                }
            }
        }
        Level { lattice, fixed, f_mat }
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

/// One explicit step on every free node: out = u + τ (f_mat·L u − g), Dirichlet nodes copied.
fn step(level: &Level, reg: Regulariser, tau: f64, u: &[DVec3], g: Option<&[DVec3]>, out: &mut [DVec3]) {
    let n = level.lattice.n;
    let h = level.lattice.h_mm;
    let inv_h2 = 1.0 / (h * h);
    let (mu, lm) = reg.lame();
    let plane = |k: usize, out: &mut [DVec3]| {
        let base = k * n * n;
        out.copy_from_slice(&u[base..base + n * n]);
        if k == 0 || k == n - 1 {
            return; // border plane: u = 0 (eq. 4.2.5)
        }
        for j in 1..n - 1 {
            let row = base + j * n;
            for i in 1..n - 1 {
                let c = row + i;
                if level.fixed[c] {
                    continue;
                }
                let a = operator::apply(u, n, c, inv_h2, mu, lm) * level.f_mat[c];
                let r = match g {
                    Some(g) => a - g[c],
                    None => a,
                };
                out[j * n + i] = u[c] + r * tau;
            }
        }
    };
    if n >= PARALLEL_FROM_N {
        out.par_chunks_mut(n * n).enumerate().for_each(|(k, o)| plane(k, o));
    } else {
        out.chunks_mut(n * n).enumerate().for_each(|(k, o)| plane(k, o));
    }
}

/// `count` steps of size `tau` (or the FED step sizes when `fed` is set), ping-ponging with
/// `scratch`; the result ends in `u`.
fn steps(
    level: &Level,
    reg: Regulariser,
    taus: &[f64],
    u: &mut Vec<DVec3>,
    g: Option<&[DVec3]>,
    scratch: &mut Vec<DVec3>,
) {
    for &tau in taus {
        step(level, reg, tau, u, g, scratch);
        std::mem::swap(u, scratch);
    }
}

/// The stable plain step on `level`.
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

/// r = g − A u at free nodes, zero at Dirichlet nodes (every element written).
fn residual(level: &Level, reg: Regulariser, u: &[DVec3], g: Option<&[DVec3]>, r: &mut [DVec3]) {
    // One step with τ = 1 gives u + A u − g.
    step(level, reg, 1.0, u, g, r);
    r.iter_mut().zip(u).for_each(|(r, u)| *r = *u - *r);
}

/// a = A u at free nodes, zero elsewhere (every element written).
fn operator_of(level: &Level, reg: Regulariser, u: &[DVec3], a: &mut [DVec3]) {
    residual(level, reg, u, None, a);
    a.iter_mut().for_each(|v| *v = -*v);
}

/// Full weighting: the coarse node gets the (¼, ½, ¼)³-weighted mean of the fine nodes around
/// 2c (fine nodes outside the lattice count as zero).
/// Subtracts the restriction from `out` (border nodes untouched).
fn subtract_restricted(fine: &Lattice, coarse: &Lattice, r: &[DVec3], out: &mut [DVec3]) {
    let w = [0.25, 0.5, 0.25];
    let nf = fine.n as isize;
    let nc = coarse.n;
    let plane = |k: usize, out: &mut [DVec3]| {
        if k == 0 || k == nc - 1 {
            return;
        }
        for j in 1..nc - 1 {
            for i in 1..nc - 1 {
                let mut s = DVec3::ZERO;
                for (dk, wk) in w.iter().enumerate() {
                    for (dj, wj) in w.iter().enumerate() {
                        for (di, wi) in w.iter().enumerate() {
                            let (fi, fj, fk) = (
                                2 * i as isize + di as isize - 1,
                                2 * j as isize + dj as isize - 1,
                                2 * k as isize + dk as isize - 1,
                            );
                            if fi < nf && fj < nf && fk < nf {
                                s += r[fine.index(fi as usize, fj as usize, fk as usize)] * (wi * wj * wk);
                            }
                        }
                    }
                }
                out[i + nc * j] -= s;
            }
        }
    };
    if nc >= PARALLEL_FROM_N / 2 {
        out.par_chunks_mut(nc * nc).enumerate().for_each(|(k, o)| plane(k, o));
    } else {
        out.chunks_mut(nc * nc).enumerate().for_each(|(k, o)| plane(k, o));
    }
}

fn inject(fine: &Lattice, coarse: &Lattice, u: &[DVec3], out: &mut [DVec3]) {
    for k in 0..coarse.n {
        for j in 0..coarse.n {
            for i in 0..coarse.n {
                out[coarse.index(i, j, k)] = u[fine.index(2 * i, 2 * j, 2 * k)];
            }
        }
    }
}

/// u += P e at free fine nodes, P trilinear (fine node f at coarse coordinate f/2).
fn prolong_add(level: &Level, coarse: &Lattice, e: &[DVec3], u: &mut [DVec3]) {
    let fine = &level.lattice;
    let n = fine.n;
    let m = coarse.n - 1;
    let fixed = &level.fixed;
    let plane = |k: usize, out: &mut [DVec3]| {
        let (k0, k1, wk) = weights(k, m);
        for j in 0..n {
            let (j0, j1, wj) = weights(j, m);
            for i in 0..n {
                let c = fine.index(i, j, k);
                if fixed[c] {
                    continue;
                }
                let (i0, i1, wi) = weights(i, m);
                let v = |a, b, cc| e[coarse.index(a, b, cc)];
                let x0 = (v(i0, j0, k0) * (1.0 - wi) + v(i1, j0, k0) * wi) * (1.0 - wj)
                    + (v(i0, j1, k0) * (1.0 - wi) + v(i1, j1, k0) * wi) * wj;
                let x1 = (v(i0, j0, k1) * (1.0 - wi) + v(i1, j0, k1) * wi) * (1.0 - wj)
                    + (v(i0, j1, k1) * (1.0 - wi) + v(i1, j1, k1) * wi) * wj;
                out[i + n * j] += x0 * (1.0 - wk) + x1 * wk;
            }
        }
    };
    if n >= PARALLEL_FROM_N {
        u.par_chunks_mut(n * n).enumerate().for_each(|(k, o)| plane(k, o));
    } else {
        u.chunks_mut(n * n).enumerate().for_each(|(k, o)| plane(k, o));
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
    scratch: Vec<DVec3>,
    residual: Vec<DVec3>,
    /// Coarse: R u, the coarse right-hand side, the coarse solution, its change.
    u_c0: Vec<DVec3>,
    g_c: Vec<DVec3>,
    u_c: Vec<DVec3>,
    e: Vec<DVec3>,
}

fn sized(v: &mut Vec<DVec3>, len: usize) -> &mut Vec<DVec3> {
    v.resize(len, DVec3::ZERO);
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
    u: &mut Vec<DVec3>,
    g: Option<&[DVec3]>,
    bufs: &mut [Buffers],
) {
    let level = &levels[l];
    let tau = plain_tau(reg, level.lattice.h_mm);
    let (b, below) = bufs.split_first_mut().expect("a buffer per level");
    let scratch = sized(&mut b.scratch, u.len());
    if l + 1 == levels.len() {
        let taus = match reg {
            Regulariser::Diffusion if s.fed_cycle_steps > 0 => {
                let cycle = fed_taus(s.fed_cycle_steps, 2.0 / reg.gershgorin(level.lattice.h_mm));
                let cycles = s.coarsest_steps.div_ceil(s.fed_cycle_steps) as usize;
                cycle.repeat(cycles)
            }
            _ => vec![tau; s.coarsest_steps as usize],
        };
        steps(level, reg, &taus, u, g, scratch);
        return;
    }
    steps(level, reg, &vec![tau; s.pre_steps as usize], u, g, scratch);
    let coarse = &levels[l + 1];
    let nc = coarse.lattice.len();
    let r = sized(&mut b.residual, u.len());
    residual(level, reg, u, g, r);
    let u_c0 = sized(&mut b.u_c0, nc);
    inject(&level.lattice, &coarse.lattice, u, u_c0);
    // g_c = A_c(R u) + R_fw(r): the coarse right-hand side of FAS.
    let g_c = sized(&mut b.g_c, nc);
    operator_of(coarse, reg, u_c0, g_c);
    r.iter_mut().for_each(|v| *v = -*v);
    subtract_restricted(&level.lattice, &coarse.lattice, r, g_c);
    let u_c = sized(&mut b.u_c, nc);
    u_c.copy_from_slice(u_c0);
    v_cycle(levels, l + 1, reg, s, u_c, Some(g_c), below);
    let e = sized(&mut b.e, nc);
    e.iter_mut()
        .zip(u_c.iter().zip(u_c0.iter()))
        .for_each(|(e, (a, b))| *e = *a - *b);
    prolong_add(level, &coarse.lattice, e, u);
    let scratch = sized(&mut b.scratch, u.len());
    steps(level, reg, &vec![tau; s.post_steps as usize], u, g, scratch);
}

/// Runs the schedule on `u` (Dirichlet values already in place) over `levels` (finest first).
/// `g` is the right-hand side on the finest level (None for the deformation itself; the
/// manufactured-solution tests pass one).
pub fn solve(levels: &[Level], reg: Regulariser, s: &Schedule, u: &mut Vec<DVec3>, g: Option<&[DVec3]>) {
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

/// `count` coarse levels below `finest` by injection (`levels` − 1 of them), finest first.
pub fn hierarchy(finest: Level, levels: u32) -> Vec<Level> {
    let mut out = vec![finest];
    while out.len() < levels as usize && out.last().is_some_and(|l| l.lattice.n >= 9) {
        let next = out.last().expect("non-empty").coarsen();
        out.push(next);
    }
    out
}
