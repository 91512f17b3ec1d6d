//! Replay speed per tool (goal: ≥ 500× real time for every tool, ≥ 1000× for the needle): the
//! example scripts `two-attempts` (34 s) and `success-intercostal` (20 s) with the needle,
//! `full-ptcd` (54 s: the needle, then the guide wire, dilator and catheter; the atlas keeps the
//! ducts' channel after the first replay, so the steady figures leave its one-off build out),
//! `palpation-sweep` (16 s) with the finger, `probe-parallel` (16 s) with the linear probe and
//! the same motion with the convex probe, recorded on the default phantom, replayed through the
//! physics with every output and digest checked, with and without the metrics. Baseline in the
//! same run: reading and decoding the session file. Also prints each file's size per minute.

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use stylet_devices::run_headless;
use stylet_devices::script::{parse, scripted_simulation};

use stylet_recorder::{Recording, SessionInfo, WriterOptions, reader};
use stylet_scoring::{Rubric, Scorer, replay};

/// The example script `file`, with `tool probe linear` turned convex when `convex`.
fn script_text(file: &str, convex: bool) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../atlases/phantom/scripts/{file}.txt"));
    let text = std::fs::read_to_string(path).unwrap();
    if convex {
        assert!(text.contains("tool probe linear"));
        text.replace("tool probe linear", "tool probe convex")
    } else {
        text
    }
}

fn record(atlas: &stylet_atlas::Atlas, name: &str, text: &str, dir: &Path) -> PathBuf {
    let script = parse(text).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let info = SessionInfo {
        trainee: "bench",
        scenario: name,
        difficulty: "beginner",
        seed: 0,
        atlas_id: &atlas.manifest.name,
        atlas_hash: &atlas.content_hash,
    };
    let out = dir.join(format!("{name}.mcap"));
    let header = stylet_recorder::recording::header(&sim, &info);
    let mut rec = Recording::start(
        &out,
        &header,
        false,
        WriterOptions {
            fsync: false,
            ..Default::default()
        },
    )
    .unwrap();
    run_headless(&mut sim, &mut device, |i, o, s| rec.tick(i, o, s));
    rec.finish().unwrap();
    out
}

fn median_s(runs: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..runs)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[runs / 2]
}

fn replay_bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let p = stylet_atlas::phantom::generate(&Default::default()).unwrap();
    stylet_atlas::write(&dir.path().join("atlas"), &p.manifest, &p.ct, &p.partial).unwrap();
    let atlas = stylet_atlas::load(&dir.path().join("atlas")).unwrap();
    let scorer = Scorer::new(&atlas, Rubric::default_rubric(), None).unwrap();
    let model = Arc::clone(&atlas.model);
    let mut g = c.benchmark_group("replay");
    g.sample_size(10);
    for (name, file, convex) in [
        ("two-attempts", "two-attempts", false),
        ("success-intercostal", "success-intercostal", false),
        ("full-ptcd", "full-ptcd", false),
        ("palpation-sweep", "palpation-sweep", false),
        ("probe-parallel", "probe-parallel", false),
        ("probe-parallel-convex", "probe-parallel", true),
    ] {
        let file = record(&atlas, name, &script_text(file, convex), dir.path());
        let session = reader::read(&file).unwrap();
        let seconds = session.ticks.len() as f64 / 1000.0;
        let bytes = std::fs::metadata(&file).unwrap().len() as f64;
        println!(
            "{name} ({seconds:.0} s): session file {:.0} KiB = {:.2} MB/min",
            bytes / 1024.0,
            bytes / 1e6 * 60.0 / seconds
        );
        let base = median_s(7, || {
            black_box(reader::read(&file).unwrap());
        });
        let bare = median_s(7, || {
            let r = replay(&session, model.clone(), &mut |_, _, _| {}).unwrap();
            assert!(r.replay_verified);
        });
        let scored = median_s(7, || {
            let r = scorer.score_session(&session).unwrap();
            assert!(r.replay_verified);
        });
        for (what, s) in [
            ("read + decode (baseline)", base),
            ("replay, checked", bare),
            ("replay + metrics + grade", scored),
        ] {
            println!(
                "{name} ({seconds:.0} s): {what}: {:.1} ms = {:.0}× real time, {:.1}× the baseline's time; a 10-minute session: {:.2} s",
                s * 1e3,
                seconds / s,
                s / base,
                s * 600.0 / seconds
            );
        }
        g.throughput(Throughput::Elements(session.ticks.len() as u64));
        g.bench_function(format!("{name}/baseline_read"), |b| {
            b.iter(|| black_box(reader::read(&file).unwrap()))
        });
        g.bench_function(format!("{name}/replay"), |b| {
            b.iter(|| black_box(replay(&session, model.clone(), &mut |_, _, _| {}).unwrap()))
        });
        g.bench_function(format!("{name}/score"), |b| {
            b.iter(|| black_box(scorer.score_session(&session).unwrap()))
        });
    }
    g.finish();
}

criterion_group!(benches, replay_bench);
criterion_main!(benches);
