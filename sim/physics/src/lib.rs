//! Stylet physics: the puncture atlas model and everything the 1 kHz haptic loop computes on it.
//!
//! Pure and deterministic (docs/architecture.md "Determinism"): no GPU, UI, async or file I/O, no
//! wall clock, no unordered iteration, `libm` for every transcendental function. Section numbers
//! (§) refer to the thesis; docs/physics.md, docs/atlas.md and docs/deformation.md describe the
//! algorithms.
//!
//! One concept per module: [`grid`] (voxel geometry), [`volume`] (sampling), [`labels`] (label
//! table and l(x, d)), [`properties`] (property tree), [`thresholds`] (HU threshold estimation),
//! [`masks`] and [`distance`] (skin/bone distance maps), [`atlas`] (the validated whole);
//! the haptic core: [`sim`] (the fixed-step loop), [`needle`] (bendable needle, §3.5),
//! [`contact`] (finger and ultrasound probe, §3.6), [`deform`] (local tissue deformation, Chapter 4), [`contrast`] (contrast agent, §3.3), [`complications`] (what a wrong puncture does), [`motion`] (breathing hook, §5.4),
//! [`device`] (device profiles), [`events`]; [`wire`] (the guide wire) and [`seldinger`] (the
//! exchange over it); [`synthetic_atlas`] (the shared pieces of small
//! hand-built atlases for tests and benchmarks).

pub mod atlas;
pub mod complications;
pub mod contact;
pub mod contrast;
pub mod deform;
pub mod device;
pub mod distance;
pub mod events;
pub mod filter;
pub mod gradient;
pub mod grid;
pub mod labels;
mod lanes;
pub mod masks;
pub mod motion;
pub mod needle;
pub mod planned_path;
pub mod probe_image;
pub mod properties;
pub mod second_hand;
pub mod seldinger;
pub mod sim;
pub mod synthetic_atlas;
#[cfg(test)]
mod test_rng;
pub mod thresholds;
pub mod volume;
pub mod wire;

pub use atlas::{AIR_HU, DistanceMaps, PunctureAtlas};
pub use complications::{ComplicationKind, Complications, Consequence, ConsequenceVolumes, NeedleTip};
pub use contrast::{ContrastAgent, ContrastSettings, ContrastTally};
pub use deform::{DeformCost, DeformField, DeformSettings, Regulariser};
pub use device::DeviceProfile;
pub use events::{Event, ProbeKind, ToolSpec};
pub use glam;
pub use grid::{Affine, Grid};
pub use labels::{HeuristicClass, HeuristicLabels, Label, LabelId, LabelTable, Role, Thresholds, UNNAMED_STRUCTURE};
pub use needle::spec::{Gauge, NeedleSpec};
pub use planned_path::PlannedPath;
pub use properties::{Materials, Param, ParamError, ParamValue, PropertyTree, TissueSpec};
pub use second_hand::{HandOutput, HandPose, HandTool, SecondHandConfig};
pub use seldinger::{Access, Refusal, WireOutput};
pub use sim::{
    DEFAULT_TICK_RATE_HZ, ForceComponents, PHYSICS_VERSION, SimConfig, SimError, Simulation, TickInput, TickOutput,
};
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
    #[error("invalid breathing motion: {0}")]
    InvalidBreathing(SettingsError),
}

/// A simulation setting outside its documented range (docs/physics.md, docs/deformation.md,
/// docs/breathing.md): the simulation refuses to start with it, and a script or recorded session
/// carrying it is refused. The variant says which part of the configuration is wrong; `setting`
/// names the field and `reason` is the message (the value and its range).
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SettingsError {
    #[error("tick rate {0} Hz must be 1 … 100000")]
    TickRate(u32),
    #[error("needle length {0} mm must be 20 … 400")]
    NeedleLength(f64),
    /// A contrast-agent setting ([`ContrastSettings`]).
    #[error("{reason}")]
    Contrast { setting: &'static str, reason: String },
    /// A tissue-deformation setting ([`DeformSettings`], [`Regulariser`]).
    #[error("{reason}")]
    Deformation { setting: &'static str, reason: String },
    /// A breathing setting (the synthetic motion or the breathing signal).
    #[error("{reason}")]
    Breathing { setting: &'static str, reason: String },
    /// A guide-wire setting ([`wire::WireSpec`]).
    #[error("guide wire: {0}")]
    Wire(String),
}
