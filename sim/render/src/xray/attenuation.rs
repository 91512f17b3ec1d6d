//! Linear attenuation coefficients at 100 keV (thesis §3.3; docs/xray.md "Attenuation"), and the
//! contrast medium as an iodine overlay on the CT's own grid.
//!
//! Tissue: μ = μ_water·(1 + HU/1000) with μ_water = 0.17 cm⁻¹ (the thesis prints m⁻¹, an OCR or
//! typesetting slip: water halves a 100 keV beam in ≈ 4 cm). CT values below −1000 HU (the
//! scanner's padding outside its field of view) count as air, μ = 0.
//! Iodine: μ_c = (μ/ρ)_I · ρ_I with (μ/ρ)_I = 1.942 cm²/g at 100 keV and ρ_I the iodine mass
//! per volume; a node of the contrast grid that holds the volume fraction f of a medium with
//! c mg iodine per ml has ρ_I = f·c/1000 g/cm³.
//! Steel (the needle): (μ/ρ)_Fe = 0.372 cm²/g × 7.9 g/cm³ ≈ 2.94 cm⁻¹ (NIST XCOM, iron, 100 keV).

use stylet_physics::ContrastAgent;

/// μ of water at 100 keV, per mm.
pub const MU_WATER_PER_MM: f32 = 0.017;
/// Mass attenuation coefficient of iodine at 100 keV (cm²/g).
pub const IODINE_CM2_PER_G: f32 = 1.942;
/// μ of stainless steel at 100 keV, per mm.
pub const MU_STEEL_PER_MM: f32 = 0.294;
/// μ of a radiopaque catheter polymer at 100 keV, per mm: polyurethane (1.3 g/cm³) filled with
/// 20 % barium sulphate by weight, μ/ρ = 0.2 × 1.36 + 0.8 × 0.17 cm²/g (barium sulphate from
/// barium's 2.196 cm²/g at 100 keV, NIST XCOM; the polymer about water's), 0.53 cm⁻¹.
pub const MU_RADIOPAQUE_POLYMER_PER_MM: f32 = 0.053;
/// The share of a dilator's and a catheter's cross-section that is wall (1 − (inner / outer
/// diameter)²): a dilator is nearly solid around its wire lumen; an 8 F drainage catheter's
/// lumen is about 0.63 of its outer diameter.
pub const DILATOR_WALL_FRACTION: f32 = 0.87;
pub const CATHETER_WALL_FRACTION: f32 = 0.6;

/// μ of a line's material (per mm of its outer cross-section): the guide wire is steel (a
/// stainless or nitinol core in its coil); the dilator and catheter radiopaque polymer.
pub fn mu_of_line(kind: crate::tools::LineKind) -> f32 {
    use crate::tools::LineKind;
    match kind {
        LineKind::GuideWire => MU_STEEL_PER_MM,
        LineKind::Dilator => MU_RADIOPAQUE_POLYMER_PER_MM * DILATOR_WALL_FRACTION,
        LineKind::Catheter => MU_RADIOPAQUE_POLYMER_PER_MM * CATHETER_WALL_FRACTION,
    }
}
/// Iodine concentration of the default contrast medium (mg/ml; e.g. iohexol 300).
pub const DEFAULT_IODINE_MG_PER_ML: f32 = 300.0;

/// The CT value the line integral sums for one voxel: HU + 1000, air (≤ −1000 HU) as 0.
/// μ = μ_water/1000 × this value.
#[inline]
pub fn water_relative(hu: f32) -> f32 {
    hu.max(-1000.0) + 1000.0
}

/// μ_c (per mm) of iodine at `iodine_g_per_cm3`: (μ/ρ)_I·ρ_I, cm⁻¹ → mm⁻¹.
#[inline]
pub fn iodine_mu_per_mm(iodine_g_per_cm3: f32) -> f32 {
    IODINE_CM2_PER_G * iodine_g_per_cm3 * 0.1
}

/// The contrast medium's μ_c on a box of the CT grid (voxels outside the box hold none).
#[derive(Debug, Clone, PartialEq)]
pub struct ContrastOverlay {
    /// CT voxel index of the box's first voxel, and its size in voxels.
    pub origin: [u32; 3],
    pub dims: [u32; 3],
    /// μ_c per mm of every box voxel, x fastest.
    pub mu_per_mm: Vec<f32>,
}

impl ContrastOverlay {
    /// μ_c (per mm) at CT index `c`: trilinear over the box's voxels, zero outside them (the
    /// field the radiograph's line integral integrates).
    pub fn mu_at_index(&self, c: stylet_physics::glam::Vec3) -> f32 {
        let o = stylet_physics::glam::Vec3::new(self.origin[0] as f32, self.origin[1] as f32, self.origin[2] as f32);
        super::joseph::trilinear_zero_outside(self.dims, c - o, |i| self.mu_per_mm[i])
    }

