//! Scoring end to end through the `stylet` binary on the default phantom: every example script,
//! recorded then scored, gives what its name says with `replay_verified`; a one-ulp change of a
//! recorded force is caught at its tick; recovered sessions are scored and flagged incomplete;
//! sessions from another physics version or atlas are refused; batches do not depend on --jobs
//! or file order.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crate::common::{fails, ok, python, s};

use serde_json::Value;
use stylet_recorder::reader;
use stylet_recorder::{SessionWriter, WriterOptions};

/// The default phantom and every example script recorded on it, once per test binary.
struct Setup {
    dir: PathBuf,
}

impl Setup {
    fn atlas(&self) -> PathBuf {
        self.dir.join("phantom")
    }
    fn session(&self, name: &str) -> PathBuf {
        self.dir.join(format!("{name}.mcap"))
    }
}

const SCRIPTS: [&str; 8] = [
    "probe-no-target",
    "success-intercostal",
    "two-attempts",
    "lung-hit",
    "vessel-hit",
    "palpation-sweep",
    "probe-across",
    "probe-parallel",
];

fn setup() -> &'static Setup {
    static S: OnceLock<Setup> = OnceLock::new();
    S.get_or_init(|| {
        let setup = Setup {
            dir: stylet_testkit::fixture_dir(),
        };
        ok(&["atlas", "phantom", "--out", s(&setup.atlas())]);
        for name in SCRIPTS {
            let script = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("atlases/phantom/scripts/{name}.txt"));
            ok(&[
                "script",
                "run",
                "--atlas",
                s(&setup.atlas()),
                "--script",
                s(&script),
                "--out",
                s(&setup.session(name)),
                "--trainee",
                "carol",
            ]);
        }
        setup
    })
}

fn score_json(file: &Path) -> Value {
    serde_json::from_str(&ok(&["score", s(file), "--atlas", s(&setup().atlas()), "--json"])).unwrap()
}

/// Sessions recorded with this physics version stay replayable bit for bit by later builds: the
/// finger, linear and convex probe sessions (the contact nodes' batched reads) and a needle session
/// with contrast (2 ml filling and spreading through the ducts for 2.5 s), recorded with physics
/// version 13 (tests/fixtures/physics-v13, the scripts beside them). A speed-up must not change
/// one output bit. They are frozen; when PHYSICS_VERSION changes on purpose, record them again
/// from their scripts on `stylet atlas phantom` with the new binary, in a folder of the new
/// version.
#[test]
fn sessions_recorded_before_the_speed_ups_replay_bit_for_bit() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/physics-v13");
    for name in [
        "finger-sweep",
        "probe-linear-across",
        "probe-convex-parallel",
        "needle-contrast",
    ] {
        let r = score_json(&dir.join(format!("{name}.mcap")));
        assert_eq!(r["replay_verified"], true, "{name}: {}", r["divergence"]);
        if name == "needle-contrast" {
            // The contrast filled the ducts: the diffusion ran in this session.
            assert_eq!(r["metrics"]["target_confirmed"], true, "{r}");
        }
    }
}

