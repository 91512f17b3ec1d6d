//! Session recording throughput on real physics output: the ticks of the `two-attempts` needle
//! script (34 s at 1 kHz) on the default phantom, written through `SessionWriter` as offline
//! recording does (blocking queue), with and without fsync at every chunk, and read back.
//! Baseline in the same run: the same ticks' raw bytes (112 B/tick) written to a file uncompressed.
//! Also prints the file size per minute and the compression ratio.

use std::hint::black_box;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use stylet_devices::run_headless;
use stylet_devices::script::{parse, scripted_simulation};

use stylet_physics::{DeformSettings, Event, Gauge, ToolSpec};
use stylet_recorder::format::TickRecord;
use stylet_recorder::{SessionHeader, SessionWriter, WriterOptions, reader};

type Ticks = Vec<(TickRecord, Vec<Event>, u64)>;

/// The needle script's ticks with their events and state digests.
fn needle_ticks() -> Ticks {
    let dir = tempfile::tempdir().unwrap();
    let p = stylet_atlas::phantom::generate(&Default::default()).unwrap();
    stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
    let atlas = stylet_atlas::load(dir.path()).unwrap();
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts/two-attempts.txt"))
            .unwrap();
    let script = parse(&text).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let mut out = Vec::new();
    run_headless(&mut sim, &mut device, |i, o, s| {
        let q = i.orientation;
        let t = TickRecord {
            tick: o.tick,
            position_mm: i.position_mm.to_array(),
            orientation: [q.w, q.x, q.y, q.z],
            buttons: i.buttons,
            force_n: o.force_n.to_array(),
            torque_nmm: o.torque_nmm.to_array(),
            tip_label: o.tip_label,
            inserted_mm: o.inserted_mm,
            second_hand: None,
        };
        out.push((t, i.events.clone(), s.state_digest()));
    });
    out
}

fn header() -> SessionHeader {
    SessionHeader {
        schema_version: stylet_recorder::SCHEMA_VERSION,
        session_id: stylet_recorder::new_session_id(),
        trainee: "bench".into(),
        scenario: "two-attempts".into(),
        difficulty: "beginner".into(),
        atlas_id: "phantom".into(),
        atlas_hash: "0".repeat(64),
        software_version: "bench".into(),
        physics_version: stylet_physics::PHYSICS_VERSION,
        tick_rate_hz: 1000,
        seed: 0,
        device: "premium".into(),
        initial_tool: ToolSpec::Needle {
            gauge: Gauge::G18,
            length_mm: 150.0,
            stylet_in: true,
        },
        wall_clock_start: stylet_recorder::wall_clock_now(),
        deformation: DeformSettings::default(),
        contrast: Default::default(),
        breathing: Default::default(),
        hardware: None,
        second_hand: None,
    }
}

fn write_session(path: &Path, ticks: &Ticks, fsync: bool) -> u64 {
    let w = SessionWriter::create(
        path,
        &header(),
        WriterOptions {
            fsync,
            ..WriterOptions::default()
        },
    )
    .unwrap();
    for (t, events, digest) in ticks {
        for e in events {
            w.event_record_blocking(stylet_recorder::EventRecord::from_event(t.tick, e))
                .unwrap();
        }
        w.record_raw_blocking(*t).unwrap();
        if t.tick % 100 == 99 || !events.is_empty() {
            w.digest_blocking(t.tick, *digest).unwrap();
        }
    }
    w.finish().unwrap().bytes
}

fn raw_bytes(t: &TickRecord, out: &mut Vec<u8>) {
    for v in t
        .position_mm
        .iter()
        .chain(&t.orientation)
        .chain(&t.force_n)
        .chain(&t.torque_nmm)
    {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&t.inserted_mm.to_le_bytes());
    out.extend_from_slice(&t.buttons.to_le_bytes());
    out.extend_from_slice(&t.tip_label.to_le_bytes());
}

fn write_raw(path: &Path, ticks: &Ticks) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut buf = Vec::with_capacity(128);
    for (t, _, _) in ticks {
        buf.clear();
        raw_bytes(t, &mut buf);
        f.write_all(&buf).unwrap();
    }
    f.into_inner().unwrap().sync_all().unwrap();
}

/// Median seconds of `runs` runs of `f`.
fn median_s(runs: usize, mut f: impl FnMut()) -> f64 {
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[runs / 2]
}

fn recorder(c: &mut Criterion) {
    let ticks = needle_ticks();
    let n = ticks.len() as u64;
    let seconds = n as f64 / 1000.0;
    let dir = tempfile::tempdir().unwrap();
    let (raw, file) = (dir.path().join("raw.bin"), dir.path().join("s.mcap"));

    let bytes = write_session(&file, &ticks, true);
    let raw_size = 112 * n + 6 * n;
    println!(
        "needle session {seconds:.0} s: {:.1} KiB = {:.3} MB/min; raw tick data {:.3} MB/min, ratio {:.1}:1",
        bytes as f64 / 1024.0,
        bytes as f64 / 1e6 / (seconds / 60.0),
        raw_size as f64 / 1e6 / (seconds / 60.0),
        raw_size as f64 / bytes as f64
    );
    let base = median_s(9, || write_raw(&raw, &ticks));
    let fast = median_s(9, || {
        write_session(&file, &ticks, false);
    });
    let synced = median_s(9, || {
        write_session(&file, &ticks, true);
    });
    let read = median_s(9, || {
        black_box(reader::read(&file).unwrap());
    });
    for (what, s) in [
        ("raw uncompressed write (baseline)", base),
        ("session writer, no fsync", fast),
        ("session writer, fsync every chunk", synced),
        ("strict read + decode", read),
    ] {
        println!(
            "{what}: {:.1} ms = {:.0}× real time, {:.1}× the baseline's time",
            s * 1e3,
            seconds / s,
            s / base
        );
    }

    let mut g = c.benchmark_group("session_file");
    g.throughput(Throughput::Elements(n));
    g.sample_size(10);
    g.bench_function("baseline_raw_write", |b| b.iter(|| write_raw(&raw, &ticks)));
    g.bench_function("writer_no_fsync", |b| b.iter(|| write_session(&file, &ticks, false)));
    g.bench_function("writer_fsync", |b| b.iter(|| write_session(&file, &ticks, true)));
    g.bench_function("read", |b| b.iter(|| black_box(reader::read(&file).unwrap())));
    g.finish();
}

criterion_group!(benches, recorder);
criterion_main!(benches);
