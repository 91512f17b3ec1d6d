//! The sampling function s(x) (docs/rendering.md "Sampling"; thesis eq. 3.1.1) in `f32`:
//! trilinear CT by eight loads with `stylet_physics::Volume::sample_index`'s inside rule, the
//! deformed sub-image J inside its grid Ω_J, labels by nearest neighbour, and the gradient by
//! central differences for shading.

use stylet_physics::LabelId;
use stylet_physics::atlas::AIR_HU;
use stylet_physics::glam::Vec3;

use crate::volume::IndexMap;

/// A scalar grid as the ray loop reads it: data (x fastest) and its dimensions.
#[derive(Clone, Copy)]
pub struct Grid3<'a> {
    pub data: &'a [f32],
    pub dims: [u32; 3],
}

impl Grid3<'_> {
    /// Trilinear value at continuous index `c`: inside when −½ ≤ c_k < n_k − ½ on every axis
    /// (then clamped to [0, n_k − 1]), else `None`. Same arithmetic order as
    /// `Volume::sample_index`, in `f32`.
    #[inline]
    pub fn trilinear(&self, c: Vec3) -> Option<f32> {
        let mut base = [0u32; 3];
        let mut frac = [0.0f32; 3];
        let mut step = [0u32; 3];
        for a in 0..3 {
            let n = self.dims[a];
            let nf = n as f32;
            let x = c[a];
            if !(x >= -0.5 && x < nf - 0.5) {
                return None;
            }
            let x = x.clamp(0.0, nf - 1.0);
            let b = (x as u32).min(n.saturating_sub(2));
            base[a] = b;
            frac[a] = if n == 1 { 0.0 } else { x - b as f32 };
            step[a] = u32::from(n > 1);
        }
        let (nx, ny) = (self.dims[0] as usize, self.dims[1] as usize);
        let (i0, j0, k0) = (base[0] as usize, base[1] as usize, base[2] as usize);
        let (di, dj, dk) = (step[0] as usize, step[1] as usize * nx, step[2] as usize * nx * ny);
        let o = i0 + nx * (j0 + ny * k0);
        let d = self.data;
        let (fx, fy, fz) = (frac[0], frac[1], frac[2]);
        let c00 = d[o] * (1.0 - fx) + d[o + di] * fx;
        let c10 = d[o + dj] * (1.0 - fx) + d[o + dj + di] * fx;
        let c01 = d[o + dk] * (1.0 - fx) + d[o + dk + di] * fx;
        let c11 = d[o + dk + dj] * (1.0 - fx) + d[o + dk + dj + di] * fx;
        let c0 = c00 * (1.0 - fy) + c10 * fy;
        let c1 = c01 * (1.0 - fy) + c11 * fy;
        Some(c0 * (1.0 - fz) + c1 * fz)
    }
}

/// Linear index of the voxel nearest `c`, or `None` outside the voxels' boxes
/// (`Grid::nearest_voxel_of_index` in `f32`).
#[inline]
pub fn nearest_voxel(c: Vec3, dims: [u32; 3]) -> Option<usize> {
    let mut v = [0usize; 3];
    for a in 0..3 {
        let r = c[a] + 0.5;
        if !(r >= 0.0 && r < dims[a] as f32) {
            return None;
        }
        v[a] = r as usize;
    }
    Some(v[0] + dims[0] as usize * (v[1] + dims[1] as usize * v[2]))
}

/// Where one sample is read: the continuous index in the CT grid and, with a deformed region,
/// in J's grid. Both are stepped along the ray in index space (c = c_e + t·M⁻¹r), so a J on the
/// CT's own grid reads exactly the CT's values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct At {
    pub ct: Vec3,
    pub j: Vec3,
}

/// s(x) and l(x) for one frame.
#[derive(Clone, Copy)]
pub struct Sampler<'a> {
    pub ct: Grid3<'a>,
    pub ct_map: IndexMap,
    /// J of eq. 3.1.1 on its own grid, when the scene carries one.
    pub deformed: Option<(Grid3<'a>, IndexMap)>,
    pub labels: &'a [LabelId],
    /// Index-space offsets of ±h along the world axes (h = ½·min CT spacing), CT and J grids.
    pub grad_ct: [Vec3; 3],
    pub grad_j: [Vec3; 3],
    /// 1 / (2h), per mm.
    pub inv_2h: f32,
}

