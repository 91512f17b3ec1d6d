//! Needle types: gauge, length, stylet, and the flexural rigidity EI calibrated on the thesis'
//! cantilever measurements (Table A.1; docs/physics.md "Needle stiffness").
//!
//! Small-deflection beam theory gives the tip deflection of a cantilever of length L under a tip
//! force F as δ = F L³ / (3 EI). Table A.1 (base in a vise, spring scale at the tip):
//!
//! | needle | L | F → δ |
//! |---|---|---|
//! | 16 G with stylet | 165 mm | 0.25 N → 6, 0.5 → 13, 0.75 → 20, 1.0 → 26, 1.25 → 33 mm |
//! | 16 G without stylet | 165 mm | 0.25 → 13, 0.5 → 26, 0.75 → 38 mm |
//! | 20 G with stylet | 200 mm | 0.05 → 13, 0.1 → 41, 0.15 → 53, 0.2 → 69 mm |
//!
//! Each series is fitted by least squares through the origin, compliance c = Σ F δ / Σ F², EI =
//! L³ / (3 c): 57 033 and 29 278 N·mm² for 16 G with and without its stylet, 7 547 N·mm² for
//! 20 G. Every load point counts: the smallest (0.05 N, 5 gram-force, where a spring scale reads
//! worst) is the 20 G series' outlier, 36 % stiffer than the fit; calibrating on it alone, as an
//! earlier version did, made the 20 G needle 1.5 times stiffer than a solid steel rod of its
//! diameter, which no needle can be. A steel tube of the nominal gauge (E = 200 000 N/mm²,
//! EI = E π (D⁴ − d⁴) / 64) gives 52 990 (16 G) and 5 378 N·mm² (20 G); a solid rod of the outer
//! diameter, the bound a lumen-filling stylet approaches, 72 944 and 6 676: the fits lie between
//! tube and rod for 16 G and 13 % above the rod for 20 G (the table's lengths are "ca.").
//!
//! 18 G, between the measured gauges, follows the power law in the outer diameter through them
//! (exponent 3.38, near the geometric 4). 22 G lies below both: it keeps the 20 G needle's ratio
//! to its geometry, EI ∝ D⁴ from 20 G (a power law extrapolated past its data would make thinner
//! needles ever stiffer than steel). Every gauge loses the same share of rigidity without its
//! stylet as the 16 G does (0.513; tube theory would say 0.73–0.89, but the measurement is the
//! only one there is).

/// Needle gauges Stylet simulates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Gauge {
    G16,
    G18,
    G20,
    G22,
}

impl Gauge {
    pub const ALL: [Gauge; 4] = [Gauge::G16, Gauge::G18, Gauge::G20, Gauge::G22];

    pub fn from_number(n: u32) -> Option<Gauge> {
        match n {
            16 => Some(Gauge::G16),
            18 => Some(Gauge::G18),
            20 => Some(Gauge::G20),
            22 => Some(Gauge::G22),
            _ => None,
        }
    }

    pub fn number(self) -> u32 {
        match self {
            Gauge::G16 => 16,
            Gauge::G18 => 18,
            Gauge::G20 => 20,
            Gauge::G22 => 22,
        }
    }

    /// Nominal outer diameter (mm), ISO 9626.
    pub fn outer_diameter_mm(self) -> f64 {
        match self {
            Gauge::G16 => 1.651,
            Gauge::G18 => 1.270,
            Gauge::G20 => 0.908,
            Gauge::G22 => 0.718,
        }
    }

    /// Flexural rigidity EI (N·mm²) with or without the stylet (see the module documentation).
    pub fn flexural_rigidity_nmm2(self, stylet_in: bool) -> f64 {
        let d16 = Gauge::G16.outer_diameter_mm();
        let d20 = Gauge::G20.outer_diameter_mm();
        let with_stylet = match self {
            Gauge::G16 => EI_16G_STYLET,
            Gauge::G20 => EI_20G_STYLET,
            // Between the measured gauges: EI ∝ D^α through both.
            Gauge::G18 => {
                let alpha = libm::log(EI_16G_STYLET / EI_20G_STYLET) / libm::log(d16 / d20);
                EI_16G_STYLET * libm::pow(Gauge::G18.outer_diameter_mm() / d16, alpha)
            }
            // Below them: the 20 G needle's ratio to its geometry, EI ∝ D⁴.
            Gauge::G22 => EI_20G_STYLET * libm::pow(Gauge::G22.outer_diameter_mm() / d20, 4.0),
        };
        if stylet_in {
            with_stylet
        } else {
            with_stylet * (EI_16G_NO_STYLET / EI_16G_STYLET)
        }
    }
}

