//! The needle's deterministic rod model (instead of the thesis' Bullet rigid bodies, §3.5.2;
//! docs/physics.md): an Euler–Bernoulli beam of m equidistant nodes in a co-rotational frame,
//! lateral deflections w_j (two components) about a reference axis, solved exactly each tick.
//!
//! Energy: E = (EI / h³) Σ_j |w_{j−1} − 2 w_j + w_{j+1}|² / 2 + Σ_j k_j |w_j − t_j|² / 2 − Σ_j f_j·w_j,
//! the second difference being the discrete curvature times h². Its minimum solves the symmetric
//! positive-definite pentadiagonal system
//!
//!   ((EI / h³) DᵀD + diag(k)) w = diag(k) t + f,
//!
//! with D the second-difference operator (free ends: no moment, no shear). The springs k_j are the
//! virtual springs of §3.5.2 (tissue at the path, the hand at the hub); f_j are external loads. The
//! LDLᵀ factorisation of a band of width 2 is O(m), has no iteration count to tune and gives the
//! same bits on every run. Small-slope theory: valid while slopes stay below about 0.3 rad.

/// Lateral deflection of one node: two components in the plane perpendicular to the axis.
pub type Lateral = [f64; 2];

/// Reusable buffers for [`solve`] (no allocation in the 1 kHz loop).
#[derive(Debug, Clone, Default)]
pub struct BeamScratch {
    a0: Vec<f64>,
    a1: Vec<f64>,
    a2: Vec<f64>,
    d: Vec<f64>,
    l1: Vec<f64>,
    l2: Vec<f64>,
    rhs: Vec<Lateral>,
    /// What the factorisation in `d`, `l1`, `l2` is of, when it succeeded: the bits of `ei`,
    /// `h` and every `k`. The springs rarely change from one tick to the next (they change when
    /// a node crosses into other tissue), and the same inputs give the same factors, so
    /// [`solve`] then skips straight to the substitutions with the same bits.
    factored: Option<(u64, u64)>,
    factored_k: Vec<u64>,
}

impl BeamScratch {
    /// Whether `d`, `l1`, `l2` hold the factorisation for exactly these inputs.
    fn holds_factors_of(&self, ei: f64, h: f64, k: &[f64]) -> bool {
        self.factored == Some((ei.to_bits(), h.to_bits()))
            && self.factored_k.len() == k.len()
            && self.factored_k.iter().zip(k).all(|(&a, b)| a == b.to_bits())
    }
}

/// Solves for the deflections `out` (len m) given per-node spring stiffness `k` (N/mm), spring
/// targets `target` (mm) and loads `load` (N), for a beam of rigidity `ei` (N·mm²) and node
/// spacing `h` (mm). Needs enough springs to hold the beam (at least two nodes, or one node with a
/// rotational hold through its neighbour); returns false for a singular system.
pub fn solve(
    ei: f64,
    h: f64,
    k: &[f64],
    target: &[Lateral],
    load: &[Lateral],
    out: &mut [Lateral],
    s: &mut BeamScratch,
) -> bool {
    let m = k.len();
    debug_assert!(target.len() == m && load.len() == m && out.len() == m);
    if m == 0 {
        return true;
    }
    let (target, load, out) = (&target[..m], &load[..m], &mut out[..m]);
    if !s.holds_factors_of(ei, h, k) {
        s.factored = None;
        if !factor(ei, h, k, s) {
            return false;
        }
        s.factored = Some((ei.to_bits(), h.to_bits()));
        s.factored_k.clear();
        s.factored_k.extend(k.iter().map(|v| v.to_bits()));
    }
    substitute(k, target, load, out, s);
    true
}

