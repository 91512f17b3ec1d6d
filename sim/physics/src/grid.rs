//! Voxel grid geometry: dimensions and the affine map from voxel index to world space.
//!
//! World space is the atlas' reference space X in millimetres, RAS+ (docs/atlas.md "Geometry"): the
//! first axis points to the patient's right, the second anterior, the third superior.
//! Voxel (i, j, k) has its centre at `affine · (i, j, k, 1)`; storage order is i fastest, then j,
//! then k (NIfTI).

use glam::DVec3;

use crate::PhysicsError;

/// Affine map world = M·index + t, with M a 3×3 matrix whose columns are the index axes in mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine {
    /// Columns of M: the world-space step of one voxel along i, j and k.
    pub axes: [DVec3; 3],
    /// World position of voxel (0, 0, 0)'s centre, in mm.
    pub origin: DVec3,
}

impl Affine {
    /// Axis-aligned grid with the given spacing (mm) and origin (mm).
    pub fn from_spacing(spacing_mm: [f64; 3], origin: DVec3) -> Self {
        Affine {
            axes: [
                DVec3::new(spacing_mm[0], 0.0, 0.0),
                DVec3::new(0.0, spacing_mm[1], 0.0),
                DVec3::new(0.0, 0.0, spacing_mm[2]),
            ],
            origin,
        }
    }

    /// From the three rows of a NIfTI `srow_*` style 3×4 matrix.
    pub fn from_rows(rows: [[f64; 4]; 3]) -> Self {
        Affine {
            axes: [
                DVec3::new(rows[0][0], rows[1][0], rows[2][0]),
                DVec3::new(rows[0][1], rows[1][1], rows[2][1]),
                DVec3::new(rows[0][2], rows[1][2], rows[2][2]),
            ],
            origin: DVec3::new(rows[0][3], rows[1][3], rows[2][3]),
        }
    }

    /// The three rows of the 3×4 matrix (NIfTI `srow_x`, `srow_y`, `srow_z`).
    pub fn rows(&self) -> [[f64; 4]; 3] {
        let [a, b, c] = self.axes;
        [
            [a.x, b.x, c.x, self.origin.x],
            [a.y, b.y, c.y, self.origin.y],
            [a.z, b.z, c.z, self.origin.z],
        ]
    }

    /// Voxel spacing in mm: the length of each index axis.
    pub fn spacing_mm(&self) -> [f64; 3] {
        [self.axes[0].length(), self.axes[1].length(), self.axes[2].length()]
    }

    /// Continuous index → world position (mm).
    #[inline]
    pub fn apply(&self, index: DVec3) -> DVec3 {
        self.origin + self.axes[0] * index.x + self.axes[1] * index.y + self.axes[2] * index.z
    }

    fn determinant(&self) -> f64 {
        self.axes[0].dot(self.axes[1].cross(self.axes[2]))
    }

    /// The inverse map (world → continuous index), or `None` for a singular or non-finite matrix.
    pub fn inverse(&self) -> Option<InverseAffine> {
        let det = self.determinant();
        if !det.is_finite() || det.abs() < 1e-12 || !self.origin.is_finite() {
            return None;
        }
        let [a, b, c] = self.axes;
        // Rows of M⁻¹ are the cross products of M's columns divided by det(M).
        let r0 = b.cross(c) / det;
        let r1 = c.cross(a) / det;
        let r2 = a.cross(b) / det;
        Some(InverseAffine {
            rows: [r0, r1, r2],
            origin: self.origin,
        })
    }

    /// Largest absolute difference of any matrix entry, in mm.
    pub fn max_abs_diff(&self, other: &Affine) -> f64 {
        let (a, b) = (self.rows(), other.rows());
        let mut d = 0.0f64;
        for r in 0..3 {
            for c in 0..4 {
                d = d.max((a[r][c] - b[r][c]).abs());
            }
        }
        d
    }
}

/// World → continuous index, precomputed once per grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InverseAffine {
    rows: [DVec3; 3],
    origin: DVec3,
}

impl InverseAffine {
    #[inline]
    pub fn apply(&self, world: DVec3) -> DVec3 {
        self.apply_vector(world - self.origin)
    }

    /// A world displacement (mm) in index units.
    #[inline]
    pub fn apply_vector(&self, v: DVec3) -> DVec3 {
        DVec3::new(self.rows[0].dot(v), self.rows[1].dot(v), self.rows[2].dot(v))
    }
}

/// Dimensions plus geometry of a voxel grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    dims: [usize; 3],
    affine: Affine,
    inverse: InverseAffine,
}

/// Upper bound on voxels per volume: 2^28 (1 GiB as f32). Protects against hostile headers.
pub const MAX_VOXELS: usize = 1 << 28;

