//! Session files end to end through the `stylet` binary: `script run --out` records what the
//! simulation did; `session inspect/verify/export/recover`; and a recording process killed with
//! SIGKILL at random moments loses at most the last second.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use crate::common::{STYLET, fails, ok, phantom_script, s};

use stylet_recorder::reader;

/// A small phantom (fast to build), written once per test binary.
fn atlas() -> &'static Path {
    static A: OnceLock<PathBuf> = OnceLock::new();
    A.get_or_init(|| {
        let a = stylet_testkit::fixture_dir().join("phantom");
        ok(&[
            "atlas",
            "phantom",
            "--out",
            a.to_str().unwrap(),
            "--dims",
            "160,160,130",
            "--spacing",
            "2.4",
        ]);
        a
    })
}

/// Records a script offline (as fast as the CPU allows) and returns the session file.
fn record(dir: &Path, name: &str, extra: &[&str]) -> PathBuf {
    let out = dir.join(format!("{name}.mcap"));
    let sc = phantom_script(name);
    let mut args = vec![
        "script",
        "run",
        "--atlas",
        s(atlas()),
        "--script",
        s(&sc),
        "--out",
        s(&out),
    ];
    args.extend_from_slice(extra);
    let text = ok(&args);
    assert!(
        text.contains("session recorded to") && text.contains("complete"),
        "{text}"
    );
    out
}

/// What `script run --out` records is what the simulation computed (same bits as its CSV), with
/// the header the scoring service needs; inspect, verify and export tell the truth about it.
#[test]
fn recorded_session_matches_the_simulation_and_the_cli_reports_it() {
    let d = tempfile::tempdir().unwrap();
    let session = record(
        d.path(),
        "success-intercostal",
        &["--trainee", "bob", "--difficulty", "advanced"],
    );
    let csv = d.path().join("run.csv");
    ok(&[
        "script",
        "run",
        "--atlas",
        s(atlas()),
        "--script",
        s(&phantom_script("success-intercostal")),
        "--csv",
        s(&csv),
    ]);

    // inspect --json: header fields, duration, counts.
    let j: serde_json::Value = serde_json::from_str(&ok(&["session", "inspect", s(&session), "--json"])).unwrap();
    let atlas_json: serde_json::Value = serde_json::from_str(&ok(&["atlas", "inspect", s(atlas()), "--json"])).unwrap();
    assert_eq!(j["ticks"], 20_000);
    assert_eq!(j["duration_s"], 20.0);
    assert_eq!(j["events"], 5);
    assert_eq!(j["event_list"][0]["name"], "stylet-remove");
    assert_eq!(j["event_list"][0]["t_s"], 11.5);
    assert_eq!(j["trainee"], "bob");
    assert_eq!(j["difficulty"], "advanced");
    assert_eq!(j["scenario"], "success-intercostal");
    assert_eq!(j["atlas_id"], "phantom");
    assert_eq!(j["atlas_hash"], atlas_json["content_hash"]);
    assert_eq!(j["physics_version"], stylet_physics::PHYSICS_VERSION);
    assert_eq!(j["tick_rate_hz"], 1000);
    assert_eq!(j["device"], "premium");
    assert_eq!(j["state"], "complete");
    assert!(j["session_id"].as_str().unwrap().len() == 36);
    assert!(j["wall_clock_start"].as_str().unwrap().ends_with('Z'));
    // A digest every 100 ticks and at each of the 5 event ticks.
    assert_eq!(j["digests"], 200 + 5);
    // Every block's forces and torques rounded (a needle's outputs always round exactly), each
    // block at most 500 ticks.
    assert_eq!(j["rounded_output_ticks"], 20_000);
    let blocks = j["rounded_output_blocks"].as_u64().unwrap();
    assert!((40..=20_000 / 100).contains(&blocks), "{blocks} blocks");
    // The world model the session replays with: every setting, reals to the bit.
    let contrast = stylet_physics::ContrastSettings::default();
    assert_eq!(j["world"]["deformation"]["enabled"], 0);
    assert_eq!(j["world"]["breathing"]["enabled"], 0);
    assert_eq!(
        j["world"]["contrast"]["front_fraction"].as_f64(),
        Some(contrast.front_fraction)
    );
    assert_eq!(j["world"]["contrast"]["tau"].as_f64(), Some(contrast.tau));
    assert_eq!(j["world"]["contrast"]["settle_s"].as_f64(), Some(contrast.settle_s));
    let text = ok(&["session", "inspect", s(&session)]);
    assert!(
        text.contains("trainee   bob") && text.contains("contrast injected: 2 ml"),
        "{text}"
    );
    assert!(
        text.contains("world     deformation off\n")
            && text.contains("          contrast: ")
            && text.contains(&format!("front_fraction {}", contrast.front_fraction))
            && text.contains(&format!("tau {}", contrast.tau))
            && text.contains("breathing off\n"),
        "{text}"
    );
    assert!(
        text.contains(&format!(
            "forces and torques of 20000 ticks stored rounded (2^-16 N, 2^-12 N·mm) in {blocks} blocks"
        )) && text.contains("0 ticks stored exactly"),
        "{text}"
    );

    assert!(ok(&["session", "verify", s(&session)]).contains("good"));

    // export --csv: the same numbers, to the last bit, as the simulation's own CSV.
    let out = d.path().join("export");
    ok(&["session", "export", s(&session), "--csv", s(&out)]);
    let exported = std::fs::read_to_string(out.join("ticks.csv")).unwrap();
    let sim_csv = std::fs::read_to_string(&csv).unwrap();
    let cols = |text: &str, names: &[&str]| -> Vec<Vec<String>> {
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let idx: Vec<usize> = names
            .iter()
            .map(|n| header.iter().position(|h| h == n).unwrap())
            .collect();
        lines
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                idx.iter().map(|&i| f[i].to_string()).collect()
            })
            .collect()
    };
    let names = ["tick", "x_mm", "y_mm", "z_mm", "tip_label", "inserted_mm"];
    let (a, b) = (cols(&exported, &names), cols(&sim_csv, &names));
    assert_eq!(a.len(), 20_000);
    assert!(a == b, "exported ticks differ from the simulation's CSV");
    // Forces and torques are stored rounded (schema 2, docs/session-format.md "Rounded
    // outputs"): the export gives the simulation's values rounded to their steps, exactly.
    use stylet_recorder::outputs::{FORCE_STEPS_PER_N, TORQUE_STEPS_PER_NMM, rounded};
    let outputs = [
        ("fx_n", FORCE_STEPS_PER_N),
        ("fy_n", FORCE_STEPS_PER_N),
        ("fz_n", FORCE_STEPS_PER_N),
        ("tx_nmm", TORQUE_STEPS_PER_NMM),
        ("ty_nmm", TORQUE_STEPS_PER_NMM),
        ("tz_nmm", TORQUE_STEPS_PER_NMM),
    ];
    let names: Vec<&str> = outputs.iter().map(|(n, _)| *n).collect();
    let (a, b) = (cols(&exported, &names), cols(&sim_csv, &names));
    let mut nonzero = 0;
    for (row_a, row_b) in a.iter().zip(&b) {
        for ((ea, eb), (name, per)) in row_a.iter().zip(row_b).zip(outputs) {
            let (got, sim) = (ea.parse::<f64>().unwrap(), eb.parse::<f64>().unwrap());
            assert_eq!(
                got.to_bits(),
                rounded(sim, per).unwrap().to_bits(),
                "{name}: {ea} vs {eb}"
            );
            nonzero += usize::from(got != 0.0);
        }
    }
    assert!(nonzero > 1000, "the session pushed back: {nonzero} non-zero outputs");
    let events = std::fs::read_to_string(out.join("events.csv")).unwrap();
    assert_eq!(events.lines().count(), 6);
    assert!(
        events.contains("contrast-inject") && events.contains(",2\n"),
        "{events}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("digests.csv"))
            .unwrap()
            .lines()
            .count(),
        206
    );
    assert!(
        std::fs::read_to_string(out.join("header.csv"))
            .unwrap()
            .contains("trainee,bob")
    );
}

