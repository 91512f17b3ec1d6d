//! The real-CT atlas from `ts-example-abdomen` and the DICOM series importer on
//! `ts-example-dicom` (the real CT data of `scripts/fetch-data`). These tests read that data and
//! fail, with a message, if it is missing.

use std::sync::OnceLock;

use stylet_atlas::import::biliary::count_components;
use stylet_atlas::import::recipe::load_recipe;
use stylet_atlas::import::{ImportReport, import, read_sources};
use stylet_atlas::{Atlas, load};
use stylet_physics::glam::DVec3;
use stylet_physics::{LabelId, Role, Volume};

struct Imported {
    report: ImportReport,
    atlas: Atlas,
    /// TotalSegmentator labels on the atlas grid.
    source: Volume<LabelId>,
}

fn imported() -> &'static Imported {
    static I: OnceLock<Imported> = OnceLock::new();
    I.get_or_init(|| {
        let recipe = crate::common::workspace().join("atlases/ts-abdomen/recipe.toml");
        let data = crate::common::shared_data().join("ts-example-abdomen");
        let dir = stylet_testkit::fixture_dir();
        let report = import(&recipe, &data, &dir).unwrap();
        let atlas = load(&dir).unwrap();
        let source = read_sources(&load_recipe(&recipe).unwrap(), &data).unwrap().labels;
        Imported { report, atlas, source }
    })
}

#[test]
fn liver_median_is_within_40_to_60_hu() {
    let a = &imported().atlas.model;
    let mut liver: Vec<f32> = a
        .ct()
        .data()
        .iter()
        .zip(a.partial_labels().data())
        .filter(|(_, l)| **l == 10)
        .map(|(v, _)| *v)
        .collect();
    let mid = liver.len() / 2;
    let median = *liver.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
    println!("liver median {median} HU over {} voxels", liver.len());
    assert!((40.0..=60.0).contains(&median), "liver median {median} HU");
}

