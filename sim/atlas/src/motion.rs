//! The breathing motion attached to an atlas (docs/breathing.md "Atlases", "Measured motion"):
//! `[breathing]` of `atlas.toml` turned into the physics' [`AtlasMotion`], reading and
//! validating measured displacement fields (NIfTI vector images, ITK/ANTs convention) and the
//! surrogate signal (CSV) they come with; and attaching such files to an atlas.

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
    let manifest = dir.join(crate::store::MANIFEST_FILE);
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
            dir.join(crate::store::MANIFEST_FILE),
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

/// Attaches measured motion to the atlas in `dir`: the files are read and checked, copied to
/// `dir/motion/` under names that carry their content (`a1-<sha256 prefix>.nii.gz`, …,
/// `signal-<prefix>.csv`) and `[breathing]` is rewritten. The atlas is loaded back. Files the
/// atlas used before are never overwritten, so on any error its `atlas.toml` is put back and
/// the atlas is exactly as it was (the new copies are removed); on success the motion files
/// the previous `[breathing]` named and the new one does not are removed.
pub fn attach_measured(
    dir: &Path,
    a1: &Path,
    a2: Option<&Path>,
    a3: Option<&Path>,
    signal: Option<&Path>,
) -> Result<crate::Atlas, AtlasError> {
    // Read everything first: a bad file changes nothing.
    for f in [Some(a1), a2, a3].into_iter().flatten() {
        read_displacement_field(f)?;
    }
    if let Some(s) = signal {
        read_signal_csv(s)?;
    }
    let before = crate::store::read_manifest_text(dir)?;
    let mut manifest = crate::store::parse_manifest(&before).map_err(|error| AtlasError::Manifest {
        path: dir.join(crate::store::MANIFEST_FILE),
        error,
    })?;
    let old_files: Vec<String> = manifest
        .breathing_or_default()
        .measured_files()
        .into_iter()
        .map(str::to_owned)
        .collect();
    let motion_dir = dir.join("motion");
    std::fs::create_dir_all(&motion_dir)
        .map_err(|e| AtlasError::file(&motion_dir, format!("cannot create directory: {e}")))?;
    let mut copied: Vec<String> = Vec::new();
    let mut copy = |from: &Path, role: &str, ext: &str| -> Result<String, AtlasError> {
        let digest = crate::store::sha256_file(from)?;
        let name = format!("motion/{role}-{}.{ext}", &digest[..16]);
        if !old_files.contains(&name) {
            let to = dir.join(&name);
            std::fs::copy(from, &to)
                .map_err(|e| AtlasError::file(&to, format!("cannot copy {}: {e}", from.display())))?;
            copied.push(name.clone());
        }
        Ok(name)
    };
    let attached = (|| -> Result<BreathingToml, AtlasError> {
        Ok(BreathingToml {
            motion: MotionKind::Measured,
            a1: Some(copy(a1, "a1", "nii.gz")?),
            a2: a2.map(|p| copy(p, "a2", "nii.gz")).transpose()?,
            a3: a3.map(|p| copy(p, "a3", "nii.gz")).transpose()?,
            signal: signal.map(|p| copy(p, "signal", "csv")).transpose()?,
            ..Default::default()
        })
    })();
    let remove = |names: &mut dyn Iterator<Item = &String>| {
        for name in names {
            let _ = std::fs::remove_file(dir.join(name));
        }
    };
    let result = attached.and_then(|toml| {
        manifest.breathing = Some(toml);
        crate::store::write_manifest(dir, &manifest)?;
        crate::load(dir).inspect_err(|_| {
            // Put the manifest back: the atlas loaded before and must load after.
            let _ = crate::store::write_manifest_text(dir, &before);
        })
    });
    match &result {
        Ok(_) => {
            let breathing = manifest.breathing_or_default();
            let new_files = breathing.measured_files();
            remove(
                &mut old_files
                    .iter()
                    .filter(|f| f.starts_with("motion/") && !new_files.contains(&f.as_str())),
            );
        }
        Err(_) => remove(&mut copied.iter()),
    }
    result
}
