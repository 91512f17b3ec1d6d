//! Stylet renderers.
//!
//! Now: the CPU reference multi-planar reformation ([`mpr`]: CT slices with window/level and a
//! label overlay, ALGORITHMS.md §4 "MPR") and the atlas figure ([`figure`]) used by
//! `stylet atlas inspect --png` and by the server for thumbnails. The wgpu ray casting, X-ray and
//! ultrasound renderers join in later issues, with this CPU path as their test oracle.

pub mod charts;
pub mod figure;
pub mod fonts;
pub mod mpr;

/// Rendering failures (file output, font set-up).
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("cannot write {path}: {message}")]
    Write { path: String, message: String },
    #[error("drawing failed: {0}")]
    Draw(String),
}
