//! Reading and writing 3-D NIfTI-1 volumes (`.nii` or `.nii.gz`) with hard limits.
//!
//! The `nifti` crate parses and writes the header; the voxel data is read here, after the header
//! has been checked (supported type, 3-D, at most [`MAX_VOXELS`], sane offset), so a hostile or
//! truncated file gives an error naming the problem instead of a panic or a huge allocation.
//! Geometry comes from the sform when present, else the qform, else the voxel sizes (NIfTI-1 §
//! "Orientation"), in the file's world space (RAS+ for NIfTI).

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use flate2::read::MultiGzDecoder;
use nifti::{Endianness, NiftiHeader, writer::WriterOptions};
use stylet_physics::glam::DVec3;
use stylet_physics::grid::MAX_VOXELS;
use stylet_physics::motion::GridField;
use stylet_physics::{Affine, Grid, LabelId, Volume};

use crate::AtlasError;

/// Most bytes of voxel data we read from one file (1 GiB).
const MAX_DATA_BYTES: usize = 1 << 30;
/// Largest extension block we skip between the header and the data (1 MiB).
const MAX_EXTENSION_BYTES: f64 = (1 << 20) as f64;

/// The voxel types we read (NIfTI datatype codes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum DType {
    U8,
    I8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl DType {
    fn from_code(code: i16) -> Option<DType> {
        Some(match code {
            2 => DType::U8,
            256 => DType::I8,
            4 => DType::I16,
            512 => DType::U16,
            8 => DType::I32,
            768 => DType::U32,
            16 => DType::F32,
            64 => DType::F64,
            _ => return None,
        })
    }

    fn size_of(self) -> usize {
        match self {
            DType::U8 | DType::I8 => 1,
            DType::I16 | DType::U16 => 2,
            DType::I32 | DType::U32 | DType::F32 => 4,
            DType::F64 => 8,
        }
    }
}

/// A volume as stored: grid, the voxel bytes, their type and the file's scaling.
struct RawVolume {
    grid: Grid,
    bytes: Vec<u8>,
    dtype: DType,
    little: bool,
    /// `scl_slope` and `scl_inter` when they change values (else `None`).
    scaling: Option<(f64, f64)>,
}

/// Calls `$f` with every `$t` of the bytes `$raw`, little- or big-endian as `$little` says.
macro_rules! each_word {
    ($raw:expr, $little:expr, $t:ty, $f:expr) => {{
        const N: usize = std::mem::size_of::<$t>();
        let mut f = $f;
        for c in $raw.chunks_exact(N) {
            let b: [u8; N] = c.try_into().expect("chunk size");
            f(if $little {
                <$t>::from_le_bytes(b)
            } else {
                <$t>::from_be_bytes(b)
            });
        }
    }};
}

impl RawVolume {
    /// Calls `f` with every value in file order, converted to f64 with the scaling applied; one
    /// loop per voxel type, no intermediate buffer.
    fn for_each_value(&self, mut f: impl FnMut(f64)) {
        let scaled = |v: f64| match self.scaling {
            Some((slope, inter)) => v * slope + inter,
            None => v,
        };
        let raw = &self.bytes;
        let little = self.little;
        macro_rules! conv {
            ($t:ty) => {
                each_word!(raw, little, $t, |v: $t| f(scaled(v as f64)))
            };
        }
        match self.dtype {
            DType::U8 => raw.iter().for_each(|&b| f(scaled(b as f64))),
            DType::I8 => raw.iter().for_each(|&b| f(scaled(b as i8 as f64))),
            DType::I16 => conv!(i16),
            DType::U16 => conv!(u16),
            DType::I32 => conv!(i32),
            DType::U32 => conv!(u32),
            DType::F32 => conv!(f32),
            DType::F64 => conv!(f64),
        }
    }

