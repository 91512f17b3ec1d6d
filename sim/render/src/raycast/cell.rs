//! Where a trilinear read lands in a voxel grid: what locating a point gives
//! (`sampler::Grid3::locate`) and what every interpolation of the ray caster reads.

/// Where a trilinear read lands: base voxel b (each ≤ n_a − 2) and fractions f ∈ [0, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    pub b: [u32; 3],
    pub f: [f32; 3],
}
