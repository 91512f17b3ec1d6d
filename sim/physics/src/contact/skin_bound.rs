//! Nodes that are certainly off the skin, without reading D_skin (work only: the same bits).
//!
//! A node off the skin (D_skin ≤ 0) only needs that answer: its force is zero and its state is
//! reset (eqs. 3.6.1–3.6.3 apply inside the skin only), so the value itself is never used. D_skin
//! is the trilinear interpolant of the skin map's voxels; along index axis a its slope is a
//! blend of differences between neighbouring voxels along a, so with S_a the largest of those
//! ([`crate::PunctureAtlas::skin_distance_steps_mm`], measured on the map when the atlas is
//! built), between two interior indices c and c′
//!
//!   D(c′) ≤ D(c) + Σ_a M_a |c′_a − c_a|,   M_a = S_a (1 + 10⁻⁹) + 10⁻⁹ mm
//!
//! (the margins cover the rounding of the interpolation). A node keeps an upper bound on D_skin where it
//! last was; while the bound carried to its new index stays below −10⁻⁶ mm (far beyond the
//! read's rounding), the node is off the skin and nothing is read. A read, or a node near the
//! grid's border (where the sampler's out-of-grid value breaks the slope bound), resets it.

use glam::DVec3;

/// Most D_skin can grow per index unit along each axis ([`self`]), from the largest steps
/// between neighbouring voxels of the map.
pub(super) fn slopes_mm(steps_mm: [f64; 3]) -> DVec3 {
    DVec3::from_array(steps_mm.map(|s| s * (1.0 + 1e-9) + 1e-9))
}

/// Below this bound (mm) a node is off the skin whatever the read's rounding.
const CERTAINLY_OFF_MM: f64 = -1e-6;

/// Added to every carried bound (mm): covers the rounding of carrying it.
const CARRY_SLACK_MM: f64 = 1e-9;

/// An upper bound on D_skin at a continuous index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct SkinBound {
    c: DVec3,
    upper_mm: f64,
}

impl SkinBound {
    /// Nothing known (a new tool, or a node near the grid's border).
    pub const UNKNOWN: SkinBound = SkinBound {
        c: DVec3::ZERO,
        upper_mm: f64::INFINITY,
    };

    /// D_skin read as `d_skin` at interior index `c` (NaN gives no bound).
    #[inline(always)]
    pub fn read(c: DVec3, d_skin: f64) -> SkinBound {
        SkinBound { c, upper_mm: d_skin }
    }

    /// The bound (mm).
    #[inline(always)]
    pub fn upper_mm(&self) -> f64 {
        self.upper_mm
    }

    /// The bound carried to interior index `c` (the last one also interior) when it proves the
    /// node off the skin there; `None` when D_skin must be read.
    #[inline(always)]
    pub fn off_skin_at(&self, c: DVec3, slopes_mm: DVec3) -> Option<SkinBound> {
        let moved = (c - self.c).abs();
        let upper_mm = self.upper_mm + slopes_mm.dot(moved) + CARRY_SLACK_MM;
        // NaN fails the test.
        (upper_mm < CERTAINLY_OFF_MM).then_some(SkinBound { c, upper_mm })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distance::subvoxel_signed_distance;
    use crate::gradient::GradientSampler;
    use crate::masks::body_mask;
    use crate::test_rng::unit;
    use crate::{Affine, Grid, Volume};

    /// On the sub-voxel skin map of a lumpy body (anisotropic voxels), D_skin read at an index
    /// never exceeds the bound carried there from a read at another index, over moves from a
    /// hundredth of a voxel to many voxels; and a carried bound below the threshold always
    /// means D_skin ≤ 0 there.
    #[test]
    fn the_carried_bound_is_never_below_the_read_value() {
        let g = Grid::new([40, 36, 24], Affine::from_spacing([0.7, 0.9, 2.0], DVec3::ZERO)).unwrap();
        let ct: Vec<f32> = (0..g.len())
            .map(|n| {
                let [i, j, k] = g.unlinear(n);
                let p = g.voxel_to_world(i, j, k) - DVec3::new(14.0, 16.0, 24.0);
                let lumps = 3.0 * libm::sin(p.x * 0.4) * libm::cos(p.y * 0.3);
                if p.length() + lumps < 13.0 { 40.0 } else { -1000.0 }
            })
            .collect();
        let ct = Volume::new(g, ct).unwrap();
        let body = body_mask(&ct, -500.0);
        let skin = subvoxel_signed_distance(&ct, &body, -500.0);
        let slopes = slopes_mm(skin.max_neighbour_steps());
        let maps = GradientSampler::on_one_grid([&skin]).unwrap();
        let mut rng = 0xB0_u64;
        let interior = |rng: &mut u64| {
            DVec3::new(
                1.0 + 36.999 * unit(rng),
                1.0 + 32.999 * unit(rng),
                1.0 + 20.999 * unit(rng),
            )
        };
        let (mut proved_off, mut tight) = (0, 0);
        for _ in 0..20_000 {
            let c = interior(&mut rng);
            let reach = [0.01, 0.3, 3.0, 30.0][(unit(&mut rng) * 4.0) as usize];
            let to = c + DVec3::new(unit(&mut rng) - 0.5, unit(&mut rng) - 0.5, unit(&mut rng) - 0.5) * reach;
            let to = to.clamp(DVec3::ONE, DVec3::new(37.999, 33.999, 21.999));
            let [d, d_to, ..] = maps.values4(&[c, to, c, c]);
            let carried = SkinBound::read(c, d).upper_mm + slopes.dot((to - c).abs()) + CARRY_SLACK_MM;
            assert!(
                d_to <= carried,
                "D_skin {d_to} at {to:?} above the bound {carried} carried from {d} at {c:?}"
            );
            if let Some(b) = SkinBound::read(c, d).off_skin_at(to, slopes) {
                assert!(d_to <= 0.0 && b.upper_mm < CERTAINLY_OFF_MM);
                proved_off += 1;
            }
            if carried - d_to < 0.05 {
                tight += 1;
            }
        }
        // The bound is used often and is close to the value on some moves (not vacuous).
        assert!(
            proved_off > 2_000 && tight > 200,
            "{proved_off} proved off the skin, {tight} within 0.05 mm"
        );
    }
}
