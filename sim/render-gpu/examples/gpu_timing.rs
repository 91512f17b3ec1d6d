//! Frame times of the GPU ray caster (not a test) on the phantom or an atlas: 512 × 512 and
//! 1225 × 1016, soft-tissue preset, naive, + ray/box, + leaping, + early termination, half
//! resolution, each with the records interpolated by the shader and, where the adapter can, by
//! the texture unit (`RecordFilter`), in the same run. Each is the median of the GPU's own pass
//! time (timestamps) and of the whole call with the image read back; the CPU reference on this
//! machine's cores beside the fast case, with the difference statistics of the images (written
//! as PNG under `$STYLET_TIMING_PNG` when set). Then the breathing patient (the synthetic motion,
//! default amplitude, at the deepest breath of the first minute) against the still one in the
//! same run, in two rounds: warped rays (the thesis' 16 ms still against 27–37 ms moving),
//! slices and the radiograph. The CPU references are drawn after the timed frames: a GPU left
//! idle for a second lowers its clock, and the frames after it would pay.
//!
//! Last, the other views against the CPU reference on this machine's cores: the radiograph at
//! 256² and 512² (the geometry of `benches/xray.rs`) and the ultrasound frame at 256 lines × 512
//! samples, B-mode alone and with colour Doppler and the needle (that of
//! `benches/ultrasound.rs`), each with its readback (and the ultrasound's log compression).
//!
//! `cargo run --profile ci -p stylet-render-gpu --example gpu_timing [-- ATLAS_DIR]`
//! (`STYLET_TIMING_ONLY=views`: the radiograph and ultrasound alone)

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
    if std::env::var("STYLET_TIMING_ONLY").as_deref() == Ok("views") {
        return views(&ctx, &atlas, &cpu, &uploads[0].1);
    }
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
    breathing(&ctx, &cpu, &uploads, &scene);
    views(&ctx, &atlas, &cpu, &uploads[0].1);
}

