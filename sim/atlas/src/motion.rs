//! The breathing motion attached to an atlas (docs/breathing.md "Atlases", "Measured motion"):
//! `[breathing]` of `atlas.toml` turned into the physics' [`AtlasMotion`], reading and
//! validating measured displacement fields (NIfTI vector images, ITK/ANTs convention) and the
//! surrogate signal (CSV) they come with. Attaching such files to an atlas is
//! `attach_motion.rs`'s job.

use std::path::{Component, Path};
use std::sync::Arc;

use stylet_physics::motion::{AtlasMotion, MeasuredMotion, SampledSignal};

use crate::AtlasError;
use crate::manifest::{BreathingToml, MotionKind};
use crate::nifti_io::read_displacement_field;

/// The largest surrogate signal file read (bytes).
pub const MAX_SIGNAL_BYTES: u64 = 64 << 20;

/// The motion `toml` describes for the atlas in `dir` (`None`: it does not breathe). Measured
/// files are read and checked; a file named outside the atlas directory is refused.
pub fn load_motion(dir: &Path, toml: &BreathingToml) -> Result<Option<AtlasMotion>, AtlasError> {
    let manifest = dir.join(crate::manifest::MANIFEST_FILE);
    match toml.motion {
        MotionKind::None => Ok(None),
        MotionKind::Synthetic => Ok(toml.synthetic().map(AtlasMotion::Synthetic)),
        MotionKind::Measured => {
            let a1 = toml.a1.as_deref().ok_or_else(|| {
                AtlasError::file(&manifest, "[breathing] motion = \"measured\" needs a1 (a field file)")
            })?;
            let field = |name: &str| -> Result<Arc<_>, AtlasError> {
                Ok(Arc::new(read_displacement_field(&inside(dir, name)?)?))
            };
            let optional = |name: &Option<String>| name.as_deref().map(field).transpose();
            Ok(Some(AtlasMotion::Measured(Arc::new(MeasuredMotion {
                a1: field(a1)?,
                a2: optional(&toml.a2)?,
                a3: optional(&toml.a3)?,
                signal: toml
                    .signal
                    .as_deref()
                    .map(|name| read_signal_csv(&inside(dir, name)?).map(Arc::new))
                    .transpose()?,
            }))))
        }
    }
}

/// `name` under `dir`: a relative path without `..`.
fn inside(dir: &Path, name: &str) -> Result<std::path::PathBuf, AtlasError> {
    let p = Path::new(name);
    if name.is_empty() || p.components().any(|c| !matches!(c, Component::Normal(_))) {
        return Err(AtlasError::file(
            dir.join(crate::manifest::MANIFEST_FILE),
            format!("[breathing] file '{name}' must be a path inside the atlas directory"),
        ));
    }
    Ok(dir.join(p))
}

/// Reads a surrogate signal: a CSV with the header `time_s,g` and one sample per row (times
/// strictly increasing from ≥ 0 s, g finite). The message names the row.
pub fn read_signal_csv(path: &Path) -> Result<SampledSignal, AtlasError> {
    let text = crate::read_small_text(path, "breathing signal", MAX_SIGNAL_BYTES)?;
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    match lines.next() {
        Some((_, h)) if h.split(',').map(str::trim).eq(["time_s", "g"]) => {}
        _ => return Err(AtlasError::file(path, "the first line must be the header 'time_s,g'")),
    }
    let (mut times, mut g) = (Vec::new(), Vec::new());
    for (i, line) in lines {
        if times.len() >= stylet_physics::motion::sampled::MAX_SAMPLES {
            return Err(AtlasError::file(
                path,
                format!("more than {} samples", stylet_physics::motion::sampled::MAX_SAMPLES),
            ));
        }
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let number = |s: &str| s.parse::<f64>().ok();
        match cells.as_slice() {
            [t, v] if number(t).is_some() && number(v).is_some() => {
                times.push(number(t).unwrap_or_default());
                g.push(number(v).unwrap_or_default());
            }
            _ => {
                return Err(AtlasError::file(
                    path,
                    format!("line {}: expected two numbers 'time_s,g', got '{line}'", i + 1),
                ));
            }
        }
    }
    // Sample k is on the (k + 2)-th line of a file without blank lines.
    SampledSignal::new(times, g).map_err(|e| AtlasError::file(path, format!("{e} (sample 1 is on line 2)")))
}
