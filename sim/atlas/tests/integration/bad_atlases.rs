//! Every kind of bad atlas gets an error that names the file and the problem (missing file,
//! dimension or affine mismatch, unknown label, NaN, property-tree cycle or unknown parent,
//! thresholds out of order), and nothing panics.

use std::fs;
use std::path::Path;
use std::time::Duration;

use crate::common::{tiny_grid, tiny_manifest, tiny_volumes, write_tiny};
use stylet_physics::glam::DVec3;
use stylet_physics::{Affine, Grid, Volume};

fn load_err(dir: &Path) -> String {
    match stylet_atlas::load(dir) {
        Ok(_) => panic!("{} loaded although it is broken", dir.display()),
        Err(e) => e.to_string(),
    }
}

fn assert_mentions(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "error {msg:?} does not mention {p:?}");
    }
}

fn edit_manifest(dir: &Path, f: impl FnOnce(String) -> String) {
    let p = dir.join("atlas.toml");
    let text = fs::read_to_string(&p).unwrap();
    let new = f(text.clone());
    assert_ne!(text, new, "the edit changed nothing");
    fs::write(p, new).unwrap();
}

#[test]
fn the_tiny_atlas_is_valid() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let a = stylet_atlas::load(d.path()).unwrap();
    assert_eq!(a.model.ct().grid().dims(), [24, 20, 16]);
    assert_eq!(a.threshold_source, stylet_atlas::ThresholdSource::Estimated);
}

#[test]
fn missing_files() {
    let d = tempfile::tempdir().unwrap();
    let e = load_err(&d.path().join("nope"));
    assert_mentions(&e, &["nope", "does not exist"]);
    let e = load_err(d.path());
    assert_mentions(&e, &["atlas.toml", "missing"]);
    write_tiny(d.path());
    fs::remove_file(d.path().join("ct.nii.gz")).unwrap();
    assert_mentions(&load_err(d.path()), &["ct.nii.gz", "cannot open"]);
    write_tiny(d.path());
    fs::remove_file(d.path().join("labels.nii.gz")).unwrap();
    assert_mentions(&load_err(d.path()), &["labels.nii.gz", "cannot open"]);
}

#[test]
fn dimension_mismatch() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let g = Grid::new([24, 20, 15], *tiny_grid().affine()).unwrap();
    stylet_atlas::nifti_io::write_labels(&d.path().join("labels.nii.gz"), &Volume::filled(g, 0), "").unwrap();
    assert_mentions(
        &load_err(d.path()),
        &["labels.nii.gz", "dimensions [24, 20, 15]", "[24, 20, 16]"],
    );
}

#[test]
fn affine_mismatch() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let shifted = Affine::from_spacing([4.0; 3], DVec3::new(-46.0, -38.0, -27.0));
    let g = Grid::new([24, 20, 16], shifted).unwrap();
    stylet_atlas::nifti_io::write_labels(&d.path().join("labels.nii.gz"), &Volume::filled(g, 0), "").unwrap();
    assert_mentions(&load_err(d.path()), &["labels.nii.gz", "affine differs", "3.0000 mm"]);
}

#[test]
fn unknown_label() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let (_, mut labels) = tiny_volumes();
    labels.set(3, 3, 3, 99);
    stylet_atlas::nifti_io::write_labels(&d.path().join("labels.nii.gz"), &labels, "").unwrap();
    assert_mentions(
        &load_err(d.path()),
        &["labels.nii.gz", "label 99", "not in the label table"],
    );
}

#[test]
fn fractional_or_negative_labels() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let mut data = vec![0.0f32; 24 * 20 * 16];
    data[100] = 1.5;
    write_f32(&d.path().join("labels.nii.gz"), data);
    assert_mentions(
        &load_err(d.path()),
        &["labels.nii.gz", "holds 1.5", "not a label number"],
    );
}

/// Writes a float32 NIfTI on the tiny grid (the atlas writer only writes int16 CTs).
fn write_f32(path: &Path, data: Vec<f32>) {
    use ndarray::ShapeBuilder;
    let arr = ndarray::Array3::from_shape_vec((24, 20, 16).f(), data).unwrap();
    let rows = tiny_grid().affine().rows();
    let f = |r: [f64; 4]| [r[0] as f32, r[1] as f32, r[2] as f32, r[3] as f32];
    let header = nifti::NiftiHeader {
        sform_code: 1,
        srow_x: f(rows[0]),
        srow_y: f(rows[1]),
        srow_z: f(rows[2]),
        ..Default::default()
    };
    nifti::writer::WriterOptions::new(path)
        .reference_header(&header)
        .write_nifti(&arr)
        .unwrap();
}

