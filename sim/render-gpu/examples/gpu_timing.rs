//! Frame times of the GPU ray caster (not a test) on the phantom or an atlas: 512 × 512 and
//! 1225 × 1016, soft-tissue preset, naive, + ray/box, + leaping, + early termination, half
//! resolution, each with the records interpolated by the shader and, where the adapter can, by
//! the texture unit (`RecordFilter`), in the same run. Each is the median of the GPU's own pass
//! time (timestamps) and of the whole call with the image read back; the CPU reference on this
//! machine's cores beside the fast case, with the difference statistics of the images (written
//! as PNG under `$STYLET_TIMING_PNG` when set).
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
use stylet_render_gpu::{CtPlacement, GpuContext, GpuRenderer, GpuVolume, RecordFilter, UploadOptions};

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
    let mut uploads = Vec::new();
    for records in [RecordFilter::Shader, RecordFilter::Hardware] {
        let t = Instant::now();
        let options = UploadOptions {
            placement: CtPlacement::Texture,
            records,
        };
        match GpuVolume::upload_with(&ctx, &cpu, options) {
            Ok(gpu) => {
                println!(
                    "upload, records by {records:?}: {:.0} ms ({:?}, {:.1} MB)",
                    t.elapsed().as_secs_f64() * 1e3,
                    gpu.ct_format(),
                    gpu.texture_bytes() as f64 / 1e6
                );
                uploads.push((records, gpu));
            }
            Err(e) => println!("records by {records:?}: {e}"),
        }
    }
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
    println!("GPU timestamps: {}", ctx.has_timestamps());
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    // The thesis' Table 3.1 analogue: each speed-up added to the last, then half resolution.
    let fast = Quality::fast(step);
    let cases = [
        ("naive", Quality::naive(step)),
        (
            "ray/box",
            Quality {
                leaping: false,
                early_termination: false,
                ..fast
            },
        ),
        (
            "+leaping",
            Quality {
                early_termination: false,
                ..fast
            },
        ),
        ("+early termination", fast),
        (
            "+early termination, leaping N = 32",
            Quality {
                occupancy_cells: 32,
                ..fast
            },
        ),
        (
            "+early termination, leaping N = 128",
            Quality {
                occupancy_cells: 128,
                ..fast
            },
        ),
        (
            "half resolution",
            Quality {
                half_resolution: true,
                ..fast
            },
        ),
    ];
    for (w, h) in [(512u32, 512u32), (1225, 1016)] {
        let mut reference = None;
        for (name, q) in cases {
            scene.quality = q;
            for (filter, gpu) in &uploads {
                let first = r.render(&ctx, gpu, &scene, w, h).unwrap(); // warm-up (pipeline, occupancy)
                let (mut pass, mut wall) = (Vec::new(), Vec::new());
                for _ in 0..FRAMES {
                    let t = Instant::now();
                    let _ = r.render(&ctx, gpu, &scene, w, h).unwrap();
                    wall.push(t.elapsed().as_secs_f64() * 1e3);
                    pass.extend(r.last_pass_ms());
                }
                let pass = if pass.is_empty() {
                    "n/a".to_string()
                } else {
                    format!("{:.2} ms", median(pass))
                };
                print!(
                    "{w}×{h} {name}, records by {filter:?}: GPU pass median {pass}, frame with readback median {:.2} ms",
                    median(wall)
                );
                if name == "+early termination" {
                    let out = reference.get_or_insert_with(|| {
                        let t = Instant::now();
                        let out = stylet_render::raycast::render(&cpu, &scene, w, h);
                        print!(
                            "; CPU reference {:.0} ms on {} threads ({} samples)",
                            t.elapsed().as_secs_f64() * 1e3,
                            rayon::current_num_threads(),
                            out.samples,
                        );
                        out
                    });
                    let d = stylet_render::image::diff(&first, &out.image).unwrap();
                    let differing = first.rgba.iter().zip(&out.image.rgba).filter(|(a, b)| a != b).count();
                    print!("; GPU − CPU {d}, {differing} pixels differ");
                    if let Some(dir) = std::env::var_os("STYLET_TIMING_PNG") {
                        let dir = std::path::Path::new(&dir);
                        first
                            .write_png(&dir.join(format!("gpu-{filter:?}-{w}x{h}.png")))
                            .unwrap();
                        out.image.write_png(&dir.join(format!("cpu-{w}x{h}.png"))).unwrap();
                    }
                }
                println!();
            }
        }
    }
}

/// Timed frames per case (after one warm-up frame).
const FRAMES: usize = 11;
