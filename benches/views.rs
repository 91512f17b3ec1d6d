//! The simulator's views at 1280 × 800 (frame rate per view): each of the seven views the window
//! can show, drawn by `stylet_app::views::ViewRenderer` on the CPU as the window draws them, at
//! full resolution, on the default phantom patient (the one `stylet sim` builds) at 13.008 s of the
//! example puncture (needle in the duct, fluoroscopy on, contrast flowing). Ratios are to the axial
//! slice of the same run. Then the resolution each view settles at in the window's 50 ms budget,
//! and the frame rate it gets there.
//!
//! `cargo bench --bench views`. The drawing pool has every core but one (the haptic loop's), as
//! in the window. Under `cargo test --all-targets` a small phantom is drawn at 64 × 40 once per
//! view: a smoke test.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::Criterion;
use stylet_app::views::{ViewKind, ViewRenderer, ViewSettings};
use stylet_atlas::phantom::{self, PhantomConfig};
use stylet_devices::Device;
use stylet_devices::script::{parse, scripted_simulation};
use stylet_render::views::{Moment, SessionLabels};

/// The tick shown (as in tests/integration/simulator.rs: contrast is flowing).
const TICK: u64 = 13_008;

fn main() {
    let measuring = std::env::args().any(|a| a == "--bench");
    let dir = tempfile::tempdir().unwrap();
    let config = if measuring {
        PhantomConfig::default()
    } else {
        PhantomConfig {
            dims: [64, 64, 48],
            spacing_mm: [6.0; 3],
            ..PhantomConfig::default()
        }
    };
    let t = Instant::now();
    let p = phantom::generate(&config).unwrap();
    stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
    let atlas = Arc::new(stylet_atlas::load(dir.path()).unwrap());
    eprintln!("phantom built and loaded in {:.1} s", t.elapsed().as_secs_f64());
    let moment = moment_of_the_puncture(&atlas);
    let (w, h) = if measuring { (1280, 800) } else { (64, 40) };

    // Full resolution: a budget no frame reaches keeps the scale at 1.
    let full = RefCell::new(
        ViewRenderer::new(
            Arc::clone(&atlas),
            ViewSettings {
                budget: Duration::from_secs(3600),
                ..ViewSettings::default()
            },
        )
        .unwrap(),
    );
    let times: RefCell<BTreeMap<&'static str, Vec<Duration>>> = RefCell::default();
    let mut c = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(3))
        .configure_from_args();
    for kind in ViewKind::ALL {
        c.bench_function(&format!("view-{}-{w}x{h}", kind.name()), |b| {
            b.iter_custom(|iters| {
                let t = Instant::now();
                for _ in 0..iters {
                    let frame = full.borrow_mut().draw(kind, &moment, w, h).unwrap();
                    assert_eq!(frame.scale, 1.0);
                }
                let el = t.elapsed();
                times
                    .borrow_mut()
                    .entry(kind.name())
                    .or_default()
                    .push(el / iters as u32);
                el
            })
        });
    }
    if !measuring {
        return;
    }
    // The window's renderer: 50 ms per view; 40 frames let the scale settle.
    let mut window = ViewRenderer::new(Arc::clone(&atlas), ViewSettings::default()).unwrap();
    let mut settled = BTreeMap::new();
    for kind in ViewKind::ALL {
        let mut last = None;
        for _ in 0..40 {
            last = Some(window.draw(kind, &moment, w, h).unwrap());
        }
        let f = last.unwrap();
        settled.insert(kind.name(), (f.scale, f.took));
    }

    let times = times.into_inner();
    let median_ms = |name: &str| {
        let mut v = times.get(name).cloned().unwrap_or_default();
        v.sort();
        v.get(v.len().saturating_sub(1) / 2).map(|d| d.as_secs_f64() * 1e3)
    };
    let [nx, ny, nz] = atlas.model.ct().grid().dims();
    println!(
        "\nViews at {w}×{h}, phantom {nx}×{ny}×{nz}, CPU on {} drawing threads (median per frame)",
        stylet_app::views::drawing_threads()
    );
    println!(
        "{:<12} {:>9} {:>7} {:>9} | {:>14} {:>9} {:>7}",
        "view", "full ms", "fps", "× axial", "scale in 50 ms", "ms", "fps"
    );
    let base = median_ms("axial");
    for kind in ViewKind::ALL {
        let Some(ms) = median_ms(kind.name()) else { continue };
        let (scale, took) = settled[kind.name()];
        let took_ms = took.as_secs_f64() * 1e3;
        println!(
            "{:<12} {ms:>9.1} {:>7.1} {:>9.2} | {scale:>14.2} {took_ms:>9.1} {:>7.1}",
            kind.name(),
            1e3 / ms,
            base.map_or(f64::NAN, |b| ms / b),
            1e3 / took_ms
        );
    }
}

/// The example puncture run headless to [`TICK`]: the state the views draw.
fn moment_of_the_puncture(atlas: &stylet_atlas::Atlas) -> Moment {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts/success-intercostal.txt"),
    )
    .unwrap();
    let (mut sim, mut device) =
        scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &parse(&text).unwrap()).unwrap();
    let labels = SessionLabels {
        scenario: "success-intercostal".into(),
        difficulty: stylet_scoring::Difficulty::Beginner,
        seed: 0,
    };
    let mut last = None;
    loop {
        let input = device
            .next(sim.tick(), last.as_ref())
            .expect("the script lasts past the tick shown");
        let out = sim.step(&input);
        if out.tick >= TICK {
            return Moment::of_simulation(&sim, &input, &out, &labels);
        }
        last = Some(out);
    }
}
