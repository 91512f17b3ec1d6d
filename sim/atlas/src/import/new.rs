//! `stylet atlas new`: a CT and an automatic segmentation become a PTCD atlas without a
//! hand-written recipe. The CT is a NIfTI file or a DICOM series folder; the labels are one
//! multi-label NIfTI (classes named by TotalSegmentator's built-in table or a CSV), a
//! TotalSegmentator output folder of per-structure masks (`liver.nii.gz`, …) or a binary DICOM SEG
//! (`super::dicom_seg`, feature `dicom`). The recipe is made from the structure names ([`super::auto`]) and the
//! importer does the rest (docs/atlas.md "New patients").

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use stylet_physics::{LabelId, Volume};

use super::classes::ClassTable;
use super::scripts::{self, GeneratedScript};
use super::steps::{Step, StepEvent, StepTimer};
use super::{ImportReport, Sources, auto, build};
use crate::{AtlasError, nifti_io};

/// Most per-structure masks read from a folder (TotalSegmentator's "total" task writes 117).
pub const MAX_MASK_FILES: usize = 1024;

/// What `atlas new` is given.
#[derive(Debug, Clone)]
pub struct NewAtlas {
    /// NIfTI CT in HU, or a folder holding one DICOM CT series.
    pub ct: PathBuf,
    /// A multi-label NIfTI, or a folder of per-structure NIfTI masks named by structure.
    pub labels: PathBuf,
    /// Class table (CSV, `id` and `structure` columns) of a multi-label map; TotalSegmentator's
    /// "total" classes when absent.
    pub classes: Option<PathBuf>,
    /// The user's corrections to the default mapping by structure name (CSV `structure,label`,
    /// [`super::mapping`]).
    pub map: Option<PathBuf>,
    /// Label voxel (i, j, k) is CT voxel (i, j, k) + offset (a cropped map that kept the CT's
    /// header, like TotalSegmentator's example); [0, 0, 0]: same grid and affine as the CT.
    pub offset_voxels: [i64; 3],
    pub name: String,
    /// Attach the synthetic breathing motion (`--no-breathing`: false).
    pub breathing: bool,
}

/// What `atlas new` made: the import's report, the atlas as loaded back (validated), and the
/// example scripts written to `out/scripts/`.
pub struct NewAtlasReport {
    pub import: ImportReport,
    pub atlas: crate::Atlas,
    pub scripts: Vec<GeneratedScript>,
}

/// Makes the atlas: reads and checks the inputs (the small ones first), writes it to `out`,
/// loads it back through the validating loader and writes the example scripts of its guided
/// path to `out/scripts/` (none without a path). `on_step` hears each step start and end (the
/// command's progress display); the report keeps the time of each.
pub fn new_atlas(
    args: &NewAtlas,
    out: &Path,
    on_step: &mut dyn FnMut(StepEvent),
) -> Result<NewAtlasReport, AtlasError> {
    let mut timer = StepTimer::new(on_step);
    let mut import = new_atlas_only(args, out, &mut timer)?;
    let atlas = timer.run(Step::Load, || crate::load(out))?;
    let scripts = match atlas.guided_path() {
        Some(p) => scripts::generate(&atlas.model, p),
        None => Vec::new(),
    };
    timer.run(Step::Scripts, || write_scripts(out, &scripts))?;
    import.timings = timer.timings.clone();
    Ok(NewAtlasReport { import, atlas, scripts })
}

/// The scripts into `out/scripts/`, each written beside its place and renamed into it.
pub fn write_scripts(out: &Path, scripts: &[GeneratedScript]) -> Result<(), AtlasError> {
    if scripts.is_empty() {
        return Ok(());
    }
    let dir = out.join("scripts");
    std::fs::create_dir_all(&dir).map_err(|e| AtlasError::file(&dir, format!("cannot create: {e}")))?;
    for s in scripts {
        let file = dir.join(&s.file_name);
        let tmp = dir.join(format!(".{}.partial", s.file_name));
        std::fs::write(&tmp, &s.text).map_err(|e| AtlasError::file(&tmp, format!("cannot write: {e}")))?;
        std::fs::rename(&tmp, &file).map_err(|e| AtlasError::file(&file, format!("cannot move into place: {e}")))?;
    }
    Ok(())
}

