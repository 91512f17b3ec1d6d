//! A label map made for the real DICOM series `ts-example-dicom`, which has none: 20
//! contrast-enhanced axial slices (portal-venous phase) of the upper abdomen, 512 × 512 at
//! 0.98 × 0.98 × 2 mm. The structures are segmented from the CT by intensity and connectivity with
//! seeds placed by looking at slice 10 (the rater's part), in the series' own grid:
//!
//! - **liver** (5): the in-plane 7 × 7 mean between 86 and 140 HU (the liver enhances to about
//!   100 HU), eroded 5 × 5, the component at the right anterior seed, dilated back within 80 HU,
//!   closed and hole-filled per slice;
//! - **portal vein** (64): the largest component above 125 HU (mean) inside the liver;
//! - **pleural effusions** (200 right, 201 left): both posterior costophrenic recesses hold
//!   layering fluid of about 75 HU with a flat upper surface; the mean between 45 and 86 HU outside
//!   the liver, eroded 7 × 7, the components at the posterior seeds, dilated back;
//! - **aorta** (52): 110–260 HU within 15 mm of its centre anterior to the vertebra;
//! - **vertebra** (32, "vertebrae_T12"): the largest bone component (above 220 HU);
//! - **right ribs** (110 … 115, "rib_right_7" … "rib_right_12"): the six bone components of the
//!   right body wall, numbered from anterior to posterior as an axial cut of the lower chest shows
//!   them (the anterior arcs descend from higher ribs). The numbering is the rater's reading, not
//!   checked against a scan of the whole chest: this map is a test fixture.
//!
//! Effusions are not in TotalSegmentator's "total" classes: the class table names them and the
//! mapping file maps them to the lung (pleura) risk labels, as a user of `--map` would.

use std::collections::VecDeque;
use std::path::Path;

use stylet_physics::{LabelId, Volume};

/// Writes `labels.nii.gz`, `classes.csv` and `map.csv` for the series in `series` into `out`.
pub fn make(series: &Path, out: &Path) {
    let ct = stylet_atlas::import::dicom::read_series(series).unwrap().ct;
    let labels = segment(&ct);
    stylet_atlas::nifti_io::write_labels(&out.join("labels.nii.gz"), &labels, "test fixture").unwrap();
    std::fs::write(
        out.join("classes.csv"),
        "id,structure\n5,liver\n64,portal_vein_and_splenic_vein\n52,aorta\n32,vertebrae_T12\n\
         110,rib_right_7\n111,rib_right_8\n112,rib_right_9\n113,rib_right_10\n114,rib_right_11\n\
         115,rib_right_12\n200,pleural_effusion_right\n201,pleural_effusion_left\n",
    )
    .unwrap();
    std::fs::write(
        out.join("map.csv"),
        "structure,label\npleural_effusion_right,40\npleural_effusion_left,41\n",
    )
    .unwrap();
}

/// The grid's dimensions and a few operations on masks of it.
#[derive(Clone, Copy)]
struct Dims {
    nx: usize,
    ny: usize,
    nz: usize,
}

impl Dims {
    fn at(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.nx * (j + self.ny * k)
    }

    fn len(&self) -> usize {
        self.nx * self.ny * self.nz
    }

    /// In-plane square (2r+1)² dilation (`any`) or erosion (`all`, outside counts as empty).
    fn square(&self, m: &[bool], r: usize, dilate: bool) -> Vec<bool> {
        let pass = |src: &[bool], along_i: bool| -> Vec<bool> {
            let mut out = vec![false; src.len()];
            let (n, lines) = if along_i {
                (self.nx, self.ny)
            } else {
                (self.ny, self.nx)
            };
            for k in 0..self.nz {
                for line in 0..lines {
                    let idx = |t: usize| {
                        if along_i {
                            self.at(t, line, k)
                        } else {
                            self.at(line, t, k)
                        }
                    };
                    let mut prefix = vec![0usize; n + 1];
                    for t in 0..n {
                        prefix[t + 1] = prefix[t] + usize::from(src[idx(t)]);
                    }
                    for t in 0..n {
                        let (lo, hi) = (t.saturating_sub(r), (t + r + 1).min(n));
                        let count = prefix[hi] - prefix[lo];
                        out[idx(t)] = if dilate { count > 0 } else { count == 2 * r + 1 };
                    }
                }
            }
            out
        };
        pass(&pass(m, true), false)
    }