impl Grid {
    pub fn new(dims: [usize; 3], affine: Affine) -> Result<Self, PhysicsError> {
        if dims.contains(&0) {
            return Err(PhysicsError::InvalidGrid(format!("dimensions {dims:?} contain a zero")));
        }
        let n = dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
        match n {
            Some(n) if n <= MAX_VOXELS => {}
            _ => {
                return Err(PhysicsError::InvalidGrid(format!(
                    "dimensions {dims:?} exceed the limit of {MAX_VOXELS} voxels"
                )));
            }
        }
        let inverse = affine.inverse().ok_or_else(|| {
            PhysicsError::InvalidGrid(format!("affine {:?} is singular or not finite", affine.rows()))
        })?;
        Ok(Grid { dims, affine, inverse })
    }

    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }
    pub fn affine(&self) -> &Affine {
        &self.affine
    }
    pub fn spacing_mm(&self) -> [f64; 3] {
        self.affine.spacing_mm()
    }
    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear storage index of voxel (i, j, k); i varies fastest.
    #[inline]
    pub fn linear(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Voxel (i, j, k) of a linear index.
    #[inline]
    pub fn unlinear(&self, idx: usize) -> [usize; 3] {
        let i = idx % self.dims[0];
        let r = idx / self.dims[0];
        [i, r % self.dims[1], r / self.dims[1]]
    }

    /// World position (mm) of the centre of the voxel with linear index `idx`.
    #[inline]
    pub fn linear_to_world(&self, idx: usize) -> DVec3 {
        let [i, j, k] = self.unlinear(idx);
        self.voxel_to_world(i, j, k)
    }

    /// World position (mm) of a voxel centre.
    #[inline]
    pub fn voxel_to_world(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.affine.apply(DVec3::new(i as f64, j as f64, k as f64))
    }

    /// Continuous index of a world position (mm); voxel centres have integer coordinates.
    #[inline]
    pub fn world_to_index(&self, world: DVec3) -> DVec3 {
        self.inverse.apply(world)
    }

    /// A world displacement (mm) in index units: world_to_index(x + v) = world_to_index(x) +
    /// world_vector_to_index(v), up to rounding.
    #[inline]
    pub fn world_vector_to_index(&self, v: DVec3) -> DVec3 {
        self.inverse.apply_vector(v)
    }

    /// A gradient taken in index units (per voxel step along i, j, k) expressed per mm along the
    /// world axes: ∇_x f = Σ_a (∂f/∂index_a) ∇_x index_a, the rows of the inverse affine.
    pub fn index_gradient_to_world(&self, g: DVec3) -> DVec3 {
        let r = &self.inverse.rows;
        r[0] * g.x + r[1] * g.y + r[2] * g.z
    }

    /// The rows of the inverse affine that [`Self::index_gradient_to_world`] weights (for the
    /// batched gathers, which repeat its products and sums lane by lane).
    pub(crate) fn index_gradient_rows(&self) -> [DVec3; 3] {
        self.inverse.rows
    }

    /// Nearest voxel of a world position, or `None` when it lies outside the grid's extent
    /// (the voxels' boxes, i.e. −0.5 … n − 0.5 in index units).
    #[inline]
    pub fn nearest_voxel(&self, world: DVec3) -> Option<[usize; 3]> {
        self.nearest_voxel_of_index(self.world_to_index(world))
    }

    /// [`Grid::nearest_voxel`] of a continuous index.
    #[inline]
    pub fn nearest_voxel_of_index(&self, c: DVec3) -> Option<[usize; 3]> {
        let mut out = [0usize; 3];
        for (a, o) in out.iter_mut().enumerate() {
            // floor(r) ∈ [0, n) ⇔ r ∈ [0, n) for integer n, and truncation is floor for r ≥ 0.
            let r = c[a] + 0.5;
            if !(r >= 0.0 && r < self.dims[a] as f64) {
                return None;
            }
            *o = r as usize;
        }
        Some(out)
    }

    /// World-space bounding box (min, max corners, mm) of the voxel centres.
    pub fn world_bounds(&self) -> (DVec3, DVec3) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for &i in &[0, self.dims[0] - 1] {
            for &j in &[0, self.dims[1] - 1] {
                for &k in &[0, self.dims[2] - 1] {
                    let p = self.voxel_to_world(i, j, k);
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
        }
        (lo, hi)
    }

    /// The index axis (0, 1 or 2) most aligned with the world's superior (z) direction: the axis
    /// along which a CT is usually cropped, so the body touches the volume's faces there.
    pub fn cranio_caudal_axis(&self) -> usize {
        let z: Vec<f64> = self.affine.axes.iter().map(|a| (a.z / a.length()).abs()).collect();
        let mut best = 0;
        for a in 1..3 {
            if z[a] > z[best] {
                best = a;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_round_trips_an_oblique_affine() {
        let affine = Affine {
            axes: [
                DVec3::new(0.9, 0.1, 0.0),
                DVec3::new(-0.1, 0.8, 0.2),
                DVec3::new(0.0, -0.3, 2.5),
            ],
            origin: DVec3::new(-100.0, 20.0, 5.0),
        };
        let g = Grid::new([10, 12, 14], affine).unwrap();
        let idx = DVec3::new(3.25, 7.5, 11.0);
        let back = g.world_to_index(g.affine().apply(idx));
        assert!((back - idx).length() < 1e-12);
    }

    #[test]
    fn rejects_singular_and_oversized_grids() {
        let singular = Affine {
            axes: [DVec3::X, DVec3::X, DVec3::Z],
            origin: DVec3::ZERO,
        };
        assert!(Grid::new([2, 2, 2], singular).is_err());
        let ok = Affine::from_spacing([1.0; 3], DVec3::ZERO);
        assert!(Grid::new([0, 2, 2], ok).is_err());
        assert!(Grid::new([1 << 10, 1 << 10, 1 << 10], ok).is_err());
    }

    #[test]
    fn nearest_voxel_covers_half_voxel_margin() {
        let g = Grid::new([4, 4, 4], Affine::from_spacing([2.0; 3], DVec3::ZERO)).unwrap();
        assert_eq!(g.nearest_voxel(DVec3::new(-0.99, 0.0, 0.0)), Some([0, 0, 0]));
        assert_eq!(g.nearest_voxel(DVec3::new(-1.01, 0.0, 0.0)), None);
        assert_eq!(g.nearest_voxel(DVec3::new(6.99, 3.1, 0.0)), Some([3, 2, 0]));
        assert_eq!(g.nearest_voxel(DVec3::new(7.01, 0.0, 0.0)), None);
    }
}
