//! Stylet renderers: the CPU side (thesis §3.2–3.4, docs/rendering.md).
//!
//! One scene description ([`scene`]) drawn by two renderers: this crate's CPU reference
//! (deterministic, rayon; the oracle in tests and what the server draws replays with) and the
//! wgpu renderer in `stylet-render-gpu` (what the desktop simulator uses), so the service and the
//! scoring workers never link wgpu. Modules: [`scene`] (clip plane, tagging, quality, hooks,
//! and the [`camera`] and [`light`] it holds), [`transfer`] (eq. 3.2.2), [`transfer_table`] (what the ray loops read), [`volume`] (the atlas prepared for rendering),
//! [`tools`] (needle, finger, probes), [`shadow`] (their shadows, Alg. 3.1/3.2), [`image`]
//! (pixels, PNG, difference statistics), [`mpr`] (slices), [`annotate`] (tip marker, scale bar,
//! letters on slices), [`xray`] (the radiograph of a C-arm, §3.3), [`ultrasound`] (B-mode and colour Doppler, §3.4), [`synthetic`] (small atlases from functions, for tests), [`figure`] (the atlas figure of `stylet atlas inspect` and the review's slices), [`corridor`] (the expert corridor) and [`overview`] (the review's turntable of a whole attempt); [`huge_pages`] asks Linux for 2 MiB pages under the volumes the ray caster reads at random.

pub mod annotate;
pub mod camera;
pub mod consequences;
pub mod corridor;
pub mod figure;
pub mod fonts;
pub mod huge_pages;
pub mod image;
pub mod index_map;
pub mod light;
pub mod mpr;
pub mod overview;
pub mod presets;
pub mod raycast;
pub mod scene;
pub mod shadow;
pub mod synthetic;
pub mod tools;
pub mod transfer;
pub mod transfer_table;
pub mod ultrasound;
pub mod upscale;
pub mod views;
pub mod volume;
pub mod warp;
pub mod xray;

/// Rendering failures (file output, font set-up).
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("cannot write {path}: {message}")]
    Write { path: String, message: String },
    #[error("cannot read {path}: {message}")]
    Read { path: String, message: String },
    #[error("drawing failed: {0}")]
    Draw(String),
    /// A scene the renderer refuses (image size, geometry, tools), with what is wrong.
    #[error("invalid scene: {0}")]
    Invalid(String),
    /// Ultrasound settings or an ultrasound scene the renderer refuses.
    #[error("invalid scene: {0}")]
    Ultrasound(#[from] ultrasound::UltrasoundError),
    /// A C-arm or X-ray scene the renderer refuses.
    #[error("invalid scene: {0}")]
    Xray(#[from] xray::XrayError),
}
