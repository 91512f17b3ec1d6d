//! What a sample's colour and light come from (thesis §3.2.2–3.2.3), in one value the
//! evaluation of a batch reads, one sample at a time or on the AVX2 lanes.

use stylet_physics::glam::Vec3;

use super::shading::PhongTerms;
use crate::transfer_table::TransferTable;

/// What a sample's colour and light come from: the frame's transfer table (classification),
/// its Phong terms, and ½ M⁻¹'s rows, which turn a record's index-space central differences
/// into the world gradient (∇s = Σ_a Δ_a·rows[a], `sampler::world_gradient`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Appearance<'a> {
    pub table: &'a TransferTable,
    pub phong: &'a PhongTerms,
    pub half_rows: [Vec3; 3],
}
