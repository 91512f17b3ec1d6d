//! DICOM CT series import: every file of a directory is one slice of one series. Slices are sorted
//! by ImagePositionPatient along the slice normal, pixels are decoded (JPEG 2000 lossless included,
//! pure Rust) and rescaled to HU, and the geometry is converted from DICOM's LPS to the atlas' RAS
//! world space. The result is a heuristic-only atlas (no partial labels) with the PTCD scenario.

use std::path::{Path, PathBuf};

use dicom_dictionary_std::tags;
use dicom_object::{DefaultDicomObject, open_file};
use dicom_pixeldata::PixelDecoder;
use stylet_physics::glam::DVec3;
use stylet_physics::{Affine, Grid, LabelId, Volume};

use crate::AtlasError;
use crate::manifest::{Manifest, Provenance, ScenarioFile};

/// Most files a series may have.
const MAX_SLICES: usize = 4096;

/// A loaded series.
#[derive(Debug, Clone)]
pub struct Series {
    pub ct: Volume<f32>,
    pub series_uid: String,
    pub description: String,
    /// Distance between consecutive slice positions (mm): the grid's third spacing.
    pub slice_spacing_mm: f64,
    /// Nominal reconstructed slice thickness (SliceThickness, mm), when present; it can exceed the
    /// spacing for overlapping reconstructions.
    pub slice_thickness_mm: Option<f64>,
}

struct SliceInfo {
    path: PathBuf,
    obj: DefaultDicomObject,
    position_lps: DVec3,
}

fn floats(
    obj: &DefaultDicomObject,
    tag: dicom_object::Tag,
    name: &str,
    path: &Path,
    n: usize,
) -> Result<Vec<f64>, AtlasError> {
    let v = obj
        .element(tag)
        .map_err(|_| AtlasError::file(path, format!("missing {name}")))?
        .to_multi_float64()
        .map_err(|e| AtlasError::file(path, format!("{name} is not numeric: {e}")))?;
    if v.len() != n || v.iter().any(|x| !x.is_finite()) {
        return Err(AtlasError::file(
            path,
            format!("{name} must hold {n} finite numbers, got {v:?}"),
        ));
    }
    Ok(v)
}

fn text(obj: &DefaultDicomObject, tag: dicom_object::Tag) -> String {
    obj.element(tag)
        .ok()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim_end_matches(['\0', ' ']).to_string())
        .unwrap_or_default()
}

