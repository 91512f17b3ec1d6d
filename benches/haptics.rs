//! The 1 kHz hot paths: one needle tick 15 cm deep (≥ 100 path nodes) and one tick of each
//! contact tool pressed on the skin over the ribs (finger 7 nodes, linear and convex probe 32) on
//! the default phantom. Criterion measures the mean; a second pass times 100 000 single ticks to
//! report the median, the 99th and the 99.9th percentile (the haptic loop's budget is 1 ms; the
//! goals: p99 ≤ 20 µs for every tool, ≤ 5 µs for the linear probe, on one core). Baseline in the
//! same run: one trilinear CT lookup per contact node (32 lookups), the least any contact tick
//! must do.
//!
//! `script_playback`: the scripted device alone playing 20 s (20 000 ticks) of a script with 2,
//! 40 000 and 1 000 000 key frames; the 2-key-frame script is the baseline (the lookup must stay
//! logarithmic: a linear scan took 0.6 s for 40 000 key frames, minutes for a million).

use std::hint::black_box;
use std::sync::Arc;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use stylet_devices::run_headless;
use stylet_devices::script::{ScriptedDevice, parse, scripted_simulation};
use stylet_physics::glam::DVec3;
use stylet_physics::{Simulation, TickInput};

struct Setup {
    _dir: tempfile::TempDir,
    atlas: stylet_atlas::Atlas,
}

fn setup() -> Setup {
    let dir = tempfile::tempdir().unwrap();
    let p = stylet_atlas::phantom::generate(&Default::default()).unwrap();
    stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
    let atlas = stylet_atlas::load(dir.path()).unwrap();
    Setup { _dir: dir, atlas }
}

/// Runs a script and returns the simulation in its final state with the last input.
fn prepared(atlas: &stylet_atlas::Atlas, text: &str) -> (Simulation, TickInput) {
    let script = parse(text).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let mut last = None;
    run_headless(&mut sim, &mut device, |i, _, _| last = Some(i.clone()));
    (sim, last.unwrap())
}

/// Median, 99th and 99.9th percentile of single ticks (µs) with the device trembling ±5 µm
/// along `axis`.
fn percentiles(sim: &mut Simulation, input: &TickInput, axis: DVec3) -> [f64; 3] {
    let mut times = Vec::with_capacity(100_000);
    for i in 0..100_000 {
        let mut inp = input.clone();
        inp.position_mm += axis * if i % 2 == 0 { 0.005 } else { -0.005 };
        let t = Instant::now();
        black_box(sim.step(&inp));
        times.push(t.elapsed().as_secs_f64() * 1e6);
    }
    times.sort_by(f64::total_cmp);
    let n = times.len();
    [times[n / 2], times[n * 99 / 100], times[n * 999 / 1000]]
}

/// A contact tool pressed 1 mm into the skin over the ribs for 3 s (the probe across them).
fn contact_script(tool: &str) -> String {
    format!(
        "stylet-script 1\ntool {tool}\nend 3\nat 0 pos 175 8 42 dir -1 0 0 xaxis 0 1 -0.24\nat 0.2 press -1 0 0 1.0\nat 3 pos 175 8 42 dir -1 0 0 xaxis 0 1 -0.24\n"
    )
}

fn haptics(c: &mut Criterion) {
    let s = setup();
    let needle_script = "stylet-script 1\ntool needle gauge 18 length 200\nend 14\nat 0 along intercostal-10-11 -10\nat 13 along intercostal-10-11 152\nat 14 along intercostal-10-11 152\n";
    let (mut needle, needle_in) = prepared(&s.atlas, needle_script);
    let nodes = needle.needle().unwrap().path().len();
    let depth = needle.needle().unwrap().inserted_mm();
    assert!(nodes >= 100, "only {nodes} path nodes");
    let axis = needle.needle().unwrap().path().tip().unwrap().tangent;
    let [m, p99, p999] = percentiles(&mut needle, &needle_in, axis);
    println!(
        "needle tick, {depth:.0} mm deep, {nodes} path nodes: median {m:.2} µs, p99 {p99:.2} µs, p99.9 {p999:.2} µs"
    );
    let mut contact = Vec::new();
    for tool in ["finger", "probe linear", "probe convex"] {
        let (mut sim, input) = prepared(&s.atlas, &contact_script(tool));
        let nodes = sim.contact().unwrap().nodes().len();
        let touching = sim.contact().unwrap().nodes().iter().filter(|n| n.in_contact).count();
        assert!(touching > 0, "{tool}: no node touches the skin");
        let [m, p99, p999] = percentiles(&mut sim, &input, DVec3::Z);
        println!(
            "{tool} tick, {nodes} nodes ({touching} in contact): median {m:.2} µs, p99 {p99:.2} µs, p99.9 {p999:.2} µs"
        );
        contact.push((tool, sim, input));
    }

    let mut g = c.benchmark_group("haptic_tick");
    let ct = s.atlas.model.clone();
    let probe = &contact[1].1;
    let pts: Vec<DVec3> = probe.contact().unwrap().nodes().iter().map(|n| n.pos).collect();
    assert_eq!(pts.len(), 32);
    g.bench_function("baseline_32_trilinear_ct_lookups", |b| {
        b.iter(|| pts.iter().map(|&p| ct.hu_at(p)).sum::<f64>())
    });
    let mut k = 0u64;
    g.bench_function("needle_150mm_deep", |b| {
        b.iter(|| {
            k += 1;
            let mut inp = needle_in.clone();
            inp.position_mm += axis * if k.is_multiple_of(2) { 0.005 } else { -0.005 };
            black_box(needle.step(&inp))
        })
    });
    for (tool, sim, input) in &mut contact {
        g.bench_function(tool.replace(' ', "_"), |b| {
            b.iter(|| {
                k += 1;
                let mut inp = input.clone();
                inp.position_mm.z += if k.is_multiple_of(2) { 0.005 } else { -0.005 };
                black_box(sim.step(&inp))
            })
        });
    }
    g.finish();
}

/// A 20 s script of `n` needle pose key frames, evenly spaced.
fn keyframe_script(n: u64) -> ScriptedDevice {
    let mut text = String::from("stylet-script 1\nend 20\n");
    for i in 0..n {
        let t = 20.0 * i as f64 / (n - 1) as f64;
        let x = 100.0 + 10.0 * (i as f64 * 0.01).sin();
        text.push_str(&format!("at {t} pos {x} 0 0 dir -1 0 {}\n", 0.1 * (i % 7) as f64));
    }
    ScriptedDevice::new(&parse(&text).unwrap(), &[]).unwrap()
}

fn script_playback(c: &mut Criterion) {
    use stylet_devices::Device;
    let mut g = c.benchmark_group("script_playback");
    g.sample_size(10);
    let mut baseline_s = None;
    for n in [2u64, 40_000, 1_000_000] {
        let mut device = keyframe_script(n);
        let ticks = device.ticks();
        assert_eq!(ticks, 20_000);
        // No events or presses: the device plays the same ticks again and again.
        let mut play = move || {
            for tick in 0..ticks {
                black_box(device.next(tick, None));
            }
        };
        let start = Instant::now();
        play();
        let s = start.elapsed().as_secs_f64();
        let base = *baseline_s.get_or_insert(s);
        println!(
            "script playback, {n} key frames, {ticks} ticks: {:.2} ms ({:.2}× the 2-key-frame script)",
            s * 1e3,
            s / base
        );
        g.bench_function(format!("{n}_keyframes_20000_ticks"), |b| b.iter(&mut play));
    }
    g.finish();
}

criterion_group!(benches, haptics, script_playback);
criterion_main!(benches);