#[test]
fn nan_in_the_ct() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let (ct, _) = tiny_volumes();
    let mut data = ct.data().to_vec();
    let idx = tiny_grid().linear(5, 6, 7);
    data[idx] = f32::NAN;
    write_f32(&d.path().join("ct.nii.gz"), data);
    assert_mentions(&load_err(d.path()), &["ct.nii.gz", "voxel (5, 6, 7)", "NaN"]);
}

#[test]
fn property_tree_cycle() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let mut m = tiny_manifest();
    m.tissues.get_mut("body").unwrap().parent = Some("liver".into());
    fs::write(d.path().join("atlas.toml"), m.to_toml()).unwrap();
    assert_mentions(&load_err(d.path()), &["atlas.toml", "cycle", "liver", "body"]);
}

#[test]
fn property_tree_unknown_parent() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    edit_manifest(d.path(), |t| {
        t.replacen("parent = \"soft_tissue\"", "parent = \"soft_tisue\"", 1)
    });
    assert_mentions(&load_err(d.path()), &["atlas.toml", "unknown parent 'soft_tisue'"]);
}

#[test]
fn parameter_without_definition() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let mut m = tiny_manifest();
    for t in m.tissues.values_mut() {
        t.cut_threshold_n = None;
    }
    fs::write(d.path().join("atlas.toml"), m.to_toml()).unwrap();
    assert_mentions(&load_err(d.path()), &["atlas.toml", "no value for 'cut_threshold_n'"]);
}

#[test]
fn thresholds_out_of_order() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    edit_manifest(d.path(), |t| {
        t.replace(
            "[heuristic]",
            "[thresholds]\nair_skin = -500.0\nskin_fat = -600.0\nfat_bone = 200.0\n\n[heuristic]",
        )
    });
    assert_mentions(
        &load_err(d.path()),
        &["atlas.toml", "out of order", "air_skin (-500)", "skin_fat (-600)"],
    );
}

#[test]
fn given_thresholds_are_used() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    edit_manifest(d.path(), |t| {
        t.replace(
            "[heuristic]",
            "[thresholds]\nair_skin = -450.0\nskin_fat = -250.0\nfat_bone = 220.0\n\n[heuristic]",
        )
    });
    let a = stylet_atlas::load(d.path()).unwrap();
    assert_eq!(a.threshold_source, stylet_atlas::ThresholdSource::Atlas);
    assert_eq!(a.model.thresholds().fat_bone_hu, 220.0);
}

#[test]
fn syntax_and_schema_errors() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    edit_manifest(d.path(), |t| {
        t.replacen("name = \"tiny\"", "name = \"tiny\"\ncolour = 3", 1)
    });
    assert_mentions(&load_err(d.path()), &["atlas.toml", "unknown field `colour`"]);
    write_tiny(d.path());
    edit_manifest(d.path(), |t| t.replacen("role = \"organ\"", "role = \"organic\"", 1));
    assert_mentions(&load_err(d.path()), &["atlas.toml", "role 'organic'"]);
    write_tiny(d.path());
    edit_manifest(d.path(), |t| t.replacen("format_version = 1", "format_version = 7", 1));
    assert_mentions(&load_err(d.path()), &["atlas.toml", "format_version 7"]);
    write_tiny(d.path());
    edit_manifest(d.path(), |t| {
        t.replacen("ct = \"ct.nii.gz\"", "ct = \"../../etc/passwd.nii\"", 1)
    });
    assert_mentions(&load_err(d.path()), &["atlas.toml", "plain file name"]);
    write_tiny(d.path());
    edit_manifest(d.path(), |t| t.replacen("[heuristic]", "[heuristic", 1));
    assert_mentions(&load_err(d.path()), &["atlas.toml", "line"]);
}

#[test]
fn guided_path_must_exist_and_lie_in_the_ct() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let mut m = tiny_manifest();
    m.difficulty.beginner.guided_path = Some("nowhere".into());
    fs::write(d.path().join("atlas.toml"), m.to_toml()).unwrap();
    assert_mentions(&load_err(d.path()), &["atlas.toml", "guided_path = \"nowhere\""]);
    let mut m = tiny_manifest();
    m.paths.push(stylet_atlas::manifest::InsertionPath {
        name: "far".into(),
        entry_mm: [0.0, 0.0, 900.0],
        target_mm: [0.0, 0.0, 0.0],
        description: String::new(),
    });
    fs::write(d.path().join("atlas.toml"), m.to_toml()).unwrap();
    assert_mentions(&load_err(d.path()), &["atlas.toml", "'far'", "outside the CT"]);
}