#[test]
fn every_example_script_scores_as_its_name_says() {
    let st = setup();
    let mut scores = Vec::new();
    for name in SCRIPTS {
        let r = score_json(&st.session(name));
        assert_eq!(r["replay_verified"], true, "{name}: {}", r["divergence"]);
        assert_eq!(r["physics_version"], stylet_physics::PHYSICS_VERSION);
        assert_eq!(r["incomplete"], false, "{name}");
        for key in [
            "attempts",
            "redirections",
            "risk_hits",
            "bone_contacts",
            "target_reached",
            "target_confirmed",
            "time_to_target_s",
            "time_total_s",
            "fluoro_time_s",
            "xray_shots",
            "path_length_mm",
            "max_force_n",
            "shaft_sweep_mm2",
            "needle_motion",
            "target_distance_mm",
        ] {
            assert!(r["metrics"].get(key).is_some(), "{name}: metrics lack {key}");
        }
        for key in ["score", "passed", "difficulty", "rubric_version"] {
            assert!(r["grade"].get(key).is_some(), "{name}: grade lacks {key}");
        }
        scores.push((name, r));
    }
    let get = |n: &str| &scores.iter().find(|(name, _)| *name == n).unwrap().1;
    let hits = |n: &str| -> Vec<String> {
        get(n)["metrics"]["risk_hits"]
            .as_array()
            .unwrap()
            .iter()
            .map(|h| h["structure"].as_str().unwrap().to_string())
            .collect()
    };

    let ok_run = get("success-intercostal");
    let m = &ok_run["metrics"];
    assert_eq!(m["attempts"], 1);
    assert_eq!(m["target_reached"], true);
    assert_eq!(m["target_confirmed"], true);
    assert!(hits("success-intercostal").is_empty());
    assert_eq!(m["bone_contacts"], 0);
    assert_eq!(m["xray_shots"], 1);
    assert!(
        (m["fluoro_time_s"].as_f64().unwrap() - 1.5).abs() < 1e-9,
        "{}",
        m["fluoro_time_s"]
    );
    assert_eq!(m["target_distance_min_mm"], 0.0);
    let g = &ok_run["grade"];
    assert_eq!(g["difficulty"], "beginner");
    assert_eq!(g["passed"], true, "{g}");
    // The script follows the planned path: guided metrics see it.
    let guided = &m["guided"];
    assert_eq!(guided["path"], "intercostal-10-11");
    assert!(guided["entry_distance_mm"].as_f64().unwrap() < 2.0, "{guided}");
    assert!(guided["angle_error_deg"].as_f64().unwrap() < 2.0, "{guided}");

    assert_eq!(get("two-attempts")["metrics"]["attempts"], 2);
    assert_eq!(get("two-attempts")["metrics"]["target_confirmed"], true);

    let lung = hits("lung-hit");
    assert!(lung.iter().any(|h| h.contains("lung")), "lung-hit: {lung:?}");
    assert_eq!(get("lung-hit")["grade"]["passed"], false);
    let lung_hit = &get("lung-hit")["metrics"]["risk_hits"][0];
    assert!(
        lung_hit["depth_mm"].as_f64().unwrap() > 1.0 && lung_hit["duration_s"].as_f64().unwrap() > 0.1,
        "{lung_hit}"
    );

    let vessel = hits("vessel-hit");
    assert!(
        vessel
            .iter()
            .any(|h| h.contains("vein") || h.contains("aorta") || h.contains("cava")),
        "vessel-hit: {vessel:?}"
    );
    assert_eq!(get("vessel-hit")["grade"]["passed"], false);

    let palp = &get("palpation-sweep")["metrics"];
    assert_eq!(palp["attempts"], 0);
    assert!(palp["palpation_time_s"].as_f64().unwrap() > 5.0, "{palp}");
    for probe in ["probe-across", "probe-parallel"] {
        let m = &get(probe)["metrics"];
        assert!(m["ultrasound_time_s"].as_f64().unwrap() > 5.0, "{probe}: {m}");
        assert_eq!(m["attempts"], 0);
    }
    // Exercises: the palpation and probe scripts are graded as what they practise, and pass.
    let exercise = |n: &str| (get(n)["exercise"].clone(), get(n)["outcome"].clone());
    for (n, e) in [
        ("success-intercostal", "puncture"),
        ("lung-hit", "puncture"),
        ("palpation-sweep", "palpation"),
        ("probe-parallel", "ultrasound_survey"),
        ("probe-across", "ultrasound_survey"),
    ] {
        assert_eq!(get(n)["exercise"], e, "{n}");
        assert_eq!(get(n)["grade"]["exercise"], e, "{n}");
    }
    for n in [
        "palpation-sweep",
        "probe-parallel",
        "probe-across",
        "success-intercostal",
    ] {
        assert_eq!(exercise(n).1, "passed", "{n}: {}", get(n)["reasons"]);
    }
    let palp = &get("palpation-sweep")["metrics"]["palpation"];
    assert!(palp["spaces_found"].as_u64().unwrap() >= 3, "{palp}");
    assert_eq!(palp["spaces_found"], palp["spaces_crossed"], "{palp}");
    for probe in ["probe-across", "probe-parallel"] {
        let u = &get(probe)["metrics"]["ultrasound"];
        assert_eq!(u["target_scanned"], true, "{probe}: {u}");
        // Ultrasound in a session without a puncture is not "missing".
        assert_eq!(get(probe)["metrics"]["workflow"]["ultrasound_before_puncture"], true);
    }
    // The poor survey never shows the target and fails, saying so in words.
    let poor = get("probe-no-target");
    assert_eq!(poor["exercise"], "ultrasound_survey");
    assert_eq!(poor["outcome"], "failed");
    assert_eq!(poor["metrics"]["ultrasound"]["target_scanned"], false);
    let reasons: Vec<&str> = poor["reasons"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r.as_str().unwrap())
        .collect();
    assert!(
        reasons
            .iter()
            .any(|r| r.contains("target never came within 5 mm of the ultrasound image")),
        "{reasons:?}"
    );
    // Failed punctures say why in words, with the consequence from the atlas TOML.
    let lung = get("lung-hit");
    assert_eq!(lung["outcome"], "failed");
    assert_eq!(lung["metrics"]["risk_hits"][0]["consequence"], "pneumothorax");
    let why = lung["reasons"].to_string();
    assert!(why.contains("right lung") && why.contains("pneumothorax"), "{why}");
    assert!(why.contains("is below the pass mark of 60 for beginner"), "{why}");
    // No metric identifier in any text meant for people.
    for (name, r) in &scores {
        for text in r["reasons"]
            .as_array()
            .unwrap()
            .iter()
            .chain(r["grade"]["failed"].as_array().unwrap())
        {
            let text = text.as_str().unwrap();
            // (Identifiers without an underscore, like "attempts", are plain words.)
            for id in stylet_scoring::rubric::rubric_metrics().filter(|id| id.contains('_')) {
                assert!(!text.contains(id), "{name}: '{id}' in {text}");
            }
            assert!(!text.contains('_'), "{name}: {text}");
        }
    }
    // Text output names the verdict.
    let text = ok(&["score", s(&setup().session("lung-hit")), "--atlas", s(&setup().atlas())]);
    assert!(
        text.contains("risk hit     right lung") && text.contains("FAILED"),
        "{text}"
    );
}

/// Rewrites a session with `edit` applied to its contents (header, ticks, output checks, events,
/// digests).
fn rewrite(src: &Path, dst: &Path, edit: impl FnOnce(&mut reader::Session)) {
    let mut session = reader::read(src).unwrap();
    edit(&mut session);
    let w = SessionWriter::create(
        dst,
        &session.header,
        WriterOptions {
            fsync: false,
            ..WriterOptions::default()
        },
    )
    .unwrap();
    for e in &session.events {
        w.event_record_blocking(e.clone()).unwrap();
    }
    for d in &session.digests {
        w.digest_blocking(d.tick, d.digest).unwrap();
    }
    w.record_read_blocking(&session.ticks, &session.output_checks).unwrap();
    w.finish().unwrap();
}

