//! DICOM SEG label maps (`stylet atlas new --labels SEG.dcm`; docs/atlas.md "New patients"): a
//! binary Segmentation object (SOP class 1.2.840.10008.5.1.4.1.1.66.4, as TotalSegmentator's
//! `--output_type dicom` and other segmentation tools write) whose frames lie on the CT's grid.
//! Each segment becomes the class of its name (SegmentLabel); each frame is placed by its
//! ImagePositionPatient and the orientation and pixel spacing of the functional groups, converted
//! from DICOM's LPS to the atlas' RAS world. Frames that do not fall on the CT's voxels (another
//! scan, a resampled segmentation) are refused: nothing is resampled.

use std::path::Path;

use dicom_dictionary_std::tags;
use dicom_object::{InMemDicomObject, OpenFileOptions};
use stylet_physics::glam::DVec3;
use stylet_physics::{LabelId, Volume};

use crate::AtlasError;

/// The Segmentation Storage SOP class.
pub const SEG_SOP_CLASS: &str = "1.2.840.10008.5.1.4.1.1.66.4";
/// Largest SEG file read (bytes): the whole object is read into memory.
pub const MAX_SEG_BYTES: u64 = 1 << 30;
/// Most segments one object may hold.
pub const MAX_SEGMENTS: usize = 1024;
/// Uncompressed transfer syntaxes whose pixel data is read as stored.
const NATIVE_SYNTAXES: [&str; 2] = ["1.2.840.10008.1.2", "1.2.840.10008.1.2.1"];

/// What was read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SegSummary {
    /// Segment names in segment-number order.
    pub segments: Vec<String>,
    /// Segments that mark no voxel.
    pub empty: Vec<String>,
    /// Voxels two segments claim (the lower segment number keeps them).
    pub overlaps: usize,
    pub frames: usize,
}

/// A frame on the CT's grid: its segment, its index in the pixel data, the voxel of its first
/// pixel and the voxel steps along a row (next column) and down a column (next row).
#[derive(PartialEq, Eq, PartialOrd, Ord)]
struct PlacedFrame {
    segment: u32,
    frame: usize,
    start: [i64; 3],
    along_col: [i64; 3],
    along_row: [i64; 3],
}

/// Whether `path` looks like a DICOM file (the "DICM" preamble marker).
pub fn is_dicom_file(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 132];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| &head[128..] == b"DICM")
}

/// A segment's name as a structure name: trimmed, lower case, spaces and hyphens as `_`
/// ("Rib right 10" → "rib_right_10", TotalSegmentator's spelling).
pub fn structure_name(label: &str) -> String {
    label
        .trim()
        .to_lowercase()
        .chars()
        .map(|c| if c == ' ' || c == '-' { '_' } else { c })
        .collect()
}

fn text(obj: &InMemDicomObject, tag: dicom_object::Tag) -> Option<String> {
    obj.element(tag)
        .ok()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim_end_matches(['\0', ' ']).to_string())
}

fn floats(obj: &InMemDicomObject, tag: dicom_object::Tag, n: usize) -> Option<Vec<f64>> {
    let v = obj.element(tag).ok()?.to_multi_float64().ok()?;
    (v.len() == n && v.iter().all(|x| x.is_finite())).then_some(v)
}

/// The first item of sequence `seq` in `obj`.
fn item(obj: &InMemDicomObject, seq: dicom_object::Tag) -> Option<&InMemDicomObject> {
    obj.element(seq).ok()?.items()?.first()
}

/// `tag` inside `seq` of a frame's functional groups, else of the shared ones.
fn grouped(
    frame: Option<&InMemDicomObject>,
    shared: Option<&InMemDicomObject>,
    seq: dicom_object::Tag,
    tag: dicom_object::Tag,
    n: usize,
) -> Option<Vec<f64>> {
    frame
        .and_then(|f| item(f, seq))
        .and_then(|i| floats(i, tag, n))
        .or_else(|| shared.and_then(|s| item(s, seq)).and_then(|i| floats(i, tag, n)))
}

