//! The regularisers ∇S of thesis §4.2.3 discretised by central differences on the
//! 26-neighbourhood (eq. 4.2.20), for an interior node of a lattice with spacing h:
//!
//! - diffusion (eq. 4.2.13, without its constant factor ½, which only rescales pseudo-time):
//!   L u = Δu, Δu ≈ (Σ_faces u_n − 6 u) / h²;
//! - linear elasticity, the Navier–Lamé operator (eq. 4.2.15): L u = μ Δu + (λ + μ) ∇(∇·u),
//!   with ∂²u_a/∂x_a² ≈ (u(+e_a) − 2u + u(−e_a))/h² and the mixed
//!   ∂²u_b/∂x_a∂x_b ≈ (u(+a+b) − u(+a−b) − u(−a+b) + u(−a−b)) / 4h² over the edge neighbours.
//!
//! Both are second-order accurate. The material function multiplies the operator (eqs. 4.2.18–
//! 4.2.19: "the general process can be inhibited"), so A u = f_mat·L u.
//!
//! The boundary conditions are displacements only (eqs. 4.2.5–4.2.7), so the steady field of the
//! elastic operator depends on the ratio λ/μ alone, that is on Poisson's ratio ν = λ/(2(λ+μ)):
//! we set μ = 1 and λ = 2ν/(1 − 2ν). Young's modulus would only matter with force conditions.

use glam::DVec3;

/// Which regulariser ∇S the solve minimises (thesis §4.2.3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Regulariser {
    /// Δu (eq. 4.2.13).
    Diffusion,
    /// μΔu + (λ+μ)∇(∇·u) with μ = 1 and λ from Poisson's ratio (eq. 4.2.15).
    LinearElastic { poisson_ratio: f64 },
}

impl Regulariser {
    /// (μ, λ + μ) of the operator.
    pub fn lame(&self) -> (f64, f64) {
        match *self {
            Regulariser::Diffusion => (1.0, 0.0),
            Regulariser::LinearElastic { poisson_ratio: nu } => {
                let lambda = 2.0 * nu / (1.0 - 2.0 * nu);
                (1.0, lambda + 1.0)
            }
        }
    }

    /// Checks the parameters: ν in [0, 0.49] (0.5 is incompressible and the operator singular).
    pub fn validate(&self) -> Result<(), crate::SettingsError> {
        if let Regulariser::LinearElastic { poisson_ratio } = *self
            && !(0.0..=0.49).contains(&poisson_ratio)
        {
            return Err(crate::SettingsError::Deformation {
                setting: "poisson_ratio",
                reason: format!("Poisson's ratio {poisson_ratio} must lie in 0 … 0.49"),
            });
        }
        Ok(())
    }

    /// Gershgorin bound of the spectral radius of L on a lattice of spacing `h_mm` (the sum of
    /// the absolute stencil weights of one row): explicit steps τ < 2 / bound are stable.
    pub fn gershgorin(&self, h_mm: f64) -> f64 {
        let (mu, lm) = self.lame();
        (12.0 * mu + 6.0 * lm) / (h_mm * h_mm)
    }
}