/// A recorded force changed by one step of its rounding (15 µN) is caught at its tick; a change
/// below that, in the exact bits the file pins by digest, at the last tick of its block.
#[test]
fn a_changed_recorded_force_is_caught_at_its_tick_or_block() {
    let st = setup();
    let d = tempfile::tempdir().unwrap();
    let tampered = d.path().join("tampered.mcap");
    rewrite(&st.session("success-intercostal"), &tampered, |s| {
        let t = &mut s.ticks[12_345];
        t.force_n[1] += 1.0 / stylet_recorder::outputs::FORCE_STEPS_PER_N;
    });
    let r = score_json(&tampered);
    assert_eq!(r["replay_verified"], false);
    assert_eq!(r["divergence"]["tick"], 12_345);
    assert_eq!(r["divergence"]["stream"], "ticks.force_n");
    // Still graded on the replayed physics, which did not change.
    let honest = score_json(&st.session("success-intercostal"));
    assert_eq!(r["metrics"], honest["metrics"]);
    let text = ok(&["score", s(&tampered), "--atlas", s(&st.atlas())]);
    assert!(
        text.contains("NOT verified: first difference at tick 12345 in ticks.force_n"),
        "{text}"
    );

    // The digest of the exact outputs of the block holding tick 12 345, one bit off: as if one
    // output had changed in its last mantissa bit.
    let low_bits = d.path().join("low-bits.mcap");
    let mut block_end = 0;
    rewrite(&st.session("success-intercostal"), &low_bits, |s| {
        let c = s.output_checks.iter_mut().find(|c| c.covers(12_345)).unwrap();
        c.digest ^= 1;
        block_end = c.last_tick();
    });
    let r = score_json(&low_bits);
    assert_eq!(r["replay_verified"], false);
    assert_eq!(r["divergence"]["stream"], "ticks.outputs_digest");
    assert_eq!(r["divergence"]["tick"], block_end);
    // Every other block of the session was checked the same way.
    let session = reader::read(&st.session("success-intercostal")).unwrap();
    let covered: u64 = session.output_checks.iter().map(|c| u64::from(c.count)).sum();
    assert_eq!(covered, session.ticks.len() as u64);

    // A changed state digest is caught too.
    let digest = d.path().join("digest.mcap");
    rewrite(&st.session("success-intercostal"), &digest, |s| {
        s.digests[7].digest ^= 1
    });
    let r = score_json(&digest);
    assert_eq!(r["replay_verified"], false);
    assert_eq!(r["divergence"]["stream"], "digests");
    assert_eq!(r["divergence"]["tick"], 799);
}

#[test]
fn recovered_sessions_are_scored_and_flagged_incomplete() {
    let st = setup();
    let d = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(st.session("two-attempts")).unwrap();
    let cut = d.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 4]).unwrap();
    let fixed = d.path().join("fixed.mcap");
    ok(&["session", "recover", s(&cut), "--out", s(&fixed)]);
    for file in [&fixed, &cut] {
        let r = score_json(file);
        assert_eq!(r["incomplete"], true, "{}", file.display());
        assert!(
            r["incomplete_reason"].as_str().unwrap().contains("damaged"),
            "{}",
            r["incomplete_reason"]
        );
        // What is there still replays bit for bit.
        assert_eq!(r["replay_verified"], true);
        // Never graded 0 / failed: not gradeable, saying what was lost.
        assert_eq!(r["outcome"], "not_gradeable", "{}", file.display());
        let why = r["reasons"][0].as_str().unwrap();
        assert!(why.starts_with("Not gradeable") && why.contains("damaged"), "{why}");
        let text = ok(&["score", s(file), "--atlas", s(&st.atlas())]);
        assert!(text.contains("NOT GRADEABLE") && !text.contains("FAILED"), "{text}");
        let ticks = r["ticks"].as_u64().unwrap();
        assert!(ticks > 10_000 && ticks < 34_000, "{ticks}");
    }
}

#[test]
fn other_physics_versions_atlases_and_garbage_are_refused_with_reasons() {
    let st = setup();
    let d = tempfile::tempdir().unwrap();
    let old = d.path().join("old.mcap");
    rewrite(&st.session("success-intercostal"), &old, |s| {
        s.header.physics_version = 999
    });
    let e = fails(&["score", s(&old), "--atlas", s(&st.atlas())]);
    assert!(
        e.contains("physics version 999") && e.contains("does not re-grade"),
        "{e}"
    );

    let other = d.path().join("other");
    ok(&[
        "atlas",
        "phantom",
        "--out",
        s(&other),
        "--dims",
        "96,96,80",
        "--spacing",
        "4",
    ]);
    let e = fails(&["score", s(&st.session("success-intercostal")), "--atlas", s(&other)]);
    assert!(e.contains("content hash") && e.contains("the atlas given"), "{e}");

    let junk = d.path().join("junk.mcap");
    std::fs::write(&junk, b"not a session").unwrap();
    let e = fails(&["score", s(&junk), "--atlas", s(&st.atlas())]);
    assert!(
        e.contains("junk.mcap") && e.contains("not a Stylet session file"),
        "{e}"
    );

    let hard = d.path().join("hard.mcap");
    rewrite(&st.session("success-intercostal"), &hard, |s| {
        s.header.difficulty = "impossible".into()
    });
    let e = fails(&["score", s(&hard), "--atlas", s(&st.atlas())]);
    assert!(e.contains("difficulty 'impossible'"), "{e}");

    let rubric = d.path().join("bad.toml");
    std::fs::write(&rubric, "name = \"x\"\nversion = 1\n").unwrap();
    let e = fails(&[
        "score",
        s(&st.session("lung-hit")),
        "--atlas",
        s(&st.atlas()),
        "--rubric",
        s(&rubric),
    ]);
    assert!(e.contains("bad.toml") && e.contains("metrics"), "{e}");
}