#[test]
fn the_example_slice_offset_is_honoured() {
    let i = imported();
    // The segmentation covers CT slices 82..111 (3 mm): z from 94.3 + 82·3 − 1.5 mm upward.
    let grid = i.source.grid();
    let lowest = i
        .source
        .data()
        .iter()
        .enumerate()
        .filter(|(_, l)| **l != 0)
        .map(|(idx, _)| {
            let [a, b, c] = grid.unlinear(idx);
            grid.voxel_to_world(a, b, c).z
        })
        .fold(f64::INFINITY, f64::min);
    let expected = 94.302 + 82.0 * 3.0 - 1.5;
    assert!(
        (lowest - expected).abs() < 1.0,
        "labels start at z = {lowest}, expected about {expected}"
    );
    // The liver label sits on liver-like CT values (a wrong offset would put it on lung or fat).
    let a = &i.atlas.model;
    let mean = |id: LabelId| {
        let v: Vec<f64> = a
            .ct()
            .data()
            .iter()
            .zip(a.partial_labels().data())
            .filter(|(_, l)| **l == id)
            .map(|(v, _)| *v as f64)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    assert!(mean(40) < -500.0, "right lung mean {}", mean(40));
}

#[test]
fn synthetic_ducts_lie_inside_the_liver_and_are_connected() {
    let i = imported();
    let labels = i.atlas.model.partial_labels();
    let mut n = 0;
    for (&l, &s) in labels.data().iter().zip(i.source.data()) {
        if l == 20 || l == 21 {
            n += 1;
            assert_eq!(s, 5, "a duct voxel lies outside the TotalSegmentator liver (label {s})");
        }
    }
    let b = i.report.biliary.as_ref().unwrap();
    assert_eq!(b.hilum_source, "portal vein");
    assert!(b.target_voxels > 300 && b.duct_voxels > 500, "{b:?}");
    assert_eq!(n, b.target_voxels + b.duct_voxels);
    let tree: Vec<bool> = labels.data().iter().map(|&l| l == 20 || l == 21).collect();
    assert_eq!(count_components(labels.grid(), &tree), 1);
    // The ducts are hypodense in the CT: bile, not liver.
    let a = &i.atlas.model;
    let core: Vec<f64> = a
        .ct()
        .data()
        .iter()
        .zip(labels.data())
        .enumerate()
        .filter(|(idx, (_, l))| **l == 21 && neighbours_all(labels, *idx, 21))
        .map(|(_, (v, _))| *v as f64)
        .collect();
    let mean = core.iter().sum::<f64>() / core.len() as f64;
    assert!(mean < 25.0, "target core mean {mean} HU");
}

fn neighbours_all(labels: &Volume<LabelId>, idx: usize, id: LabelId) -> bool {
    let g = labels.grid();
    let [i, j, k] = g.unlinear(idx);
    let [nx, ny, nz] = g.dims();
    if i == 0 || j == 0 || k == 0 || i + 1 == nx || j + 1 == ny || k + 1 == nz {
        return false;
    }
    [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
        .iter()
        .all(|&(a, b, c)| labels.get(i + a, j + b, k + c) == id && labels.get(i - a, j - b, k - c) == id)
}

/// The importer's window, checked independently: a straight line from the skin to the target
/// crossing no bone (neither by CT value nor by the source rib/vertebra labels) and no risk
/// structure, passing within 10 mm of both bounds it is named after. The usual right 10th–11th
/// space is about 30 mm wide in this patient where lines reach the target (no line within 10 mm
/// of both ribs), so the recipe asks for the space below the right 10th rib bounded by the costal
/// cartilage (TotalSegmentator 113/117).
#[test]
fn the_intercostal_path_below_rib_10_reaches_the_target_between_the_bounds_it_is_named_after() {
    let i = imported();
    let w = i.report.window.as_ref().unwrap();
    assert!(w.requested_found, "importer reports: {}", i.report.to_text());
    let chosen = w.found.as_ref().unwrap();
    assert_eq!((chosen.upper, chosen.lower), (113, 117));
    assert!(!chosen.transpleural(), "{chosen:?}");
    let path = &i.atlas.manifest.paths[0];
    assert_eq!(path.name, "intercostal-right-10-cartilage");
    assert_eq!(
        i.atlas.manifest.difficulty.beginner.guided_path.as_deref(),
        Some(path.name.as_str())
    );
    let m = &i.atlas.model;
    let (a, b) = (DVec3::from_array(path.entry_mm), DVec3::from_array(path.target_mm));
    assert!(m.skin_distance().sample(a, -1.0).abs() < 2.0, "entry lies on the skin");
    let risk: Vec<LabelId> = m.label_table().with_role(Role::Risk).map(|l| l.id).collect();
    let bones: Vec<LabelId> = (30..=33).chain(98..=103).chain(110..=115).chain([117]).collect();
    let n = (a.distance(b) / 0.25) as usize;
    let (mut d10, mut d11) = (f64::INFINITY, f64::INFINITY);
    let rib_voxels = |id: LabelId| -> Vec<DVec3> {
        let g = i.source.grid();
        i.source
            .data()
            .iter()
            .enumerate()
            .filter(|(_, l)| **l == id)
            .map(|(idx, _)| {
                let [x, y, z] = g.unlinear(idx);
                g.voxel_to_world(x, y, z)
            })
            .collect()
    };
    let (r10, r11) = (rib_voxels(chosen.upper), rib_voxels(chosen.lower));
    for s in 0..=n {
        let x = a + (b - a) * (s as f64 / n as f64);
        assert!(m.hu_at(x) < m.thresholds().fat_bone_hu, "bone-like CT value at {x}");
        let src = i.source.nearest(x, 0);
        assert!(!bones.contains(&src), "source bone label {src} at {x}");
        let l = m.partial_label_at(x);
        assert!(!risk.contains(&l), "risk label {l} at {x}");
        d10 = d10.min(r10.iter().map(|p| p.distance(x)).fold(f64::INFINITY, f64::min));
        d11 = d11.min(r11.iter().map(|p| p.distance(x)).fold(f64::INFINITY, f64::min));
    }
    assert_eq!(m.partial_label_at(b), 21, "the path ends in the target");
    assert!(
        d10 <= 10.0 && d11 <= 10.0,
        "passes close to its upper ({d10:.1} mm) and lower bound ({d11:.1} mm)"
    );
    println!("{}", i.report.to_text());
}

#[test]
fn real_ct_summary_lists_the_mapped_labels() {
    let s = stylet_atlas::summary::Summary::of(&imported().atlas);
    let names: Vec<&str> = s.labels.iter().map(|l| l.name.as_str()).collect();
    for n in [
        "liver",
        "portal vein",
        "right hepatic duct",
        "bile duct",
        "right lung",
        "gallbladder",
    ] {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    assert_eq!(s.dims, [244, 202, 224]);
    assert_eq!(s.spacing_mm, [1.5, 1.5, 1.5]);
}

#[cfg(feature = "dicom")]
#[test]
fn dicom_series_loads_with_the_right_geometry_and_hu() {
    let dir = crate::common::shared_data().join("ts-example-dicom");
    let s = stylet_atlas::import::dicom::read_series(&dir).unwrap();
    let g = s.ct.grid();
    assert_eq!(g.dims(), [512, 512, 20]);
    let sp = g.spacing_mm();
    assert!(
        (sp[0] - 0.9765625).abs() < 1e-9 && (sp[1] - 0.9765625).abs() < 1e-9,
        "{sp:?}"
    );
    // 3 mm slices (SliceThickness) reconstructed every 2 mm: positions −804.5 … −766.5 mm.
    assert_eq!(s.slice_thickness_mm, Some(3.0));
    assert!((s.slice_spacing_mm - 2.0).abs() < 1e-9);
    assert!((sp[2] - 2.0).abs() < 1e-9);
    // LPS (−249.5, −437.5, z) becomes RAS (+249.5, +437.5, z); the lowest slice comes first.
    let o = g.affine().origin;
    assert!(
        (o - DVec3::new(249.51171875, 437.51171875, -804.5)).length() < 1e-6,
        "{o}"
    );
    assert_eq!(g.affine().axes[0], DVec3::new(-0.9765625, 0.0, 0.0));
    assert_eq!(g.affine().axes[1], DVec3::new(0.0, -0.9765625, 0.0));
    // HU: stored values rescaled by −1024 (air at −1024, not 0); soft tissue near the centre.
    let (lo, hi) =
        s.ct.data()
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    assert_eq!(lo, -1024.0);
    assert!(hi > 1000.0, "max {hi}");
    let mut centre: Vec<f32> = (236..276)
        .flat_map(|j| (236..276).map(move |i| (i, j)))
        .map(|(i, j)| s.ct.get(i, j, 10))
        .collect();
    let mid = centre.len() / 2;
    let median = *centre.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
    assert!((-150.0..=150.0).contains(&median), "median near the centre {median} HU");
}

#[cfg(feature = "dicom")]
#[test]
fn dicom_import_writes_a_loadable_heuristic_atlas() {
    let dir = crate::common::shared_data().join("ts-example-dicom");
    let out = tempfile::tempdir().unwrap();
    stylet_atlas::import::dicom::import_series(&dir, out.path(), "dicom-test").unwrap();
    let a = load(out.path()).unwrap();
    assert_eq!(a.model.ct().grid().dims(), [512, 512, 20]);
    assert!(a.model.partial_labels().data().iter().all(|&l| l == 0));
    let bone = a.model.label_voxel_counts().iter().find(|(id, _)| *id == 4).unwrap().1;
    assert!(
        bone > 10_000,
        "the heuristic finds the spine and ribs: {bone} bone voxels"
    );
}

#[cfg(feature = "dicom")]
#[test]
fn a_broken_dicom_file_is_named() {
    let src = crate::common::shared_data().join("ts-example-dicom");
    let dir = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(&src).unwrap() {
        let p = e.unwrap().path();
        if p.file_name().unwrap().to_string_lossy().starts_with("CT") {
            std::fs::copy(&p, dir.path().join(p.file_name().unwrap())).unwrap();
        }
    }
    let victim = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .min()
        .unwrap();
    let bytes = std::fs::read(&victim).unwrap();
    std::fs::write(&victim, &bytes[..600]).unwrap();
    let e = stylet_atlas::import::dicom::read_series(dir.path())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&victim.file_name().unwrap().to_string_lossy().to_string()),
        "{e}"
    );
}
