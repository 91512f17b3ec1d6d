//! The atlas crate's integration tests, one module per subject, in one test binary.
//! `cargo test -p stylet-atlas --test integration MODULE::` runs one module.

mod common;

mod bad_atlases;
mod cache;
mod fuzz_loading;
mod new_atlas;
mod phantom;
mod properties;
mod real_ct;