    /// Calls `f` with every value when the file holds integers without scaling (label maps):
    /// no float round trip. `false` (and no call) for other files.
    fn for_each_integer(&self, mut f: impl FnMut(i64)) -> bool {
        if self.scaling.is_some() {
            return false;
        }
        let raw = &self.bytes;
        let little = self.little;
        macro_rules! conv {
            ($t:ty) => {
                each_word!(raw, little, $t, |v: $t| f(v as i64))
            };
        }
        match self.dtype {
            DType::U8 => raw.iter().for_each(|&b| f(b as i64)),
            DType::I8 => raw.iter().for_each(|&b| f(b as i8 as i64)),
            DType::I16 => conv!(i16),
            DType::U16 => conv!(u16),
            DType::I32 => conv!(i32),
            DType::U32 => conv!(u32),
            DType::F32 | DType::F64 => return false,
        }
        true
    }

    /// Every value as f64 (for fields read component by component).
    fn values(&self) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.bytes.len() / self.dtype.size_of());
        self.for_each_value(|v| out.push(v));
        out
    }
}

fn err(path: &Path, message: impl Into<String>) -> AtlasError {
    AtlasError::file(path, message)
}

/// Whether the file starts with the gzip magic.
fn is_gzip(path: &Path) -> Result<bool, AtlasError> {
    let mut file = File::open(path).map_err(|e| err(path, format!("cannot open: {e}")))?;
    let mut magic = [0u8; 2];
    let n = file
        .read(&mut magic)
        .map_err(|e| err(path, format!("cannot read: {e}")))?;
    Ok(n == 2 && magic == [0x1f, 0x8b])
}

/// A reader of the file's bytes (decompressed when it is gzip) and whether it is gzip.
fn open_checked(path: &Path) -> Result<(Box<dyn Read>, bool), AtlasError> {
    crate::check_regular_file(path)?;
    let gzip = is_gzip(path)?;
    let file = BufReader::with_capacity(
        1 << 20,
        File::open(path).map_err(|e| err(path, format!("cannot open: {e}")))?,
    );
    if gzip {
        Ok((
            Box::new(BufReader::with_capacity(1 << 20, MultiGzDecoder::new(file))),
            true,
        ))
    } else {
        Ok((Box::new(file), false))
    }
}

fn open(path: &Path) -> Result<Box<dyn Read>, AtlasError> {
    open_checked(path).map(|(r, _)| r)
}

/// Reads just the header and the grid it describes (cheap: used to compare files).
pub fn read_grid(path: &Path) -> Result<Grid, AtlasError> {
    let mut r = open(path)?;
    let header = NiftiHeader::from_reader(&mut r).map_err(|e| err(path, format!("not a NIfTI-1 file: {e}")))?;
    Ok(check_header(path, &header, Shape::Scalar)?.0)
}

/// Reads just the header of a displacement field ([`read_displacement_field`]'s shape) and the
/// grid it describes.
pub fn read_field_grid(path: &Path) -> Result<Grid, AtlasError> {
    let mut r = open(path)?;
    let header = NiftiHeader::from_reader(&mut r).map_err(|e| err(path, format!("not a NIfTI-1 file: {e}")))?;
    Ok(check_header(path, &header, Shape::Vector3)?.0)
}

/// What a file must hold per voxel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Shape {
    /// One value: a 3-D volume (trailing dimensions of 1 allowed).
    Scalar,
    /// Three components: ITK's vector image, dimensions (x, y, z, 1, 3).
    Vector3,
}