/// The LDLᵀ factorisation of A = c·DᵀD + diag(k) into `s.d`, `s.l1`, `s.l2` (len m = k.len() ≥ 1);
/// false when A is not safely positive definite.
fn factor(ei: f64, h: f64, k: &[f64], s: &mut BeamScratch) -> bool {
    let m = k.len();
    let c = ei / (h * h * h);
    // The three bands of A = c·DᵀD + diag(k): a0[j] = A(j, j), a1[j] = A(j, j+1), a2[j] = A(j, j+2).
    // (Loops are peeled so the hot path has no branches or bounds checks; the arithmetic and its
    // order are those of the plain textbook loops, so the bits are too.)
    for v in [&mut s.a0, &mut s.a1, &mut s.a2, &mut s.d, &mut s.l1, &mut s.l2] {
        v.resize(m, 0.0);
    }
    s.rhs.resize(m, [0.0; 2]);
    let (a0, a1, a2) = (&mut s.a0[..m], &mut s.a1[..m], &mut s.a2[..m]);
    a0.copy_from_slice(k);
    a1.fill(0.0);
    a2.fill(0.0);
    for r in 1..m.saturating_sub(1) {
        // Row r of D: (1, −2, 1) at columns r−1, r, r+1.
        a0[r - 1] += c;
        a0[r] += 4.0 * c;
        a0[r + 1] += c;
        a1[r - 1] -= 2.0 * c;
        a1[r] -= 2.0 * c;
        a2[r - 1] += c;
    }
    // LDLᵀ: l1[j] = L(j, j−1), l2[j] = L(j, j−2), d[j] = D_j.
    let (d, l1, l2) = (&mut s.d[..m], &mut s.l1[..m], &mut s.l2[..m]);
    let positive = |dj: f64, a: f64| dj.is_finite() && dj > 1e-9 * a.abs().max(1e-300);
    if !positive(a0[0], a0[0]) {
        return false;
    }
    d[0] = a0[0];
    if m >= 2 {
        l1[1] = a1[0] / d[0];
        let d1 = a0[1] - l1[1] * l1[1] * d[0];
        if !positive(d1, a0[1]) {
            return false;
        }
        d[1] = d1;
    }
    for j in 2..m {
        let l2j = a2[j - 2] / d[j - 2];
        let l1j = (a1[j - 1] - l2j * l1[j - 1] * d[j - 2]) / d[j - 1];
        let dj = a0[j] - l1j * l1j * d[j - 1] - l2j * l2j * d[j - 2];
        if !positive(dj, a0[j]) {
            return false;
        }
        (l1[j], l2[j], d[j]) = (l1j, l2j, dj);
    }
    true
}

