//! What a clinician should know about the inputs before approving a new patient (the validation
//! report): the source CT's grid and HU range, how much of the body the label map covers, and
//! warnings — sparse labels, thick slices, structures a PTCD scenario expects but the map lacks, CT
//! values no HU-calibrated scan has.

use stylet_physics::{LabelId, Volume};

use crate::manifest::Manifest;

/// Tissue for the coverage count: CT values at or above this (HU) are body, not air or lung.
pub const TISSUE_HU: f32 = -500.0;
/// Below this share of the tissue voxels labelled, most of the body is left to the heuristic.
pub const LOW_COVERAGE: f64 = 0.2;
/// Below this (HU) a value is not tissue or air: padding outside the field of view, or an error.
pub const BELOW_AIR_HU: f32 = -1100.0;
/// Slices thicker than this (mm) blur 2–3 mm ducts and narrow rib gaps.
pub const THICK_SLICE_MM: f64 = 3.0;

/// Facts about the source CT and label map, gathered while importing.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceSummary {
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    /// The CT's range, padding excluded.
    pub hu_min: f32,
    pub hu_max: f32,
    /// A single value below [`BELOW_AIR_HU`] filling the voxels outside the scanner's field of
    /// view (−2048 or −3024 HU, say) and how many voxels hold it; such padding is harmless.
    pub padding: Option<(f32, u64)>,
    /// The median CT value of the tissue voxels (≥ [`TISSUE_HU`]); `None` without any.
    pub tissue_median_hu: Option<f32>,
    /// Voxels at or above [`TISSUE_HU`] and, of those, with a source label.
    pub tissue_voxels: u64,
    pub labelled_tissue_voxels: u64,
    /// The first and last axial slice (k) with a source label.
    pub labelled_slices: Option<(usize, usize)>,
}

impl SourceSummary {
    pub fn of(ct: &Volume<f32>, labels: &Volume<LabelId>) -> SourceSummary {
        let grid = ct.grid();
        let dims = grid.dims();
        let slab = dims[0] * dims[1];
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        // Values below BELOW_AIR_HU: how many, and whether they are all one value.
        let (mut below, mut below_value, mut below_uniform) = (0u64, f32::NAN, true);
        let (mut tissue, mut labelled) = (0u64, 0u64);
        // Tissue values binned by whole HU from −500 to 4 000 for the median (a 35 M-voxel CT
        // is not sorted for one number).
        let mut bins = vec![0u64; 4501];
        let mut slices: Option<(usize, usize)> = None;
        for (idx, (&v, &l)) in ct.data().iter().zip(labels.data()).enumerate() {
            if v < BELOW_AIR_HU {
                if below == 0 {
                    below_value = v;
                }
                below_uniform &= v == below_value;
                below += 1;
            } else if v.is_finite() {
                lo = lo.min(v);
                hi = hi.max(v);
            }
            if l != 0 {
                let k = idx / slab.max(1);
                slices = Some(slices.map_or((k, k), |(a, b)| (a.min(k), b.max(k))));
            }
            if v >= TISSUE_HU {
                tissue += 1;
                labelled += (l != 0) as u64;
                let last = bins.len() - 1;
                bins[((v - TISSUE_HU) as usize).min(last)] += 1;
            }
        }
        let tissue_median_hu = (tissue > 0).then(|| {
            let half = tissue.div_ceil(2);
            let mut seen = 0;
            let bin = bins
                .iter()
                .position(|&n| {
                    seen += n;
                    seen >= half
                })
                .unwrap_or(0);
            TISSUE_HU + bin as f32
        });
        let padding = (below > 0 && below_uniform).then_some((below_value, below));
        if below > 0 && !below_uniform {
            // Values below air that are not one padding value count in the range (and warn).
            lo = lo.min(ct.data().iter().copied().fold(f32::INFINITY, f32::min));
        }
        SourceSummary {
            dims,
            spacing_mm: grid.spacing_mm(),
            hu_min: lo,
            hu_max: hi,
            padding,
            tissue_median_hu,
            tissue_voxels: tissue,
            labelled_tissue_voxels: labelled,
            labelled_slices: slices,
        }
    }

    /// The share of tissue voxels with a source label (0 … 1).
    pub fn coverage(&self) -> f64 {
        if self.tissue_voxels == 0 {
            0.0
        } else {
            self.labelled_tissue_voxels as f64 / self.tissue_voxels as f64
        }
    }
}

