//! Loading and writing atlas directories (`atlas.toml` + NIfTI volumes), with validation that names
//! the file and the problem for every kind of bad input (docs/atlas.md "Validation").

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};
use stylet_physics::glam::DVec3;
use stylet_physics::thresholds::estimate_thresholds;
use stylet_physics::{LabelId, PhysicsError, PunctureAtlas, Volume};

use crate::cache::{self, CacheMode, CacheStatus};
use crate::manifest::{self, FORMAT_VERSION, Manifest, ManifestError, PathProblem, ThresholdsToml};
use crate::{AtlasError, nifti_io};

/// The manifest's file name, also under this module's name.
pub use crate::manifest::MANIFEST_FILE;

/// Largest `atlas.toml` we read.
const MAX_MANIFEST_BYTES: u64 = 4 << 20;

/// Where the heuristic thresholds came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ThresholdSource {
    /// Given in `atlas.toml`.
    Atlas,
    /// Estimated from the CT histogram at load time.
    Estimated,
}

impl ThresholdSource {
    pub fn as_str(self) -> &'static str {
        match self {
            ThresholdSource::Atlas => "atlas",
            ThresholdSource::Estimated => "estimated",
        }
    }
}

/// A loaded, validated atlas.
#[derive(Debug, Clone)]
pub struct Atlas {
    pub dir: PathBuf,
    pub manifest: Manifest,
    /// The volumes and tables the physics and the renderers read; shared (an `Arc`) so that a
    /// scorer, a simulation and the views of one atlas hold one copy of the CT, not one each.
    pub model: std::sync::Arc<PunctureAtlas>,
    pub threshold_source: ThresholdSource,
    /// SHA-256 over the manifest and both volume files (docs/atlas.md "Content hash"), hex.
    pub content_hash: String,
    /// Whether the distance maps came from the derived-data cache (docs/atlas.md), and the
    /// cache write a deriving load started (shared by the clones; the last one waits for it).
    cache: std::sync::Arc<cache::CacheWork>,
}

impl Atlas {
    /// Where this load's distance maps came from; after a deriving load, waits until its cache
    /// write has finished (it runs beside the caller's work).
    pub fn cache_status(&self) -> CacheStatus {
        self.cache.status()
    }
}

fn manifest_error(dir: &Path, error: ManifestError) -> AtlasError {
    AtlasError::Manifest {
        path: dir.join(MANIFEST_FILE),
        error,
    }
}

fn refused_manifest(dir: &Path, error: ManifestError) -> AtlasError {
    AtlasError::RefusedManifest {
        path: dir.join(MANIFEST_FILE),
        error,
    }
}

