//! Scalar volumes on a [`Grid`] and their sampling functions (thesis eq. 3.1.1; docs/atlas.md
//! "Geometry").
//!
//! The image function I is the trilinear interpolation of the CT grid; labels use nearest-neighbour
//! lookup, never interpolation. Outside the grid's extent the caller's `outside` value is returned
//! (air for CT). Within half a voxel of the outermost centres the edge value is used, so trilinear
//! and nearest lookups agree on where the volume ends.

use glam::DVec3;

use crate::gradient::GradientSampler;
use crate::{Grid, PhysicsError};

/// A scalar field stored voxel by voxel, i fastest.
#[derive(Debug, Clone, PartialEq)]
pub struct Volume<T> {
    grid: Grid,
    data: Vec<T>,
}

impl<T: Copy> Volume<T> {
    pub fn new(grid: Grid, data: Vec<T>) -> Result<Self, PhysicsError> {
        if data.len() != grid.len() {
            return Err(PhysicsError::InvalidGrid(format!(
                "volume has {} values but its grid {:?} needs {}",
                data.len(),
                grid.dims(),
                grid.len()
            )));
        }
        Ok(Volume { grid, data })
    }

    pub fn filled(grid: Grid, value: T) -> Self {
        Volume {
            data: vec![value; grid.len()],
            grid,
        }
    }

    pub fn grid(&self) -> &Grid {
        &self.grid
    }
    pub fn data(&self) -> &[T] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }
    pub fn into_data(self) -> Vec<T> {
        self.data
    }

    #[inline]
    pub fn get(&self, i: usize, j: usize, k: usize) -> T {
        self.data[self.grid.linear(i, j, k)]
    }

    #[inline]
    pub fn set(&mut self, i: usize, j: usize, k: usize, v: T) {
        let idx = self.grid.linear(i, j, k);
        self.data[idx] = v;
    }

    /// Nearest-neighbour lookup at a world position (mm).
    #[inline]
    pub fn nearest(&self, world: DVec3, outside: T) -> T {
        match self.grid.nearest_voxel(world) {
            Some([i, j, k]) => self.get(i, j, k),
            None => outside,
        }
    }

    /// A volume of the same grid with every value mapped.
    pub fn map<U: Copy>(&self, f: impl Fn(T) -> U) -> Volume<U> {
        Volume {
            grid: self.grid,
            data: self.data.iter().map(|&v| f(v)).collect(),
        }
    }
}

impl Volume<f32> {
    /// An upper bound on the difference between neighbouring voxels along each index axis,
    /// |v(i + e_a) − v(i)|, tight to a relative 10⁻⁶ (∞ when a value is not finite): along axis a
    /// the trilinear interpolant changes by at most this much per index unit. One pass, rayon
    /// over z-slices, plain loops the compiler vectorises.
    pub fn max_neighbour_steps(&self) -> [f64; 3] {
        use rayon::prelude::*;
        let [nx, ny, nz] = self.grid.dims();
        let slab = nx * ny;
        let data = &self.data;
        // max |a − b| over pairs, in f32: the rounded difference is within a relative 2⁻²⁴ of
        // the exact one, so the result is widened by 10⁻⁶ below.
        fn max_diff(a: &[f32], b: &[f32]) -> f32 {
            a.iter().zip(b).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()))
        }
        let (finite, m) = (0..nz)
            .into_par_iter()
            .map(|k| {
                let s = &data[k * slab..(k + 1) * slab];
                let finite = s.iter().fold(true, |ok, v| ok & v.is_finite());
                let mut m = [0.0f32; 3];
                for row in s.chunks_exact(nx) {
                    m[0] = m[0].max(max_diff(&row[1..], &row[..nx - 1]));
                }
                if ny > 1 {
                    m[1] = max_diff(&s[nx..], &s[..slab - nx]);
                }
                if k + 1 < nz {
                    m[2] = max_diff(&data[(k + 1) * slab..(k + 2) * slab], s);
                }
                (finite, m)
            })
            .reduce(
                || (true, [0.0f32; 3]),
                |(fa, a), (fb, b)| (fa & fb, [a[0].max(b[0]), a[1].max(b[1]), a[2].max(b[2])]),
            );
        if !finite {
            return [f64::INFINITY; 3];
        }
        m.map(|d| d as f64 * (1.0 + 1e-6))
    }

    /// Trilinear interpolation at a world position (mm), `outside` beyond the grid's extent.
    #[inline]
    pub fn sample(&self, world: DVec3, outside: f32) -> f32 {
        self.sample_index(self.grid.world_to_index(world), outside)
    }

    /// Trilinear interpolation at a continuous index.
    pub fn sample_index(&self, c: DVec3, outside: f32) -> f32 {
        trilinear(c, self.grid.dims(), |i, j, k| self.get(i, j, k) as f64).map_or(outside, |v| v as f32)
    }

    /// Gradient of the trilinear field by central differences, in value units per mm along the
    /// world axes (the distance-map directions of eqs. 3.6.1 and 3.6.4; see [`GradientSampler`],
    /// which callers sampling many points should keep).
    pub fn gradient(&self, world: DVec3, outside: f32) -> DVec3 {
        GradientSampler::new(self).gradient_at_index(self.grid.world_to_index(world), outside)
    }
}

