//! Attaching measured breathing motion to an atlas directory (`stylet atlas attach-motion`,
//! docs/breathing.md "Measured motion"): the files are checked as [`crate::motion`] reads them,
//! copied into the atlas and named in its `atlas.toml`.

use std::path::Path;

use crate::AtlasError;
use crate::manifest::{BreathingToml, MANIFEST_FILE, MotionKind};
use crate::motion::read_signal_csv;
use crate::nifti_io::read_displacement_field;
use crate::store::{parse_manifest, read_manifest_text, sha256_file, write_manifest, write_manifest_text};

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
    let before = read_manifest_text(dir)?;
    let mut manifest = parse_manifest(&before).map_err(|error| AtlasError::Manifest {
        path: dir.join(MANIFEST_FILE),
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
        let digest = sha256_file(from)?;
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
        write_manifest(dir, &manifest)?;
        crate::load(dir).inspect_err(|_| {
            // Put the manifest back: the atlas loaded before and must load after.
            let _ = write_manifest_text(dir, &before);
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