#[test]
fn batch_results_do_not_depend_on_jobs_or_file_order() {
    let st = setup();
    let d = tempfile::tempdir().unwrap();
    let mut files: Vec<String> = SCRIPTS
        .iter()
        .map(|n| st.session(n).to_str().unwrap().to_string())
        .collect();
    let (a, b) = (d.path().join("a.csv"), d.path().join("b.csv"));
    let atlas = st.atlas();
    let mut args = vec!["score", "--atlas", s(&atlas), "--jobs", "1", "--csv", s(&a)];
    args.extend(files.iter().map(String::as_str));
    let table = ok(&args);
    assert!(
        table.contains("success-intercostal") && table.contains("passed"),
        "{table}"
    );
    files.reverse();
    let mut args = vec!["score", "--atlas", s(&atlas), "--jobs", "2", "--csv", s(&b)];
    args.extend(files.iter().map(String::as_str));
    ok(&args);
    let (ca, cb) = (
        std::fs::read_to_string(&a).unwrap(),
        std::fs::read_to_string(&b).unwrap(),
    );
    assert_eq!(ca, cb);
    let mut lines = ca.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert!(header.contains(&"replay_verified") && header.contains(&"score") && header.contains(&"attempts"));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), SCRIPTS.len());
    assert!(rows.iter().all(|r| r.contains(",scored,true,")), "{rows:?}");
}

/// Records a script text on the default phantom and scores it.
fn score_text(name: &str, text: &str) -> Value {
    let d = tempfile::tempdir().unwrap();
    score_json(&record_text(d.path(), name, text))
}

/// Records script `text` on the fixture's phantom as `dir/name.mcap` and returns its path.
fn record_text(dir: &Path, name: &str, text: &str) -> PathBuf {
    let st = setup();
    let script = dir.join(format!("{name}.txt"));
    std::fs::write(&script, text).unwrap();
    let session = dir.join(format!("{name}.mcap"));
    ok(&[
        "script",
        "run",
        "--atlas",
        s(&st.atlas()),
        "--script",
        s(&script),
        "--out",
        s(&session),
    ]);
    session
}

#[test]
fn redirections_and_bone_contacts_are_counted() {
    // In along the planned path to 60 mm, back 15 mm without leaving the body, in again: one
    // redirection in one attempt. Then a 3 mm wobble: below R = 5 mm, not a redirection.
    let r = score_text(
        "redirect",
        "stylet-script 1\nend 12\nat 0 along intercostal-10-11 -10\nat 4 along intercostal-10-11 60\n\
         at 5 along intercostal-10-11 45\nat 7 along intercostal-10-11 70\nat 8 along intercostal-10-11 67\n\
         at 9 along intercostal-10-11 72\nat 12 along intercostal-10-11 -10\n",
    );
    assert_eq!(r["replay_verified"], true);
    let m = &r["metrics"];
    assert_eq!(m["attempts"], 1, "{m}");
    assert_eq!(m["redirections"], 1, "{m}");
    // It completes while the needle goes in again from 45 mm (5 s) to 70 mm (7 s).
    let at = m["redirection_times_s"].as_array().unwrap();
    assert_eq!(at.len(), 1, "{m}");
    assert!((5.0..7.0).contains(&at[0].as_f64().unwrap()), "{m}");
    // Aimed at a rib: the tip stops on bone.
    let r = score_text(
        "rib",
        "stylet-script 1\nend 8\nat 0 aim 160 0 30 50.5 45 30 -15\nat 1 aim 160 0 30 50.5 45 30 -15\n\
         at 6 aim 160 0 30 50.5 45 30 40\nat 7 aim 160 0 30 50.5 45 30 -15\n",
    );
    let m = &r["metrics"];
    assert_eq!(m["bone_contacts"], 1, "{m}");
    assert!(m["risk_hits"].as_array().unwrap().is_empty(), "{m}");
    assert!(m["max_force_n"].as_f64().unwrap() > 5.0, "{m}");
}

/// The service scores with `score_session_traced` (the dashboard's review trace is taken in the
/// same replay); the trace must not change the score: the same report as `stylet score`'s path.
#[test]
fn taking_the_review_trace_does_not_change_the_score() {
    let atlas = stylet_atlas::load(&setup().atlas()).unwrap();
    let scorer = stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None).unwrap();
    for name in SCRIPTS {
        let session = reader::verify(&setup().session(name)).unwrap();
        let plain = scorer.score_session(&session).unwrap();
        let (traced, trace) = scorer.score_session_traced(&session).unwrap();
        assert_eq!(plain, traced, "{name}");
        assert!(plain.replay_verified, "{name}");
        assert!(!trace.t_s.is_empty(), "{name}: empty trace");
    }
}

/// The shaft sweep (area the simulated shaft sweeps sideways) and needle bending read 0 for a straight scripted
/// in-and-out — a script moves the device exactly along the needle's own axis, so the shaft only
/// slides and carries no sideways load — and are clearly above 0 when the needle is swept sideways
/// while inserted (the thesis' Fig. 3.13 angulation) or loaded sideways at the hub without
/// advancing.
#[test]
fn shaft_sweep_and_bending_are_zero_only_for_a_straight_insertion() {
    let (e, t) = ("152.6 1.5 15.9", "50.5 30 7.5");
    let metrics = |name: &str, text: String| {
        let r = score_text(name, &text);
        assert_eq!(r["replay_verified"], true, "{name}");
        let m = &r["metrics"];
        let (damage, bending) = (
            m["shaft_sweep_mm2"].as_f64().unwrap(),
            m["max_bending_mm"].as_f64().unwrap(),
        );
        println!("{name}: shaft sweep {damage:.1} mm², bending {bending:.2} mm");
        (damage, bending)
    };
    let straight = metrics(
        "straight",
        format!("stylet-script 1\nend 10\nat 0 aim {e} {t} -10\nat 4 aim {e} {t} 60\nat 9 aim {e} {t} -10\n"),
    );
    let swept = metrics(
        "swept",
        format!("stylet-script 1\nend 10\nat 0 aim {e} {t} -10\nat 4 aim {e} {t} 30\nat 9 aim {e} 50.5 30 -30.0 90\n"),
    );
    let loaded = metrics(
        "loaded",
        format!(
            "stylet-script 1\nend 10\nat 0 aim {e} {t} -10\nat 4 aim {e} {t} 50\nat 5 aim {e} {t} 50\nat 8 aim {e} 50.5 30 -12.5 50\n"
        ),
    );
    assert!(straight.0 < 1.0 && straight.1 < 0.05, "straight: {straight:?}");
    assert!(
        swept.0 > 100.0 && swept.1 > 1.0,
        "swept sideways while inserted: {swept:?}"
    );
    assert!(loaded.1 > 0.5, "loaded sideways at the hub: {loaded:?}");
}

