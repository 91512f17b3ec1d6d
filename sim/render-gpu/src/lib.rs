//! Stylet's GPU renderer (docs/rendering.md): wgpu compute shaders drawing the scene that
//! `stylet-render` describes, with the same per-ray algorithm as its CPU reference.