#[test]
fn truncated_and_garbage_volumes() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let ct = d.path().join("ct.nii.gz");
    let bytes = fs::read(&ct).unwrap();
    fs::write(&ct, &bytes[..bytes.len() / 2]).unwrap();
    let e = load_err(d.path());
    assert!(e.contains("ct.nii.gz"), "{e}");
    fs::write(
        &ct,
        b"this is not a NIfTI file at all, just some text that is long enough to fill a header",
    )
    .unwrap();
    assert_mentions(&load_err(d.path()), &["ct.nii.gz", "NIfTI"]);
}

#[test]
fn writing_is_atomic_and_leaves_no_partial_files() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let names: Vec<String> = fs::read_dir(d.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    let mut names = names;
    names.sort();
    assert_eq!(names, ["atlas.toml", "ct.nii.gz", "labels.nii.gz"]);
}

/// Runs `f` on its own thread and waits at most 30 s, so a regression that blocks in open(2)
/// fails the test instead of hanging the suite.
#[cfg(unix)]
fn within_30_s<T: Send + 'static>(what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(Duration::from_secs(30))
        .unwrap_or_else(|_| panic!("{what} did not return within 30 s (blocked opening a FIFO?)"))
}

#[cfg(unix)]
fn mkfifo(path: &Path) {
    let _ = fs::remove_file(path);
    let status = std::process::Command::new("mkfifo").arg(path).status().unwrap();
    assert!(status.success(), "mkfifo {}", path.display());
}

/// A FIFO named like an atlas file must not make `stylet atlas inspect` hang: every atlas file
/// is checked to be a regular file before it is opened.
#[cfg(unix)]
#[test]
fn a_fifo_in_place_of_an_atlas_file_is_refused_without_hanging() {
    for name in ["ct.nii.gz", "labels.nii.gz", "atlas.toml"] {
        let d = tempfile::tempdir().unwrap();
        write_tiny(d.path());
        mkfifo(&d.path().join(name));
        let dir = d.path().to_path_buf();
        let r = within_30_s(&format!("loading with a FIFO {name}"), move || {
            stylet_atlas::load(&dir).map(|_| ()).map_err(|e| e.to_string())
        });
        let e = r.expect_err("an atlas with a FIFO loaded");
        assert_mentions(&e, &[name, "named pipe (FIFO)", "not a regular file"]);
    }
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    fs::remove_file(d.path().join("ct.nii.gz")).unwrap();
    fs::create_dir(d.path().join("ct.nii.gz")).unwrap();
    assert_mentions(
        &load_err(d.path()),
        &["ct.nii.gz", "is a directory, not a regular file"],
    );
}

/// Symlinks are followed: a volume shared between atlases through a link loads, with the same
/// content hash as a copy.
#[cfg(unix)]
#[test]
fn symlinks_to_regular_files_load() {
    let d = tempfile::tempdir().unwrap();
    let atlas = d.path().join("atlas");
    write_tiny(&atlas);
    let hash = stylet_atlas::load(&atlas).unwrap().content_hash;
    fs::rename(atlas.join("ct.nii.gz"), d.path().join("shared-ct.nii.gz")).unwrap();
    std::os::unix::fs::symlink(d.path().join("shared-ct.nii.gz"), atlas.join("ct.nii.gz")).unwrap();
    assert_eq!(stylet_atlas::load(&atlas).unwrap().content_hash, hash);
    // A link to a FIFO is no better than the FIFO.
    mkfifo(&d.path().join("pipe"));
    fs::remove_file(atlas.join("ct.nii.gz")).unwrap();
    std::os::unix::fs::symlink(d.path().join("pipe"), atlas.join("ct.nii.gz")).unwrap();
    let r = within_30_s("loading with a link to a FIFO", move || {
        stylet_atlas::load(&atlas).map(|_| ()).map_err(|e| e.to_string())
    });
    assert_mentions(&r.unwrap_err(), &["ct.nii.gz", "named pipe (FIFO)"]);
}

/// The importers' operator files: a recipe or a DICOM slice that is a FIFO is refused, not waited on.
#[cfg(unix)]
#[test]
fn import_inputs_that_are_not_regular_files_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let recipe = d.path().join("recipe.toml");
    mkfifo(&recipe);
    let r = within_30_s("loading a FIFO recipe", move || {
        stylet_atlas::import::recipe::load_recipe(&recipe)
            .map(|_| ())
            .map_err(|e| e.to_string())
    });
    assert_mentions(&r.unwrap_err(), &["recipe.toml", "named pipe (FIFO)"]);
    #[cfg(feature = "dicom")]
    {
        let series = d.path().join("series");
        fs::create_dir(&series).unwrap();
        mkfifo(&series.join("slice-001.dcm"));
        let r = within_30_s("reading a series with a FIFO", move || {
            stylet_atlas::import::dicom::read_series(&series)
                .map(|_| ())
                .map_err(|e| e.to_string())
        });
        assert_mentions(&r.unwrap_err(), &["slice-001.dcm", "named pipe (FIFO)"]);
    }
}