/// Damaged and foreign files: verify and export fail with the reason; recover rewrites the intact
/// part as a finished file that says it is incomplete; nothing panics.
#[test]
fn damaged_files_are_named_and_recovered() {
    let d = tempfile::tempdir().unwrap();
    let session = record(d.path(), "two-attempts", &[]);
    let bytes = std::fs::read(&session).unwrap();
    let full = reader::read(&session).unwrap();

    let cut = d.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let e = fails(&["session", "verify", s(&cut)]);
    assert!(e.contains("cut short"), "{e}");
    let e = fails(&["session", "export", s(&cut), "--csv", s(&d.path().join("x"))]);
    assert!(e.contains("session recover"), "{e}");
    let j: serde_json::Value = serde_json::from_str(&ok(&["session", "inspect", s(&cut), "--json"])).unwrap();
    assert_eq!(j["state"], "damaged");
    let kept = j["ticks"].as_u64().unwrap();
    assert!(kept > 15_000 && kept < 34_000, "{kept}");

    let fixed = d.path().join("fixed.mcap");
    let text = ok(&["session", "recover", s(&cut), "--out", s(&fixed)]);
    assert!(text.contains(&format!("recovered {kept} ticks")), "{text}");
    let r = reader::read(&fixed).unwrap();
    assert!(r.finished && !r.complete());
    assert!(r.end.as_ref().unwrap().reason.contains("recovered from"), "{:?}", r.end);
    assert_eq!(r.ticks.len() as u64, kept);
    assert!(r.ticks.iter().zip(&full.ticks).all(|(a, b)| a.same_bits(b)));
    assert!(r.events.iter().all(|e| e.tick <= r.ticks.last().unwrap().tick));
    assert_eq!(r.header, full.header);
    let e = fails(&["session", "verify", s(&fixed)]);
    assert!(e.contains("incomplete") && e.contains("recovered from"), "{e}");

    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 0x40;
    let flip = d.path().join("flip.mcap");
    std::fs::write(&flip, &flipped).unwrap();
    let e = fails(&["session", "verify", s(&flip)]);
    assert!(e.contains("at byte"), "{e}");

    let junk = d.path().join("junk.mcap");
    std::fs::write(&junk, b"definitely not a session").unwrap();
    for cmd in ["inspect", "verify"] {
        let e = fails(&["session", cmd, s(&junk)]);
        assert!(e.contains("not a Stylet session file"), "{e}");
    }
    let e = fails(&["session", "inspect", s(&d.path().join("missing.mcap"))]);
    assert!(e.contains("missing.mcap") && e.contains("No such file"), "{e}");
    // A failed recover leaves no output file behind.
    let none = d.path().join("none.mcap");
    fails(&["session", "recover", s(&junk), "--out", s(&none)]);
    assert!(!none.exists());
}

