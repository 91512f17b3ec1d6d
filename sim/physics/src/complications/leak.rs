//! The leak of one puncture: fluid or air through a hole of the needle's size into a compliant
//! space, until the space's pressure balances the source's or the hole seals (docs/complications.md).
//!
//! Orifice flow (Torricelli; the sharp-edged orifice of any fluid-mechanics text):
//!
//!   Q = C_d · A(t) · √(2 · Δp / ρ),   Δp = p_source − V / C,   A(t) = π d² / 4 · e^(−t_open / τ_seal)
//!
//! with C_d = 0.61, the hole's diameter d the needle's outer diameter, ρ the leaking medium's
//! density, C the compliance of the space it fills (tissue around a haematoma, the pleural space)
//! and τ_seal how fast the hole closes (clot, lung recoil). Integrated with explicit Euler steps
//! of the complications' sub-rate: V⁺ = V + Q·Δt. The volume never exceeds p_source · C, where the
//! flow stops.

/// Discharge coefficient of a sharp-edged orifice.
pub const DISCHARGE_COEFFICIENT: f64 = 0.61;

/// 1 mmHg and 1 cmH₂O in pascal.
pub const PA_PER_MMHG: f64 = 133.322;
pub const PA_PER_CMH2O: f64 = 98.0665;

/// One kind of leak's constants.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeakModel {
    /// Pressure driving the leak (Pa above the space it fills).
    pub source_pa: f64,
    /// Density of what leaks (kg/m³).
    pub density_kg_m3: f64,
    /// Compliance of the space it fills (ml/Pa).
    pub compliance_ml_per_pa: f64,
    /// Time constant of the hole's closing while it leaks (s).
    pub seal_time_s: f64,
    /// Holes narrower than this do not leak at all (mm): fine needles pass with impunity.
    pub min_hole_mm: f64,
    /// The needle in the hole closes it: the leak runs only once the needle has left the site.
    pub plugged_by_needle: bool,
}

impl LeakModel {
    /// Flow (ml/s) through a hole of `hole_mm` open for `open_s`, with `volume_ml` already out.
    pub fn rate_ml_per_s(&self, hole_mm: f64, open_s: f64, volume_ml: f64) -> f64 {
        let dp = self.source_pa - volume_ml / self.compliance_ml_per_pa;
        if dp <= 0.0 || hole_mm < self.min_hole_mm {
            return 0.0;
        }
        let d_m = hole_mm * 1e-3;
        let area_m2 = 0.25 * std::f64::consts::PI * d_m * d_m * libm::exp(-open_s / self.seal_time_s);
        DISCHARGE_COEFFICIENT * area_m2 * libm::sqrt(2.0 * dp / self.density_kg_m3) * 1e6
    }

    /// The volume at which the space's pressure balances the source's (ml).
    pub fn limit_ml(&self) -> f64 {
        self.source_pa * self.compliance_ml_per_pa
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const VEIN: LeakModel = LeakModel {
        source_pa: 8.0 * PA_PER_MMHG,
        density_kg_m3: 1060.0,
        compliance_ml_per_pa: 3.0 / PA_PER_MMHG,
        seal_time_s: 60.0,
        min_hole_mm: 1.0,
        plugged_by_needle: false,
    };

    #[test]
    fn an_18_gauge_hole_in_a_vein_bleeds_about_a_millilitre_a_second() {
        // 0.61 · π/4 · (1.27 mm)² · √(2 · 1067 Pa / 1060 kg/m³) = 1.09 ml/s.
        let q = VEIN.rate_ml_per_s(1.27, 0.0, 0.0);
        assert!((q - 1.09).abs() < 0.01, "{q}");
        // Area goes with d²: a 19 G hole (1.07 mm) bleeds (1.07/1.27)² as much.
        let q19 = VEIN.rate_ml_per_s(1.07, 0.0, 0.0);
        assert!((q19 / q - libm::pow(1.07 / 1.27, 2.0)).abs() < 1e-9);
    }

    #[test]
    fn the_flow_slows_as_the_hole_seals_and_stops_at_the_balance() {
        let q0 = VEIN.rate_ml_per_s(1.27, 0.0, 0.0);
        assert!((VEIN.rate_ml_per_s(1.27, 60.0, 0.0) / q0 - libm::exp(-1.0)).abs() < 1e-12);
        // Back pressure: a quarter of the way to the limit, √(3/4) of the flow.
        let quarter = 0.25 * VEIN.limit_ml();
        assert!((VEIN.rate_ml_per_s(1.27, 0.0, quarter) / q0 - 0.75f64.sqrt()).abs() < 1e-9);
        assert_eq!(VEIN.rate_ml_per_s(1.27, 0.0, VEIN.limit_ml()), 0.0);
        assert!((VEIN.limit_ml() - 24.0).abs() < 1e-9);
    }

    #[test]
    fn a_fine_needle_does_not_bleed() {
        assert_eq!(VEIN.rate_ml_per_s(0.72, 0.0, 0.0), 0.0);
    }
}