/// The trilinear blend at continuous index `c` of a grid of `dims` nodes, `node(i, j, k)` read at
/// the eight corners and blended along x, then y, then z: `None` outside −½ ≤ c_a < n_a − ½ on
/// any axis (NaN included); c is clamped into [0, n − 1] so the half-voxel margin takes the
/// edge value, and a one-node axis reads its node. Every volume and field of the physics
/// interpolates with it.
#[inline]
pub fn trilinear<T>(c: DVec3, dims: [usize; 3], node: impl Fn(usize, usize, usize) -> T) -> Option<T>
where
    T: Copy + std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T>,
{
    let d = dims;
    let mut base = [0usize; 3];
    let mut frac = [0.0f64; 3];
    for a in 0..3 {
        let x = c[a];
        let n = d[a] as f64;
        if !(x >= -0.5 && x < n - 0.5) {
            return None;
        }
        let x = x.clamp(0.0, n - 1.0);
        // x ≥ 0, so truncation is floor (and avoids a libm call on baseline x86-64).
        let b = (x as usize).min(d[a].saturating_sub(2));
        base[a] = b;
        frac[a] = if d[a] == 1 { 0.0 } else { x - b as f64 };
    }
    let step = |a: usize| usize::from(d[a] > 1);
    let (i0, j0, k0) = (base[0], base[1], base[2]);
    let (i1, j1, k1) = (i0 + step(0), j0 + step(1), k0 + step(2));
    let (fx, fy, fz) = (frac[0], frac[1], frac[2]);
    let c00 = node(i0, j0, k0) * (1.0 - fx) + node(i1, j0, k0) * fx;
    let c10 = node(i0, j1, k0) * (1.0 - fx) + node(i1, j1, k0) * fx;
    let c01 = node(i0, j0, k1) * (1.0 - fx) + node(i1, j0, k1) * fx;
    let c11 = node(i0, j1, k1) * (1.0 - fx) + node(i1, j1, k1) * fx;
    let c0 = c00 * (1.0 - fy) + c10 * fy;
    let c1 = c01 * (1.0 - fy) + c11 * fy;
    Some(c0 * (1.0 - fz) + c1 * fz)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Affine;

    fn ramp() -> Volume<f32> {
        let g = Grid::new(
            [4, 3, 2],
            Affine::from_spacing([2.0, 1.0, 3.0], DVec3::new(10.0, 0.0, 0.0)),
        )
        .unwrap();
        let mut data = Vec::new();
        for k in 0..2 {
            for j in 0..3 {
                for i in 0..4 {
                    data.push((i + 10 * j + 100 * k) as f32);
                }
            }
        }
        Volume::new(g, data).unwrap()
    }

    #[test]
    fn trilinear_reproduces_linear_fields() {
        let v = ramp();
        // index (1.5, 0.25, 0.5) → world (13, 0.25, 1.5)
        let x = v.sample(DVec3::new(13.0, 0.25, 1.5), -1.0);
        assert!((x - (1.5 + 2.5 + 50.0)).abs() < 1e-5, "{x}");
        // Gradient: 1/2 per mm along x, 10 per mm along y, 100/3 per mm along z.
        let g = v.gradient(DVec3::new(13.0, 1.0, 1.5), -1.0);
        assert!((g - DVec3::new(0.5, 10.0, 100.0 / 3.0)).length() < 1e-4, "{g}");
    }

    #[test]
    fn outside_and_margin() {
        let v = ramp();
        assert_eq!(v.sample(DVec3::new(9.1, 0.0, 0.0), -1.0), 0.0); // within half a voxel
        assert_eq!(v.sample(DVec3::new(9.1, -0.6, 0.0), -1.0), -1.0);
        assert_eq!(v.nearest(DVec3::new(16.9, 2.4, 4.4), 7.0), 123.0);
        assert_eq!(v.nearest(DVec3::new(17.1, 2.4, 4.4), 7.0), 7.0);
    }

    #[test]
    fn wrong_length_is_an_error() {
        let g = Grid::new([2, 2, 2], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        assert!(Volume::new(g, vec![0.0f32; 7]).is_err());
    }

    /// The steps are the largest neighbour differences along each axis (widened), wherever they lie (a
    /// single jump in the last slab, row or column counts), and any value that is not finite
    /// makes every step infinite.
    #[test]
    fn neighbour_steps_are_the_largest_differences_per_axis() {
        let g = Grid::new([5, 4, 3], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let field = |i: usize, j: usize, k: usize| i as f32 * 0.5 - j as f32 * 2.0 + k as f32 * 3.0;
        let mut data: Vec<f32> = (0..g.len())
            .map(|n| {
                let [i, j, k] = g.unlinear(n);
                field(i, j, k)
            })
            .collect();
        // Widened by 10⁻⁶ (the differences are exact in f32 here).
        let widened = |m: [f64; 3]| m.map(|d| d * (1.0 + 1e-6));
        assert_eq!(
            Volume::new(g, data.clone()).unwrap().max_neighbour_steps(),
            widened([0.5, 2.0, 3.0])
        );
        // A jump at the far corner: voxel (4, 3, 2) raised by 10.
        data[g.len() - 1] += 10.0;
        assert_eq!(
            Volume::new(g, data.clone()).unwrap().max_neighbour_steps(),
            widened([10.5, 8.0, 13.0])
        );
        for bad in [f32::NEG_INFINITY, f32::NAN] {
            let mut d = data.clone();
            d[7] = bad;
            assert_eq!(Volume::new(g, d).unwrap().max_neighbour_steps(), [f64::INFINITY; 3]);
        }
    }
}