/// Reports stored before exercises and outcomes still load: punctures, outcome from the grade,
/// reasons phrased again in words.
/// A lateral shift of the hand with the needle 50 mm in tissue: the simulated shaft stays on its
/// channel (thesis eq. 3.5.1 places the hub from the skin entry along the device axis), so the
/// shaft sweep stays near 0, but the hand feels the base spring pull it back (eq. 3.5.7) and the
/// rigid needle line sweeps shift × depth (PerkTutor's tissue damage): the shift is not scored as
/// harmless. The same script without the shift sweeps nothing.
#[test]
fn a_lateral_shift_in_tissue_is_felt_and_counted_as_tissue_damage() {
    // Entry E and target T of the success path; U ⊥ (T − E), 5 mm.
    let (e, t): ([f64; 3], [f64; 3]) = ([152.6, 1.5, 15.9], [50.5, 30.0, 7.5]);
    let d = [t[0] - e[0], t[1] - e[1], t[2] - e[2]];
    let n = (d[1] * d[1] + d[0] * d[0]).sqrt();
    let u = [-d[1] / n * 5.0, d[0] / n * 5.0, 0.0];
    let p = |v: [f64; 3], k: f64| format!("{} {} {}", v[0] + k * u[0], v[1] + k * u[1], v[2] + k * u[2]);
    let script = |k: f64| {
        format!(
            "stylet-script 1\nend 8\nat 0 aim {e0} {t0} -10\nat 4 aim {e0} {t0} 50\nat 5 aim {e0} {t0} 50\nat 6 aim {e1} {t1} 50\n",
            e0 = p(e, 0.0),
            t0 = p(t, 0.0),
            e1 = p(e, k),
            t1 = p(t, k)
        )
    };
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, k: f64| {
        let st = setup();
        let path = dir.path().join(format!("{name}.txt"));
        std::fs::write(&path, script(k)).unwrap();
        let (session, csv) = (
            dir.path().join(format!("{name}.mcap")),
            dir.path().join(format!("{name}.csv")),
        );
        ok(&[
            "script",
            "run",
            "--atlas",
            s(&st.atlas()),
            "--script",
            s(&path),
            "--out",
            s(&session),
            "--csv",
            s(&csv),
        ]);
        let r = score_json(&session);
        assert_eq!(r["replay_verified"], true, "{name}");
        // Largest force across the needle axis from 6 s on (after the shift).
        let text = std::fs::read_to_string(&csv).unwrap();
        let mut lines = text.lines();
        let head: Vec<&str> = lines.next().unwrap().split(',').collect();
        let col = |c: &str| head.iter().position(|h| *h == c).unwrap();
        let (ts, fx, fy, fz) = (col("t_s"), col("fx_n"), col("fy_n"), col("fz_n"));
        let dl = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let lateral = lines
            .map(|l| {
                l.split(',')
                    .map(|v| v.parse::<f64>().unwrap_or(f64::NAN))
                    .collect::<Vec<_>>()
            })
            .filter(|v| v[ts] >= 6.0)
            .map(|v| {
                let f = [v[fx], v[fy], v[fz]];
                let along = (f[0] * d[0] + f[1] * d[1] + f[2] * d[2]) / dl;
                ((f[0] * f[0] + f[1] * f[1] + f[2] * f[2]) - along * along)
                    .max(0.0)
                    .sqrt()
            })
            .fold(0.0, f64::max);
        let m = &r["metrics"];
        let nm = &m["needle_motion"];
        let get = |v: &Value| v.as_f64().unwrap();
        println!(
            "{name}: lateral force {lateral:.2} N, shaft sweep {:.1} mm², tissue damage {:.1} mm², tissue displaced {:.2} mm",
            get(&m["shaft_sweep_mm2"]),
            get(&nm["tissue_damage_mm2"]),
            get(&m["max_tissue_displacement_mm"])
        );
        (
            lateral,
            get(&m["shaft_sweep_mm2"]),
            get(&nm["tissue_damage_mm2"]),
            get(&nm["time_in_tissue_s"]),
        )
    };
    let held = run("held", 0.0);
    let shifted = run("shifted", 1.0);
    assert!(held.2 < 1.0, "held still: no tissue damage, {held:?}");
    // 5 mm × the inserted length (≈ 50 mm, less the skin's give before the puncture).
    assert!(shifted.2 > 150.0 && shifted.2 < 260.0, "{shifted:?}");
    assert!(
        shifted.1 < 0.1 * shifted.2,
        "the shaft sweep misses the shift: {shifted:?}"
    );
    assert!(
        shifted.0 > held.0 + 1.0,
        "the hand feels the shift: {shifted:?} vs {held:?}"
    );
    assert_eq!(held.3, shifted.3, "the same time in tissue");
}