    /// The box around `voxels` (CT voxel index, μ_c per mm); `None` when there are none or a
    /// voxel lies outside `ct_dims`.
    pub fn from_voxels(voxels: &[([usize; 3], f32)], ct_dims: [usize; 3]) -> Option<ContrastOverlay> {
        if voxels.iter().any(|(v, _)| (0..3).any(|a| v[a] >= ct_dims[a])) {
            return None;
        }
        let mut lo = [usize::MAX; 3];
        let mut hi = [0usize; 3];
        for (v, _) in voxels {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
        if voxels.is_empty() {
            return None;
        }
        let dims = [hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1];
        let mut mu_per_mm = vec![0.0f32; dims[0] * dims[1] * dims[2]];
        for (v, mu) in voxels {
            let (i, j, k) = (v[0] - lo[0], v[1] - lo[1], v[2] - lo[2]);
            mu_per_mm[i + dims[0] * (j + dims[1] * k)] += mu;
        }
        Some(ContrastOverlay {
            origin: lo.map(|v| v as u32),
            dims: dims.map(|v| v as u32),
            mu_per_mm,
        })
    }

    /// `base` with `changes` (CT voxel index, μ per mm) added: the box around both. `None` when
    /// both are empty or a change lies outside `ct_dims`.
    pub fn merged(
        base: Option<&ContrastOverlay>,
        changes: &[([usize; 3], f32)],
        ct_dims: [usize; 3],
    ) -> Option<ContrastOverlay> {
        let mut voxels = changes.to_vec();
        if let Some(b) = base {
            let [nx, ny, nz] = b.dims.map(|d| d as usize);
            let o = b.origin.map(|v| v as usize);
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        let mu = b.mu_per_mm[i + nx * (j + ny * k)];
                        if mu != 0.0 {
                            voxels.push(([o[0] + i, o[1] + j, o[2] + k], mu));
                        }
                    }
                }
            }
        }
        match ContrastOverlay::from_voxels(&voxels, ct_dims) {
            None if changes.is_empty() => base.cloned(),
            merged => merged,
        }
    }

    /// The contrast the simulation holds (docs/contrast.md), as a medium of `iodine_mg_per_ml`.
    /// A voxel cannot hold more than undiluted medium: the physics' ρ, which exceeds 1 at the node
    /// the syringe feeds (it conserves mass, not volume), is drawn as min(ρ, 1).
    pub fn from_agent(agent: &ContrastAgent, ct_dims: [usize; 3], iodine_mg_per_ml: f32) -> Option<ContrastOverlay> {
        let voxels: Vec<([usize; 3], f32)> = agent
            .filled_voxels()
            .into_iter()
            .map(|(v, fraction)| {
                (
                    v,
                    iodine_mu_per_mm(fraction.min(1.0) as f32 * iodine_mg_per_ml / 1000.0),
                )
            })
            .collect();
        ContrastOverlay::from_voxels(&voxels, ct_dims)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn water_relative_values_follow_the_hounsfield_scale() {
        assert_eq!(water_relative(0.0), 1000.0);
        assert_eq!(water_relative(-1000.0), 0.0);
        assert_eq!(water_relative(-2048.0), 0.0);
        assert_eq!(water_relative(1000.0), 2000.0);
        // 300 mg/ml iodine: 1.942 × 0.3 = 0.5826 /cm.
        assert!((iodine_mu_per_mm(0.3) - 0.05826).abs() < 1e-6);
    }

    #[test]
    fn an_overlay_is_the_box_around_its_voxels() {
        let o = ContrastOverlay::from_voxels(&[([3, 4, 5], 1.0), ([5, 4, 6], 2.0)], [10, 10, 10]).unwrap();
        assert_eq!(o.origin, [3, 4, 5]);
        assert_eq!(o.dims, [3, 1, 2]);
        assert_eq!(o.mu_per_mm, vec![1.0, 0.0, 0.0, 0.0, 0.0, 2.0]);
        assert!(ContrastOverlay::from_voxels(&[], [10, 10, 10]).is_none());
        assert!(ContrastOverlay::from_voxels(&[([10, 0, 0], 1.0)], [10, 10, 10]).is_none());
    }

    #[test]
    fn merging_adds_changes_to_an_overlay_in_a_box_around_both() {
        let base = ContrastOverlay::from_voxels(&[([3, 4, 5], 1.0)], [10, 10, 10]).unwrap();
        let m = ContrastOverlay::merged(Some(&base), &[([3, 4, 5], -0.25), ([4, 4, 5], 0.5)], [10, 10, 10]).unwrap();
        assert_eq!((m.origin, m.dims), ([3, 4, 5], [2, 1, 1]));
        assert_eq!(m.mu_per_mm, vec![0.75, 0.5]);
        assert_eq!(ContrastOverlay::merged(Some(&base), &[], [10, 10, 10]), Some(base));
        assert_eq!(ContrastOverlay::merged(None, &[], [10, 10, 10]), None);
    }
}