/// Crash safety: a child recording in real time is killed with SIGKILL at random moments; every
/// tick older than one second before the kill is recovered, bit for bit as an offline recording
/// of the same script has it.
#[test]
fn sigkill_while_recording_loses_at_most_the_last_second() {
    let d = tempfile::tempdir().unwrap();
    let reference = reader::read(&record(d.path(), "two-attempts", &[])).unwrap();
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64
        | 1;
    println!("kill-time seed {seed}");
    let mut state = seed;
    let kills_ms: Vec<u64> = (0..4)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            1200 + state % 3300
        })
        .collect();
    let results = Arc::new(Mutex::new(Vec::new()));
    std::thread::scope(|scope| {
        for (i, &kill_ms) in kills_ms.iter().enumerate() {
            let (dir, results) = (d.path(), results.clone());
            scope.spawn(move || {
                let out = dir.join(format!("killed-{i}.mcap"));
                let sc = phantom_script("two-attempts");
                let mut child = STYLET
                    .command()
                    .args([
                        "script",
                        "run",
                        "--atlas",
                        s(atlas()),
                        "--script",
                        s(&sc),
                        "--out",
                        s(&out),
                    ])
                    .args(["--realtime", "--progress", "10"])
                    .stdout(Stdio::piped())
                    .stderr(Stdio::null())
                    .spawn()
                    .unwrap();
                let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
                // Wait for tick 0, then let it record for `kill_ms`.
                let first = lines.next().unwrap().unwrap();
                assert_eq!(first, "tick 0");
                let reader = std::thread::spawn(move || {
                    let mut last = 0u64;
                    for l in lines.map_while(Result::ok) {
                        if let Some(t) = l.strip_prefix("tick ") {
                            last = t.parse().unwrap();
                        }
                    }
                    last
                });
                let started = Instant::now();
                std::thread::sleep(Duration::from_millis(kill_ms));
                child.kill().unwrap(); // SIGKILL
                child.wait().unwrap();
                let elapsed = started.elapsed();
                // Every progress line printed before the kill is in the pipe: the child was
                // between tick `last` and tick `last + 10` when it died.
                let last_printed = reader.join().unwrap();
                results.lock().unwrap().push((i, kill_ms, elapsed, last_printed, out));
            });
        }
    });
    for (i, kill_ms, elapsed, last_printed, out) in results.lock().unwrap().iter() {
        let at_kill = last_printed + 10;
        let r = reader::recover(out).unwrap_or_else(|e| panic!("child {i}: {e}"));
        assert!(
            r.damage.is_some() && !r.finished,
            "child {i}: a killed recording cannot be finished"
        );
        let recovered = r.ticks.len() as u64;
        println!(
            "child {i}: killed after {kill_ms} ms ({:.3} s), at tick ≤ {at_kill}, recovered {recovered} ticks",
            elapsed.as_secs_f64()
        );
        assert!(at_kill >= 1000, "child {i}: only reached tick {at_kill} in {elapsed:?}");
        assert!(
            recovered + 1000 >= at_kill,
            "child {i}: recovered {recovered} ticks, killed at tick {at_kill}"
        );
        assert!(
            r.ticks.iter().zip(&reference.ticks).all(|(a, b)| a.same_bits(b)),
            "child {i}: ticks differ"
        );
        assert!(
            r.ticks.iter().enumerate().all(|(k, t)| t.tick == k as u64),
            "child {i}: ticks not contiguous"
        );
        assert!(
            r.digests.iter().all(|d| reference.digests.contains(d)),
            "child {i}: digests differ"
        );
        // And the CLI turns it into a finished file marked incomplete.
        let fixed = out.with_extension("fixed.mcap");
        ok(&["session", "recover", s(out), "--out", s(&fixed)]);
        assert_eq!(reader::read(&fixed).unwrap().ticks.len() as u64, recovered);
    }
}