    /// Per slice: closing by a (2r+1)² square, then holes filled.
    fn close_and_fill(&self, m: &[bool], r: usize) -> Vec<bool> {
        let closed = self.square(&self.square(m, r, true), r, false);
        self.fill_holes(&closed)
    }

    /// Per slice: background not reachable from the slice's border becomes foreground.
    fn fill_holes(&self, m: &[bool]) -> Vec<bool> {
        let mut reached = vec![false; m.len()];
        let mut queue = VecDeque::new();
        for k in 0..self.nz {
            for j in 0..self.ny {
                for i in 0..self.nx {
                    let border = i == 0 || j == 0 || i + 1 == self.nx || j + 1 == self.ny;
                    let p = self.at(i, j, k);
                    if border && !m[p] {
                        reached[p] = true;
                        queue.push_back((i, j, k));
                    }
                }
            }
        }
        while let Some((i, j, k)) = queue.pop_front() {
            for (di, dj) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                let (a, b) = (i as i64 + di, j as i64 + dj);
                if a < 0 || b < 0 || a >= self.nx as i64 || b >= self.ny as i64 {
                    continue;
                }
                let p = self.at(a as usize, b as usize, k);
                if !m[p] && !reached[p] {
                    reached[p] = true;
                    queue.push_back((a as usize, b as usize, k));
                }
            }
        }
        reached.iter().map(|&r| !r).collect()
    }

    /// Connected components (6-neighbourhood, or 26 with `full`; `planar`: within each slice,
    /// 4-neighbourhood): component number per voxel (0 = background) and each one's voxels.
    fn components(&self, m: &[bool], full: bool, planar: bool) -> (Vec<u32>, Vec<Vec<usize>>) {
        let mut offsets = Vec::new();
        for dk in -1i64..=1 {
            for dj in -1i64..=1 {
                for di in -1i64..=1 {
                    let manhattan = di.abs() + dj.abs() + dk.abs();
                    let ok = if planar {
                        dk == 0 && manhattan == 1
                    } else {
                        manhattan == 1 || (full && manhattan > 0)
                    };
                    if ok {
                        offsets.push((di, dj, dk));
                    }
                }
            }
        }
        let mut label = vec![0u32; m.len()];
        let mut comps: Vec<Vec<usize>> = Vec::new();
        for start in 0..m.len() {
            if !m[start] || label[start] != 0 {
                continue;
            }
            let id = comps.len() as u32 + 1;
            let mut voxels = vec![start];
            label[start] = id;
            let mut q = 0;
            while q < voxels.len() {
                let p = voxels[q];
                q += 1;
                let (i, r) = (p % self.nx, p / self.nx);
                let (j, k) = (r % self.ny, r / self.ny);
                for &(di, dj, dk) in &offsets {
                    let (a, b, c) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
                    if a < 0 || b < 0 || c < 0 || a >= self.nx as i64 || b >= self.ny as i64 || c >= self.nz as i64 {
                        continue;
                    }
                    let n = self.at(a as usize, b as usize, c as usize);
                    if m[n] && label[n] == 0 {
                        label[n] = id;
                        voxels.push(n);
                    }
                }
            }
            comps.push(voxels);
        }
        (label, comps)
    }

    /// The component most voxels of the disk of radius `r` around (i, j) in slice k belong to.
    fn component_at(&self, label: &[u32], (i, j, k): (usize, usize, usize), r: i64) -> u32 {
        let mut counts = std::collections::BTreeMap::new();
        for dj in -r..=r {
            for di in -r..=r {
                if di * di + dj * dj <= r * r {
                    let l = label[self.at((i as i64 + di) as usize, (j as i64 + dj) as usize, k)];
                    if l > 0 {
                        *counts.entry(l).or_insert(0usize) += 1;
                    }
                }
            }
        }
        counts
            .into_iter()
            .max_by_key(|&(l, n)| (n, std::cmp::Reverse(l)))
            .expect("a structure at the seed")
            .0
    }
}

