//! The validation report of a new patient (docs/atlas.md "Validation report"): what
//! `stylet atlas new` made, laid out for the clinician who approves it before trainees see the
//! patient. One folder: `index.html` (self-contained but for its pictures), `slices.png` (axial,
//! coronal, sagittal through the target with every structure in its own colour, the paths and a
//! legend) and two ray-cast views cut along the guided path with the labels on the cut
//! (`3d-anterior.png`, `3d-right.png`).
//!
//! Written beside its place and renamed into it, so a report is whole or absent.

mod html;
mod images;

use std::path::{Path, PathBuf};

use stylet_atlas::Atlas;
use stylet_atlas::import::ImportReport;

/// One example script's smoke test (the command runs them; the report shows the outcome).
#[derive(Debug, Clone, PartialEq)]
pub struct SmokeResult {
    pub script: String,
    /// What the script must do ("reaches and confirms the target, …").
    pub expected: String,
    /// What the replayed, scored session did.
    pub got: String,
    pub passed: bool,
    pub seconds: f64,
}

/// Everything the report shows.
pub struct ReportInput<'a> {
    pub atlas: &'a Atlas,
    pub import: &'a ImportReport,
    pub smoke: &'a [SmokeResult],
    /// The command's inputs, as the user named them (shown, never opened).
    pub ct_source: &'a str,
    pub labels_source: &'a str,
}

/// The files written.
#[derive(Debug, Clone)]
pub struct ReportFiles {
    pub dir: PathBuf,
    pub html: PathBuf,
    pub images: Vec<PathBuf>,
}

#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error("drawing {what}: {message}")]
    Render { what: &'static str, message: String },
}

impl ReportError {
    fn file(path: &Path, e: impl std::fmt::Display) -> ReportError {
        ReportError::File {
            path: path.to_path_buf(),
            message: e.to_string(),
        }
    }
}

/// Side of the 3D views (px).
pub const VIEW_PX: (u32, u32) = (560, 460);

/// Writes the report into `dir` (replacing a previous one): pictures, then the page.
pub fn write_report(dir: &Path, input: &ReportInput) -> Result<ReportFiles, ReportError> {
    let parent = dir.parent().unwrap_or(Path::new("."));
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "report".into());
    let tmp = parent.join(format!(".{name}.partial"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| ReportError::file(&tmp, format!("cannot clear: {e}")))?;
    }
    std::fs::create_dir_all(&tmp).map_err(|e| ReportError::file(&tmp, format!("cannot create: {e}")))?;
    let pictures = images::draw(&tmp, input)?;
    let page = html::page(input, &pictures);
    let html_tmp = tmp.join("index.html");
    std::fs::write(&html_tmp, page).map_err(|e| ReportError::file(&html_tmp, format!("cannot write: {e}")))?;
    if dir.exists() {
        std::fs::remove_dir_all(dir).map_err(|e| ReportError::file(dir, format!("cannot replace: {e}")))?;
    }
    std::fs::rename(&tmp, dir).map_err(|e| ReportError::file(dir, format!("cannot move into place: {e}")))?;
    Ok(ReportFiles {
        dir: dir.to_path_buf(),
        html: dir.join("index.html"),
        images: pictures.iter().map(|p| dir.join(&p.file)).collect(),
    })
}
