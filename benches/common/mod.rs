//! What the haptic benches share: the phantom, a scripted run to its end, the paced single-tick
//! timing loop and recording a scripted session.

#![allow(dead_code)]

use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use stylet_devices::run_headless;
use stylet_devices::script::{Script, scripted_simulation};
use stylet_physics::glam::DVec3;
use stylet_physics::{Simulation, TickInput};
use stylet_recorder::WriterOptions;
use stylet_recorder::recording::{Recording, SessionInfo, header};

/// The default phantom, written to a temporary directory and loaded.
pub fn phantom() -> (tempfile::TempDir, stylet_atlas::Atlas) {
    let dir = tempfile::tempdir().unwrap();
    let p = stylet_atlas::phantom::generate(&Default::default()).unwrap();
    stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
    let atlas = stylet_atlas::load(dir.path()).unwrap();
    (dir, atlas)
}

/// Runs `script` to its end and returns the simulation and the last input.
pub fn prepared(atlas: &stylet_atlas::Atlas, script: &Script) -> (Simulation, TickInput) {
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), script).unwrap();
    let mut last = None;
    run_headless(&mut sim, &mut device, |i, _, _| last = Some(i.clone()));
    (sim, last.unwrap())
}

/// The times of `n` single ticks (µs, in tick order), the device trembling ±5 µm along the
/// needle (else z), one tick per millisecond as in the haptic loop.
pub fn tick_times(sim: &mut Simulation, input: &TickInput, n: usize) -> Vec<f64> {
    let axis = sim
        .needle()
        .and_then(|n| n.path().tip())
        .map_or(DVec3::Z, |t| t.tangent);
    let mut times = Vec::with_capacity(n);
    let start = Instant::now();
    for i in 0..n {
        let mut inp = input.clone();
        inp.position_mm += axis * if i % 2 == 0 { 0.005 } else { -0.005 };
        let due = start + std::time::Duration::from_millis(i as u64);
        while Instant::now() < due {
            std::hint::spin_loop();
        }
        let t = Instant::now();
        black_box(sim.step(&inp));
        times.push(t.elapsed().as_secs_f64() * 1e6);
    }
    times
}

/// Median, 99th and 99.9th percentile of `times`.
pub fn quantiles(mut times: Vec<f64>) -> (f64, f64, f64) {
    times.sort_by(f64::total_cmp);
    let n = times.len();
    (times[n / 2], times[n * 99 / 100], times[n * 999 / 1000])
}

/// Records `script` on `atlas` into `file`, as the desktop app does.
pub fn record(atlas: &stylet_atlas::Atlas, script: &Script, file: &Path) {
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), script).unwrap();
    let info = SessionInfo {
        trainee: "bench",
        scenario: "bench",
        difficulty: "beginner",
        seed: 0,
        atlas_id: &atlas.manifest.name,
        atlas_hash: &atlas.content_hash,
    };
    let mut rec = Recording::start(file, &header(&sim, &info), false, WriterOptions::default()).unwrap();
    run_headless(&mut sim, &mut device, |i, o, s| rec.tick(i, o, s));
    rec.finish().unwrap();
}

/// The one-minute needle script of the replay-speed figures (`seconds` long: in for two thirds,
/// then held).
pub fn needle_session_script(seconds: u32) -> String {
    format!(
        "stylet-script 1\ntool needle gauge 18 length 200\nend {seconds}\nat 0 along intercostal-10-11 -10\nat {} along intercostal-10-11 100\nat {seconds} along intercostal-10-11 100\n",
        seconds * 2 / 3
    )
}

/// Records `script` into `file`, replays it through the scoring's replay (checked verified) and
/// returns the replay's wall time (s).
pub fn replay_time_s(atlas: &stylet_atlas::Atlas, script: &Script, file: &Path) -> f64 {
    record(atlas, script, file);
    let session = stylet_recorder::reader::read(file).unwrap();
    let t = Instant::now();
    let r = stylet_scoring::replay::replay(&session, Arc::clone(&atlas.model), &mut |_, _, _| {}).unwrap();
    let s = t.elapsed().as_secs_f64();
    assert!(r.replay_verified, "{}: {:?}", file.display(), r.divergence);
    s
}