/// What a warning is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WarningKind {
    LabelCoverage,
    SliceSpacing,
    MissingStructure,
    ImplausibleHu,
}

impl WarningKind {
    pub fn title(self) -> &'static str {
        match self {
            WarningKind::LabelCoverage => "label coverage",
            WarningKind::SliceSpacing => "slice spacing",
            WarningKind::MissingStructure => "missing structure",
            WarningKind::ImplausibleHu => "implausible CT values",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct Warning {
    pub kind: WarningKind,
    pub text: String,
}

/// Atlas labels a PTCD scenario expects from the segmentation (label id, what is lost without it).
const EXPECTED: [(LabelId, &str, &str); 6] = [
    (
        11,
        "portal vein",
        "the biliary tree grows from the hilum's centre instead; no portal-vein risk",
    ),
    (13, "inferior vena cava", "no caval risk structure"),
    (14, "aorta", "no aortic risk structure"),
    (
        40,
        "right lung",
        "the lung is risk only by the CT heuristic (air), not by name",
    ),
    (50, "gallbladder", "no gallbladder risk structure"),
    (60, "kidney", "no renal risk structure"),
];

/// The warnings for a new atlas made from `summary`'s inputs (`manifest`: the atlas made, its
/// labels those present; `window_found`: whether an intercostal window was found).
pub fn warnings(summary: &SourceSummary, manifest: &Manifest, window_found: bool) -> Vec<Warning> {
    let mut out = Vec::new();
    let mut warn = |kind, text: String| out.push(Warning { kind, text });
    let coverage = summary.coverage();
    if coverage < LOW_COVERAGE {
        warn(
            WarningKind::LabelCoverage,
            format!(
                "{:.0} % of the body's voxels (CT ≥ {TISSUE_HU} HU) carry a label; the rest is classified by CT value and depth alone",
                100.0 * coverage
            ),
        );
    }
    if let Some((k0, k1)) = summary.labelled_slices
        && (k0 > 0 || k1 + 1 < summary.dims[2])
    {
        warn(
            WarningKind::LabelCoverage,
            format!(
                "labels on axial slices {k0} … {k1} of 0 … {}: structures beyond are unlabelled",
                summary.dims[2] - 1
            ),
        );
    }
    let s = summary.spacing_mm;
    if s[2] > THICK_SLICE_MM {
        warn(
            WarningKind::SliceSpacing,
            format!(
                "slices every {:.1} mm (more than {THICK_SLICE_MM} mm): thin ducts and narrow rib gaps are blurred",
                s[2]
            ),
        );
    }
    let (min_s, max_s) = (s[0].min(s[1]).min(s[2]), s[0].max(s[1]).max(s[2]));
    if max_s > 4.0 * min_s {
        warn(
            WarningKind::SliceSpacing,
            format!(
                "voxels of {:.2} × {:.2} × {:.2} mm: more than 4 times longer along one axis",
                s[0], s[1], s[2]
            ),
        );
    }
    for (id, name, loss) in EXPECTED {
        if !manifest.labels.iter().any(|l| l.id == id) {
            warn(
                WarningKind::MissingStructure,
                format!("no {name} in the label map: {loss}"),
            );
        }
    }
    if !window_found {
        warn(
            WarningKind::MissingStructure,
            "no intercostal window: the label map has no neighbouring right ribs, or no straight line between them reaches the target clear of bone and risk structures".into(),
        );
    }
    if summary.hu_min > -900.0 {
        warn(
            WarningKind::ImplausibleHu,
            format!(
                "the lowest CT value is {:.0} HU: air reads about −1000 HU, so the scan may not be in HU (rescale slope and intercept?)",
                summary.hu_min
            ),
        );
    }
    if summary.hu_min < BELOW_AIR_HU || summary.hu_max > 4000.0 {
        warn(
            WarningKind::ImplausibleHu,
            format!(
                "CT values from {:.0} to {:.0} HU: outside the −1 024 … 3 071 HU of a calibrated scan (metal or a wrong rescale)",
                summary.hu_min, summary.hu_max
            ),
        );
    }
    if let Some(m) = summary.tissue_median_hu
        && !(-200.0..=200.0).contains(&m)
    {
        warn(
            WarningKind::ImplausibleHu,
            format!("the body's median CT value is {m:.0} HU; soft tissue reads −100 … 100 HU"),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_physics::glam::DVec3;
    use stylet_physics::{Affine, Grid};

    fn volumes(spacing: [f64; 3], ct: impl Fn(usize) -> f32, label: impl Fn(usize) -> LabelId) -> SourceSummary {
        let grid = Grid::new([10, 10, 10], Affine::from_spacing(spacing, DVec3::ZERO)).unwrap();
        let ct = Volume::new(grid, (0..1000).map(&ct).collect()).unwrap();
        let labels = Volume::new(grid, (0..1000).map(&label).collect()).unwrap();
        SourceSummary::of(&ct, &labels)
    }

    fn manifest_with(ids: &[LabelId]) -> Manifest {
        let mut scenario = crate::manifest::ScenarioFile::ptcd();
        // The kidney is a label `atlas new` adds to the scenario's.
        scenario.labels.push(crate::manifest::LabelToml {
            id: 60,
            name: "kidney".into(),
            role: "risk".into(),
            tissue: "viscus".into(),
            consequence: None,
        });
        scenario.keep_labels(|id| ids.contains(&id));
        Manifest::new("t", "", Default::default(), scenario)
    }

    #[test]
    fn a_good_scan_has_no_warnings() {
        // Half air, half soft tissue; every tissue voxel labelled on every slice.
        let s = volumes([0.8, 0.8, 1.0], |i| if i % 2 == 0 { -1000.0 } else { 40.0 }, |_| 5);
        assert_eq!(s.tissue_voxels, 500);
        assert_eq!(s.coverage(), 1.0);
        assert_eq!(s.tissue_median_hu, Some(40.0));
        assert_eq!(s.labelled_slices, Some((0, 9)));
        let m = manifest_with(&[10, 11, 13, 14, 40, 50, 60]);
        assert_eq!(warnings(&s, &m, true), vec![]);
    }

    #[test]
    fn padding_outside_the_field_of_view_is_not_a_warning() {
        let pad = |i: usize| {
            if i < 100 {
                -2048.0
            } else if i.is_multiple_of(2) {
                -1000.0
            } else {
                40.0
            }
        };
        let s = volumes([0.8, 0.8, 1.0], pad, |_| 5);
        assert_eq!(s.padding, Some((-2048.0, 100)));
        assert_eq!((s.hu_min, s.hu_max), (-1000.0, 40.0));
        let m = manifest_with(&[10, 11, 13, 14, 40, 50, 60]);
        assert_eq!(warnings(&s, &m, true), vec![]);
        // Two different values below air are not padding.
        let s = volumes(
            [0.8, 0.8, 1.0],
            |i| {
                if i < 50 {
                    -2048.0
                } else if i < 100 {
                    -3000.0
                } else {
                    40.0
                }
            },
            |_| 5,
        );
        assert_eq!((s.padding, s.hu_min), (None, -3000.0));
        assert!(
            warnings(&s, &m, true)
                .iter()
                .any(|w| w.kind == WarningKind::ImplausibleHu)
        );
    }

    #[test]
    fn each_problem_is_named() {
        // Thick slices, a CT not in HU (no air, median 1 040), labels on slices 2 … 4 only.
        let s = volumes(
            [0.7, 0.7, 5.0],
            |_| 1040.0,
            |i| if (200..500).contains(&i) && i % 3 == 0 { 5 } else { 0 },
        );
        let m = manifest_with(&[10, 14]);
        let w = warnings(&s, &m, false);
        let kinds = |k| w.iter().filter(|x| x.kind == k).count();
        assert_eq!(kinds(WarningKind::LabelCoverage), 2, "{w:?}");
        assert_eq!(kinds(WarningKind::SliceSpacing), 2, "{w:?}");
        // Portal vein, IVC, lung, gallbladder, kidney, and no window.
        assert_eq!(kinds(WarningKind::MissingStructure), 6, "{w:?}");
        assert_eq!(kinds(WarningKind::ImplausibleHu), 2, "{w:?}");
        assert!(w.iter().any(|x| x.text.contains("slices 2 … 4 of 0 … 9")), "{w:?}");
        assert!(w.iter().any(|x| x.text.contains("no gallbladder")), "{w:?}");
    }
}