/// Validates the header; returns the grid and the data type.
fn check_header(path: &Path, h: &NiftiHeader, shape: Shape) -> Result<(Grid, DType), AtlasError> {
    if &h.magic != b"n+1\0" {
        return Err(err(
            path,
            "only single-file NIfTI-1 (.nii / .nii.gz) is supported (magic is not \"n+1\")",
        ));
    }
    let rank = h.dim[0];
    if !(1..=7).contains(&rank) {
        return Err(err(
            path,
            format!("dim[0] = {rank} is not a valid number of dimensions"),
        ));
    }
    let dims: Vec<usize> = (1..=rank as usize).map(|a| h.dim[a] as usize).collect();
    if dims.contains(&0) {
        return Err(err(path, format!("dimension list {dims:?} contains a zero")));
    }
    match shape {
        Shape::Scalar if dims.len() > 3 && dims[3..].iter().any(|&d| d != 1) => {
            return Err(err(path, format!("expected a 3-D volume, got dimensions {dims:?}")));
        }
        Shape::Vector3 if !(dims.len() == 5 && dims[3] == 1 && dims[4] == 3) => {
            return Err(err(
                path,
                format!(
                    "expected a displacement field of dimensions (x, y, z, 1, 3) as ITK and ANTs write them, got {dims:?}"
                ),
            ));
        }
        _ => {}
    }
    let d3 = [dims[0], *dims.get(1).unwrap_or(&1), *dims.get(2).unwrap_or(&1)];
    let n = d3[0] as u128 * d3[1] as u128 * d3[2] as u128;
    if n > MAX_VOXELS as u128 {
        return Err(err(
            path,
            format!("dimensions {d3:?} exceed the limit of {MAX_VOXELS} voxels"),
        ));
    }
    let dtype = DType::from_code(h.datatype)
        .ok_or_else(|| err(path, format!("unsupported NIfTI datatype code {}", h.datatype)))?;
    if !h.vox_offset.is_finite() || (h.vox_offset as f64) < 348.0 || h.vox_offset as f64 > 348.0 + MAX_EXTENSION_BYTES {
        return Err(err(
            path,
            format!("vox_offset {} is outside 348 … 348 + 1 MiB", h.vox_offset),
        ));
    }
    let affine = header_affine(h).map_err(|e| err(path, e.to_string()))?;
    let grid = Grid::new(d3, affine).map_err(|e| err(path, e.to_string()))?;
    Ok((grid, dtype))
}

/// Why a header's voxel-to-world transform cannot be used.
#[derive(Debug, thiserror::Error)]
enum AffineError {
    #[error("sform contains non-finite numbers")]
    SformNotFinite,
    #[error("voxel sizes (pixdim) {0:?} must be finite and positive")]
    VoxelSizes(Vec<f64>),
    #[error("qform contains non-finite numbers")]
    QformNotFinite,
}

/// sform if its code is set, else qform, else the voxel sizes (NIfTI-1 methods 3, 2, 1).
fn header_affine(h: &NiftiHeader) -> Result<Affine, AffineError> {
    let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
    if h.sform_code > 0 {
        if !finite(&h.srow_x) || !finite(&h.srow_y) || !finite(&h.srow_z) {
            return Err(AffineError::SformNotFinite);
        }
        let r = |s: [f32; 4]| [s[0] as f64, s[1] as f64, s[2] as f64, s[3] as f64];
        return Ok(Affine::from_rows([r(h.srow_x), r(h.srow_y), r(h.srow_z)]));
    }
    let pix: Vec<f64> = h.pixdim[1..4].iter().map(|&p| p as f64).collect();
    if pix.iter().any(|p| !p.is_finite() || *p <= 0.0) {
        return Err(AffineError::VoxelSizes(pix));
    }
    if h.qform_code > 0 {
        let (b, c, d) = (h.quatern_b as f64, h.quatern_c as f64, h.quatern_d as f64);
        let off = [h.quatern_x as f64, h.quatern_y as f64, h.quatern_z as f64];
        if ![b, c, d].iter().chain(off.iter()).all(|v| v.is_finite()) {
            return Err(AffineError::QformNotFinite);
        }
        let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
        let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let r = [
            [
                a * a + b * b - c * c - d * d,
                2.0 * (b * c - a * d),
                2.0 * (b * d + a * c),
            ],
            [
                2.0 * (b * c + a * d),
                a * a + c * c - b * b - d * d,
                2.0 * (c * d - a * b),
            ],
            [
                2.0 * (b * d - a * c),
                2.0 * (c * d + a * b),
                a * a + d * d - c * c - b * b,
            ],
        ];
        let col = |j: usize, s: f64| DVec3::new(r[0][j] * s, r[1][j] * s, r[2][j] * s);
        return Ok(Affine {
            axes: [col(0, pix[0]), col(1, pix[1]), col(2, pix[2] * qfac)],
            origin: DVec3::new(off[0], off[1], off[2]),
        });
    }
    Ok(Affine::from_spacing([pix[0], pix[1], pix[2]], DVec3::ZERO))
}