/// PerkTutor's needle-motion metrics, recomputed from the session file alone by an independent
/// Python implementation (recorder/python/needle_motion.py: the pose stream, `inserted_mm` and
/// the tool events, nothing of the replay), equal what `stylet score` measured in the replay, on
/// scripted sessions of one, two and no successful punctures and a pivot in tissue.
#[test]
fn needle_motion_matches_an_independent_python_recomputation() {
    let st = setup();
    let dir = tempfile::tempdir().unwrap();
    let pivot = record_text(
        dir.path(),
        "pivot",
        "stylet-script 1\nend 7\nat 0 aim 152.6 1.5 15.9 50.5 30 7.5 -10\nat 3 aim 152.6 1.5 15.9 50.5 30 7.5 40\n\
         at 4 aim 152.6 1.5 15.9 50.5 30 7.5 40\nat 5 aim 152.6 1.5 15.9 50.5 40 7.5 40\nat 5.5 aim 152.6 1.5 15.9 50.5 -20 7.5 40\n",
    );
    let sessions = [
        st.session("success-intercostal"),
        st.session("two-attempts"),
        st.session("vessel-hit"),
        st.session("palpation-sweep"),
        pivot,
    ];
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("recorder/python/needle_motion.py");
    for session in &sessions {
        let out = std::process::Command::new(python())
            .arg(&script)
            .arg(session)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let py: Value = serde_json::from_slice(&out.stdout).unwrap();
        let rust = score_json(session)["metrics"]["needle_motion"].clone();
        let name = session.file_stem().unwrap().to_string_lossy();
        if name == "pivot" {
            // A 30° turn in half a second (60 °/s) in tissue: one rotational action; the sweep
            // of the needle line.
            assert_eq!(rust["reorientations"], 1, "{rust}");
            assert!(rust["tissue_damage_mm2"].as_f64().unwrap() > 100.0, "{rust}");
        }
        println!("{name}: stylet {rust}\n{name}: python {py}");
        for key in [
            "path_length_mm",
            "path_in_tissue_mm",
            "path_outside_tissue_mm",
            "time_in_tissue_s",
            "tissue_damage_mm2",
            "jerk_mm_per_s2_5",
            "depth_perception_mm",
            "reorientations",
        ] {
            let (a, b) = (rust[key].as_f64().unwrap(), py[key].as_f64().unwrap());
            // Same formulas in another language and order of operations: equal to rounding (a
            // straight push sweeps 10⁻⁹ mm² of rounding noise, computed differently on each side).
            assert!(
                (a - b).abs() <= 1e-9 * a.abs().max(b.abs()) + 1e-6,
                "{name}: {key} stylet {a} python {b}"
            );
        }
    }
}

#[test]
fn reports_stored_before_outcomes_still_load() {
    let st = setup();
    let mut v = score_json(&st.session("lung-hit"));
    let obj = v.as_object_mut().unwrap();
    for key in ["exercise", "outcome", "reasons"] {
        obj.remove(key);
    }
    let grade = obj["grade"].as_object_mut().unwrap();
    for key in ["exercise", "pass_score", "unmet"] {
        grade.remove(key);
    }
    for d in grade["deductions"].as_array_mut().unwrap() {
        d.as_object_mut().unwrap().remove("free");
    }
    for h in obj["metrics"]["risk_hits"].as_array_mut().unwrap() {
        let h = h.as_object_mut().unwrap();
        h.remove("consequence");
        h.remove("point_mm");
    }
    // Before rubric version 7 the shaft's swept area was `tissue_damage_mm2`, and there was no
    // `needle_motion`.
    let metrics = obj["metrics"].as_object_mut().unwrap();
    let sweep = metrics.remove("shaft_sweep_mm2").unwrap();
    metrics.insert("tissue_damage_mm2".into(), sweep.clone());
    metrics.remove("needle_motion");
    let old: stylet_scoring::ScoreReport = serde_json::from_value(v).unwrap();
    assert_eq!(Some(old.metrics.shaft_sweep_mm2), sweep.as_f64());
    assert_eq!(old.metrics.needle_motion, None);
    assert_eq!(
        stylet_scoring::rubric::metric_value(&old.metrics, "tissue_damage_mm2"),
        None
    );
    assert_eq!(old.exercise, stylet_scoring::Exercise::Puncture);
    assert_eq!(old.outcome, stylet_scoring::Outcome::Failed);
    assert!(
        old.reasons.iter().any(|r| r.contains("right lung")),
        "{:?}",
        old.reasons
    );
    assert!(old.reasons.iter().all(|r| !r.contains('_')), "{:?}", old.reasons);
}

/// A finger pressed in one place crosses no intercostal space: the palpation fails, in words.
#[test]
fn a_palpation_that_does_not_sweep_fails_with_its_reason() {
    let text = "stylet-script 1\ndevice premium\ntool finger\nend 6\n\nat 0 pos 175 8 60 dir -1 0 0\nat 0.5 press -1 0 0 1.0\nat 6 release\n";
    // Recorded under the palpation scenario's name, so graded as a palpation.
    let r = score_text("palpation-sweep", text);
    assert_eq!(r["exercise"], "palpation");
    assert_eq!(r["outcome"], "failed");
    assert_eq!(r["metrics"]["palpation"]["spaces_found"], 0);
    assert!(
        r["reasons"]
            .to_string()
            .contains("0 intercostal spaces found: at least 1 required."),
        "{}",
        r["reasons"]
    );
}

