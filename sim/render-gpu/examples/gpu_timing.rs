//! Frame times of the GPU ray caster on the phantom (not a test): 512 × 512 and 1225 × 1016 with
//! the soft-tissue preset-like transfer function, everything fast on, next to the CPU reference
//! on this machine's cores.
//!
//! `cargo run --profile ci -p stylet-render-gpu --example gpu_timing [-- ATLAS_DIR]`

use std::sync::Arc;
use std::time::Instant;

use stylet_physics::glam::Vec3;
use stylet_render::presets::{Preset, render_settings};
use stylet_render::scene::{Camera, Light, Quality, Scene, Tagging};
use stylet_render::tools::ToolState;
use stylet_render::transfer::TransferFunction;
use stylet_render::volume::RenderVolume;
use stylet_render_gpu::{GpuContext, GpuRenderer, GpuVolume};

fn main() {
    let dir = tempfile::tempdir().unwrap();
    let atlas_dir = match std::env::args().nth(1) {
        Some(d) => std::path::PathBuf::from(d),
        None => {
            let p = stylet_atlas::phantom::generate(&Default::default()).unwrap();
            stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
            dir.path().to_path_buf()
        }
    };
    let atlas = stylet_atlas::load(&atlas_dir).unwrap();
    let tf = TransferFunction::from_preset(Preset::Soft.of(&render_settings(&atlas.manifest))).unwrap();
    let cpu = RenderVolume::new(Arc::clone(&atlas.model));
    let ctx = GpuContext::new().unwrap();
    println!("adapter: {}", ctx.adapter());
    let t = Instant::now();
    let gpu = GpuVolume::upload(&ctx, &cpu).unwrap();
    println!(
        "upload: {:.0} ms ({:?}, {:.1} MB)",
        t.elapsed().as_secs_f64() * 1e3,
        gpu.ct_format(),
        gpu.texture_bytes() as f64 / 1e6
    );
    let g = cpu.atlas.ct().grid();
    let [nx, ny, nz] = g.dims();
    let (a, b) = (g.voxel_to_world(0, 0, 0), g.voxel_to_world(nx - 1, ny - 1, nz - 1));
    let camera = Camera::framing(a.min(b).as_vec3(), a.max(b).as_vec3(), 25.0, 15.0);
    let s = g.spacing_mm();
    let step = (0.5 * s[0].min(s[1]).min(s[2])) as f32;
    println!("CT {nx} × {ny} × {nz}, step {step} mm");
    let mut scene = Scene {
        camera,
        transfer: tf,
        light: Light::over_shoulder(&camera),
        clip: None,
        tagging: Tagging::Off,
        quality: Quality::fast(step),
        tools: ToolState::default(),
        background: Vec3::new(0.05, 0.05, 0.07),
        deformed: None,
        motion: None,
    };
    let mut r = GpuRenderer::new(&ctx);
    for (w, h) in [(512u32, 512u32), (1225, 1016)] {
        for (name, q) in [
            ("fast", Quality::fast(step)),
            (
                "half",
                Quality {
                    half_resolution: true,
                    ..Quality::fast(step)
                },
            ),
        ] {
            scene.quality = q;
            let _ = r.render(&ctx, &gpu, &scene, w, h).unwrap(); // warm-up (pipeline, occupancy)
            let mut times: Vec<f64> = (0..3)
                .map(|_| {
                    let t = Instant::now();
                    let _ = r.render(&ctx, &gpu, &scene, w, h).unwrap();
                    t.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            times.sort_by(f64::total_cmp);
            let t = Instant::now();
            let out = stylet_render::raycast::render(&cpu, &scene, w, h);
            let t_cpu = t.elapsed().as_secs_f64() * 1e3;
            println!(
                "{w}×{h} {name}: GPU median {:.0} ms (min {:.0}); CPU reference {:.0} ms on {} threads ({} samples)",
                times[1],
                times[0],
                t_cpu,
                rayon::current_num_threads(),
                out.samples
            );
        }
    }
}
