//! Shared set-up of the GPU tests: one device for all the tests (a test FAILS when there is no
//! adapter: CI installs Mesa's lavapipe), a small synthetic atlas, the phantom, and the
//! GPU-versus-CPU comparison with its statistics printed.

use std::sync::{Arc, Mutex, OnceLock};

use stylet_physics::glam::{DVec3, Vec3};
use stylet_render::image::{DiffStats, Image, Tolerance, diff};
use stylet_render::scene::{Camera, Light, Quality, Scene, Tagging};
use stylet_render::synthetic;
use stylet_render::tools::ToolState;
use stylet_render::transfer::{TransferFunction, Trapezoid};
use stylet_render::volume::RenderVolume;
use stylet_render_gpu::{CtPlacement, GpuContext, GpuRenderer, GpuVolume, RecordFilter, UploadOptions};

/// The device, opened once; no adapter is a failure with the fix in the message.
pub fn ctx() -> &'static GpuContext {
    static C: OnceLock<GpuContext> = OnceLock::new();
    C.get_or_init(|| {
        // SAFETY-free: set before any thread of this binary reads the environment.
        let ctx = GpuContext::new().unwrap_or_else(|e| {
            panic!("the GPU tests need an adapter (CI installs libvulkan1 mesa-vulkan-drivers): {e}")
        });
        eprintln!("GPU adapter: {}", ctx.adapter());
        ctx
    })
}

/// One renderer per binary (its caches are per renderer), shared by the tests' threads.
pub fn renderer() -> &'static Mutex<GpuRenderer> {
    static R: OnceLock<Mutex<GpuRenderer>> = OnceLock::new();
    R.get_or_init(|| Mutex::new(GpuRenderer::new(ctx())))
}

pub use stylet_render::synthetic::{RISK, TARGET};
pub const BONE_HU: f32 = 1000.0;
pub const SOFT_HU: f32 = 40.0;

/// An atlas prepared for both renderers.
pub struct Both {
    pub cpu: RenderVolume,
    pub gpu: GpuVolume,
}

/// An n³ atlas at `spacing` mm centred on the origin, CT and partial labels from functions of
/// the voxel centre (mm): [`synthetic::atlas`] on both renderers.
pub fn synthetic(n: usize, spacing: f64, ct: impl Fn(DVec3) -> f32, partial: impl Fn(DVec3) -> u16) -> Both {
    synthetic_with(n, spacing, ct, partial, CtPlacement::Auto)
}

/// [`synthetic`] with the CT's placement on the GPU chosen.
pub fn synthetic_with(
    n: usize,
    spacing: f64,
    ct: impl Fn(DVec3) -> f32,
    partial: impl Fn(DVec3) -> u16,
    placement: CtPlacement,
) -> Both {
    synthetic_upload(
        n,
        spacing,
        ct,
        partial,
        UploadOptions {
            placement,
            records: RecordFilter::Auto,
        },
    )
}

/// [`synthetic`] with every upload choice given.
pub fn synthetic_upload(
    n: usize,
    spacing: f64,
    ct: impl Fn(DVec3) -> f32,
    partial: impl Fn(DVec3) -> u16,
    options: UploadOptions,
) -> Both {
    let a = synthetic::atlas(n, spacing, ct, partial);
    let cpu = RenderVolume::new(Arc::new(a));
    let gpu = GpuVolume::upload_with(ctx(), &cpu, options).unwrap();
    Both { cpu, gpu }
}

/// A soft-tissue body (radius 42 mm, skin-like shell 3 mm) with a bone sphere of 14 mm, a target
/// (labelled, 60 HU) and a risk vessel (labelled, 200 HU) inside; air around.
pub fn body(p: DVec3) -> f32 {
    let r = p.length();
    if r < 14.0 {
        BONE_HU
    } else if (p - DVec3::new(20.0, 5.0, 10.0)).length() < 8.0 {
        60.0
    } else if (p.x + 22.0).hypot(p.y - 5.0) < 5.0 && r < 40.0 {
        200.0
    } else if r < 39.0 {
        SOFT_HU
    } else if r < 42.0 {
        -200.0
    } else {
        -1000.0
    }
}