/// Contrast is physics (eqs. 3.3.1–3.3.2): injected into the liver it is extravasation, deducted
/// by the rubric; the puncture is confirmed only when contrast filled the ducts, which it cannot
/// through a needle with the stylet in.
#[test]
fn contrast_outside_the_ducts_is_extravasation_and_confirmation_needs_filled_ducts() {
    let r = score_text(
        "extravasation",
        "stylet-script 1\nend 24\nat 0 along intercostal-10-11 -15\nat 1 along intercostal-10-11 -15\n\
         at 8 along intercostal-10-11 65\nat 8.5 event stylet-remove\nat 9 event contrast-inject 1\n\
         at 11 event stylet-insert\nat 11 along intercostal-10-11 65\nat 13 along intercostal-10-11 111\n\
         at 13.5 event stylet-remove\nat 14 event contrast-inject 2\nat 17 event stylet-insert\n\
         at 17 along intercostal-10-11 111\nat 23 along intercostal-10-11 -15\n",
    );
    assert_eq!(r["replay_verified"], true, "{r}");
    let m = &r["metrics"];
    let ml = |k: &str| m[k].as_f64().unwrap();
    assert!((ml("extravasated_ml") - 1.0).abs() < 1e-9, "{m}");
    assert!((ml("contrast_in_ducts_ml") - 2.0).abs() < 1e-9, "{m}");
    assert!(ml("contrast_extent_mm") >= 10.0, "{m}");
    assert_eq!(m["target_confirmed"], true, "{m}");
    let deductions = r["grade"]["deductions"].as_array().unwrap();
    assert!(
        deductions
            .iter()
            .any(|d| d["metric"] == "extravasated_ml" && (d["points"].as_f64().unwrap() - 5.0).abs() < 1e-6),
        "{deductions:?}"
    );

    // The stylet came out in the target, but the contrast was "injected" with it back in.
    let r = score_text(
        "stylet-in",
        "stylet-script 1\nend 20\nat 0 along intercostal-10-11 -15\nat 1 along intercostal-10-11 -15\n\
         at 11 along intercostal-10-11 111\nat 11.5 event stylet-remove\nat 12 event stylet-insert\n\
         at 12.5 event contrast-inject 2\nat 14 along intercostal-10-11 111\nat 19.5 along intercostal-10-11 -15\n",
    );
    let m = &r["metrics"];
    assert_eq!(m["stylet_removed_in_target"], true, "{m}");
    assert_eq!(m["contrast_in_ducts_ml"].as_f64(), Some(0.0), "{m}");
    assert_eq!(m["target_confirmed"], false, "{m}");
    assert_eq!(r["grade"]["passed"], false, "{r}");
}

/// The dose-area product is the fluoroscopy time × the scenario C-arm's kerma rate × its beam
/// area at the isocentre (docs/metrics.md), so moving the source toward the patient (a smaller
/// field at the isocentre) lowers it.
#[test]
fn the_dose_area_product_follows_the_scenarios_c_arm() {
    let st = setup();
    let r = score_json(&st.session("success-intercostal"));
    let m = &r["metrics"];
    let fluoro_s = m["fluoro_time_s"].as_f64().unwrap();
    assert!(fluoro_s > 1.0, "{m}");
    // 5 mGy/min at the isocentre over 300 × 300 mm × (750/1000)² = 506.25 cm².
    let rate = 5e-3 / 60.0 * 506.25;
    let dap = m["dose_area_product_gy_cm2"].as_f64().unwrap();
    assert!((dap - fluoro_s * rate).abs() < 1e-12, "{dap} vs {}", fluoro_s * rate);

    // The same atlas with the source at 375 mm: a quarter of the area at the isocentre.
    let d = tempfile::tempdir().unwrap();
    let near = d.path().join("near");
    std::fs::create_dir(&near).unwrap();
    for f in std::fs::read_dir(st.atlas()).unwrap() {
        let f = f.unwrap().path();
        // Files only: not the derived-data cache folder.
        if f.is_file() {
            std::fs::copy(&f, near.join(f.file_name().unwrap())).unwrap();
        }
    }
    let manifest = near.join("atlas.toml");
    let text = std::fs::read_to_string(&manifest).unwrap();
    assert_eq!(
        text.matches("source_to_isocenter_mm = 750.0").count(),
        1,
        "one scenario sets a C-arm"
    );
    std::fs::write(
        &manifest,
        text.replace("source_to_isocenter_mm = 750.0", "source_to_isocenter_mm = 375.0"),
    )
    .unwrap();
    let session = d.path().join("success-intercostal.mcap");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts/success-intercostal.txt");
    ok(&[
        "script",
        "run",
        "--atlas",
        s(&near),
        "--script",
        s(&script),
        "--out",
        s(&session),
    ]);
    let r: Value = serde_json::from_str(&ok(&["score", s(&session), "--atlas", s(&near), "--json"])).unwrap();
    let near_dap = r["metrics"]["dose_area_product_gy_cm2"].as_f64().unwrap();
    assert!((near_dap - dap / 4.0).abs() < 1e-12, "{near_dap} vs {}", dap / 4.0);
}

/// "Target scanned before the puncture": an ultrasound sweep that shows the target, then the
/// puncture, sets it; a sweep of the wrong flank does not, and the rubric metric
/// `missing_target_scan` reads it.
#[test]
fn the_target_must_be_in_the_ultrasound_image_before_the_puncture() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts");
    // The survey's keyframes, then the probe lifted off the skin (anterior, y = 300 mm) and
    // carried to the right flank before the tool change: keyframes interpolate across it, and a
    // probe dragged through the patient to the needle's entry would see the target on the way.
    let probe_lines = |name: &str| {
        let text = std::fs::read_to_string(dir.join(format!("{name}.txt"))).unwrap();
        let lines: Vec<&str> = text.lines().filter(|l| l.starts_with("at ")).collect();
        let last_pose = lines.iter().rev().find(|l| l.contains(" pos ")).unwrap();
        let t: Vec<&str> = last_pose.split_whitespace().collect();
        let (x, z) = (t[3], t[5]);
        let lift = format!("at 16.4 pos {x} 300 {z} dir 0 -1 0\nat 16.9 pos 200 300 17 dir 0 -1 0\n");
        lines.iter().map(|l| format!("{l}\n")).collect::<String>() + &lift
    };
    let puncture = "at 17 tool needle gauge 18 length 150 stylet in\n\
                    at 17 along intercostal-10-11 -15\nat 18 along intercostal-10-11 -15\n\
                    at 28 along intercostal-10-11 111\nat 28.5 event stylet-remove\n\
                    at 29 event contrast-inject 2\nat 31 event stylet-insert\n\
                    at 36 along intercostal-10-11 -15\n";
    let session = |name: &str, survey: &str| {
        score_text(
            name,
            &format!(
                "stylet-script 1\ndevice premium\ntool probe linear\nend 37\n{}{puncture}",
                probe_lines(survey)
            ),
        )
    };
    let seen = session("scan-then-puncture", "probe-parallel");
    let w = &seen["metrics"]["workflow"];
    assert_eq!(w["ultrasound_before_puncture"], true, "{w}");
    assert_eq!(w["target_scanned_before_puncture"], true, "{w}");
    assert_eq!(seen["metrics"]["ultrasound"]["target_scanned"], true, "{seen}");
    let missed = session("wrong-flank-then-puncture", "probe-no-target");
    let w = &missed["metrics"]["workflow"];
    assert_eq!(w["ultrasound_before_puncture"], true, "{w}");
    assert_eq!(w["target_scanned_before_puncture"], false, "{w}");
}