/// Reads a DICOM CT series from a directory.
pub fn read_series(dir: &Path) -> Result<Series, AtlasError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| AtlasError::file(dir, format!("cannot list directory: {e}")))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| !p.is_dir() && !p.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.')))
        .filter(|p| {
            !p.file_name()
                .is_some_and(|n| n.to_string_lossy().to_ascii_lowercase().ends_with(".md"))
        })
        .collect();
    // Subdirectories are skipped; a FIFO or device among the slices is an error, not a hang.
    for p in &files {
        crate::check_regular_file(p)?;
    }
    files.retain(|p| p.is_file());
    files.sort();
    if files.is_empty() {
        return Err(AtlasError::file(dir, "no files in the series directory"));
    }
    if files.len() > MAX_SLICES {
        return Err(AtlasError::file(
            dir,
            format!("{} files; a series may have at most {MAX_SLICES}", files.len()),
        ));
    }
    let mut slices = Vec::with_capacity(files.len());
    for path in files {
        let obj = open_file(&path).map_err(|e| AtlasError::file(&path, format!("not a readable DICOM file: {e}")))?;
        let pos = floats(&obj, tags::IMAGE_POSITION_PATIENT, "ImagePositionPatient", &path, 3)?;
        slices.push(SliceInfo {
            position_lps: DVec3::new(pos[0], pos[1], pos[2]),
            obj,
            path,
        });
    }
    let first = &slices[0];
    let iop = floats(
        &first.obj,
        tags::IMAGE_ORIENTATION_PATIENT,
        "ImageOrientationPatient",
        &first.path,
        6,
    )?;
    let spacing = floats(&first.obj, tags::PIXEL_SPACING, "PixelSpacing", &first.path, 2)?;
    let rows: u32 = first
        .obj
        .element(tags::ROWS)
        .ok()
        .and_then(|e| e.to_int().ok())
        .ok_or_else(|| AtlasError::file(&first.path, "missing Rows"))?;
    let cols: u32 = first
        .obj
        .element(tags::COLUMNS)
        .ok()
        .and_then(|e| e.to_int().ok())
        .ok_or_else(|| AtlasError::file(&first.path, "missing Columns"))?;
    let series_uid = text(&first.obj, tags::SERIES_INSTANCE_UID);
    let description = text(&first.obj, tags::SERIES_DESCRIPTION);
    let row_dir = DVec3::new(iop[0], iop[1], iop[2]);
    let col_dir = DVec3::new(iop[3], iop[4], iop[5]);
    if (row_dir.length() - 1.0).abs() > 1e-3
        || (col_dir.length() - 1.0).abs() > 1e-3
        || row_dir.dot(col_dir).abs() > 1e-3
    {
        return Err(AtlasError::file(
            &first.path,
            format!("ImageOrientationPatient {iop:?} is not two orthonormal directions"),
        ));
    }
    if spacing.iter().any(|&s| s <= 0.0) || rows == 0 || cols == 0 {
        return Err(AtlasError::file(
            &first.path,
            "PixelSpacing, Rows and Columns must be positive",
        ));
    }
    let normal = row_dir.cross(col_dir);
    for s in &slices[1..] {
        let same = text(&s.obj, tags::SERIES_INSTANCE_UID) == series_uid
            && floats(
                &s.obj,
                tags::IMAGE_ORIENTATION_PATIENT,
                "ImageOrientationPatient",
                &s.path,
                6,
            )? == iop
            && floats(&s.obj, tags::PIXEL_SPACING, "PixelSpacing", &s.path, 2)? == spacing
            && s.obj.element(tags::ROWS).ok().and_then(|e| e.to_int::<u32>().ok()) == Some(rows)
            && s.obj.element(tags::COLUMNS).ok().and_then(|e| e.to_int::<u32>().ok()) == Some(cols);
        if !same {
            return Err(AtlasError::file(
                &s.path,
                "belongs to another series or has another geometry than the first file",
            ));
        }
    }
    let (rows, cols) = (rows, cols);
    // Sort along the slice normal.
    slices.sort_by(|a, b| a.position_lps.dot(normal).total_cmp(&b.position_lps.dot(normal)));
    let n = slices.len();
    let first_path = slices[0].path.clone();
    let slice_spacing = if n > 1 {
        let gaps: Vec<f64> = slices
            .windows(2)
            .map(|w| (w[1].position_lps - w[0].position_lps).dot(normal))
            .collect();
        let mean = gaps.iter().sum::<f64>() / gaps.len() as f64;
        if let Some((i, g)) = gaps
            .iter()
            .enumerate()
            .find(|(_, g)| (**g - mean).abs() > 0.01 * mean.abs().max(0.1) || **g <= 1e-6)
        {
            return Err(AtlasError::file(
                &slices[i + 1].path,
                format!("slice gap {g:.3} mm differs from the series' mean {mean:.3} mm (missing or duplicate slice?)"),
            ));
        }
        mean
    } else {
        floats(&slices[0].obj, tags::SLICE_THICKNESS, "SliceThickness", &first_path, 1)
            .map(|v| v[0])
            .unwrap_or(1.0)
    };
    let slice_thickness_mm = floats(&slices[0].obj, tags::SLICE_THICKNESS, "SliceThickness", &first_path, 1)
        .ok()
        .map(|v| v[0]);
    let slice_dir = if n > 1 {
        (slices[n - 1].position_lps - slices[0].position_lps).normalize()
    } else {
        normal
    };

    let (nx, ny) = (cols as usize, rows as usize);
    let mut data = vec![0.0f32; nx * ny * n];
    for (k, s) in slices.iter().enumerate() {
        let decoded = s
            .obj
            .decode_pixel_data()
            .map_err(|e| AtlasError::file(&s.path, format!("cannot decode pixel data: {e}")))?;
        let arr = decoded
            .to_ndarray::<f32>()
            .map_err(|e| AtlasError::file(&s.path, format!("cannot convert pixel data: {e}")))?;
        let shape = arr.shape().to_vec();
        if shape.len() != 4 || shape[0] != 1 || shape[1] != ny || shape[2] != nx || shape[3] != 1 {
            return Err(AtlasError::file(
                &s.path,
                format!("pixel data has shape {shape:?}, expected one {ny}×{nx} grey frame"),
            ));
        }
        for r in 0..ny {
            for c in 0..nx {
                let v = arr[[0, r, c, 0]];
                if !v.is_finite() {
                    return Err(AtlasError::file(&s.path, format!("pixel ({c}, {r}) is not a number")));
                }
                data[c + nx * (r + ny * k)] = v;
            }
        }
    }
    // LPS → RAS: negate x and y. Index i runs along the row direction (columns), j along rows.
    let lps_to_ras = |v: DVec3| DVec3::new(-v.x, -v.y, v.z);
    let affine = Affine {
        axes: [
            lps_to_ras(row_dir * spacing[1]),
            lps_to_ras(col_dir * spacing[0]),
            lps_to_ras(slice_dir * slice_spacing),
        ],
        origin: lps_to_ras(slices[0].position_lps),
    };
    let grid = Grid::new([nx, ny, n], affine).map_err(|e| AtlasError::file(dir, e.to_string()))?;
    let ct = Volume::new(grid, data).map_err(|e| AtlasError::file(dir, e.to_string()))?;
    Ok(Series {
        ct,
        series_uid,
        description,
        slice_spacing_mm: slice_spacing,
        slice_thickness_mm,
    })
}

/// Imports a series as a heuristic-only PTCD atlas.
pub fn import_series(dir: &Path, out: &Path, name: &str) -> Result<Series, AtlasError> {
    let series = read_series(dir)?;
    let labels: Volume<LabelId> = Volume::filled(*series.ct.grid(), 0);
    let mut scenario = ScenarioFile::ptcd();
    scenario.keep_labels(|_| false);
    let provenance = Provenance {
        source: format!(
            "DICOM series {} ({})",
            if series.series_uid.is_empty() {
                "without SeriesInstanceUID"
            } else {
                series.series_uid.as_str()
            },
            series.description
        ),
        generator: format!(
            "stylet {} (atlas import-dicom {})",
            env!("CARGO_PKG_VERSION"),
            dir.display()
        ),
        seed: None,
        license: String::new(),
        citation: String::new(),
        notes: vec![
            format!(
                "{} slices, slice spacing {:.3} mm, slice thickness {}, LPS converted to RAS",
                series.ct.grid().dims()[2],
                series.slice_spacing_mm,
                series
                    .slice_thickness_mm
                    .map(|t| format!("{t:.3} mm"))
                    .unwrap_or_else(|| "not given".into())
            ),
            "no partial labels: every structure comes from the heuristic".into(),
        ],
    };
    let mut manifest = Manifest::new(name, "CT imported from a DICOM series", provenance, scenario);
    // No organ is labelled, so nothing places the diaphragm: this patient does not breathe.
    manifest.breathing = Some(crate::manifest::BreathingToml::attached(false));
    crate::write(out, &manifest, &series.ct, &labels)?;
    Ok(series)
}