/// Parses and checks an `atlas.toml` on its own (no volumes): syntax, version, labels, tree,
/// thresholds, presets and paths. Used by the loader and by the fuzz tests.
pub fn parse_manifest(text: &str) -> Result<Manifest, ManifestError> {
    let m: Manifest = toml::from_str(text).map_err(|e| ManifestError::Syntax(e.to_string().trim_end().to_string()))?;
    if m.format_version != FORMAT_VERSION {
        return Err(ManifestError::UnsupportedVersion {
            found: m.format_version,
        });
    }
    if m.name.trim().is_empty() {
        return Err(ManifestError::EmptyName);
    }
    for (key, file) in [("volumes.ct", &m.volumes.ct), ("volumes.labels", &m.volumes.labels)] {
        check_file_name(file).map_err(|problem| ManifestError::VolumeFile {
            key,
            file: file.clone(),
            problem,
        })?;
    }
    if m.volumes.ct == m.volumes.labels {
        return Err(ManifestError::SameVolumeFile);
    }
    // Checked before any file is opened: an atlas reads nothing outside its folder, and a path
    // that would leave it is refused alike whether or not something is there.
    if let Some(b) = &m.breathing {
        for (key, file) in [("a1", &b.a1), ("a2", &b.a2), ("a3", &b.a3), ("signal", &b.signal)] {
            if let Some(file) = file {
                check_inside(file).map_err(|problem| ManifestError::BreathingFile { key, problem })?;
            }
        }
    }
    let labels = manifest::label_table(&m.labels, &m.heuristic)?;
    let tree = manifest::property_tree(&m.tissues)?;
    stylet_physics::Materials::resolve(&labels, &tree).map_err(ManifestError::Materials)?;
    if !m.heuristic.risk_depth_mm.is_finite() || m.heuristic.risk_depth_mm < 0.0 {
        return Err(ManifestError::RiskDepth {
            value: m.heuristic.risk_depth_mm,
        });
    }
    if let Some(t) = &m.thresholds {
        t.with_depth(m.heuristic.risk_depth_mm)
            .validate()
            .map_err(ManifestError::Thresholds)?;
    }
    let mut names = std::collections::BTreeSet::new();
    for p in &m.paths {
        let name = || p.name.clone();
        if p.name.trim().is_empty() {
            return Err(ManifestError::UnnamedPath);
        }
        if !names.insert(p.name.as_str()) {
            return Err(ManifestError::DuplicatePath { name: name() });
        }
        if p.entry_mm.iter().chain(&p.target_mm).any(|v| !v.is_finite()) {
            return Err(ManifestError::NonFinitePath { name: name() });
        }
        if DVec3::from_array(p.entry_mm).distance(DVec3::from_array(p.target_mm)) < 1.0 {
            return Err(ManifestError::ShortPath { name: name() });
        }
    }
    for (level, preset) in [
        ("beginner", &m.difficulty.beginner),
        ("advanced", &m.difficulty.advanced),
        ("expert", &m.difficulty.expert),
    ] {
        if let Some(g) = &preset.guided_path
            && !names.contains(g.as_str())
        {
            return Err(ManifestError::UnknownGuidedPath { level, path: g.clone() });
        }
    }
    Ok(m)
}

/// Volume files must be plain names inside the atlas directory (no paths, no "..").
fn check_file_name(name: &str) -> Result<(), PathProblem> {
    let ok = !name.is_empty()
        && name != "."
        && name != ".."
        && !name.contains('/')
        && !name.contains('\\')
        && !name.contains('\0');
    if !ok {
        return Err(PathProblem::NotPlainName);
    }
    if !(name.ends_with(".nii") || name.ends_with(".nii.gz")) {
        return Err(PathProblem::NotNifti);
    }
    Ok(())
}

/// A path the manifest names below the atlas folder (`motion/a1.nii.gz`): relative, of plain
/// components, never `..`.
fn check_inside(path: &str) -> Result<(), PathProblem> {
    let ok = !path.is_empty()
        && !path.contains(['\\', '\0'])
        && path
            .split('/')
            .all(|part| !part.is_empty() && part != "." && part != "..");
    if ok { Ok(()) } else { Err(PathProblem::OutsideAtlas) }
}

pub(crate) fn read_manifest_text(dir: &Path) -> Result<String, AtlasError> {
    if !dir.is_dir() {
        return Err(AtlasError::file(dir, "atlas directory does not exist"));
    }
    let path = dir.join(MANIFEST_FILE);
    crate::check_regular_file(&path)?;
    let file = fs::File::open(&path).map_err(|e| AtlasError::file(&path, format!("missing or unreadable: {e}")))?;
    let mut bytes = Vec::new();
    file.take(MAX_MANIFEST_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| AtlasError::file(&path, format!("cannot read: {e}")))?;
    if bytes.len() as u64 > MAX_MANIFEST_BYTES {
        return Err(AtlasError::file(
            &path,
            format!("larger than {MAX_MANIFEST_BYTES} bytes"),
        ));
    }
    String::from_utf8(bytes).map_err(|_| AtlasError::file(&path, "not UTF-8 text"))
}

