//! Stylet's GPU renderer (docs/rendering.md): wgpu compute shaders drawing the scene that
//! `stylet-render` describes, with the same per-ray algorithm as its CPU reference, so the two
//! images differ only by floating-point rounding.
//!
//! - [`GpuContext`]: a headless device (any adapter, including Mesa's software Vulkan, lavapipe).
//! - [`GpuVolume`]: the atlas volumes uploaded once (CT as 16-bit integers when it can be, labels,
//!   label styles).
//! - [`GpuRenderer`]: the ray-casting pipeline (`shaders/raycast.wgsl`); per frame only the
//!   uniforms and the tool primitives are written.
//! - [`GpuMpr`]: slices with the label overlay (`shaders/mpr.wgsl`).
//! - [`GpuXray`]: the C-arm's radiograph with contrast and needle (`shaders/xray.wgsl`).
//! - [`GpuUltrasound`]: B-mode and colour Doppler along the scan lines (`shaders/ultrasound.wgsl`).
//!
//! Only the desktop simulator and the CLI link this crate; the service and the scoring workers
//! draw with the CPU reference and never link wgpu.

mod context;
mod motion;
pub mod mpr;
mod pipeline;
pub mod raycast;
mod timer;
pub mod ultrasound;
pub mod volume;
pub mod xray;

pub use context::{AdapterSummary, GpuContext};
pub use motion::{MAX_FIELD_BYTES, draws as draws_breathing};
pub use mpr::GpuMpr;
pub use raycast::GpuRenderer;
pub use ultrasound::GpuUltrasound;
pub use volume::{CtFormat, CtPlacement, GpuVolume, RecordFilter, UploadOptions};
pub use xray::GpuXray;

/// Why the GPU could not draw.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter at all: on a machine without a GPU install Mesa's software Vulkan
    /// (`libvulkan1 mesa-vulkan-drivers`).
    #[error(
        "no GPU adapter found ({0}); on a machine without a GPU install Mesa's software Vulkan (apt-get install libvulkan1 mesa-vulkan-drivers)"
    )]
    NoAdapter(String),
    #[error("the GPU adapter {adapter} refused a device: {message}")]
    RequestDevice { adapter: String, message: String },
    /// The volume or the image does not fit the device's limits (checked before allocating).
    #[error("{what} exceeds the GPU's limit: {needed} > {limit}")]
    Limits { what: String, needed: u64, limit: u64 },
    /// Bad input: image size, transfer function, too many primitives, a grid the GPU cannot read.
    #[error("invalid input: {0}")]
    Invalid(String),
    /// A feature of the scene this renderer does not draw yet.
    #[error("the GPU renderer does not support {0} yet")]
    Unsupported(&'static str),
    /// Reading the image back from the GPU failed.
    #[error("reading the image back from the GPU failed: {0}")]
    Readback(String),
}
