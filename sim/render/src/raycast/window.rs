//! Eight consecutive lattice points of one ray placed and located at once (docs/rendering.md
//! "Sample lanes"): t_k = (k + j)·Δ, c = c_e + t·c_r and `Grid3::locate` (the inside rule, the
//! clamp, the base voxel and the fractions) for k … k + 7, on AVX2 lanes where the CPU has them.
//! Every number is the one the march computes one point at a time, bit for bit; the march then
//! visits the points in order and drops the rest of a window when it leaps. Without the lanes
//! each point is placed only when the march reaches it (`placer::Placer::point`).

use stylet_physics::glam::Vec3;

use super::cell::Cell;

/// Points per window.
pub const POINTS: usize = 8;

/// Lattice points k … k + 7 of a ray, located in the CT grid.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Window {
    /// t of each point.
    pub t: [f32; POINTS],
    /// Base voxel per axis and point (meaningful where `inside` is set).
    pub b: [[u32; POINTS]; 3],
    /// Fractions per axis and point.
    pub f: [[f32; POINTS]; 3],
    /// Bit i: point i lies in the sampling domain (`Grid3::locate` gave a cell).
    pub inside: u8,
}

impl Default for Window {
    fn default() -> Self {
        Window {
            t: [0.0; POINTS],
            b: [[0; POINTS]; 3],
            f: [[0.0; POINTS]; 3],
            inside: 0,
        }
    }
}

impl Window {
    /// Point `i`'s base voxel and fractions, inside or not.
    #[inline(always)]
    pub fn cell_at(&self, i: usize) -> Cell {
        Cell {
            b: [self.b[0][i], self.b[1][i], self.b[2][i]],
            f: [self.f[0][i], self.f[1][i], self.f[2][i]],
        }
    }

    /// Point `i`'s cell, when it lies inside.
    #[inline(always)]
    pub fn cell(&self, i: usize) -> Option<Cell> {
        (self.inside & (1 << i) != 0).then(|| self.cell_at(i))
    }
}

/// A ray's lattice in CT index space: c(t) = `ce` + t·`dc` at t_k = (k + `j`)·`step`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Lattice {
    pub ce: Vec3,
    pub dc: Vec3,
    pub j: f32,
    pub step: f32,
}

/// t_k = (k + j)·Δ: the only formula for a lattice point (the AVX2 lanes of
/// `Avx2::place` do the same operations).
#[inline]
pub(crate) fn lattice(k: u32, j: f32, step: f32) -> f32 {
    (k as f32 + j) * step
}