pub(crate) fn sha256_file(path: &Path) -> Result<String, AtlasError> {
    crate::check_regular_file(path)?;
    let mut f = fs::File::open(path).map_err(|e| AtlasError::file(path, format!("cannot open: {e}")))?;
    let mut h = Sha256::new();
    std::io::copy(&mut f, &mut h).map_err(|e| AtlasError::file(path, format!("cannot read: {e}")))?;
    Ok(hex(&h.finalize()))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Reads and checks the `atlas.toml` of the atlas folder `dir` (no volume is read).
pub fn read_manifest(dir: &Path) -> Result<Manifest, AtlasError> {
    let text = read_manifest_text(dir)?;
    parse_manifest(&text).map_err(|e| manifest_error(dir, e))
}

/// The atlas content hash: SHA-256 of "stylet-atlas-v1\n" followed by one line
/// `"<file name> <sha256 of the file>\n"` for atlas.toml, the CT and the label map, in that order,
/// then for each measured breathing file (a1, a2, a3, signal) the atlas has.
pub fn content_hash(dir: &Path, manifest: &Manifest) -> Result<String, AtlasError> {
    let mut h = Sha256::new();
    h.update(b"stylet-atlas-v1\n");
    let breathing = manifest.breathing_or_default();
    let files = [
        MANIFEST_FILE,
        manifest.volumes.ct.as_str(),
        manifest.volumes.labels.as_str(),
    ];
    for name in files.into_iter().chain(breathing.measured_files()) {
        let digest = sha256_file(&dir.join(name))?;
        h.update(format!("{name} {digest}\n").as_bytes());
    }
    Ok(hex(&h.finalize()))
}

/// The voxels an atlas holds, from its files' headers alone (no volume is read): the CT's grid,
/// or the labels' when that is larger (the loader refuses a mismatch only after reading both),
/// plus each measured breathing field's grid. The memory and the derived-data cache of a load
/// grow with it: what a server checks against its limit before loading an atlas it is sent.
pub fn voxel_count(dir: &Path) -> Result<u64, AtlasError> {
    let text = read_manifest_text(dir)?;
    let manifest = parse_manifest(&text).map_err(|e| manifest_error(dir, e))?;
    let voxels = |grid: stylet_physics::Grid| grid.len() as u64;
    let ct = voxels(nifti_io::read_grid(&dir.join(&manifest.volumes.ct))?);
    let labels = voxels(nifti_io::read_grid(&dir.join(&manifest.volumes.labels))?);
    let breathing = manifest.breathing_or_default();
    let mut fields = 0u64;
    for name in breathing.measured_files() {
        if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            fields += voxels(nifti_io::read_field_grid(&dir.join(name))?);
        }
    }
    Ok(ct.max(labels) + fields)
}

/// Loads and validates an atlas directory, its distance maps from the derived-data cache when
/// it holds this atlas' content (else derived, and cached).
pub fn load(dir: &Path) -> Result<Atlas, AtlasError> {
    load_with(dir, CacheMode::Use)
}

