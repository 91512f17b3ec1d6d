//! Stylet puncture atlases on disk (thesis §6.1, docs/atlas.md).
//!
//! An atlas is a directory with `atlas.toml` and two NIfTI volumes (CT in HU, partial label map).
//! This crate reads and validates it into a [`stylet_physics::PunctureAtlas`], writes it, and makes
//! new ones: the procedural [`phantom`] (the embedded default) and the [`import`]ers for real CT
//! (NIfTI + label maps such as TotalSegmentator output, and DICOM series behind the `dicom`
//! feature).

pub mod attach_motion;
pub mod cache;
pub mod difficulty;
pub mod import;
pub mod manifest;
pub mod motion;
pub mod nifti_io;
pub mod phantom;
pub mod store;
pub mod summary;
pub mod validation;

use std::path::{Path, PathBuf};

pub use cache::{CacheMode, CacheStatus};
pub use difficulty::{Difficulty, UnknownDifficulty};
pub use manifest::{EchoClass, Exercise, Manifest, ScenarioFile};
pub use store::{Atlas, ThresholdSource, load, load_with, write};

/// A problem with atlas input, always naming the file it concerns. The typed variants keep the
/// check that failed (`error`); their message is the path followed by that error's.
#[derive(Debug, thiserror::Error)]
pub enum AtlasError {
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
    /// An `atlas.toml`, a scenario file or a recipe's labels that fail their checks.
    #[error("{}: {error}", path.display())]
    Manifest {
        path: PathBuf,
        error: manifest::ManifestError,
    },
    /// A manifest about to be written that fails its checks: the atlas is left as it was.
    #[error("{}: refusing to write an invalid manifest: {error}", path.display())]
    RefusedManifest {
        path: PathBuf,
        error: manifest::ManifestError,
    },
    /// A validation record (or a script name) that fails its checks.
    #[error("{}: {error}", path.display())]
    Record {
        path: PathBuf,
        error: validation::RecordError,
    },
    /// A class table CSV that cannot be read, or a structure it cannot take.
    #[error("{}: {error}", path.display())]
    ClassTable {
        path: PathBuf,
        error: import::classes::ClassTableError,
    },
    /// A mapping override CSV that cannot be read.
    #[error("{}: {error}", path.display())]
    Mapping {
        path: PathBuf,
        error: import::mapping::MappingError,
    },
    /// The `[biliary]` table of the recipe at `path` cannot grow a biliary tree in this liver.
    #[error("{}: [biliary]: {error}", path.display())]
    Biliary {
        path: PathBuf,
        error: import::biliary::BiliaryError,
    },
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

/// Refuses an operator file that exists but is not a regular file, before it is opened: opening a
/// FIFO blocks until a writer comes (`stylet atlas inspect` hung forever), and a device, socket or
/// directory is no atlas file either. Symlinks are followed, so a link to a regular file (a CT
/// shared between atlases) is fine. A missing or unreadable file passes: the open that follows
/// says what is wrong with it.
pub(crate) fn check_regular_file(path: &Path) -> Result<(), AtlasError> {
    match std::fs::metadata(path) {
        Ok(m) if !m.is_file() => Err(AtlasError::file(
            path,
            format!("is a {}, not a regular file", file_kind(&m.file_type())),
        )),
        _ => Ok(()),
    }
}

/// A small text file (`what`: "class table", "mapping file"), refused unread when it is not a
/// regular file or holds more than `max_bytes`.
pub(crate) fn read_small_text(path: &Path, what: &str, max_bytes: u64) -> Result<String, AtlasError> {
    check_regular_file(path)?;
    let len = std::fs::metadata(path)
        .map_err(|e| AtlasError::file(path, format!("cannot read: {e}")))?
        .len();
    if len > max_bytes {
        return Err(AtlasError::file(
            path,
            format!("{what} is {len} bytes, more than the {max_bytes} accepted"),
        ));
    }
    std::fs::read_to_string(path).map_err(|e| AtlasError::file(path, format!("cannot read: {e}")))
}

fn file_kind(t: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "named pipe (FIFO)";
        }
        if t.is_socket() {
            return "socket";
        }
        if t.is_block_device() || t.is_char_device() {
            return "device";
        }
    }
    if t.is_dir() { "directory" } else { "special file" }
}