pub fn body_labels(p: DVec3) -> u16 {
    if (p - DVec3::new(20.0, 5.0, 10.0)).length() < 8.0 {
        TARGET
    } else if (p.x + 22.0).hypot(p.y - 5.0) < 5.0 && p.length() < 40.0 {
        RISK
    } else {
        0
    }
}

/// The synthetic atlas (48³ voxels of 2 mm; CT values integers, so it uploads as 16-bit).
pub fn small() -> &'static Both {
    static S: OnceLock<Both> = OnceLock::new();
    S.get_or_init(|| synthetic(48, 2.0, body, body_labels))
}

/// The synthetic atlas with its CT in a 3D texture and in a storage buffer (both shader
/// variants, whatever the adapter), 16-bit and float.
pub fn placements() -> &'static [(&'static str, Both); 4] {
    static S: OnceLock<[(&'static str, Both); 4]> = OnceLock::new();
    S.get_or_init(|| {
        let float = |p: DVec3| body(p) + (p.x * 0.37) as f32;
        [
            (
                "int16-texture",
                synthetic_with(40, 2.4, body, body_labels, CtPlacement::Texture),
            ),
            (
                "int16-buffer",
                synthetic_with(40, 2.4, body, body_labels, CtPlacement::Buffer),
            ),
            (
                "float-texture",
                synthetic_with(40, 2.4, float, body_labels, CtPlacement::Texture),
            ),
            (
                "float-buffer",
                synthetic_with(40, 2.4, float, body_labels, CtPlacement::Buffer),
            ),
        ]
    })
}

/// The synthetic atlas with fractional CT values (a smooth ramp added), so it uploads as
/// 32-bit floats.
pub fn small_float() -> &'static Both {
    static S: OnceLock<Both> = OnceLock::new();
    S.get_or_init(|| synthetic(40, 2.4, |p| body(p) + (p.x * 0.37) as f32, body_labels))
}

/// The default phantom (written and loaded once per test binary; stored as integer HU, so it
/// uploads as 16-bit).
pub fn phantom() -> &'static Both {
    static P: OnceLock<Both> = OnceLock::new();
    P.get_or_init(|| {
        let dir = stylet_testkit::fixture_dir();
        let p = stylet_atlas::phantom::generate(&Default::default()).unwrap();
        stylet_atlas::write(&dir, &p.manifest, &p.ct, &p.partial).unwrap();
        let atlas = stylet_atlas::load(&dir).unwrap();
        let cpu = RenderVolume::new(Arc::clone(&atlas.model));
        let gpu = GpuVolume::upload(ctx(), &cpu).unwrap();
        Both { cpu, gpu }
    })
}

pub fn trapezoid(tissue: &str, hu: [f32; 4], rgb: [f32; 3], opacity: f32, weight: f32) -> Trapezoid {
    Trapezoid {
        tissue: tissue.into(),
        hu,
        rgb,
        opacity,
        weight,
    }
}

/// Preset-like transfer functions: skin, soft tissue and bone as weighted trapezoid sums, and
/// a windowing ramp.
pub fn transfer_functions() -> Vec<(&'static str, TransferFunction)> {
    let skin = trapezoid("skin", [-600.0, -350.0, -120.0, 0.0], [0.93, 0.75, 0.65], 0.35, 1.0);
    let soft = trapezoid("soft", [-150.0, 0.0, 100.0, 180.0], [0.8, 0.35, 0.3], 0.06, 1.0);
    let bone = trapezoid("bone", [150.0, 400.0, 3000.0, 3100.0], [1.0, 0.98, 0.9], 0.7, 1.0);
    vec![
        (
            "skin",
            TransferFunction::Trapezoids(vec![
                skin.clone(),
                Trapezoid {
                    weight: 0.3,
                    ..soft.clone()
                },
            ]),
        ),
        (
            "soft",
            TransferFunction::Trapezoids(vec![
                Trapezoid {
                    weight: 0.2,
                    ..skin.clone()
                },
                soft.clone(),
                Trapezoid {
                    weight: 0.5,
                    ..bone.clone()
                },
            ]),
        ),
        (
            "bone",
            TransferFunction::Trapezoids(vec![bone, Trapezoid { weight: 0.1, ..soft }]),
        ),
        (
            "window",
            TransferFunction::Window {
                level_hu: 40.0,
                width_hu: 400.0,
                opacity: 0.05,
            },
        ),
    ]
}