/// L u at the interior node `c` of a lattice with `n` nodes per axis (`inv_h2` = 1/h²); `mu`,
/// `lm` = μ, λ+μ (from [`Regulariser::lame`]).
///
/// # Panics
/// If `c` is not an interior node (a neighbour would lie outside `u`).
#[inline(always)]
pub fn apply(u: &[DVec3], n: usize, c: usize, inv_h2: f64, mu: f64, lm: f64) -> DVec3 {
    let (sx, sy, sz) = (1, n, n * n);
    // The farthest neighbours (edge neighbours ±(sy + sz)) lie inside `u`: one check for all.
    assert!(c >= sy + sz && c + sy + sz < u.len(), "node {c} is not interior");
    // SAFETY: every offset below is at most sy + sz from c, checked above.
    let at = |i: usize| unsafe { *u.get_unchecked(i) };
    let uc = at(c);
    let two_c = uc + uc;
    // Second differences along each axis (all components).
    let dxx = at(c + sx) + at(c - sx) - two_c;
    let dyy = at(c + sy) + at(c - sy) - two_c;
    let dzz = at(c + sz) + at(c - sz) - two_c;
    let lap = dxx + dyy + dzz;
    if lm == 0.0 {
        return lap * (mu * inv_h2);
    }
    // Mixed second differences over the 12 edge neighbours.
    let mixed = |a: usize, b: usize| (at(c + a + b) - at(c + a - b)) - (at(c - a + b) - at(c - a - b));
    let dxy = mixed(sx, sy) * 0.25;
    let dxz = mixed(sx, sz) * 0.25;
    let dyz = mixed(sy, sz) * 0.25;
    let grad_div = DVec3::new(dxx.x + dxy.y + dxz.z, dxy.x + dyy.y + dyz.z, dxz.x + dyz.y + dzz.z);
    (lap * mu + grad_div * lm) * inv_h2
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deform::lattice::Lattice;

    /// The operator applied to u(x) = sin-like smooth field, against its exact value: the error
    /// falls by ≈ 4 when h halves (second order), for both regularisers.
    #[test]
    fn both_operators_are_second_order() {
        // u = (sin x cos y, sin y cos z, sin z cos x) (x in rad = mm / 10).
        let u_exact = |p: DVec3| {
            let p = p / 10.0;
            DVec3::new(
                libm::sin(p.x) * libm::cos(p.y),
                libm::sin(p.y) * libm::cos(p.z),
                libm::sin(p.z) * libm::cos(p.x),
            )
        };
        // Exact operators (chain rule, then the 1/100 from the scaling).
        let lap_exact = |p: DVec3| -2.0 * u_exact(p) / 100.0;
        let grad_div_exact = |p: DVec3| {
            let q = p / 10.0;
            let (sx, cx, sy, cy, sz, cz) = (
                libm::sin(q.x),
                libm::cos(q.x),
                libm::sin(q.y),
                libm::cos(q.y),
                libm::sin(q.z),
                libm::cos(q.z),
            );
            // div u = cos x cos y + cos y cos z + cos z cos x.
            DVec3::new(-sx * cy - cz * sx, -cx * sy - sy * cz, -cy * sz - sz * cx) / 100.0
        };
        for reg in [
            Regulariser::Diffusion,
            Regulariser::LinearElastic { poisson_ratio: 0.45 },
        ] {
            let (mu, lm) = reg.lame();
            let exact = |p: DVec3| lap_exact(p) * mu + grad_div_exact(p) * lm;
            let mut errors = Vec::new();
            for h in [2.0, 1.0, 0.5] {
                let n = 9;
                let centre = DVec3::new(3.0, -2.0, 5.0);
                let l = Lattice {
                    n,
                    h_mm: h,
                    origin_mm: centre - DVec3::splat(4.0 * h),
                };
                let f: Vec<DVec3> = (0..l.len())
                    .map(|i| {
                        let [a, b, c] = l.ijk(i);
                        u_exact(l.position(a, b, c))
                    })
                    .collect();
                let got = apply(&f, n, l.index(4, 4, 4), 1.0 / (h * h), mu, lm);
                errors.push((got - exact(centre)).length());
            }
            for w in errors.windows(2) {
                let order = libm::log2(w[0] / w[1]);
                assert!(order > 1.9 && order < 2.1, "{reg:?}: errors {errors:?}");
            }
        }
    }

    #[test]
    fn poisson_ratio_is_checked() {
        assert!(Regulariser::LinearElastic { poisson_ratio: 0.5 }.validate().is_err());
        assert!(Regulariser::LinearElastic { poisson_ratio: 0.45 }.validate().is_ok());
        assert!(Regulariser::Diffusion.validate().is_ok());
    }
}