fn read_raw(path: &Path) -> Result<RawVolume, AtlasError> {
    read_raw_shaped(path, Shape::Scalar)
}

/// The file's values (for a vector image: every voxel's first component, then every second,
/// then every third) after the header is checked for `shape`.
fn read_raw_shaped(path: &Path, shape: Shape) -> Result<RawVolume, AtlasError> {
    let (mut r, gzip) = open_checked(path)?;
    let h = NiftiHeader::from_reader(&mut r).map_err(|e| err(path, format!("not a NIfTI-1 file: {e}")))?;
    let (grid, dtype) = check_header(path, &h, shape)?;
    if shape == Shape::Vector3 {
        // NIFTI_INTENT_DISPVECT (1006) or NIFTI_INTENT_VECTOR (1007, ITK); 0 from tools that leave it.
        if ![0, 1006, 1007].contains(&h.intent_code) {
            return Err(err(
                path,
                format!(
                    "intent code {} is not a vector (1007, as ITK writes) or displacement (1006)",
                    h.intent_code
                ),
            ));
        }
        if !matches!(dtype, DType::F32 | DType::F64) {
            return Err(err(path, "a displacement field must hold float32 or float64 values"));
        }
    }
    let components = if shape == Shape::Vector3 { 3 } else { 1 };
    // Skip the extension block between the 348-byte header and the data.
    let skip = (h.vox_offset as u64).saturating_sub(348);
    let skipped = std::io::copy(&mut (&mut r).take(skip), &mut std::io::sink())
        .map_err(|e| err(path, format!("cannot read: {e}")))?;
    if skipped != skip {
        return Err(err(
            path,
            format!("file ends inside the header extensions ({skipped} of {skip} bytes)"),
        ));
    }
    let size = dtype.size_of();
    let nbytes = grid.len() * size * components;
    if nbytes > MAX_DATA_BYTES {
        return Err(err(
            path,
            format!("{nbytes} bytes of voxel data exceed the limit of {MAX_DATA_BYTES}"),
        ));
    }
    // Reserved up front only as far as the file can hold (deflate expands at most 1032-fold; an
    // uncompressed file holds at most its size), so a header that promises more than the file
    // holds cannot make us allocate it.
    let file_bytes = std::fs::metadata(path).map(|m| m.len() as usize).unwrap_or(0);
    let expansion = if gzip { 1032 } else { 1 };
    let mut raw = Vec::with_capacity(nbytes.min(file_bytes.saturating_mul(expansion)));
    let got = (&mut r)
        .take(nbytes as u64)
        .read_to_end(&mut raw)
        .map_err(|e| err(path, format!("cannot read voxel data: {e}")))?;
    if got != nbytes {
        return Err(err(
            path,
            format!("file is truncated: {got} of {nbytes} bytes of voxel data"),
        ));
    }
    let (slope, inter) = (h.scl_slope as f64, h.scl_inter as f64);
    let scales = slope != 0.0 && slope.is_finite() && inter.is_finite() && (slope != 1.0 || inter != 0.0);
    Ok(RawVolume {
        grid,
        bytes: raw,
        dtype,
        little: h.endianness == Endianness::Little,
        scaling: scales.then_some((slope, inter)),
    })
}

/// Reads a CT volume in HU. Non-finite values are an error naming the first voxel.
pub fn read_ct(path: &Path) -> Result<Volume<f32>, AtlasError> {
    let raw = read_raw(path)?;
    let mut data = Vec::with_capacity(raw.grid.len());
    let mut bad = None;
    raw.for_each_value(|v| {
        if bad.is_none() && (!v.is_finite() || v.abs() > 1e6) {
            bad = Some((data.len(), v));
        }
        data.push(v as f32);
    });
    if let Some((pos, v)) = bad {
        let [i, j, k] = raw.grid.unlinear(pos);
        return Err(err(
            path,
            format!("voxel ({i}, {j}, {k}) holds {v} which is not a CT value"),
        ));
    }
    Volume::new(raw.grid, data).map_err(|e| err(path, e.to_string()))
}

