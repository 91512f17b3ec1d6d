//! Stylet puncture atlases on disk (thesis §6.1, ALGORITHMS.md §0–1, docs/atlas.md).
//!
//! An atlas is a directory with `atlas.toml` and two NIfTI volumes (CT in HU, partial label map).
//! This crate reads and validates it into a [`stylet_physics::PunctureAtlas`], writes it, and makes
//! new ones: the procedural [`phantom`] (the embedded default) and the [`import`]ers for real CT
//! (NIfTI + label maps such as TotalSegmentator output, and DICOM series behind the `dicom`
//! feature).

pub mod import;
pub mod manifest;
pub mod nifti_io;
pub mod phantom;
pub mod store;
pub mod summary;

use std::path::{Path, PathBuf};

pub use manifest::{Manifest, ScenarioFile};
pub use store::{Atlas, ThresholdSource, load, write};

/// A problem with atlas input, always naming the file it concerns.
#[derive(Debug, thiserror::Error)]
pub enum AtlasError {
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
    #[error("{0}")]
    Other(String),
}

impl AtlasError {
    pub fn file(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        AtlasError::File {
            path: path.as_ref().to_path_buf(),
            message: message.into(),
        }
    }
}