/// Reads the binary SEG at `path` onto `labels` (the CT's grid): each segment's voxels get the
/// label `class_of(name)` returns, where no lower-numbered segment claimed them already.
pub fn read_seg(
    path: &Path,
    labels: &mut Volume<LabelId>,
    class_of: &mut dyn FnMut(&str) -> Result<LabelId, super::classes::ClassTableError>,
) -> Result<SegSummary, AtlasError> {
    let fail = |m: String| AtlasError::file(path, m);
    crate::check_regular_file(path)?;
    let len = std::fs::metadata(path)
        .map_err(|e| fail(format!("cannot read: {e}")))?
        .len();
    if len > MAX_SEG_BYTES {
        return Err(fail(format!("{len} bytes, more than the {MAX_SEG_BYTES} accepted")));
    }
    let obj = OpenFileOptions::new()
        .open_file(path)
        .map_err(|e| fail(format!("not a readable DICOM file: {e}")))?;
    let sop = text(&obj, tags::SOP_CLASS_UID).unwrap_or_default();
    if sop != SEG_SOP_CLASS {
        return Err(fail(format!(
            "not a DICOM Segmentation (SOP class {sop:?}, expected {SEG_SOP_CLASS})"
        )));
    }
    let syntax = obj.meta().transfer_syntax().trim_end_matches('\0').to_string();
    if !NATIVE_SYNTAXES.contains(&syntax.as_str()) {
        return Err(fail(format!(
            "its pixel data is encoded with transfer syntax {syntax}; only uncompressed segmentations are read"
        )));
    }
    let kind = text(&obj, tags::SEGMENTATION_TYPE).unwrap_or_default();
    if kind != "BINARY" {
        return Err(fail(format!(
            "SegmentationType {kind:?}: only BINARY segmentations are read (a FRACTIONAL one needs a threshold)"
        )));
    }
    let int = |tag, name: &str| -> Result<usize, AtlasError> {
        obj.element(tag)
            .ok()
            .and_then(|e| e.to_int::<u32>().ok())
            .map(|v| v as usize)
            .ok_or_else(|| fail(format!("missing or bad {name}")))
    };
    let (rows, cols) = (int(tags::ROWS, "Rows")?, int(tags::COLUMNS, "Columns")?);
    let frames = obj
        .element(tags::NUMBER_OF_FRAMES)
        .ok()
        .and_then(|e| e.to_str().ok())
        .and_then(|s| s.trim_end_matches(['\0', ' ']).trim().parse::<usize>().ok())
        .ok_or_else(|| fail("missing or bad NumberOfFrames".into()))?;
    if int(tags::BITS_ALLOCATED, "BitsAllocated")? != 1 {
        return Err(fail("BitsAllocated must be 1 in a BINARY segmentation".into()));
    }
    let [nx, ny, nz] = labels.grid().dims();
    if rows * cols > nx * ny || frames == 0 || frames > nz * MAX_SEGMENTS {
        return Err(fail(format!(
            "{frames} frames of {rows} × {cols} pixels do not fit the CT's {nx} × {ny} × {nz} voxels"
        )));
    }

    // The segments, by number.
    let items = obj
        .element(tags::SEGMENT_SEQUENCE)
        .ok()
        .and_then(|e| e.items())
        .ok_or_else(|| fail("missing SegmentSequence".into()))?;
    if items.is_empty() || items.len() > MAX_SEGMENTS {
        return Err(fail(format!("{} segments (1 … {MAX_SEGMENTS} accepted)", items.len())));
    }
    let mut segments: Vec<(u32, String)> = Vec::new();
    for it in items {
        let number = it
            .element(tags::SEGMENT_NUMBER)
            .ok()
            .and_then(|e| e.to_int::<u32>().ok())
            .ok_or_else(|| fail("a segment has no SegmentNumber".into()))?;
        let name = structure_name(&text(it, tags::SEGMENT_LABEL).unwrap_or_default());
        let name = if name.is_empty() {
            format!("segment_{number}")
        } else {
            name
        };
        if segments.iter().any(|(n, _)| *n == number) {
            return Err(fail(format!("segment number {number} appears twice")));
        }
        segments.push((number, name));
    }
    segments.sort();
    let mut class = std::collections::BTreeMap::new();
    for (number, name) in &segments {
        class.insert(
            *number,
            class_of(name).map_err(|e| fail(format!("segment {number} ({name}): {e}")))?,
        );
    }

    // Geometry: one orientation and spacing (the frames' or the shared ones), a position per frame.
    let shared = item(&obj, tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE);
    let per_frame = obj
        .element(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE)
        .ok()
        .and_then(|e| e.items())
        .ok_or_else(|| fail("missing PerFrameFunctionalGroupsSequence".into()))?;
    if per_frame.len() != frames {
        return Err(fail(format!(
            "{} per-frame functional groups for {frames} frames",
            per_frame.len()
        )));
    }
    let pixel = obj
        .element(tags::PIXEL_DATA)
        .ok()
        .and_then(|e| e.to_bytes().ok())
        .ok_or_else(|| fail("missing PixelData".into()))?;
    let bits = frames * rows * cols;
    if pixel.len() < bits.div_ceil(8) {
        return Err(fail(format!(
            "PixelData holds {} bytes, {frames} frames of {rows} × {cols} bits need {} (cut short?)",
            pixel.len(),
            bits.div_ceil(8)
        )));
    }
    let grid = *labels.grid();
    let mut placed: Vec<PlacedFrame> = Vec::with_capacity(frames);
    for (f, groups) in per_frame.iter().enumerate() {
        let at = |m: &str| fail(format!("frame {}: {m}", f + 1));
        let iop = grouped(
            Some(groups),
            shared,
            tags::PLANE_ORIENTATION_SEQUENCE,
            tags::IMAGE_ORIENTATION_PATIENT,
            6,
        )
        .ok_or_else(|| at("no ImageOrientationPatient"))?;
        let spacing = grouped(
            Some(groups),
            shared,
            tags::PIXEL_MEASURES_SEQUENCE,
            tags::PIXEL_SPACING,
            2,
        )
        .ok_or_else(|| at("no PixelSpacing"))?;
        let ipp = grouped(
            Some(groups),
            None,
            tags::PLANE_POSITION_SEQUENCE,
            tags::IMAGE_POSITION_PATIENT,
            3,
        )
        .ok_or_else(|| at("no ImagePositionPatient"))?;
        let number = item(groups, tags::SEGMENT_IDENTIFICATION_SEQUENCE)
            .and_then(|i| i.element(tags::REFERENCED_SEGMENT_NUMBER).ok())
            .and_then(|e| e.to_int::<u32>().ok())
            .ok_or_else(|| at("no ReferencedSegmentNumber"))?;
        if !class.contains_key(&number) {
            return Err(at(&format!("refers to segment {number}, which SegmentSequence lacks")));
        }
        let ras = |v: DVec3| DVec3::new(-v.x, -v.y, v.z);
        let origin = ras(DVec3::new(ipp[0], ipp[1], ipp[2]));
        let row_dir = ras(DVec3::new(iop[0], iop[1], iop[2]));
        let col_dir = ras(DVec3::new(iop[3], iop[4], iop[5]));
        let index = |w: DVec3| grid.world_to_index(w);
        let start = index(origin);
        let along_col = index(origin + row_dir * spacing[1]) - start;
        let along_row = index(origin + col_dir * spacing[0]) - start;
        let whole = |v: DVec3| -> Option<[i64; 3]> {
            let r = v.round();
            ((v - r).abs().max_element() < 0.01).then_some([r.x as i64, r.y as i64, r.z as i64])
        };
        let unit = |v: &[i64; 3]| v.iter().map(|x| x.abs()).sum::<i64>() == 1;
        let (Some(s), Some(dc), Some(dr)) = (whole(start), whole(along_col), whole(along_row)) else {
            return Err(at(
                "its pixels do not lie on the CT's voxels (another scan, or resampled?)",
            ));
        };
        // Rows and columns along two different axes of the CT (not the same one either way).
        if !unit(&dc) || !unit(&dr) || (0..3).any(|a| dc[a] != 0 && dr[a] != 0) {
            return Err(at("its pixel spacing or orientation differs from the CT's"));
        }
        let corner = |r: i64, c: i64| [0, 1, 2].map(|a| s[a] + c * dc[a] + r * dr[a]);
        let (last_r, last_c) = (rows as i64 - 1, cols as i64 - 1);
        for p in [
            corner(0, 0),
            corner(0, last_c),
            corner(last_r, 0),
            corner(last_r, last_c),
        ] {
            if p.iter().zip([nx, ny, nz]).any(|(&v, n)| v < 0 || v >= n as i64) {
                return Err(at("it lies outside the CT (another scan?)"));
            }
        }
        placed.push(PlacedFrame {
            segment: number,
            frame: f,
            start: s,
            along_col: dc,
            along_row: dr,
        });
    }
    // The lower segment number first: it keeps the voxels two segments claim.
    placed.sort();
    let mut marked = std::collections::BTreeSet::new();
    let mut overlaps = 0;
    let data = labels.data_mut();
    for PlacedFrame {
        segment: number,
        frame: f,
        start: s,
        along_col: dc,
        along_row: dr,
    } in placed
    {
        let id = class[&number];
        let first_bit = f * rows * cols;
        for r in 0..rows {
            for c in 0..cols {
                let bit = first_bit + r * cols + c;
                if pixel[bit / 8] >> (bit % 8) & 1 == 0 {
                    continue;
                }
                let v = [0, 1, 2].map(|a| (s[a] + c as i64 * dc[a] + r as i64 * dr[a]) as usize);
                let dst = &mut data[v[0] + nx * (v[1] + ny * v[2])];
                marked.insert(number);
                if *dst == 0 {
                    *dst = id;
                } else if *dst != id {
                    overlaps += 1;
                }
            }
        }
    }
    let empty = segments
        .iter()
        .filter(|(n, _)| !marked.contains(n))
        .map(|(_, name)| name.clone())
        .collect();
    Ok(SegSummary {
        segments: segments.into_iter().map(|(_, n)| n).collect(),
        empty,
        overlaps,
        frames,
    })
}