/// As [`load`]; `CacheMode::Off` derives everything and leaves the cache alone.
pub fn load_with(dir: &Path, cache_mode: CacheMode) -> Result<Atlas, AtlasError> {
    let text = read_manifest_text(dir)?;
    let manifest = parse_manifest(&text).map_err(|e| manifest_error(dir, e))?;
    let labels = manifest::label_table(&manifest.labels, &manifest.heuristic).map_err(|e| manifest_error(dir, e))?;
    manifest::check_scenarios(&manifest.scenarios).map_err(|e| manifest_error(dir, e))?;
    let tree = manifest::property_tree(&manifest.tissues).map_err(|e| manifest_error(dir, e))?;

    let motion = crate::motion::load_motion(dir, &manifest.breathing_or_default())?;
    let ct_path = dir.join(&manifest.volumes.ct);
    let labels_path = dir.join(&manifest.volumes.labels);
    // The content hash keys the cache: the files are hashed and the cache is read (for the grid
    // the CT's header gives) while the volumes decompress.
    let ct_grid = nifti_io::read_grid(&ct_path)?;
    let ((ct, partial), hashed) = rayon::join(
        || rayon::join(|| nifti_io::read_ct(&ct_path), || nifti_io::read_labels(&labels_path)),
        || {
            content_hash(dir, &manifest).map(|hash| {
                let cached = match cache_mode {
                    CacheMode::Use => cache::read(dir, &hash, &ct_grid),
                    CacheMode::Off => Ok(None),
                };
                (hash, cached)
            })
        },
    );
    let (ct, partial, (content_hash, mut cached)) = (ct?, partial?, hashed?);
    check_same_grid(&ct_path, &ct, &labels_path, &partial)?;
    if ct.grid() != &ct_grid {
        // The CT changed between its header read and its load: derive from what was loaded.
        cached = Err(cache::CacheError::CtChanged);
    }

    let depth = manifest.heuristic.risk_depth_mm;
    let (thresholds, threshold_source) = match (&manifest.thresholds, &cached) {
        (Some(t), _) => (t.with_depth(depth), ThresholdSource::Atlas),
        (None, Ok(Some(d))) => (d.thresholds, ThresholdSource::Estimated),
        (None, _) => (
            estimate_thresholds(&ct, depth).map_err(|e| AtlasError::file(&ct_path, e.to_string()))?,
            ThresholdSource::Estimated,
        ),
    };
    if let Ok(Some(d)) = &cached
        && d.thresholds != thresholds
    {
        cached = Err(cache::CacheError::OtherThresholds(d.thresholds));
    }
    let (maps, refused) = match cached {
        Ok(Some(d)) => (Some(d.maps), None),
        Ok(None) => (None, None),
        Err(reason) => (None, Some(reason)),
    };
    let from_cache = maps.is_some();
    let model = PunctureAtlas::with_distance_maps(ct, partial, labels, tree, thresholds, maps)
        .and_then(|m| m.with_skin_layer_mm(manifest.heuristic.skin_layer_mm))
        .and_then(|m| m.with_breathing(motion))
        .map_err(|e| match e {
            PhysicsError::InvalidLabels(_) => AtlasError::file(&labels_path, e.to_string()),
            PhysicsError::NotFinite(_) => AtlasError::file(&ct_path, e.to_string()),
            PhysicsError::Mismatch(_) | PhysicsError::InvalidGrid(_) => {
                AtlasError::file(&labels_path, format!("{e} (CT: {})", ct_path.display()))
            }
            _ => AtlasError::file(dir.join(MANIFEST_FILE), e.to_string()),
        })?;
    let (lo, hi) = model.ct().grid().world_bounds();
    for p in &manifest.paths {
        for (what, v) in [("entry", p.entry_mm), ("target", p.target_mm)] {
            let v = DVec3::from_array(v);
            if v.cmplt(lo - 1e-6).any() || v.cmpgt(hi + 1e-6).any() {
                return Err(AtlasError::file(
                    dir.join(MANIFEST_FILE),
                    format!(
                        "insertion path '{}': {what} {v} mm lies outside the CT ({lo} … {hi} mm)",
                        p.name
                    ),
                ));
            }
        }
    }
    let model = std::sync::Arc::new(model);
    let cache = match (cache_mode, from_cache) {
        (CacheMode::Off, _) => cache::CacheWork::settled(CacheStatus::Disabled),
        (CacheMode::Use, true) => cache::CacheWork::settled(CacheStatus::Hit),
        (CacheMode::Use, false) => {
            let (model, dir, content_hash) = (model.clone(), dir.to_path_buf(), content_hash.clone());
            cache::CacheWork::spawn(move || {
                let derived = cache::DerivedRef {
                    thresholds: model.thresholds(),
                    skin_distance: model.skin_distance(),
                    bone_distance: model.bone_distance(),
                };
                match (cache::write(&dir, &content_hash, derived), refused) {
                    (Err(error), _) => CacheStatus::NotWritten {
                        error: error.to_string(),
                    },
                    (Ok(()), Some(refused)) => CacheStatus::Rebuilt {
                        refused: refused.to_string(),
                    },
                    (Ok(()), None) => CacheStatus::Written,
                }
            })
        }
    };
    Ok(Atlas {
        dir: dir.to_path_buf(),
        manifest,
        model,
        threshold_source,
        content_hash,
        cache: std::sync::Arc::new(cache),
    })
}