/// [`new_atlas`] without loading it back or writing scripts.
pub fn new_atlas_only(args: &NewAtlas, out: &Path, timer: &mut StepTimer) -> Result<ImportReport, AtlasError> {
    let name = args.name.trim();
    if name.is_empty() || name.len() > 64 {
        return Err(AtlasError::file(out, "the atlas name must be 1 … 64 characters"));
    }
    let mut classes = match &args.classes {
        Some(p) => ClassTable::read_csv(p)?,
        None => ClassTable::totalsegmentator(),
    };
    let overrides = args
        .map
        .as_deref()
        .map(super::mapping::MappingOverride::read_csv)
        .transpose()?;
    let seg = !args.labels.is_dir() && is_dicom_seg(&args.labels);
    if seg && args.classes.is_some() {
        return Err(AtlasError::file(
            &args.labels,
            "a DICOM SEG names its own segments; --classes is for a multi-label NIfTI",
        ));
    }
    if seg && args.offset_voxels != [0, 0, 0] {
        return Err(AtlasError::file(
            &args.labels,
            "a DICOM SEG places its frames by their positions; --offset-voxels is for a NIfTI label map",
        ));
    }
    let masks = if args.labels.is_dir() {
        if args.classes.is_some() {
            return Err(AtlasError::file(
                &args.labels,
                "a folder of per-structure masks is named by its file names; --classes is for one multi-label file",
            ));
        }
        Some(mask_files(&args.labels)?)
    } else {
        None
    };
    let mut notes = Vec::new();
    let ct = timer.run(Step::ReadCt, || read_ct(&args.ct, &mut notes))?;
    let mut labels = Volume::filled(*ct.grid(), 0 as LabelId);
    timer.run(Step::ReadLabels, || match masks {
        Some(files) => merge_masks(&files, &ct, &mut classes, &mut labels, &mut notes),
        None if seg => read_seg(&args.labels, &mut classes, &mut labels, &mut notes),
        None => {
            let l = nifti_io::read_labels(&args.labels)?;
            super::place_labels(ct.grid(), &l, args.offset_voxels, &args.labels, &mut labels, &mut notes)
        }
    })?;
    let present: BTreeSet<LabelId> = labels.data().iter().copied().filter(|&l| l != 0).collect();
    if present.is_empty() {
        return Err(AtlasError::file(&args.labels, "the label map labels no voxel"));
    }
    let mut recipe = auto::ptcd_recipe(name, &classes, &present, &args.labels, overrides.as_ref())?;
    recipe.recipe.breathing = Some(crate::manifest::BreathingToml::attached(args.breathing));
    notes.insert(
        0,
        format!(
            "{} structures found ({}), named by {}",
            present.len(),
            present
                .iter()
                .map(|&id| classes.describe(id))
                .collect::<Vec<_>>()
                .join(", "),
            classes.source
        ),
    );
    build(&recipe, Sources { ct, labels, notes }, classes, out, timer)
}

/// Whether the label file is a DICOM object (then a DICOM SEG), not a NIfTI file.
fn is_dicom_seg(path: &Path) -> bool {
    #[cfg(feature = "dicom")]
    {
        super::dicom_seg::is_dicom_file(path)
    }
    #[cfg(not(feature = "dicom"))]
    {
        let _ = path;
        false
    }
}

/// A DICOM SEG onto the CT's grid: each segment the class of its name (names the table lacks get
/// new classes after its last).
fn read_seg(
    path: &Path,
    classes: &mut ClassTable,
    labels: &mut Volume<LabelId>,
    notes: &mut Vec<String>,
) -> Result<(), AtlasError> {
    #[cfg(feature = "dicom")]
    {
        let mut class_of = |name: &str| classes.id_of(name).map_or_else(|| classes.add(name), Ok);
        let s = super::dicom_seg::read_seg(path, labels, &mut class_of)?;
        notes.push(format!(
            "labels from the DICOM SEG {} ({} segments in {} frames){}{}",
            path.display(),
            s.segments.len(),
            s.frames,
            if s.empty.is_empty() {
                String::new()
            } else {
                format!("; empty: {}", s.empty.join(", "))
            },
            if s.overlaps == 0 {
                String::new()
            } else {
                format!(
                    "; {} voxels claimed by two segments kept the lower-numbered",
                    s.overlaps
                )
            }
        ));
        Ok(())
    }
    #[cfg(not(feature = "dicom"))]
    {
        let _ = (classes, labels, notes);
        Err(AtlasError::file(path, "a DICOM SEG needs the `dicom` feature"))
    }
}