/// Least-squares fit of 16 G with stylet: Σ F δ / Σ F² = 26.25 mm/N over 165 mm.
pub const EI_16G_STYLET: f64 = 165.0 * 165.0 * 165.0 / (3.0 * (90.25 / 3.4375));
/// Least-squares fit of 16 G without stylet: 51.14 mm/N over 165 mm.
pub const EI_16G_NO_STYLET: f64 = 165.0 * 165.0 * 165.0 / (3.0 * (44.75 / 0.875));
/// Least-squares fit of 20 G with stylet: Σ F δ / Σ F² = 26.5 / 0.075 = 353.3 mm/N over 200 mm.
pub const EI_20G_STYLET: f64 = 200.0 * 200.0 * 200.0 / (3.0 * (26.5 / 0.075));

/// A needle: gauge and shaft length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeedleSpec {
    pub gauge: Gauge,
    /// Shaft length l̄ from hub to tip (mm).
    pub length_mm: f64,
}

impl NeedleSpec {
    /// A 150 mm needle (PTCD needles such as the Chiba needle are 150–200 mm).
    pub fn new(gauge: Gauge) -> Self {
        NeedleSpec {
            gauge,
            length_mm: 150.0,
        }
    }

    /// Refuses a shaft length outside 20 … 400 mm.
    pub fn validate(&self) -> Result<(), crate::SettingsError> {
        if !(self.length_mm.is_finite() && (20.0..=400.0).contains(&self.length_mm)) {
            return Err(crate::SettingsError::NeedleLength(self.length_mm));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibrated_values() {
        assert!((EI_16G_STYLET - 57_033.0).abs() < 1.0, "{EI_16G_STYLET}");
        assert!((EI_16G_NO_STYLET - 29_279.0).abs() < 1.0, "{EI_16G_NO_STYLET}");
        assert!((EI_20G_STYLET - 7_547.2).abs() < 0.1, "{EI_20G_STYLET}");
        // Thinner needles bend more; removing the stylet roughly halves the rigidity.
        let ei: Vec<f64> = Gauge::ALL.iter().map(|g| g.flexural_rigidity_nmm2(true)).collect();
        assert!(ei.windows(2).all(|w| w[0] > w[1]), "{ei:?}");
        let r = Gauge::G18.flexural_rigidity_nmm2(false) / Gauge::G18.flexural_rigidity_nmm2(true);
        assert!((r - 0.513).abs() < 0.01, "{r}");
        // 18 G: 57 033 · (1.270 / 1.651)^3.383 = 23 480; 22 G: 7 547 · (0.718 / 0.908)⁴ = 2 951.
        assert!((ei[1] - 23_480.0).abs() < 5.0, "{}", ei[1]);
        assert!((ei[3] - 2_951.0).abs() < 2.0, "{}", ei[3]);
    }

    /// A steel tube of the nominal gauge (E = 200 000 N/mm², nominal regular-wall diameters)
    /// and a solid rod of its outer diameter (the bound a stylet filling the lumen approaches):
    /// every needle with its stylet lies above the tube and below 1.15 rods.
    #[test]
    fn rigidities_are_those_of_steel_needles() {
        let steel =
            |d: f64, inner: f64| 200_000.0 * std::f64::consts::PI * (libm::pow(d, 4.0) - libm::pow(inner, 4.0)) / 64.0;
        for (g, inner_mm) in [
            (Gauge::G16, 1.194),
            (Gauge::G18, 0.838),
            (Gauge::G20, 0.603),
            (Gauge::G22, 0.413),
        ] {
            let d = g.outer_diameter_mm();
            let (tube, rod) = (steel(d, inner_mm), steel(d, 0.0));
            let ei = g.flexural_rigidity_nmm2(true);
            println!(
                "{} G: EI {ei:.0} N·mm², tube {tube:.0} ({:.2}×), rod {rod:.0} ({:.2}×)",
                g.number(),
                ei / tube,
                ei / rod
            );
            assert!(
                ei > tube && ei < 1.15 * rod,
                "{} G: {ei} vs tube {tube}, rod {rod}",
                g.number()
            );
        }
    }
}
