//! Stylet physics: the puncture atlas model and everything the 1 kHz haptic loop computes on it.
//!
//! Pure and deterministic (DESIGN.md "Determinism rules"): no GPU, UI, async or file I/O, no wall
//! clock, no unordered iteration. Section numbers (§) refer to the thesis; `ALGORITHMS.md` is our
//! digest of it in `../shared/spec/`.
//!
//! One concept per module: [`grid`] (voxel geometry), [`volume`] (sampling), [`labels`] (label
//! table and l(x, d)), [`properties`] (property tree), [`thresholds`] (HU threshold estimation),
//! [`masks`] and [`distance`] (skin/bone distance maps), [`atlas`] (the validated whole).

pub mod atlas;
pub mod distance;
pub mod grid;
pub mod labels;
pub mod masks;
pub mod properties;
pub mod thresholds;
pub mod volume;

pub use atlas::{AIR_HU, PunctureAtlas};
pub use glam;
pub use grid::{Affine, Grid};
pub use labels::{HeuristicClass, HeuristicLabels, Label, LabelId, LabelTable, Role, Thresholds};
pub use properties::{Materials, Param, ParamValue, PropertyTree, TissueSpec};
pub use volume::Volume;

/// What can be wrong with atlas data handed to the physics crate. The messages name the problem;
/// the atlas loader adds which file it came from.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum PhysicsError {
    #[error("invalid grid: {0}")]
    InvalidGrid(String),
    #[error("CT and labels do not match: {0}")]
    Mismatch(String),
    #[error("non-finite value: {0}")]
    NotFinite(String),
    #[error("invalid labels: {0}")]
    InvalidLabels(String),
    #[error("invalid property tree: {0}")]
    InvalidPropertyTree(String),
    #[error("invalid thresholds: {0}")]
    InvalidThresholds(String),
}
