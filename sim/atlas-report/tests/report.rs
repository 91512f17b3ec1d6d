//! The validation report on the real abdominal CT with partial labels: the page and
//! its pictures are written whole, name the window by its ribs, list every structure with its
//! colour, carry the warnings and the step times, escape what a class table names, and fit a phone.
//! Reads the real CT data (`scripts/fetch-data`, `$STYLET_DATA`) and fails, with a message, without it.

use std::path::{Path, PathBuf};

use stylet_atlas::import::checks::WarningKind;
use stylet_atlas::import::classes::ClassTable;
use stylet_atlas::import::new::{NewAtlas, new_atlas};
use stylet_atlas_report::{ReportInput, SmokeResult, write_report};

fn shared_data() -> PathBuf {
    stylet_testkit::real_ct_data()
}

/// TotalSegmentator's classes with the unmapped class 79 (spinal cord) renamed to markup.
fn hostile_classes(dir: &Path) -> PathBuf {
    let ts = ClassTable::totalsegmentator();
    let mut csv = String::from("id,structure\n");
    for id in 1..=117 {
        let name = if id == 79 {
            "<img src=x onerror=alert(1)>"
        } else {
            ts.name(id).unwrap()
        };
        csv += &format!("{id},{name}\n");
    }
    let p = dir.join("classes.csv");
    std::fs::write(&p, csv).unwrap();
    p
}

#[test]
fn the_abdominal_scenario_gets_a_whole_report() {
    let d = shared_data().join("ts-example-abdomen");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("abdomen");
    let args = NewAtlas {
        ct: d.join("example_ct.nii.gz"),
        labels: d.join("example_seg.nii.gz"),
        classes: Some(hostile_classes(tmp.path())),
        map: None,
        offset_voxels: [0, 0, 82],
        name: "abdomen".into(),
        breathing: true,
    };
    let made = new_atlas(&args, &out, &mut |_| {}).unwrap();
    let import = &made.import;
    // The label map covers 0 … 81 + its own slices: a coverage warning, named.
    assert!(
        import.warnings.iter().any(|w| w.kind == WarningKind::LabelCoverage),
        "{:?}",
        import.warnings
    );
    let smoke = [SmokeResult {
        script: "success.txt".into(),
        expected: "reaches and confirms the target".into(),
        got: "target reached true".into(),
        passed: true,
        seconds: 0.1,
    }];
    let files = write_report(
        &out.join("report"),
        &ReportInput {
            atlas: &made.atlas,
            import,
            smoke: &smoke,
            ct_source: "example_ct.nii.gz",
            labels_source: "example_seg.nii.gz",
        },
    )
    .unwrap();
    let html = std::fs::read_to_string(&files.html).unwrap();
    for png in &files.images {
        let bytes = std::fs::read(png).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{}", png.display());
        let name = png.file_name().unwrap().to_str().unwrap();
        assert!(html.contains(&format!("src=\"{name}\"")), "{name} not on the page");
    }
    assert_eq!(files.images.len(), 3);
    // The windows ranked by clinical score, each named by its bounds with their distances, the
    // space asked for (no line within 10 mm of both its ribs here) said missing.
    let w = import.window.as_ref().unwrap();
    assert!(html.contains("ranked by clinical score"), "no ranking explained");
    for (k, f) in w.ranked.iter().enumerate() {
        let row = format!(
            "<tr><td class=\"n\">{}</td><td>{}</td><td>{} ({:.1} mm) / {} ({:.1} mm)</td>",
            k + 1,
            stylet_atlas::import::window::space_name(&import.classes, f.upper, f.lower),
            import
                .classes
                .describe(f.upper)
                .replace('<', "&lt;")
                .replace('>', "&gt;"),
            f.upper_distance_mm,
            import
                .classes
                .describe(f.lower)
                .replace('<', "&lt;")
                .replace('>', "&gt;"),
            f.lower_distance_mm
        );
        assert!(html.contains(&row), "window {} missing: {row}", k + 1);
        assert!(
            html.contains(&format!("{:.1}</td>", f.penalty())),
            "penalty of window {}",
            k + 1
        );
    }
    assert!(html.matches("transpleural").count() > w.ranked.iter().filter(|f| f.transpleural()).count());
    assert!(html.contains("right 10th–11th intercostal space</td><td>rib_right_10 (113) / rib_right_11 (114)</td>"));
    assert!(html.contains("within 10 mm of both"));
    // Every structure of the atlas in the legend with a swatch.
    for l in made.atlas.model.label_table().labels() {
        assert!(
            html.contains(&format!("<td>{}</td>", l.name.replace('&', "&amp;"))),
            "{} missing",
            l.name
        );
    }
    assert_eq!(
        html.matches("class=\"sw\"").count(),
        made.atlas.model.label_table().labels().len()
    );
    for w in &import.warnings {
        assert!(html.contains(w.kind.title()), "warning {w:?} missing");
    }
    assert!(html.contains("Time per step") && html.contains("growing the biliary tree"));
    assert!(html.contains("scripts/success.txt: passed"));
    // The class table's markup is text on the page, never markup.
    assert!(
        html.contains("&lt;img src=x onerror=alert(1)&gt;"),
        "hostile name not shown escaped"
    );
    assert!(!html.contains("<img src=x"), "hostile name not escaped");
    // Fits a phone: laid out at the screen's width, every table in a box that scrolls sideways.
    assert!(html.contains("<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"));
    assert!(html.matches("<table").count() >= 4);
    assert_eq!(
        html.matches("<table").count(),
        html.matches("<div class=\"scroll\"><table").count()
    );
    // Written whole: no partial folder left beside it; a second report replaces the first.
    assert!(!tmp.path().join("abdomen/.report.partial").exists());
    let again = write_report(
        &out.join("report"),
        &ReportInput {
            atlas: &made.atlas,
            import,
            smoke: &[],
            ct_source: "a",
            labels_source: "b",
        },
    )
    .unwrap();
    let html = std::fs::read_to_string(again.html).unwrap();
    assert!(html.contains("No example scripts"));
}