/// The CT: a NIfTI file, or a DICOM series folder.
fn read_ct(path: &Path, notes: &mut Vec<String>) -> Result<Volume<f32>, AtlasError> {
    if path.is_dir() {
        #[cfg(feature = "dicom")]
        {
            let series = super::dicom::read_series(path)?;
            notes.push(format!(
                "CT from the DICOM series in {} ({} slices)",
                path.display(),
                series.ct.grid().dims()[2]
            ));
            return Ok(series.ct);
        }
        #[cfg(not(feature = "dicom"))]
        {
            let _ = notes;
            return Err(AtlasError::file(path, "a DICOM series needs the `dicom` feature"));
        }
    }
    nifti_io::read_ct(path)
}

/// The NIfTI files of a mask folder, sorted by name, with their structure names (the file name
/// without `.nii` / `.nii.gz`). Other files are ignored; too many masks are refused.
fn mask_files(dir: &Path) -> Result<Vec<(String, PathBuf)>, AtlasError> {
    let mut files = Vec::new();
    let entries = std::fs::read_dir(dir).map_err(|e| AtlasError::file(dir, format!("cannot read the folder: {e}")))?;
    for entry in entries {
        let entry = entry.map_err(|e| AtlasError::file(dir, format!("cannot read the folder: {e}")))?;
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let Some(stem) = file_name
            .strip_suffix(".nii.gz")
            .or_else(|| file_name.strip_suffix(".nii"))
        else {
            continue;
        };
        if stem.is_empty() || stem.starts_with('.') {
            continue;
        }
        files.push((stem.to_string(), entry.path()));
        if files.len() > MAX_MASK_FILES {
            return Err(AtlasError::file(
                dir,
                format!("more than {MAX_MASK_FILES} NIfTI masks in the folder"),
            ));
        }
    }
    files.sort();
    if files.is_empty() {
        return Err(AtlasError::file(
            dir,
            "no NIfTI masks (<structure>.nii.gz) in the folder",
        ));
    }
    Ok(files)
}

/// Merges per-structure masks into one label map: each structure's class from the table by
/// name (names the table lacks get new classes after its last). Every header is checked against
/// the CT before any mask is read; a voxel two masks claim keeps the first (by file name).
fn merge_masks(
    files: &[(String, PathBuf)],
    ct: &Volume<f32>,
    classes: &mut ClassTable,
    labels: &mut Volume<LabelId>,
    notes: &mut Vec<String>,
) -> Result<(), AtlasError> {
    let grid = ct.grid();
    for (_, path) in files {
        let g = nifti_io::read_grid(path)?;
        if g.dims() != grid.dims() {
            return Err(AtlasError::file(
                path,
                format!("mask has dimensions {:?} but the CT has {:?}", g.dims(), grid.dims()),
            ));
        }
        let diff = grid.affine().max_abs_diff(g.affine());
        if diff > 1e-3 {
            return Err(AtlasError::file(
                path,
                format!("mask affine differs from the CT's by up to {diff:.4} mm (another patient or scan?)"),
            ));
        }
    }
    let (mut overlaps, mut empty) = (0usize, Vec::new());
    for (structure, path) in files {
        let id = classes
            .id_of(structure)
            .map_or_else(|| classes.add(structure), Ok)
            .map_err(|error| AtlasError::ClassTable {
                path: path.clone(),
                error,
            })?;
        let mask = nifti_io::read_labels(path)?;
        let mut any = false;
        for (dst, &m) in labels.data_mut().iter_mut().zip(mask.data()) {
            if m != 0 {
                any = true;
                if *dst == 0 {
                    *dst = id;
                } else {
                    overlaps += 1;
                }
            }
        }
        if !any {
            empty.push(structure.clone());
        }
    }
    notes.push(format!(
        "{} masks merged{}{}",
        files.len(),
        if empty.is_empty() {
            String::new()
        } else {
            format!("; empty (structure not found in this scan): {}", empty.join(", "))
        },
        if overlaps == 0 {
            String::new()
        } else {
            format!("; {overlaps} voxels claimed by two masks kept the first")
        }
    ));
    Ok(())
}