fn segment(ct: &Volume<f32>) -> Volume<LabelId> {
    let [nx, ny, nz] = ct.grid().dims();
    assert_eq!(
        [nx, ny, nz],
        [512, 512, 20],
        "the seeds are placed for ts-example-dicom"
    );
    let d = Dims { nx, ny, nz };
    let a = ct.data();
    let mask = |f: &dyn Fn(usize) -> bool| -> Vec<bool> { (0..d.len()).map(f).collect() };

    // The body: per slice, the largest component above −300 HU, holes filled (no arms, no table).
    let (label, comps) = d.components(&mask(&|p| a[p] > -300.0), false, true);
    let mut body = vec![false; d.len()];
    for k in 0..nz {
        let largest = comps
            .iter()
            .enumerate()
            .filter(|(_, c)| c[0] / (nx * ny) == k)
            .max_by_key(|(_, c)| c.len())
            .map(|(n, _)| n as u32 + 1);
        for j in 0..ny {
            for i in 0..nx {
                let p = d.at(i, j, k);
                body[p] = Some(label[p]) == largest;
            }
        }
    }
    let body = d.fill_holes(&body);

    // The in-plane 7 × 7 mean: the liver and the effusions differ by 25 HU, the noise is 12 HU.
    let mut sm = vec![0f32; d.len()];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let (mut sum, mut n) = (0f32, 0f32);
                for b in j.saturating_sub(3)..(j + 4).min(ny) {
                    for c in i.saturating_sub(3)..(i + 4).min(nx) {
                        sum += a[d.at(c, b, k)];
                        n += 1.0;
                    }
                }
                sm[d.at(i, j, k)] = sum / n;
            }
        }
    }

    let mut out = vec![0 as LabelId; d.len()];
    // Bone: the vertebra (largest) and the six ribs of the right body wall.
    let (_, bones) = d.components(&mask(&|p| a[p] > 220.0 && body[p]), true, false);
    let centroid = |c: &[usize]| -> (f64, f64) {
        let (mut si, mut sj) = (0.0, 0.0);
        for &p in c {
            si += (p % nx) as f64;
            sj += ((p / nx) % ny) as f64;
        }
        (si / c.len() as f64, sj / c.len() as f64)
    };
    let vertebra = (0..bones.len()).max_by_key(|&n| bones[n].len()).unwrap();
    for &p in &bones[vertebra] {
        out[p] = 32;
    }
    let mut right_ribs: Vec<(f64, usize)> = (0..bones.len())
        .filter(|&n| n != vertebra && bones[n].len() > 150)
        .filter_map(|n| {
            let (ci, cj) = centroid(&bones[n]);
            (ci < 245.0).then_some((cj, n))
        })
        .collect();
    right_ribs.sort_by(|a, b| a.0.total_cmp(&b.0));
    assert_eq!(right_ribs.len(), 6, "six right ribs in the slab");
    for (number, &(_, n)) in right_ribs.iter().enumerate() {
        for &p in &bones[n] {
            out[p] = 110 + number as LabelId;
        }
    }

    // The liver, then its largest vessel as the portal vein.
    let soft = mask(&|p| sm[p] > 86.0 && sm[p] < 140.0 && body[p]);
    let (label, _) = d.components(&d.square(&soft, 2, false), false, false);
    let seed = d.component_at(&label, (150, 250, 10), 25);
    let core = mask(&|p| label[p] == seed);
    let grown = d.square(&core, 2, true);
    let liver = d.close_and_fill(&mask(&|p| grown[p] && sm[p] > 80.0 && a[p] < 220.0), 2);
    let liver = mask(&|p| liver[p] && out[p] == 0);
    let (_, vessels) = d.components(&mask(&|p| liver[p] && sm[p] > 125.0), false, false);
    for p in (0..d.len()).filter(|&p| liver[p]) {
        out[p] = 5;
    }
    if let Some(portal) = vessels.iter().max_by_key(|c| c.len()) {
        for &p in portal {
            out[p] = 64;
        }
    }

    // The layering pleural effusions of both posterior recesses.
    let fluid = mask(&|p| sm[p] > 45.0 && sm[p] <= 86.0 && body[p] && out[p] == 0);
    let (label, _) = d.components(&d.square(&fluid, 3, false), false, false);
    for (seed, value) in [((150, 340, 10), 200), ((350, 330, 10), 201)] {
        let id = d.component_at(&label, seed, 25);
        let grown = d.square(&mask(&|p| label[p] == id), 3, true);
        let effusion = d.close_and_fill(&mask(&|p| grown[p] && fluid[p]), 2);
        for p in 0..d.len() {
            if effusion[p] && out[p] == 0 {
                out[p] = value;
            }
        }
    }

    // The aorta: enhanced blood within 15 mm of its centre.
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = d.at(i, j, k);
                let r2 = (j as i64 - 297).pow(2) + (i as i64 - 265).pow(2);
                if r2 < 15 * 15 && a[p] > 110.0 && a[p] < 260.0 && out[p] == 0 {
                    out[p] = 52;
                }
            }
        }
    }
    Volume::new(*ct.grid(), out).unwrap()
}