/// The largest displacement a field may hold (mm): breathing moves organs by centimetres.
pub const MAX_DISPLACEMENT_MM: f64 = 100.0;

/// Reads a displacement field as ITK and ANTs write it (docs/breathing.md "Measured motion"): a
/// NIfTI vector image of dimensions (x, y, z, 1, 3), float, intent 1007 (or 1006, or unset), the
/// vectors in ITK's LPS physical space (mm), the grid in the header's RAS world. Returned in
/// Stylet's RAS: (−x, −y, z). Each vector must be finite and at most [`MAX_DISPLACEMENT_MM`].
pub fn read_displacement_field(path: &Path) -> Result<GridField, AtlasError> {
    let raw = read_raw_shaped(path, Shape::Vector3)?;
    let n = raw.grid.len();
    let components = raw.values();
    let mut values = Vec::with_capacity(n);
    for i in 0..n {
        let lps = [components[i], components[n + i], components[2 * n + i]];
        let length = (lps[0] * lps[0] + lps[1] * lps[1] + lps[2] * lps[2]).sqrt();
        if !(length.is_finite() && length <= MAX_DISPLACEMENT_MM) {
            let [x, y, z] = raw.grid.unlinear(i);
            return Err(err(
                path,
                format!(
                    "the displacement at voxel ({x}, {y}, {z}) is {lps:?} mm: each must be finite and at most {MAX_DISPLACEMENT_MM} mm long"
                ),
            ));
        }
        values.push([-lps[0] as f32, -lps[1] as f32, lps[2] as f32]);
    }
    GridField::new(raw.grid, values).map_err(|e| err(path, e.to_string()))
}

/// Writes a displacement field the way [`read_displacement_field`] reads it (ITK's convention:
/// LPS vectors, intent 1007, float32).
pub fn write_displacement_field(path: &Path, field: &GridField, description: &str) -> Result<(), AtlasError> {
    let grid = field.grid();
    let [nx, ny, nz] = grid.dims();
    let n = grid.len();
    let mut data = vec![0.0f32; 3 * n];
    for (i, v) in field.values().iter().enumerate() {
        data[i] = -v[0];
        data[n + i] = -v[1];
        data[2 * n + i] = v[2];
    }
    use ndarray::ShapeBuilder;
    let array = ndarray::Array5::from_shape_vec((nx, ny, nz, 1, 3).f(), data).map_err(|e| err(path, e.to_string()))?;
    let mut header = header_for(grid, description);
    header.intent_code = 1007;
    WriterOptions::new(path)
        .reference_header(&header)
        .write_nifti(&array)
        .map_err(|e| err(path, format!("cannot write: {e}")))
}

/// Reads a label map: whole numbers from 0 to 65535.
pub fn read_labels(path: &Path) -> Result<Volume<LabelId>, AtlasError> {
    let raw = read_raw(path)?;
    let mut data = Vec::with_capacity(raw.grid.len());
    let mut bad = None;
    let integers = raw.for_each_integer(|v| {
        if bad.is_none() && !(0..=LabelId::MAX as i64).contains(&v) {
            bad = Some((data.len(), v as f64));
        }
        data.push(v as LabelId);
    });
    if !integers {
        raw.for_each_value(|v| {
            if bad.is_none() && !(v.is_finite() && v >= 0.0 && v <= LabelId::MAX as f64 && v.fract() == 0.0) {
                bad = Some((data.len(), v));
            }
            data.push(v as LabelId);
        });
    }
    if let Some((pos, v)) = bad {
        let [i, j, k] = raw.grid.unlinear(pos);
        return Err(err(
            path,
            format!("voxel ({i}, {j}, {k}) holds {v}, not a label number 0 … 65535"),
        ));
    }
    Volume::new(raw.grid, data).map_err(|e| err(path, e.to_string()))
}