/// A recipe's class table that is broken is refused with the file and the line named, before any CT
/// is read, and nothing is written.
#[test]
fn a_bad_class_table_is_refused_before_anything_is_read_or_written() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let d = tempfile::tempdir().unwrap();
    let recipes = d.path().join("recipes");
    fs::create_dir(&recipes).unwrap();
    fs::copy(root.join("atlases/ptcd.toml"), d.path().join("ptcd.toml")).unwrap();
    let recipe = fs::read_to_string(root.join("atlases/ts-abdomen/recipe.toml"))
        .unwrap()
        .replace("[source]\n", "[source]\nclasses = \"classes.csv\"\n");
    assert!(recipe.contains("classes = \"classes.csv\""));
    fs::write(recipes.join("recipe.toml"), recipe).unwrap();
    // No CT in the data directory: the class table must be refused first.
    let data = d.path().join("data");
    fs::create_dir(&data).unwrap();
    let out = d.path().join("out");
    for (csv, want) in [
        ("id,structure\n5,liver\n5,spleen\n", "line 3: class 5 is listed twice"),
        ("structure\nliver\n", "no `id` column"),
        ("id,structure\n-3,liver\n", "class number \"-3\" is not 1"),
    ] {
        fs::write(data.join("classes.csv"), csv).unwrap();
        let e = stylet_atlas::import::import(&recipes.join("recipe.toml"), &data, &out)
            .unwrap_err()
            .to_string();
        assert_mentions(&e, &["classes.csv", want]);
        assert!(!out.exists(), "{csv:?} wrote {}", out.display());
    }
    // A path out of the data directory is refused by the recipe check.
    let text = fs::read_to_string(recipes.join("recipe.toml")).unwrap();
    fs::write(
        recipes.join("recipe.toml"),
        text.replace("classes.csv", "../classes.csv"),
    )
    .unwrap();
    let e = stylet_atlas::import::import(&recipes.join("recipe.toml"), &data, &out)
        .unwrap_err()
        .to_string();
    assert_mentions(&e, &["recipe.toml", "inside the data directory"]);
}

/// Breathing files must lie inside the atlas folder: an absolute path or one through `..` is
/// refused before anything is opened, with the same answer whether or not a file is there (no
/// oracle of the server's files through an uploaded atlas).
#[test]
fn breathing_paths_outside_the_atlas_are_refused_alike() {
    let d = tempfile::tempdir().unwrap();
    let atlas = d.path().join("atlas");
    fs::create_dir(&atlas).unwrap();
    write_tiny(&atlas);
    fs::write(d.path().join("secret.nii.gz"), b"exists").unwrap();
    let mut answers = Vec::new();
    for path in [
        "/etc/passwd",
        "/no/such/file.nii.gz",
        "../secret.nii.gz",
        "../missing.nii.gz",
        "motion/../../secret.nii.gz",
    ] {
        let manifest = fs::read_to_string(atlas.join("atlas.toml")).unwrap();
        // The tiny atlas breathes with the synthetic motion: its files are measured ones now.
        let measured = format!("motion = \"measured\"\na1 = {path:?}\n");
        let edited = if manifest.contains("[breathing]") {
            manifest.replacen("motion = \"synthetic\"\n", &measured, 1)
        } else {
            format!("{manifest}\n[breathing]\n{measured}")
        };
        assert!(edited.contains(&measured), "{edited}");
        let e = stylet_atlas::store::parse_manifest(&edited).unwrap_err();
        assert!(
            matches!(
                e,
                stylet_atlas::manifest::ManifestError::BreathingFile {
                    key: "a1",
                    problem: stylet_atlas::manifest::PathProblem::OutsideAtlas
                }
            ),
            "{e}"
        );
        let e = e.to_string();
        assert_mentions(&e, &["breathing.a1", "inside the atlas directory"]);
        answers.push(e);
        let saved = fs::read_to_string(atlas.join("atlas.toml")).unwrap();
        fs::write(atlas.join("atlas.toml"), &edited).unwrap();
        let loaded = load_err(&atlas);
        let counted = stylet_atlas::store::voxel_count(&atlas).unwrap_err().to_string();
        fs::write(atlas.join("atlas.toml"), saved).unwrap();
        assert_mentions(&loaded, &["breathing.a1", "inside the atlas directory"]);
        assert_mentions(&counted, &["breathing.a1", "inside the atlas directory"]);
    }
    assert!(answers.windows(2).all(|w| w[0] == w[1]), "{answers:#?}");
}