/// The median of `FRAMES` calls of `f` after a warm-up call (ms), and the warm-up's output.
fn timed<T>(mut f: impl FnMut() -> T) -> (f64, T) {
    let first = f();
    let mut wall: Vec<f64> = (0..FRAMES)
        .map(|_| {
            let t = Instant::now();
            let _ = f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    wall.sort_by(f64::total_cmp);
    (wall[wall.len() / 2], first)
}

/// Still against breathing, same frames: ray casting (GPU pass and with readback), a coronal
/// slice and the radiograph.
fn breathing(ctx: &GpuContext, cpu: &RenderVolume, uploads: &[(RecordFilter, GpuVolume)], scene: &Scene) {
    use stylet_physics::motion::{BreathingSettings, BreathingSignal};
    use stylet_render::mpr::{Plane, SliceSpec, Window};
    use stylet_render::scene::MotionHook;
    use stylet_render::xray::{CArm, XrayScene};
    let settings = BreathingSettings::on();
    let model = match settings.build(&cpu.atlas) {
        Ok(m) => m,
        Err(e) => return println!("breathing: {e}"),
    };
    let signal = BreathingSignal::new(settings.signal).unwrap();
    let t_s = (0..600)
        .map(|i| i as f64 * 0.1)
        .max_by(|&a, &b| signal.g(a).total_cmp(&signal.g(b)))
        .unwrap();
    let hook = MotionHook { model, t_s };
    println!(
        "breathing: synthetic motion, amplitude {} mm, g = {:.3} at {t_s:.1} s, bound {:.1} mm",
        settings.motion.amplitude_mm,
        signal.g(t_s),
        hook.model.max_displacement_mm()
    );
    let mut r = GpuRenderer::new(ctx);
    let mut moving = scene.clone();
    moving.quality = Quality::fast(scene.quality.step_mm);
    moving.motion = Some(hook.clone());
    let mut still = moving.clone();
    still.motion = None;
    // Two rounds, the CPU references after both: a second of CPU work between GPU frames lets
    // the GPU lower its clocks, which the first frames after it would pay.
    let mut compare = Vec::new();
    for round in 1..=2 {
        for (w, h) in [(512u32, 512u32), (1225, 1016)] {
            for (filter, gpu) in uploads {
                let mut line = format!("round {round}, {w}×{h} ray casting, records by {filter:?}:");
                let mut ms = [0.0; 2];
                for (i, (name, s)) in [("still", &still), ("breathing", &moving)].into_iter().enumerate() {
                    let mut pass = Vec::new();
                    let (wall, image) = timed(|| {
                        let image = r.render(ctx, gpu, s, w, h).unwrap();
                        pass.extend(r.last_pass_ms());
                        image
                    });
                    pass.sort_by(f64::total_cmp);
                    ms[i] = pass.get(pass.len() / 2).copied().unwrap_or(wall);
                    let pass = pass.get(pass.len() / 2).map_or("n/a".into(), |p| format!("{p:.2} ms"));
                    line += &format!(" {name} GPU pass {pass}, with readback {wall:.2} ms;");
                    if round == 1 && name == "breathing" && *filter == RecordFilter::Shader {
                        compare.push((w, h, image));
                    }
                }
                println!("{line} breathing ÷ still {:.2}", ms[1] / ms[0]);
            }
        }
    }
    for (w, h, image) in compare {
        let t = Instant::now();
        let out = stylet_render::raycast::render(cpu, &moving, w, h);
        let d = stylet_render::image::diff(&image, &out.image).unwrap();
        println!(
            "{w}×{h} breathing, CPU reference {:.0} ms, GPU (records by Shader) − CPU {d}",
            t.elapsed().as_secs_f64() * 1e3
        );
        if let Some(dir) = std::env::var_os("STYLET_TIMING_PNG") {
            let dir = std::path::Path::new(&dir);
            image
                .write_png(&dir.join(format!("gpu-breathing-{w}x{h}.png")))
                .unwrap();
            out.image
                .write_png(&dir.join(format!("cpu-breathing-{w}x{h}.png")))
                .unwrap();
        }
    }
    let gpu = &uploads[0].1;
    let (lo, hi) = cpu.atlas.ct().grid().world_bounds();
    let spec = SliceSpec::plane(&cpu.atlas, Plane::Coronal, (lo + hi) * 0.5, Window::ABDOMEN, 512);
    let mut mpr = stylet_render_gpu::GpuMpr::new(ctx);
    let (t_still, _) = timed(|| mpr.render(ctx, gpu, &spec).unwrap());
    let (t_moving, _) = timed(|| mpr.render_moving(ctx, gpu, &spec, Some(&hook), None).unwrap());
    println!("coronal slice 512 px: still {t_still:.2} ms, breathing {t_moving:.2} ms (with readback)");
    let scene = XrayScene {
        c_arm: CArm::posterior_anterior(((lo + hi) * 0.5).as_vec3()),
        needle: None,
        lines: Vec::new(),
        contrast: None,
    };
    let mut xray = stylet_render_gpu::GpuXray::new(ctx);
    let (t_still, _) = timed(|| xray.render(ctx, gpu, &scene, 1024, 1024).unwrap());
    let (t_moving, _) = timed(|| xray.render_moving(ctx, gpu, &scene, Some(&hook), 1024, 1024).unwrap());
    println!("radiograph 1024²: still {t_still:.2} ms, breathing {t_moving:.2} ms (with readback)");
}

/// Timed frames per case (after one warm-up frame).
const FRAMES: usize = 21;

/// The radiograph and the ultrasound frame on the GPU against the CPU reference (ms, with
/// readback), as `benches/xray.rs` and `benches/ultrasound.rs` set them up.
fn views(ctx: &GpuContext, atlas: &stylet_atlas::Atlas, cpu: &RenderVolume, gpu: &GpuVolume) {
    use stylet_physics::ProbeKind;
    use stylet_render::tools::NeedleShape;
    use stylet_render::ultrasound::{self, EchoTable, FlowField, UltrasoundScene, UltrasoundSettings};
    use stylet_render::xray::{CArm, XrayScene};
    let (lo, hi) = cpu.atlas.ct().grid().world_bounds();
    let mut c_arm = CArm::posterior_anterior(((lo + hi) * 0.5).as_vec3());
    c_arm.detector_mm = [400.0, 400.0];
    let scene = XrayScene {
        c_arm,
        needle: None,
        lines: Vec::new(),
        contrast: None,
    };
    // Every GPU frame first, then the CPU's (an idle GPU lowers its clock).
    let mut xray = stylet_render_gpu::GpuXray::new(ctx);
    let sizes = [256u32, 512];
    let gpu_ms = sizes.map(|n| timed(|| xray.render(ctx, gpu, &scene, n, n).unwrap()).0);
    for (n, t_gpu) in sizes.into_iter().zip(gpu_ms) {
        let (t_cpu, _) = timed(|| stylet_render::xray::render(&cpu.atlas, &scene, n, n).unwrap());
        println!(
            "radiograph {n}²: GPU {t_gpu:.2} ms, CPU reference {t_cpu:.1} ms on {} threads (medians, with readback)",
            rayon::current_num_threads()
        );
    }
    let Some(path) = atlas.planned_paths().first().cloned() else {
        return println!("ultrasound: the atlas has no planned path to image");
    };
    let probe = match ultrasound::probe::facing_path(&cpu.atlas, ProbeKind::Convex, path.entry_mm, path.target_mm) {
        Some(p) => p,
        None => return println!("ultrasound: no probe pose faces the planned path"),
    };
    let echo = std::sync::Arc::new(EchoTable::of_atlas(atlas));
    let flow = std::sync::Arc::new(FlowField::build(&cpu.atlas, &echo));
    let bmode = UltrasoundScene {
        probe,
        settings: UltrasoundSettings::for_probe(ProbeKind::Convex),
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
    let mut us = stylet_render_gpu::GpuUltrasound::new(ctx);
    let s = &bmode.settings;
    let scenes = [("B-mode", &bmode), ("B-mode + Doppler + needle", &full)];
    let gpu_ms = scenes.map(|(_, scene)| {
        let mut pass = Vec::new();
        let (wall, _) = timed(|| {
            us.render(ctx, gpu, scene).unwrap();
            pass.extend(us.last_pass_ms());
        });
        pass.sort_by(f64::total_cmp);
        (wall, pass.get(pass.len() / 2).copied())
    });
    for ((name, scene), (t_gpu, pass)) in scenes.into_iter().zip(gpu_ms) {
        let (t_cpu, _) = timed(|| ultrasound::render(&cpu.atlas, scene).unwrap());
        let pass = pass.map_or("n/a".into(), |p| format!("{p:.2} ms"));
        println!(
            "ultrasound {name}, {} lines × {} samples: GPU pass {pass}, frame {t_gpu:.2} ms; CPU reference {t_cpu:.1} ms (medians)",
            s.lines, s.samples
        );
    }
}