fn header_for(grid: &Grid, description: &str) -> NiftiHeader {
    let rows = grid.affine().rows();
    let f = |r: [f64; 4]| [r[0] as f32, r[1] as f32, r[2] as f32, r[3] as f32];
    let s = grid.spacing_mm();
    let mut h = NiftiHeader {
        sform_code: 1,
        qform_code: 0,
        srow_x: f(rows[0]),
        srow_y: f(rows[1]),
        srow_z: f(rows[2]),
        xyzt_units: 2, // millimetres
        ..NiftiHeader::default()
    };
    h.pixdim[0] = 1.0;
    h.pixdim[1] = s[0] as f32;
    h.pixdim[2] = s[1] as f32;
    h.pixdim[3] = s[2] as f32;
    // An axis-aligned grid also gets the equivalent qform (identity rotation) for older viewers.
    let axes = grid.affine().axes;
    if axes[0].y == 0.0
        && axes[0].z == 0.0
        && axes[1].x == 0.0
        && axes[1].z == 0.0
        && axes[2].x == 0.0
        && axes[2].y == 0.0
        && axes[0].x > 0.0
        && axes[1].y > 0.0
        && axes[2].z > 0.0
    {
        h.qform_code = 1;
        h.quatern_b = 0.0;
        h.quatern_c = 0.0;
        h.quatern_d = 0.0;
        h.quatern_x = rows[0][3] as f32;
        h.quatern_y = rows[1][3] as f32;
        h.quatern_z = rows[2][3] as f32;
    }
    let mut d = description.as_bytes().to_vec();
    d.truncate(79);
    d.resize(80, 0);
    h.descrip = d;
    h
}

fn write_array<T: nifti::DataElement + bytemuck::Pod>(
    path: &Path,
    grid: &Grid,
    data: Vec<T>,
    description: &str,
) -> Result<(), AtlasError> {
    let [nx, ny, nz] = grid.dims();
    use ndarray::ShapeBuilder;
    let array = ndarray::Array3::from_shape_vec((nx, ny, nz).f(), data).map_err(|e| err(path, e.to_string()))?;
    let header = header_for(grid, description);
    WriterOptions::new(path)
        .reference_header(&header)
        .write_nifti(&array)
        .map_err(|e| err(path, format!("cannot write: {e}")))
}

/// A float32 image on a plane in world space (RAS+, mm): pixel (i, j) lies at
/// `origin_mm + i · col_mm + j · row_mm`; `normal` (unit) completes the affine. Pixel (i, j) is
/// `values[j · width + i]`.
#[derive(Debug, Clone, Copy)]
pub struct PlaneImage<'a> {
    pub width: usize,
    pub height: usize,
    pub origin_mm: [f64; 3],
    pub col_mm: [f64; 3],
    pub row_mm: [f64; 3],
    pub normal: [f64; 3],
    pub values: &'a [f32],
}

/// Writes `image` as a 2D float32 NIfTI-1 (`.nii` or `.nii.gz`): the sform (code 1, scanner
/// RAS+) places every pixel where it lies, pixdim holds the pixel pitch, `descrip` says what the
/// values are (at most 79 bytes) and `intent_name` names them (at most 15).
pub fn write_plane_f32(
    path: &Path,
    image: &PlaneImage,
    description: &str,
    intent_name: &str,
) -> Result<(), AtlasError> {
    let (w, h) = (image.width, image.height);
    if w == 0 || h == 0 || image.values.len() != w * h {
        return Err(err(
            path,
            format!("a {w} × {h} image needs {} values, not {}", w * h, image.values.len()),
        ));
    }
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() as f32;
    let row = |k: usize| {
        [
            image.col_mm[k] as f32,
            image.row_mm[k] as f32,
            image.normal[k] as f32,
            image.origin_mm[k] as f32,
        ]
    };
    let mut header = NiftiHeader {
        sform_code: 1,
        qform_code: 0,
        srow_x: row(0),
        srow_y: row(1),
        srow_z: row(2),
        xyzt_units: 2, // millimetres
        ..NiftiHeader::default()
    };
    header.pixdim[0] = 1.0;
    header.pixdim[1] = norm(image.col_mm);
    header.pixdim[2] = norm(image.row_mm);
    header.pixdim[3] = 1.0;
    let mut d = description.as_bytes().to_vec();
    d.truncate(79);
    d.resize(80, 0);
    header.descrip = d;
    let name = intent_name.as_bytes();
    let n = name.len().min(15);
    header.intent_name[..n].copy_from_slice(&name[..n]);
    use ndarray::ShapeBuilder;
    let array =
        ndarray::Array2::from_shape_vec((w, h).f(), image.values.to_vec()).map_err(|e| err(path, e.to_string()))?;
    WriterOptions::new(path)
        .reference_header(&header)
        .write_nifti(&array)
        .map_err(|e| err(path, format!("cannot write: {e}")))
}

