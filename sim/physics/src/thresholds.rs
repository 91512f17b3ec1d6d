//! Estimation of the heuristic's HU thresholds from the CT histogram, for atlases that give none
//! (thesis §6.1.2: "thresholds … have to be estimated … based on the image data").
//!
//! - t_air→skin: Otsu's threshold between air (and lung) and tissue, on −1100 … 300 HU.
//! - t_skin→fat: halfway between t_air→skin and the fat peak (the mode on −250 … −30 HU), so all
//!   of the fat peak is fat and only partial-volume voxels at the body surface are skin.
//! - t_fat→bone: the soft-tissue peak (mode on −30 … 120 HU) plus [`BONE_MARGIN_HU`], but never
//!   below [`MIN_FAT_BONE_HU`]: cancellous bone starts around 150–200 HU, enhanced vessels reach
//!   150–200 HU as well; the partial labels take precedence for the labelled vessels.

use crate::{PhysicsError, Thresholds, Volume};

/// Added to the soft-tissue peak to find the bone threshold.
pub const BONE_MARGIN_HU: f64 = 150.0;
/// Lowest bone threshold the estimator returns.
pub const MIN_FAT_BONE_HU: f64 = 180.0;
/// δ of eq. 6.1.1 when the atlas gives none: deeper than the skin and subcutaneous fat of a slim
/// patient, shallower than the intercostal space.
pub const DEFAULT_RISK_DEPTH_MM: f64 = 15.0;

const LO_HU: i32 = -1100;
const HI_HU: i32 = 3000;

/// Histogram of CT values in 1 HU bins from −1100 to 3000 HU (values beyond are clamped).
#[derive(Debug, Clone)]
pub struct Histogram {
    counts: Vec<u64>,
}

impl Histogram {
    pub fn of(ct: &Volume<f32>) -> Self {
        let mut counts = vec![0u64; (HI_HU - LO_HU + 1) as usize];
        for &v in ct.data() {
            let b = (v.round() as i64).clamp(LO_HU as i64, HI_HU as i64) - LO_HU as i64;
            counts[b as usize] += 1;
        }
        Histogram { counts }
    }

    fn bin(hu: i32) -> usize {
        (hu.clamp(LO_HU, HI_HU) - LO_HU) as usize
    }

    /// Number of values in [lo, hi) HU.
    pub fn count(&self, lo: i32, hi: i32) -> u64 {
        self.counts[Self::bin(lo)..Self::bin(hi)].iter().sum()
    }

    /// Otsu's threshold on [lo, hi): the HU that maximises the between-class variance.
    pub fn otsu(&self, lo: i32, hi: i32) -> Option<f64> {
        let (a, b) = (Self::bin(lo), Self::bin(hi));
        let total: f64 = self.counts[a..b].iter().map(|&c| c as f64).sum();
        if total == 0.0 {
            return None;
        }
        let sum_all: f64 = (a..b).map(|i| i as f64 * self.counts[i] as f64).sum();
        let (mut w0, mut s0) = (0.0, 0.0);
        let mut best = (f64::NEG_INFINITY, None);
        for t in a..b {
            w0 += self.counts[t] as f64;
            s0 += t as f64 * self.counts[t] as f64;
            let w1 = total - w0;
            if w0 == 0.0 || w1 == 0.0 {
                continue;
            }
            let m0 = s0 / w0;
            let m1 = (sum_all - s0) / w1;
            let var = w0 * w1 * (m0 - m1) * (m0 - m1);
            if var > best.0 {
                best = (var, Some(t));
            }
        }
        // Threshold between bin t (class 0) and t + 1 (class 1).
        best.1.map(|t| (t as i32 + LO_HU) as f64 + 1.0)
    }

    /// The most frequent HU on [lo, hi] after smoothing with a ±10 HU box, if any value is there.
    pub fn mode(&self, lo: i32, hi: i32) -> Option<f64> {
        let mut best = (0u64, None);
        for hu in lo..=hi {
            let s = self.count(hu - 10, hu + 11);
            if s > best.0 {
                best = (s, Some(hu as f64));
            }
        }
        best.1
    }
}

/// Estimates the thresholds of eq. 6.1.1 from the CT values.
pub fn estimate_thresholds(ct: &Volume<f32>, risk_depth_mm: f64) -> Result<Thresholds, PhysicsError> {
    let h = Histogram::of(ct);
    let air_skin = h.otsu(-1100, 300).ok_or_else(|| {
        PhysicsError::InvalidThresholds("cannot estimate thresholds: no CT values between −1100 and 300 HU".into())
    })?;
    if h.count(-1100, air_skin as i32) == 0 || h.count(air_skin as i32, 3001) == 0 {
        return Err(PhysicsError::InvalidThresholds(
            "cannot estimate thresholds: the CT has no air/tissue contrast (is it a CT in HU?)".into(),
        ));
    }
    let fat_peak = h.mode(-250, -30).unwrap_or(-100.0);
    let skin_fat = ((air_skin + fat_peak) / 2.0).round();
    let soft_peak = h.mode(-30, 120).unwrap_or(40.0);
    let fat_bone = (soft_peak + BONE_MARGIN_HU).max(MIN_FAT_BONE_HU).round();
    let t = Thresholds {
        air_skin_hu: air_skin.round(),
        skin_fat_hu: skin_fat,
        fat_bone_hu: fat_bone,
        risk_depth_mm,
    };
    t.validate()?;
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Affine, Grid};
    use glam::DVec3;

    #[test]
    fn thresholds_separate_synthetic_tissue_classes() {
        // 40 % air, 20 % fat, 35 % muscle, 5 % bone with a little spread.
        let n = 10_000;
        let grid = Grid::new([n, 1, 1], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let data: Vec<f32> = (0..n)
            .map(|i| {
                let jitter = ((i * 37) % 41) as f32 - 20.0;
                match i % 20 {
                    0..=7 => -1000.0 + jitter,
                    8..=11 => -100.0 + jitter,
                    12..=18 => 45.0 + jitter,
                    _ => 700.0 + 10.0 * jitter,
                }
            })
            .collect();
        let ct = Volume::new(grid, data).unwrap();
        let t = estimate_thresholds(&ct, 15.0).unwrap();
        assert!(t.air_skin_hu > -980.0 && t.air_skin_hu < -120.0, "{t:?}");
        assert!(t.skin_fat_hu > t.air_skin_hu && t.skin_fat_hu < -120.0, "{t:?}");
        assert!((180.0..=215.0).contains(&t.fat_bone_hu), "{t:?}");
    }

    #[test]
    fn a_uniform_image_has_no_thresholds() {
        let grid = Grid::new([10, 10, 10], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let ct = Volume::filled(grid, 40.0f32);
        assert!(estimate_thresholds(&ct, 15.0).is_err());
    }
}