/// Writes `labels` (on the grid of the DICOM series it was made for) as a binary DICOM SEG at
/// `out`: one segment per label of `names` (number, SegmentLabel), one frame per segment and
/// slice the segment marks, placed by ImagePositionPatient in DICOM's LPS. `drop_last_bytes`
/// cuts the pixel data short (a damaged file).
pub fn write_seg(labels: &Volume<LabelId>, names: &[(LabelId, &str)], out: &Path, drop_last_bytes: usize) {
    use dicom_core::value::DataSetSequence;
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};

    let grid = labels.grid();
    let [nx, ny, nz] = grid.dims();
    let lps = |v: stylet_physics::glam::DVec3| [-v.x, -v.y, v.z];
    let o = grid.voxel_to_world(0, 0, 0);
    let row_dir = (grid.voxel_to_world(1, 0, 0) - o).normalize();
    let col_dir = (grid.voxel_to_world(0, 1, 0) - o).normalize();
    let sp = grid.spacing_mm();
    let seq = |items: Vec<InMemDicomObject>| DataSetSequence::from(items);
    let floats = |v: &[f64]| PrimitiveValue::from(v.iter().map(|x| format!("{x:.6}")).collect::<Vec<_>>().join("\\"));

    let mut obj = InMemDicomObject::new_empty();
    let put_str =
        |o: &mut InMemDicomObject, tag, vr, s: &str| o.put(DataElement::new(tag, vr, PrimitiveValue::from(s)));
    put_str(&mut obj, tags::SOP_CLASS_UID, VR::UI, "1.2.840.10008.5.1.4.1.1.66.4");
    put_str(&mut obj, tags::SOP_INSTANCE_UID, VR::UI, "2.25.1234567890");
    put_str(&mut obj, tags::MODALITY, VR::CS, "SEG");
    put_str(&mut obj, tags::SEGMENTATION_TYPE, VR::CS, "BINARY");
    obj.put(DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(ny as u16)));
    obj.put(DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(nx as u16)));
    obj.put(DataElement::new(
        tags::BITS_ALLOCATED,
        VR::US,
        PrimitiveValue::from(1u16),
    ));
    obj.put(DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(1u16)));
    obj.put(DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(0u16)));
    obj.put(DataElement::new(
        tags::SAMPLES_PER_PIXEL,
        VR::US,
        PrimitiveValue::from(1u16),
    ));
    put_str(&mut obj, tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2");
    let segments: Vec<InMemDicomObject> = names
        .iter()
        .enumerate()
        .map(|(n, (_, name))| {
            let mut s = InMemDicomObject::new_empty();
            s.put(DataElement::new(
                tags::SEGMENT_NUMBER,
                VR::US,
                PrimitiveValue::from(n as u16 + 1),
            ));
            put_str(&mut s, tags::SEGMENT_LABEL, VR::LO, name);
            put_str(&mut s, tags::SEGMENT_ALGORITHM_TYPE, VR::CS, "SEMIAUTOMATIC");
            s
        })
        .collect();
    obj.put(DataElement::new(tags::SEGMENT_SEQUENCE, VR::SQ, seq(segments)));
    let mut shared = InMemDicomObject::new_empty();
    let mut orientation = InMemDicomObject::new_empty();
    let (r, c) = (lps(row_dir), lps(col_dir));
    orientation.put(DataElement::new(
        tags::IMAGE_ORIENTATION_PATIENT,
        VR::DS,
        floats(&[r[0], r[1], r[2], c[0], c[1], c[2]]),
    ));
    shared.put(DataElement::new(
        tags::PLANE_ORIENTATION_SEQUENCE,
        VR::SQ,
        seq(vec![orientation]),
    ));
    let mut measures = InMemDicomObject::new_empty();
    measures.put(DataElement::new(tags::PIXEL_SPACING, VR::DS, floats(&[sp[1], sp[0]])));
    measures.put(DataElement::new(tags::SLICE_THICKNESS, VR::DS, floats(&[sp[2]])));
    shared.put(DataElement::new(
        tags::PIXEL_MEASURES_SEQUENCE,
        VR::SQ,
        seq(vec![measures]),
    ));
    obj.put(DataElement::new(
        tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE,
        VR::SQ,
        seq(vec![shared]),
    ));

    let mut frames = Vec::new();
    let mut bits: Vec<u8> = Vec::new();
    let mut nbits = 0usize;
    for (n, &(label, _)) in names.iter().enumerate() {
        for k in 0..nz {
            let slice = &labels.data()[k * nx * ny..(k + 1) * nx * ny];
            if !slice.contains(&label) {
                continue;
            }
            for &v in slice {
                if nbits.is_multiple_of(8) {
                    bits.push(0);
                }
                if v == label {
                    *bits.last_mut().unwrap() |= 1 << (nbits % 8);
                }
                nbits += 1;
            }
            let mut position = InMemDicomObject::new_empty();
            position.put(DataElement::new(
                tags::IMAGE_POSITION_PATIENT,
                VR::DS,
                floats(&lps(grid.voxel_to_world(0, 0, k))),
            ));
            let mut ident = InMemDicomObject::new_empty();
            ident.put(DataElement::new(
                tags::REFERENCED_SEGMENT_NUMBER,
                VR::US,
                PrimitiveValue::from(n as u16 + 1),
            ));
            let mut frame = InMemDicomObject::new_empty();
            frame.put(DataElement::new(
                tags::PLANE_POSITION_SEQUENCE,
                VR::SQ,
                seq(vec![position]),
            ));
            frame.put(DataElement::new(
                tags::SEGMENT_IDENTIFICATION_SEQUENCE,
                VR::SQ,
                seq(vec![ident]),
            ));
            frames.push(frame);
        }
    }
    put_str(&mut obj, tags::NUMBER_OF_FRAMES, VR::IS, &frames.len().to_string());
    obj.put(DataElement::new(
        tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE,
        VR::SQ,
        seq(frames),
    ));
    if bits.len() % 2 == 1 {
        bits.push(0);
    }
    bits.truncate(bits.len() - drop_last_bytes.min(bits.len()));
    obj.put(DataElement::new(tags::PIXEL_DATA, VR::OB, PrimitiveValue::from(bits)));
    let file = obj
        .with_meta(
            FileMetaTableBuilder::new()
                .media_storage_sop_class_uid("1.2.840.10008.5.1.4.1.1.66.4")
                .media_storage_sop_instance_uid("2.25.1234567890")
                .transfer_syntax("1.2.840.10008.1.2.1"),
        )
        .unwrap();
    file.write_to_file(out).unwrap();
}

/// The label map [`make`] writes, with its class names (for [`write_seg`]).
pub fn made_labels(dir: &Path) -> (Volume<LabelId>, Vec<(LabelId, String)>) {
    let labels = stylet_atlas::nifti_io::read_labels(&dir.join("labels.nii.gz")).unwrap();
    let classes = std::fs::read_to_string(dir.join("classes.csv")).unwrap();
    let names = classes
        .lines()
        .skip(1)
        .map(|l| {
            let (id, name) = l.split_once(',').unwrap();
            (id.parse().unwrap(), name.to_string())
        })
        .collect();
    (labels, names)
}
