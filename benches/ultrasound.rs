//! Ultrasound speed (the thesis reports ≈ 8 ms a frame, §3.7): frames of the real 512 × 512 × 133
//! chest CT at 256 scan lines × 512 samples on the CPU reference (2-thread rayon pool): B-mode,
//! B-mode with colour Doppler and the needle, the scan conversion to a 640 × 512 image, and the
//! once-per-atlas flow-axis estimate; the same frames on the GPU renderer (lavapipe where there is
//! no GPU; `STYLET_BENCH_GPU=0` skips it), including the read-back and the CPU's log compression.
//! The convex probe sits beside the atlas' planned path, imaging it in plane
//! (`stylet render --view ultrasound`'s default). Ratios are to the B-mode frame of the same run;
//! frames per second = 1000 / ms.
//!
//! `cargo bench --bench ultrasound` (STYLET_DATA as for the render bench). Under
//! `cargo test --all-targets` a small phantom is drawn once: a smoke test.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::Criterion;
use stylet_physics::ProbeKind;
use stylet_render::tools::NeedleShape;
use stylet_render::ultrasound::{self, EchoTable, FlowField, UltrasoundScene, UltrasoundSettings, render};
use stylet_render::volume::RenderVolume;
use stylet_render_gpu::{GpuContext, GpuUltrasound, GpuVolume};

#[path = "common/chest.rs"]
mod chest;

fn main() {
    let measuring = std::env::args().any(|a| a == "--bench");
    // SAFETY: no other thread runs yet.
    unsafe { std::env::set_var("RAYON_NUM_THREADS", "2") };
    let mut keep = None;
    let dir = chest::atlas_dir(measuring, &mut keep);
    let atlas = stylet_atlas::load(&dir).unwrap();
    let path = atlas.planned_paths()[0].clone();
    let probe = ultrasound::probe::facing_path(&atlas.model, ProbeKind::Convex, path.entry_mm, path.target_mm).unwrap();
    let echo = Arc::new(EchoTable::of_atlas(&atlas));
    let t = Instant::now();
    let flow = Arc::new(FlowField::build(&atlas.model, &echo));
    eprintln!(
        "flow axes of {} cells in {:.0} ms",
        flow.cells(),
        t.elapsed().as_secs_f64() * 1e3
    );
    let mut settings = UltrasoundSettings::for_probe(ProbeKind::Convex);
    if !measuring {
        settings.lines = 32;
        settings.samples = 64;
    }
    let bmode = UltrasoundScene {
        probe,
        settings,
        seed: 1,
        time_s: 0.0,
        needle: None,
        lines: Vec::new(),
        echo: echo.clone(),
        doppler: None,
        guide_mm: None,
        outline_target: true,
        breathing: None,
        consequences: Default::default(),
    };
    // The needle along the planned path, 80 % of the way in.
    let (e, tg) = (path.entry_mm.as_vec3(), path.target_mm.as_vec3());
    let full = UltrasoundScene {
        needle: Some(NeedleShape {
            nodes_mm: (0..=20)
                .map(|k| e + (tg - e) * (0.8 * k as f32 / 20.0) - (tg - e).normalize() * 20.0)
                .collect(),
            diameter_mm: 1.27,
            hub_length_mm: 20.0,
            hub_diameter_mm: 4.0,
        }),
        doppler: Some(flow),
        guide_mm: Some([e, tg]),
        ..bmode.clone()
    };

    let times: RefCell<BTreeMap<String, Vec<Duration>>> = RefCell::default();
    let mut c = Criterion::default()
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
        .configure_from_args();
    let timed = |c: &mut Criterion, name: &str, f: &dyn Fn()| {
        c.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let t = Instant::now();
                for _ in 0..iters {
                    f();
                }
                let el = t.elapsed();
                times
                    .borrow_mut()
                    .entry(name.to_string())
                    .or_default()
                    .push(el / iters as u32);
                el
            })
        });
    };
    let lines = format!("{}x{}", settings.lines, settings.samples);
    let base = format!("us-bmode-{lines}");
    timed(&mut c, &base, &|| {
        render(&atlas.model, &bmode).unwrap();
    });
    timed(&mut c, &format!("us-doppler-needle-{lines}"), &|| {
        render(&atlas.model, &full).unwrap();
    });
    if std::env::var("STYLET_BENCH_GPU").as_deref() != Ok("0") {
        let ctx = GpuContext::new().expect("a GPU adapter (lavapipe will do); STYLET_BENCH_GPU=0 skips the GPU");
        let vol = GpuVolume::upload(&ctx, &RenderVolume::new(Arc::clone(&atlas.model))).unwrap();
        eprintln!("GPU: {}", ctx.adapter());
        let us = RefCell::new(GpuUltrasound::new(&ctx));
        timed(&mut c, &format!("us-GPU-bmode-{lines}"), &|| {
            us.borrow_mut().render(&ctx, &vol, &bmode).unwrap();
        });
        timed(&mut c, &format!("us-GPU-doppler-needle-{lines}"), &|| {
            us.borrow_mut().render(&ctx, &vol, &full).unwrap();
        });
    }
    let frame = render(&atlas.model, &full).unwrap();
    timed(&mut c, "us-scan-convert-640x512", &|| {
        frame.to_image(640, 512);
    });
    if !measuring {
        return;
    }
    let times = times.into_inner();
    let median_ms = |name: &str| {
        let mut v = times.get(name).cloned().unwrap_or_default();
        v.sort();
        v.get(v.len().saturating_sub(1) / 2).map(|d| d.as_secs_f64() * 1e3)
    };
    let [nx, ny, nz] = atlas.model.ct().grid().dims();
    println!("\nUltrasound, {nx}×{ny}×{nz} CT, convex probe, CPU on 2 threads (median per frame)");
    println!("{:<30} {:>8} {:>8} {:>12}", "", "ms", "fps", "× B-mode");
    let b = median_ms(&base);
    for name in times.keys() {
        let Some(ms) = median_ms(name) else { continue };
        println!(
            "{name:<30} {ms:>8.2} {:>8.0} {:>12.2}",
            1e3 / ms,
            b.map_or(f64::NAN, |b| ms / b)
        );
    }
}
