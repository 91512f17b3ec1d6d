//! World millimetres to a voxel grid's continuous index in `f32`, as both renderers compute it.

use stylet_physics::Grid;
use stylet_physics::glam::{DVec3, Vec3};

/// World → continuous index of a grid in `f32`, c = M⁻¹(x − o): what both renderers use
/// (the GPU receives `rows` and `origin` as uniforms).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IndexMap {
    /// Rows of M⁻¹ (index units per mm).
    pub rows: [Vec3; 3],
    /// World position of voxel (0, 0, 0)'s centre (mm).
    pub origin: Vec3,
    pub dims: [u32; 3],
}

impl IndexMap {
    /// The grid's inverse affine rounded to `f32`.
    pub fn of(grid: &Grid) -> IndexMap {
        let row = |a: usize| {
            let mut e = DVec3::ZERO;
            e[a] = 1.0;
            grid.index_gradient_to_world(e).as_vec3()
        };
        let [nx, ny, nz] = grid.dims();
        IndexMap {
            rows: [row(0), row(1), row(2)],
            origin: grid.affine().origin.as_vec3(),
            dims: [nx as u32, ny as u32, nz as u32],
        }
    }

    /// Continuous index of a world point: (r₀·p, r₁·p, r₂·p) with p = x − origin.
    #[inline]
    pub fn point(&self, x: Vec3) -> Vec3 {
        self.vector(x - self.origin)
    }

    /// Index-space image of a world vector (M⁻¹v).
    #[inline]
    pub fn vector(&self, v: Vec3) -> Vec3 {
        Vec3::new(self.rows[0].dot(v), self.rows[1].dot(v), self.rows[2].dot(v))
    }
}