impl<'a> Sampler<'a> {
    pub fn new(
        ct: Grid3<'a>,
        ct_map: IndexMap,
        deformed: Option<(Grid3<'a>, IndexMap)>,
        labels: &'a [LabelId],
        h_mm: f32,
    ) -> Self {
        let axis = |m: &IndexMap, a: usize| {
            let mut e = Vec3::ZERO;
            e[a] = h_mm;
            m.vector(e)
        };
        let grad_ct = [axis(&ct_map, 0), axis(&ct_map, 1), axis(&ct_map, 2)];
        let grad_j = match &deformed {
            Some((_, m)) => [axis(m, 0), axis(m, 1), axis(m, 2)],
            None => [Vec3::ZERO; 3],
        };
        Sampler {
            ct,
            ct_map,
            deformed,
            labels,
            grad_ct,
            grad_j,
            inv_2h: 1.0 / (2.0 * h_mm),
        }
    }

    /// Index coordinates of a world point in both grids (used with the motion warp).
    #[inline]
    pub fn at_world(&self, x: Vec3) -> At {
        At {
            ct: self.ct_map.point(x),
            j: match &self.deformed {
                Some((_, m)) => m.point(x),
                None => Vec3::ZERO,
            },
        }
    }

    /// s(x): J inside Ω_J, else the CT, else air.
    #[inline]
    pub fn s(&self, at: At) -> f32 {
        if let Some((j, _)) = &self.deformed
            && let Some(v) = j.trilinear(at.j)
        {
            return v;
        }
        self.ct.trilinear(at.ct).unwrap_or(AIR_HU)
    }

    /// ∇s by central differences at ±h along the world axes (HU/mm).
    #[inline]
    pub fn gradient(&self, at: At) -> Vec3 {
        let mut g = Vec3::ZERO;
        if self.deformed.is_none() {
            // The same values as below without J's bookkeeping (the common case).
            for a in 0..3 {
                let plus = self.ct.trilinear(at.ct + self.grad_ct[a]).unwrap_or(AIR_HU);
                let minus = self.ct.trilinear(at.ct - self.grad_ct[a]).unwrap_or(AIR_HU);
                g[a] = (plus - minus) * self.inv_2h;
            }
            return g;
        }
        for a in 0..3 {
            let plus = At {
                ct: at.ct + self.grad_ct[a],
                j: at.j + self.grad_j[a],
            };
            let minus = At {
                ct: at.ct - self.grad_ct[a],
                j: at.j - self.grad_j[a],
            };
            g[a] = (self.s(plus) - self.s(minus)) * self.inv_2h;
        }
        g
    }

    /// l(x): the label of the CT voxel nearest the sample, 0 outside.
    #[inline]
    pub fn label(&self, at: At) -> LabelId {
        match nearest_voxel(at.ct, self.ct.dims) {
            Some(i) => self.labels[i],
            None => 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_physics::glam::DVec3;
    use stylet_physics::{Affine, Grid, Volume};

    #[test]
    fn trilinear_matches_the_physics_sampler() {
        let g = Grid::new(
            [5, 4, 3],
            Affine::from_spacing([1.0, 2.0, 3.0], DVec3::new(-2.0, 1.0, 0.5)),
        )
        .unwrap();
        let data: Vec<f32> = (0..g.len()).map(|i| ((i * 37) % 23) as f32 * 10.0 - 100.0).collect();
        let vol = Volume::new(g, data.clone()).unwrap();
        let grid = Grid3 {
            data: &data,
            dims: [5, 4, 3],
        };
        for i in 0..400 {
            let f = i as f64;
            let c = DVec3::new(
                (f * 0.37).sin() * 3.5 + 2.0,
                (f * 0.11).cos() * 3.0 + 1.5,
                (f * 0.23).sin() * 2.0 + 1.0,
            );
            let want = vol.sample_index(c, AIR_HU);
            let got = grid.trilinear(c.as_vec3()).unwrap_or(AIR_HU);
            assert!((want - got).abs() < 0.05, "{c:?}: {want} vs {got}");
        }
        assert_eq!(grid.trilinear(Vec3::new(-0.51, 0.0, 0.0)), None);
        assert_eq!(grid.trilinear(Vec3::new(4.5, 0.0, 0.0)), None);
        assert_eq!(grid.trilinear(Vec3::new(4.49, 3.0, 2.0)), Some(data[data.len() - 1]));
        assert_eq!(
            nearest_voxel(Vec3::new(4.49, 3.0, 2.0), [5, 4, 3]),
            Some(data.len() - 1)
        );
        assert_eq!(nearest_voxel(Vec3::new(4.5, 3.0, 2.0), [5, 4, 3]), None);
    }
}