/// World box of the CT's voxel centres.
pub fn bounds(v: &RenderVolume) -> (Vec3, Vec3) {
    let g = v.atlas.ct().grid();
    let [nx, ny, nz] = g.dims();
    let (a, b) = (g.voxel_to_world(0, 0, 0), g.voxel_to_world(nx - 1, ny - 1, nz - 1));
    (a.min(b).as_vec3(), a.max(b).as_vec3())
}

/// The whole CT framed from anterior, 25° toward the patient's right, 15° up; steps of half
/// the smallest voxel; everything fast on.
pub fn scene(v: &RenderVolume, transfer: TransferFunction) -> Scene {
    let (lo, hi) = bounds(v);
    let camera = Camera::framing(lo, hi, 25.0, 15.0);
    let s = v.atlas.ct().grid().spacing_mm();
    Scene {
        camera,
        transfer,
        light: Light::over_shoulder(&camera),
        clip: None,
        tagging: Tagging::Off,
        quality: Quality::fast((0.5 * s[0].min(s[1]).min(s[2])) as f32),
        tools: ToolState::default(),
        background: Vec3::new(0.05, 0.05, 0.07),
        deformed: None,
        motion: None,
    }
}

/// Renders `scene` on the GPU.
pub fn render_gpu(both: &Both, scene: &Scene, w: u32, h: u32) -> Image {
    renderer()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .render(ctx(), &both.gpu, scene, w, h)
        .unwrap_or_else(|e| panic!("GPU render failed: {e}"))
}

/// Renders `scene` on the GPU and with the CPU reference, prints the difference statistics,
/// writes both images (and a difference image) under $TMPDIR/stylet-gpu/ and checks `tol`.
pub fn compare(name: &str, both: &Both, scene: &Scene, w: u32, h: u32, tol: Tolerance) -> DiffStats {
    let t = std::time::Instant::now();
    let gpu = renderer()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .render(ctx(), &both.gpu, scene, w, h)
        .unwrap_or_else(|e| panic!("{name}: GPU render failed: {e}"));
    let t_gpu = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let cpu = stylet_render::raycast::render(&both.cpu, scene, w, h).image;
    let t_cpu = t.elapsed().as_secs_f64();
    let d = diff(&gpu, &cpu).expect("same size");
    let differing = gpu.rgba.iter().zip(&cpu.rgba).filter(|(a, b)| a != b).count();
    println!(
        "{name} ({w}×{h}): {d}; {differing} of {} pixels differ; GPU {:.0} ms, CPU {:.0} ms",
        gpu.rgba.len(),
        t_gpu * 1e3,
        t_cpu * 1e3
    );
    let dir = std::env::temp_dir().join("stylet-gpu");
    std::fs::create_dir_all(&dir).unwrap();
    gpu.write_png(&dir.join(format!("{name}-gpu.png"))).unwrap();
    cpu.write_png(&dir.join(format!("{name}-cpu.png"))).unwrap();
    difference_image(&gpu, &cpu)
        .write_png(&dir.join(format!("{name}-diff.png")))
        .unwrap();
    assert!(
        tol.admits(&d),
        "{name}: GPU against CPU {d} exceeds the tolerance (mean {}, p99 {}, max {}); images in {}",
        tol.mean,
        tol.p99,
        tol.max,
        dir.display()
    );
    d
}