/// Writes a CT as int16 HU (values rounded and clamped to −32768 … 32767).
pub fn write_ct(path: &Path, ct: &Volume<f32>, description: &str) -> Result<(), AtlasError> {
    let data: Vec<i16> = ct
        .data()
        .iter()
        .map(|&v| v.round().clamp(i16::MIN as f32, i16::MAX as f32) as i16)
        .collect();
    write_array(path, ct.grid(), data, description)
}

/// Writes a label map as uint8 when every label fits, else uint16.
pub fn write_labels(path: &Path, labels: &Volume<LabelId>, description: &str) -> Result<(), AtlasError> {
    if labels.data().iter().all(|&l| l <= u8::MAX as LabelId) {
        let data: Vec<u8> = labels.data().iter().map(|&l| l as u8).collect();
        write_array(path, labels.grid(), data, description)
    } else {
        write_array(path, labels.grid(), labels.data().to_vec(), description)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ITK's convention: the file holds LPS vectors, intent 1007, dimensions (x, y, z, 1, 3);
    /// Stylet reads RAS back.
    #[test]
    fn displacement_fields_are_written_and_read_in_itk_convention() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("u.nii.gz");
        let grid = Grid::new(
            [4, 3, 2],
            Affine::from_spacing([2.0, 3.0, 4.0], DVec3::new(-4.0, 1.0, 2.0)),
        )
        .unwrap();
        let field = GridField::sample(grid, |x| DVec3::new(1.0, 2.0, 3.0) + x * 0.01);
        write_displacement_field(&path, &field, "test").unwrap();
        let raw = read_raw_shaped(&path, Shape::Vector3).unwrap().values();
        let n = grid.len();
        let v0 = field.values()[0];
        assert_eq!(
            [raw[0], raw[n], raw[2 * n]],
            [-v0[0] as f64, -v0[1] as f64, v0[2] as f64]
        );
        let mut r = open(&path).unwrap();
        let h = NiftiHeader::from_reader(&mut r).unwrap();
        assert_eq!((h.intent_code, &h.dim[..6]), (1007, &[5u16, 4, 3, 2, 1, 3][..]));
        let back = read_displacement_field(&path).unwrap();
        assert_eq!(back.values(), field.values());
        assert_eq!(back.grid(), field.grid());
        // Too long a displacement is refused, naming the voxel.
        let far = dir.path().join("far.nii.gz");
        write_displacement_field(&far, &GridField::sample(grid, |_| DVec3::new(0.0, 0.0, 150.0)), "far").unwrap();
        let e = read_displacement_field(&far).unwrap_err().to_string();
        assert!(e.contains("voxel (0, 0, 0)") && e.contains("at most 100 mm"), "{e}");
        // A scalar volume is not a field, and a field is not a CT.
        let ct = dir.path().join("ct.nii.gz");
        write_ct(&ct, &Volume::filled(grid, 40.0), "ct").unwrap();
        let e = read_displacement_field(&ct).unwrap_err().to_string();
        assert!(e.contains("(x, y, z, 1, 3)"), "{e}");
        let e = read_ct(&path).unwrap_err().to_string();
        assert!(e.contains("3-D volume"), "{e}");
    }
}