/// Solves L D Lᵀ w = diag(k) t + f into `out` with the factors in `s` (from [`factor`]).
fn substitute(k: &[f64], target: &[Lateral], load: &[Lateral], out: &mut [Lateral], s: &mut BeamScratch) {
    let m = k.len();
    let (d, l1, l2) = (&s.d[..m], &s.l1[..m], &s.l2[..m]);
    // Forward substitution L y = b.
    let y = &mut s.rhs[..m];
    let b = |j: usize| [k[j] * target[j][0] + load[j][0], k[j] * target[j][1] + load[j][1]];
    y[0] = b(0);
    if m >= 2 {
        let b1 = b(1);
        y[1] = [b1[0] - l1[1] * y[0][0], b1[1] - l1[1] * y[0][1]];
    }
    for j in 2..m {
        let bj = b(j);
        y[j] = [
            bj[0] - l1[j] * y[j - 1][0] - l2[j] * y[j - 2][0],
            bj[1] - l1[j] * y[j - 1][1] - l2[j] * y[j - 2][1],
        ];
    }
    // D z = y, then Lᵀ w = z.
    let last = m - 1;
    out[last] = [y[last][0] / d[last], y[last][1] / d[last]];
    if m >= 2 {
        let j = m - 2;
        out[j] = [
            y[j][0] / d[j] - l1[j + 1] * out[j + 1][0],
            y[j][1] / d[j] - l1[j + 1] * out[j + 1][1],
        ];
    }
    for j in (0..m.saturating_sub(2)).rev() {
        out[j] = [
            y[j][0] / d[j] - l1[j + 1] * out[j + 1][0] - l2[j + 2] * out[j + 2][0],
            y[j][1] / d[j] - l1[j + 1] * out[j + 1][1] - l2[j + 2] * out[j + 2][1],
        ];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dense reference: assemble A and solve by Gaussian elimination.
    fn dense(ei: f64, h: f64, k: &[f64], rhs: &[f64]) -> Vec<f64> {
        let m = k.len();
        let c = ei / (h * h * h);
        let mut a = vec![vec![0.0; m]; m];
        for (j, kj) in k.iter().enumerate() {
            a[j][j] += kj;
        }
        for r in 1..m - 1 {
            let coef = [(r - 1, 1.0), (r, -2.0), (r + 1, 1.0)];
            for &(i, ci) in &coef {
                for &(jj, cj) in &coef {
                    a[i][jj] += c * ci * cj;
                }
            }
        }
        let mut b = rhs.to_vec();
        for col in 0..m {
            for row in col + 1..m {
                let f = a[row][col] / a[col][col];
                for cc in col..m {
                    a[row][cc] -= f * a[col][cc];
                }
                b[row] -= f * b[col];
            }
        }
        let mut x = vec![0.0; m];
        for row in (0..m).rev() {
            let mut v = b[row];
            for cc in row + 1..m {
                v -= a[row][cc] * x[cc];
            }
            x[row] = v / a[row][row];
        }
        x
    }

    #[test]
    fn band_solver_matches_dense_elimination() {
        let m = 9;
        let k: Vec<f64> = (0..m)
            .map(|j| if j == 0 || j == m - 1 { 50.0 } else { 0.3 * j as f64 })
            .collect();
        let target: Vec<Lateral> = (0..m)
            .map(|j| [libm::sin(j as f64 * 0.7), libm::cos(j as f64)])
            .collect();
        let load: Vec<Lateral> = (0..m).map(|j| [0.01 * j as f64, -0.02]).collect();
        let mut out = vec![[0.0; 2]; m];
        assert!(solve(
            3000.0,
            5.0,
            &k,
            &target,
            &load,
            &mut out,
            &mut BeamScratch::default()
        ));
        for comp in 0..2 {
            let rhs: Vec<f64> = (0..m).map(|j| k[j] * target[j][comp] + load[j][comp]).collect();
            let x = dense(3000.0, 5.0, &k, &rhs);
            for j in 0..m {
                assert!(
                    (x[j] - out[j][comp]).abs() < 1e-9 * (1.0 + x[j].abs()),
                    "{j}: {} vs {}",
                    x[j],
                    out[j][comp]
                );
            }
        }
    }

    /// A cantilever (two nodes clamped) with a tip load follows δ = F L³ / (3 EI). Holding nodes 0
    /// and 1 clamps the beam halfway between them, so the free length is (m − 1.5) h.
    #[test]
    fn cantilever_matches_beam_theory() {
        let (ei, len, f, m) = (57_000.0, 165.0, 0.5, 34);
        let h = len / (m as f64 - 1.5);
        let mut k = vec![0.0; m];
        k[0] = 1e9;
        k[1] = 1e9;
        let target = vec![[0.0; 2]; m];
        let mut load = vec![[0.0; 2]; m];
        load[m - 1] = [f, 0.0];
        let mut out = vec![[0.0; 2]; m];
        assert!(solve(ei, h, &k, &target, &load, &mut out, &mut BeamScratch::default()));
        let expect = f * len * len * len / (3.0 * ei);
        let got = out[m - 1][0];
        assert!((got - expect).abs() / expect < 0.001, "{got} vs {expect}");
    }

    #[test]
    fn an_unheld_beam_is_singular() {
        let m = 5;
        let mut out = vec![[0.0; 2]; m];
        assert!(!solve(
            1000.0,
            5.0,
            &[0.0; 5],
            &[[0.0; 2]; 5],
            &[[0.0; 2]; 5],
            &mut out,
            &mut BeamScratch::default()
        ));
    }

    /// A scratch reused across solves (the needle's, tick after tick) gives the bits of a fresh
    /// one: whether its factors are reused (same springs), redone (one spring changed, another
    /// node count, another rigidity) or refused (an unheld beam), and after a refusal.
    #[test]
    fn reused_factors_give_the_bits_of_a_fresh_solve() {
        let mut rng = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            rng = crate::motion::signal::mix64(rng);
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut shared = BeamScratch::default();
        let mut k: Vec<f64> = (0..31).map(|j| if j < 2 { 50.0 } else { 0.4 }).collect();
        let (mut reused, mut changed) = (0, 0);
        for step in 0..400 {
            let mut ei = 2.0e5;
            match step % 10 {
                // The springs as the needle advances: one node meets other tissue.
                3 => {
                    let j = 2 + (next() * 29.0) as usize;
                    k[j] = 0.1 + 2.0 * next();
                    changed += 1;
                }
                // Another needle.
                7 if step % 20 == 7 => ei = 1.5e5,
                _ => reused += 1,
            }
            // Now and then a beam nothing holds, and one node fewer.
            let (ks, m): (Vec<f64>, usize) = match step % 37 {
                11 => (vec![0.0; k.len()], k.len()),
                19 => (k[..30].to_vec(), 30),
                _ => (k.clone(), k.len()),
            };
            let target: Vec<Lateral> = (0..m).map(|_| [next() - 0.5, 2.0 * next() - 1.0]).collect();
            let load: Vec<Lateral> = (0..m).map(|_| [0.01 * (next() - 0.5), 0.0]).collect();
            let (mut a, mut b) = (vec![[0.0; 2]; m], vec![[0.0; 2]; m]);
            let ok_shared = solve(ei, 5.0, &ks, &target, &load, &mut a, &mut shared);
            let ok_fresh = solve(ei, 5.0, &ks, &target, &load, &mut b, &mut BeamScratch::default());
            assert_eq!(ok_shared, ok_fresh, "step {step}");
            let bits = |w: &[Lateral]| w.iter().flat_map(|l| l.map(f64::to_bits)).collect::<Vec<_>>();
            assert_eq!(bits(&a), bits(&b), "step {step}");
        }
        assert!(reused > 300 && changed > 30);
    }
}