/// |a − b| per channel, scaled ×8 so one grey level shows.
pub fn difference_image(a: &Image, b: &Image) -> Image {
    let mut out = Image::new(a.width, a.height);
    for (o, (p, q)) in out.rgba.iter_mut().zip(a.rgba.iter().zip(&b.rgba)) {
        for c in 0..3 {
            o[c] = p[c].abs_diff(q[c]).saturating_mul(8);
        }
    }
    out
}

/// The phantom breathing at its deepest breath of the first minute (amplitude 25 mm, so the
/// motion is many voxels).
pub fn breathing_hook(both: &Both) -> (stylet_render::scene::MotionHook, f64) {
    use stylet_physics::motion::{BreathingSettings, BreathingSignal};
    let mut settings = BreathingSettings::on();
    settings.motion.amplitude_mm = 25.0;
    let model = settings.build(&both.cpu.atlas).unwrap();
    let signal = BreathingSignal::new(settings.signal).unwrap();
    let t_s = (0..600)
        .map(|i| i as f64 * 0.1)
        .max_by(|&a, &b| signal.g(a).total_cmp(&signal.g(b)))
        .unwrap();
    (stylet_render::scene::MotionHook { model, t_s }, signal.g(t_s))
}

/// A measured-style motion on the phantom (three grid fields on grids of their own, as an
/// imported registration gives, thesis eq. 5.3.6): a₁ the synthetic motion's displacement at its
/// deepest breath per unit g sampled on a 5 mm grid, a₂ a third of it on a 7 mm grid, a₃ a
/// constant 1.5 mm cranial shift on a 20 mm grid; driven by the default signal at its deepest
/// breath. Returns the hook and g.
pub fn measured_hook(both: &Both) -> (stylet_render::scene::MotionHook, f64) {
    use std::sync::Arc;
    use stylet_physics::glam::DVec3;
    use stylet_physics::motion::{BreathingSignal, GridField, SpatialField, Surrogate};
    use stylet_physics::{Affine, Grid};
    let (synthetic, _) = breathing_hook(both);
    let (lo, hi) = both.cpu.atlas.ct().grid().world_bounds();
    let grid = |spacing: f64| {
        let n = ((hi - lo) / spacing).ceil().as_uvec3();
        Grid::new(
            [n.x as usize + 1, n.y as usize + 1, n.z as usize + 1],
            Affine::from_spacing([spacing; 3], lo),
        )
        .unwrap()
    };
    let (model, t_peak) = (synthetic.model.clone(), synthetic.t_s);
    let g_peak = {
        let s = BreathingSignal::new(stylet_physics::motion::BreathingSettings::on().signal).unwrap();
        s.g(t_peak)
    };
    let per_g = move |x: DVec3| model.displacement(x, t_peak) / g_peak;
    let a1 = GridField::sample(grid(5.0), per_g.clone());
    let a2 = GridField::sample(grid(7.0), move |x| per_g(x) / 3.0);
    let a3 = GridField::sample(grid(20.0), |_| DVec3::new(0.0, 0.0, 1.5));
    let signal = BreathingSignal::new(stylet_physics::motion::BreathingSettings::on().signal).unwrap();
    // A moment on the way in: g′ is not zero, so a₂ counts.
    let t_s = (0..600)
        .map(|i| i as f64 * 0.1)
        .find(|&t| signal.g(t) > 0.6 && signal.g_and_rate(t).1 > 0.0)
        .unwrap();
    let g = signal.g(t_s);
    let model = Arc::new(Surrogate {
        a1: Arc::new(a1) as Arc<dyn SpatialField>,
        a2: Some(Arc::new(a2)),
        a3: Some(Arc::new(a3)),
        signal: signal.into(),
    });
    (stylet_render::scene::MotionHook { model, t_s }, g)
}