fn check_same_grid(
    ct_path: &Path,
    ct: &Volume<f32>,
    labels_path: &Path,
    labels: &Volume<LabelId>,
) -> Result<(), AtlasError> {
    let (a, b) = (ct.grid(), labels.grid());
    if a.dims() != b.dims() {
        return Err(AtlasError::file(
            labels_path,
            format!(
                "dimensions {:?} differ from the CT's {:?} ({})",
                b.dims(),
                a.dims(),
                ct_path.display()
            ),
        ));
    }
    let diff = a.affine().max_abs_diff(b.affine());
    if diff > 1e-3 {
        return Err(AtlasError::file(
            labels_path,
            format!(
                "affine differs from the CT's ({}) by up to {diff:.4} mm: labels {:?}, CT {:?}",
                ct_path.display(),
                b.affine().rows(),
                a.affine().rows()
            ),
        ));
    }
    Ok(())
}

/// Writes an atlas directory: volumes first, `atlas.toml` last, each through a temporary file
/// renamed into place, so a crash never leaves a manifest that points at half-written volumes.
/// Thresholds are written only if the manifest carries them.
pub fn write(dir: &Path, manifest: &Manifest, ct: &Volume<f32>, labels: &Volume<LabelId>) -> Result<(), AtlasError> {
    fs::create_dir_all(dir).map_err(|e| AtlasError::file(dir, format!("cannot create directory: {e}")))?;
    let text = manifest.to_toml();
    parse_manifest(&text).map_err(|e| refused_manifest(dir, e))?;
    let tmp = |name: &str| dir.join(format!(".{name}.partial.nii.gz"));
    let ct_tmp = tmp("ct");
    let labels_tmp = tmp("labels");
    let description = format!("stylet atlas {}", manifest.name);
    let (a, b) = rayon::join(
        || nifti_io::write_ct(&ct_tmp, ct, &description),
        || nifti_io::write_labels(&labels_tmp, labels, &description),
    );
    a?;
    b?;
    let rename = |from: &Path, to: &Path| {
        fs::rename(from, to).map_err(|e| AtlasError::file(to, format!("cannot move into place: {e}")))
    };
    rename(&ct_tmp, &dir.join(&manifest.volumes.ct))?;
    rename(&labels_tmp, &dir.join(&manifest.volumes.labels))?;
    write_manifest_text(dir, &text)
}

/// Rewrites `atlas.toml` alone (checked first), atomically.
pub(crate) fn write_manifest(dir: &Path, manifest: &Manifest) -> Result<(), AtlasError> {
    let text = manifest.to_toml();
    parse_manifest(&text).map_err(|e| refused_manifest(dir, e))?;
    write_manifest_text(dir, &text)
}

/// `text` as `atlas.toml`, through a temporary file renamed into place.
pub(crate) fn write_manifest_text(dir: &Path, text: &str) -> Result<(), AtlasError> {
    let manifest_tmp = dir.join(".atlas.toml.partial");
    fs::write(&manifest_tmp, text).map_err(|e| AtlasError::file(&manifest_tmp, format!("cannot write: {e}")))?;
    fs::rename(&manifest_tmp, dir.join(MANIFEST_FILE))
        .map_err(|e| AtlasError::file(dir.join(MANIFEST_FILE), format!("cannot move into place: {e}")))
}

impl Atlas {
    /// The thresholds in `atlas.toml` form (for summaries).
    pub fn thresholds_toml(&self) -> ThresholdsToml {
        ThresholdsToml::from_thresholds(self.model.thresholds())
    }

    /// The atlas' planned insertion paths (`[[paths]]`), as the physics, scripts and scoring use
    /// them.
    /// The path a beginner is guided along (else the first planned path): the one the example
    /// scripts follow. `None` without planned paths.
    pub fn guided_path(&self) -> Option<&crate::manifest::InsertionPath> {
        let guided = self.manifest.difficulty.beginner.guided_path.as_ref();
        let paths = &self.manifest.paths;
        paths.iter().find(|p| Some(&p.name) == guided).or(paths.first())
    }

    pub fn planned_paths(&self) -> Vec<stylet_physics::PlannedPath> {
        self.manifest
            .paths
            .iter()
            .map(|p| stylet_physics::PlannedPath {
                name: p.name.clone(),
                entry_mm: stylet_physics::glam::DVec3::from_array(p.entry_mm),
                target_mm: stylet_physics::glam::DVec3::from_array(p.target_mm),
            })
            .collect()
    }
}