/// "Needle visible in the ultrasound plane": the share of the insertion time the tip lies in the
/// image of the probe's last pose on the skin. A probe beside the path imaging it in plane
/// (`stylet render --view ultrasound`'s default placement), then the puncture along the path:
/// nearly all the time; the same probe turned 90° about its beam (the plane across the path): the
/// tip only crosses it; no probe: no value.
#[test]
fn the_needle_in_the_ultrasound_plane_is_measured_against_the_last_probe_image() {
    use stylet_physics::ProbeKind;
    use stylet_physics::glam::{DQuat, DVec3};
    let atlas = stylet_atlas::load(&setup().atlas()).unwrap();
    let path = atlas
        .planned_paths()
        .into_iter()
        .find(|p| p.name == "intercostal-10-11")
        .unwrap();
    let probe =
        stylet_render::ultrasound::probe::facing_path(&atlas.model, ProbeKind::Convex, path.entry_mm, path.target_mm)
            .unwrap();
    let puncture = "at 3 tool needle gauge 18 length 150 stylet in\n\
                    at 3 along intercostal-10-11 -15\nat 4 along intercostal-10-11 -15\n\
                    at 14 along intercostal-10-11 111\nat 15 along intercostal-10-11 -15\n";
    let session = |name: &str, turn_deg: f64| {
        let q = probe.orientation.as_dquat() * DQuat::from_rotation_z(turn_deg.to_radians());
        let (p, dir, x) = (probe.position_mm.as_dvec3(), q * DVec3::Z, q * DVec3::X);
        // Held on the skin until 2.5 s, then lifted 60 mm straight off before the tool change
        // (keyframes interpolate: a probe dragged to the needle's start would image elsewhere).
        let at = |t: f64, p: DVec3| {
            format!(
                "at {t} pos {} {} {} dir {} {} {} xaxis {} {} {}\n",
                p.x, p.y, p.z, dir.x, dir.y, dir.z, x.x, x.y, x.z
            )
        };
        let pose = at(0.0, p) + &at(2.5, p) + &at(2.8, p - dir * 60.0);
        score_text(
            name,
            &format!("stylet-script 1\ndevice premium\ntool probe convex\nend 16\n{pose}{puncture}"),
        )
    };
    let in_plane = session("needle-in-plane", 0.0);
    let share = in_plane["metrics"]["needle_in_plane_share"].as_f64().unwrap();
    // The first fifth of the way the tip is still beside the fan (the probe sits 50 mm from the
    // entry; a convex sector is 58 mm wide at the face): it enters the image from its edge.
    assert!(share > 0.7, "in plane: {share}");
    let across = session("needle-across-plane", 90.0);
    let share = across["metrics"]["needle_in_plane_share"].as_f64().unwrap();
    assert!(share < 0.2, "across: {share}");
    let none = score_text(
        "needle-no-probe",
        &format!("stylet-script 1\ndevice premium\nend 16\n{puncture}"),
    );
    assert!(
        none["metrics"]["needle_in_plane_share"].is_null(),
        "{}",
        none["metrics"]
    );
}

/// The world model travels in the header and replay runs exactly it: a session with tissue
/// deformation and an injection replays verified and measures the displaced tissue; the same
/// ticks under a header whose deformation or contrast settings were changed do not verify.
#[test]
fn replay_runs_the_world_model_of_the_header() {
    let d = tempfile::tempdir().unwrap();
    let session = record_text(
        d.path(),
        "world",
        "stylet-script 1\ndeformation on\nend 16\nat 0 along intercostal-10-11 -15\n\
         at 1 along intercostal-10-11 -15\nat 11 along intercostal-10-11 111\n\
         at 11.5 event stylet-remove\nat 12 event contrast-inject 2\nat 15 along intercostal-10-11 111\n",
    );
    let header = reader::read(&session).unwrap().header;
    assert!(header.deformation.enabled);
    assert_eq!(header.contrast, stylet_physics::ContrastSettings::default());
    let r = score_json(&session);
    assert_eq!(r["replay_verified"], true, "{r}");
    let m = &r["metrics"];
    assert!(m["max_tissue_displacement_mm"].as_f64().unwrap() > 0.1, "{m}");
    assert!(m["contrast_in_ducts_ml"].as_f64().unwrap() > 0.0, "{m}");

    type Change = Box<dyn Fn(&mut reader::Session)>;
    let changed: [(&str, Change); 3] = [
        ("deformation off", Box::new(|s| s.header.deformation.enabled = false)),
        (
            "a stiffer tissue",
            Box::new(|s| s.header.deformation.material_k_per_hu = 0.02),
        ),
        ("a faster syringe", Box::new(|s| s.header.contrast.rate_ml_per_s = 2.0)),
    ];
    for (what, edit) in changed {
        let tampered = d.path().join("tampered.mcap");
        rewrite(&session, &tampered, |s| edit(s));
        let r = score_json(&tampered);
        assert_eq!(r["replay_verified"], false, "{what}: {r}");
    }
}
