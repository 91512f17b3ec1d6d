//! The material function of thesis eq. 4.2.17 with the "1 +" its printed equation lacks
//! (docs/deformation.md): f_mat(I) = 1 − 1 / (1 + e^{−k (I − s)}), a logistic step from 1 (soft
//! tissue, deforms freely) to 0 (hard tissue) around s HU. The thesis sets
//! s = (100 HU + 250 HU)/2 = 175 HU and k = 0.001 /HU, with which f_mat barely varies over the HU
//! range of soft tissue; k is exposed.

/// f_mat(`hu`) for steepness `k_per_hu` and midpoint `s_hu` (eq. 4.2.17).
#[inline]
pub fn f_mat(hu: f64, k_per_hu: f64, s_hu: f64) -> f64 {
    1.0 - 1.0 / (1.0 + libm::exp(-k_per_hu * (hu - s_hu)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn soft_is_one_hard_is_zero_and_the_midpoint_is_half() {
        assert!((f_mat(175.0, 0.02, 175.0) - 0.5).abs() < 1e-15);
        assert!(f_mat(-100.0, 0.02, 175.0) > 0.99);
        assert!(f_mat(1000.0, 0.02, 175.0) < 1e-6);
        // The thesis' k = 0.001: fat and liver differ by under 4 %.
        let d = f_mat(-100.0, 0.001, 175.0) - f_mat(60.0, 0.001, 175.0);
        assert!(d > 0.0 && d < 0.04, "{d}");
    }
}
