//! The GPU renderer's integration tests against the CPU reference, one module per renderer, in
//! one test binary sharing one device. `cargo test -p stylet-render-gpu --test integration
//! MODULE::` runs one module.

mod common;

mod mpr;
mod raycast;
mod ultrasound;
mod xray;
