//! The GPU ray caster against the CPU reference (docs/rendering.md): the same scene drawn by both,
//! per-pixel difference statistics within a stated tolerance, for each preset-like transfer
//! function, each tagging mode with a clip plane, the tools, half resolution and the speed
//! switches, on a small synthetic atlas and on the phantom.
//!
//! These tests run on whatever adapter wgpu finds (lavapipe on CI and on machines without a
//! GPU) and fail when there is none.

use crate::common::*;
use stylet_physics::ProbeKind;
use stylet_physics::glam::{Quat, Vec3};
use stylet_render::image::Tolerance;
use stylet_render::scene::{ClipPlane, Quality, Scene, Tagging};
use stylet_render::tools::{FingerShape, NeedleShape, ProbeShape, ToolState};
use stylet_render_gpu::{CtPlacement, GpuError, GpuVolume, RecordFilter, UploadOptions};

/// GPU against CPU. Both run the same f32 formulas in the same order; what differs is the
/// rounding of the shader compiler (fused multiply-adds, pow, normalize, sqrt and division to
/// within a few ulp on Vulkan). A few-ulp change in a sample's index coordinate or opacity moves
/// an 8-bit channel by at most 1 almost everywhere (mean, p99); where it flips a discrete
/// decision (a lattice point on the exact edge of the volume, a leaping cell or the clip plane; a
/// label's nearest voxel on the plane; a tool's silhouette) one pixel may differ more (max).
const GPU_CPU: Tolerance = Tolerance {
    mean: 0.1,
    p99: 1,
    max: 64,
};

#[test]
fn transfer_functions_match_the_cpu_on_the_synthetic_atlas() {
    let b = small();
    for (name, tf) in transfer_functions() {
        compare(&format!("small-{name}"), b, &scene(&b.cpu, tf), 160, 132, GPU_CPU);
    }
}

#[test]
fn a_float_ct_matches_the_cpu() {
    let b = small_float();
    assert_eq!(b.gpu.ct_format(), stylet_render_gpu::CtFormat::Float32);
    for (name, tf) in transfer_functions() {
        let mut s = scene(&b.cpu, tf);
        s.clip = Some(ClipPlane::through_tool(Vec3::new(20.0, 5.0, 10.0), Vec3::Z, &s.camera));
        s.tagging = Tagging::Risk;
        compare(&format!("float-{name}"), b, &s, 160, 132, GPU_CPU);
    }
}

#[test]
fn ct_in_a_texture_or_a_buffer_16_bit_or_float_matches_the_cpu() {
    for (name, b) in placements() {
        assert_eq!(b.gpu.ct_in_buffer(), name.ends_with("buffer"));
        let mut s = scene(&b.cpu, transfer_functions().swap_remove(1).1);
        s.clip = Some(ClipPlane::through_tool(Vec3::new(20.0, 5.0, 10.0), Vec3::Z, &s.camera));
        s.tagging = Tagging::Labels;
        compare(&format!("placement-{name}"), b, &s, 120, 100, GPU_CPU);
    }
}

/// Hook of eq. 3.1.1: a deformed sub-image J on its own (offset, finer) grid replaces the CT
/// inside Ω_J, with leaping treating Ω_J as occupied.
#[test]
fn a_deformed_region_matches_the_cpu() {
    use stylet_physics::glam::DVec3;
    use stylet_physics::{Affine, Grid, Volume};
    let b = small();
    let g = Grid::new(
        [14, 12, 10],
        Affine::from_spacing([1.5; 3], DVec3::new(5.0, -10.0, 0.0)),
    )
    .unwrap();
    let data: Vec<f32> = (0..g.len())
        .map(|i| {
            let [x, y, z] = g.unlinear(i);
            if (x + y + z) % 5 == 0 {
                1000.0
            } else {
                40.0 + x as f32 * 3.0
            }
        })
        .collect();
    let mut s = scene(&b.cpu, transfer_functions().swap_remove(1).1);
    s.deformed = Some(stylet_render::scene::DeformedRegion {
        volume: std::sync::Arc::new(Volume::new(g, data).unwrap()),
    });
    compare("small-deformed", b, &s, 160, 132, GPU_CPU);
    s.quality.leaping = false;
    compare("small-deformed-noleap", b, &s, 160, 132, GPU_CPU);
}

#[test]
fn tagging_modes_with_a_clip_plane_match_the_cpu() {
    let b = small();
    let (_, tf) = transfer_functions().swap_remove(1);
    let mut s = scene(&b.cpu, tf);
    // A plane through the target's centre facing the camera: the cut shows target and vessel.
    s.clip = Some(ClipPlane::through_tool(Vec3::new(20.0, 5.0, 10.0), Vec3::Z, &s.camera));
    for tagging in Tagging::ALL {
        s.tagging = tagging;
        compare(&format!("small-clip-{}", tagging.as_str()), b, &s, 160, 132, GPU_CPU);
    }
}

#[test]
fn speed_switches_and_half_resolution_match_the_cpu() {
    let b = small();
    let (_, tf) = transfer_functions().swap_remove(1);
    let step = 1.0;
    let cases = [
        ("naive", Quality::naive(step)),
        (
            "raybox",
            Quality {
                leaping: false,
                early_termination: false,
                ..Quality::fast(step)
            },
        ),
        (
            "leap16",
            Quality {
                occupancy_cells: 16,
                early_termination: false,
                ..Quality::fast(step)
            },
        ),
        (
            "leap128",
            Quality {
                occupancy_cells: 128,
                ..Quality::fast(step)
            },
        ),
        (
            "nojitter",
            Quality {
                jitter: false,
                ..Quality::fast(step)
            },
        ),
        (
            "half",
            Quality {
                half_resolution: true,
                ..Quality::fast(step)
            },
        ),
    ];
    for (name, q) in cases {
        let mut s = scene(&b.cpu, tf.clone());
        s.quality = q;
        compare(&format!("small-{name}"), b, &s, 161, 133, GPU_CPU);
    }
}

/// `RecordFilter::Hardware`: the texture unit interpolates the records (one filtered read of
/// `Rgba16Snorm` instead of eight loads). The voxel values are the CPU's exactly; the trilinear
/// weights have the filter's precision (1/256 voxel on NVIDIA and AMD), so a sample may move by
/// up to 1/512 of the step between neighbouring voxels, which across a 1000 HU bone edge is 2 HU:
/// more pixels move by a level than with the shader's own blend. Measured on an H200 (chest CT,
/// docs/rendering.md "GPU on hardware"): mean 0.06–0.07, p99 1, max 8–13; lavapipe's weights are
/// full floats (mean 0.000, max 1). The tolerance allows twice the hardware's mean and one level
/// more at p99; a records scale off by 9 % already fails it (mean 0.33, p99 4).
const FILTERED: Tolerance = Tolerance {
    mean: 0.15,
    p99: 2,
    max: 64,
};

#[test]
fn hardware_filtered_records_match_the_cpu() {
    assert!(
        ctx().has_16bit_norm(),
        "the adapter lacks 16-bit normalised textures (lavapipe and every desktop GPU have them)"
    );
    let hardware = UploadOptions {
        placement: CtPlacement::Texture,
        records: RecordFilter::Hardware,
    };
    let b = synthetic_upload(48, 2.0, body, body_labels, hardware);
    assert_eq!(b.gpu.record_filter(), RecordFilter::Hardware);
    for (name, tf) in transfer_functions() {
        compare(&format!("filtered-{name}"), &b, &scene(&b.cpu, tf), 160, 132, FILTERED);
    }
    let mut s = scene(&b.cpu, transfer_functions().swap_remove(1).1);
    s.clip = Some(ClipPlane::through_tool(Vec3::new(20.0, 5.0, 10.0), Vec3::Z, &s.camera));
    s.tagging = Tagging::Risk;
    s.tools = tools();
    compare("filtered-clip-tools", &b, &s, 160, 132, FILTERED);
    s.quality = Quality::naive(1.0);
    compare("filtered-naive", &b, &s, 160, 132, FILTERED);
}

/// Hardware filtering asked for where it cannot be had is a named error, never a silent
/// fallback: fractional CT values (float records) or records in a storage buffer.
#[test]
fn hardware_filtering_where_it_cannot_be_had_is_refused() {
    let hardware = |placement| UploadOptions {
        placement,
        records: RecordFilter::Hardware,
    };
    let err = |cpu: &stylet_render::volume::RenderVolume, placement| match GpuVolume::upload_with(
        ctx(),
        cpu,
        hardware(placement),
    ) {
        Err(GpuError::Invalid(m)) => m,
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("hardware filtering accepted"),
    };
    let m = err(&small_float().cpu, CtPlacement::Texture);
    assert!(m.contains("fractional values"), "{m}");
    let m = err(&small().cpu, CtPlacement::Buffer);
    assert!(m.contains("storage buffer"), "{m}");
    // The default on a software adapter stays with the shader's exact blend.
    if ctx().adapter().device_type == "Cpu" {
        assert_eq!(small().gpu.record_filter(), RecordFilter::Shader);
    }
}

/// Frame times come from the GPU's own clock where the adapter has one: the pass of a 161 × 133
/// frame takes a positive, finite time; without a clock there is no time rather than a made-up one.
#[test]
fn the_gpu_times_its_own_ray_casting_pass() {
    let b = small();
    let (_, tf) = transfer_functions().swap_remove(1);
    let mut s = scene(&b.cpu, tf);
    s.quality = Quality::naive(0.5);
    let mut r = renderer().lock().unwrap_or_else(|e| e.into_inner());
    for _ in 0..2 {
        // The first pass may include the driver's compilation of the shader.
        r.render(ctx(), &b.gpu, &s, 161, 133).unwrap();
    }
    let pass_ms = r.last_pass_ms();
    eprintln!("adapter timestamps: {}, pass: {pass_ms:?} ms", ctx().has_timestamps());
    if !ctx().has_timestamps() {
        assert_eq!(pass_ms, None, "no clock, no time");
        return;
    }
    let ms = pass_ms.expect("an adapter with timestamps times the pass");
    assert!(ms.is_finite() && ms > 0.0, "pass time {ms} ms");
}

/// A needle entering the body toward the target, the fingertip beside it and a linear probe on
/// the surface; a light from the camera's upper right so their shadows fall on the body.
fn tools() -> ToolState {
    let tip = Vec3::new(16.0, 20.0, 10.0);
    let hub = Vec3::new(30.0, 70.0, 25.0);
    let nodes_mm = (0..=10).map(|i| hub + (tip - hub) * (i as f32 / 10.0)).collect();
    ToolState {
        lines: Vec::new(),
        needle: Some(NeedleShape {
            nodes_mm,
            diameter_mm: 1.27,
            hub_length_mm: 20.0,
            hub_diameter_mm: 4.0,
        }),
        finger: Some(FingerShape {
            center_mm: Vec3::new(-10.0, 48.0, 0.0),
            radius_mm: 8.0,
        }),
        probe: Some(ProbeShape {
            kind: ProbeKind::Linear,
            position_mm: Vec3::new(-20.0, 30.0, -25.0),
            // Pressing along −y (into the body from anterior).
            orientation: Quat::from_rotation_arc(Vec3::Z, -Vec3::Y),
        }),
    }
}

/// The tools (needle, fingertip, linear and convex probe) and their shadows (Alg. 3.1, 3.2) drawn
/// by both renderers: a plain comparison, tools and shadows on; then the shadows only darken.
#[test]
fn tools_and_their_shadows_match_the_cpu() {
    let b = small();
    let (_, tf) = transfer_functions().swap_remove(1);
    let (w, h) = (160u32, 132u32);
    for kind in [ProbeKind::Linear, ProbeKind::Convex] {
        let mut s = scene(&b.cpu, tf.clone());
        s.tools = tools();
        s.tools.probe = Some(ProbeShape {
            kind,
            ..s.tools.probe.unwrap()
        });
        compare(&format!("tools-{kind:?}"), b, &s, w, h, GPU_CPU);
        let shadowed = render_gpu(b, &s, w, h);
        s.light.shadow_in = 1.0;
        compare(&format!("tools-{kind:?}-no-shadow"), b, &s, w, h, GPU_CPU);
        let unshadowed = render_gpu(b, &s, w, h);
        let (mut darker, mut brighter) = (0, 0);
        for (p, q) in shadowed.rgba.iter().zip(&unshadowed.rgba) {
            let (sp, sq) = (
                p[0] as u32 + p[1] as u32 + p[2] as u32,
                q[0] as u32 + q[1] as u32 + q[2] as u32,
            );
            if sp + 3 < sq {
                darker += 1;
            } else if sp > sq + 3 {
                brighter += 1;
            }
        }
        println!("tools {kind:?}: shadows darken {darker} pixels, brighten {brighter}");
        assert!(
            darker > 50 && brighter == 0,
            "{kind:?}: {darker} darker, {brighter} brighter"
        );
    }
}

#[test]
fn the_phantom_matches_the_cpu_per_transfer_function_and_tagging() {
    let b = phantom();
    for (name, tf) in transfer_functions() {
        compare(&format!("phantom-{name}"), b, &scene(&b.cpu, tf), 320, 264, GPU_CPU);
    }
    let (_, tf) = transfer_functions().swap_remove(1);
    let mut s = scene(&b.cpu, tf);
    let (lo, hi) = bounds(&b.cpu);
    s.clip = Some(ClipPlane::through_tool((lo + hi) * 0.5, Vec3::Z, &s.camera));
    for tagging in Tagging::ALL {
        s.tagging = tagging;
        compare(&format!("phantom-clip-{}", tagging.as_str()), b, &s, 320, 264, GPU_CPU);
    }
    s.quality.half_resolution = true;
    compare("phantom-clip-labels-half", b, &s, 320, 264, GPU_CPU);
}

#[test]
fn bad_input_gets_a_named_error() {
    let b = small();
    let (_, tf) = transfer_functions().swap_remove(0);
    let s = scene(&b.cpu, tf);
    let mut r = renderer().lock().unwrap_or_else(|e| e.into_inner());
    assert!(matches!(r.render(ctx(), &b.gpu, &s, 0, 10), Err(GpuError::Invalid(_))));
    let mut bad = s.clone();
    bad.quality.step_mm = 0.0;
    assert!(matches!(r.render(ctx(), &b.gpu, &bad, 8, 8), Err(GpuError::Invalid(_))));
    let mut bad = s.clone();
    bad.transfer = stylet_render::transfer::TransferFunction::Trapezoids(vec![]);
    assert!(matches!(r.render(ctx(), &b.gpu, &bad, 8, 8), Err(GpuError::Invalid(_))));
    // A motion that never moves is the still patient.
    let mut moving = s.clone();
    moving.motion = Some(stylet_render::scene::MotionHook {
        model: std::sync::Arc::new(stylet_physics::motion::Static),
        t_s: 0.0,
    });
    assert_eq!(
        r.render(ctx(), &b.gpu, &moving, 40, 30).unwrap(),
        r.render(ctx(), &b.gpu, &s, 40, 30).unwrap()
    );
}

/// The soft preset at the moment of `hook` on both renderers (fast switches): the GPU matches
/// the CPU and the frame differs from the still one. Returns the moving scene.
fn check_warped(name: &str, b: &Both, hook: stylet_render::scene::MotionHook, g: f64) -> Scene {
    let (_, tf) = transfer_functions().swap_remove(1);
    let still = scene(&b.cpu, tf);
    let mut s = still.clone();
    s.motion = Some(hook);
    println!("{name} g = {g:.3}");
    compare(&format!("phantom-{name}"), b, &s, 320, 264, GPU_CPU);
    let moved = render_gpu(b, &s, 320, 264);
    let at_rest = render_gpu(b, &still, 320, 264);
    let changed = moved.rgba.iter().zip(&at_rest.rgba).filter(|(a, b)| a != b).count();
    println!("{name} changes {changed} of {} pixels", moved.rgba.len());
    assert!(
        changed > 2000,
        "the {name} frame differs from the still one in {changed} pixels"
    );
    s
}

/// Rays warped by the breathing motion (eqs. 5.4.1–5.4.2) on the GPU against the CPU
/// reference: fast switches and naive, a clip plane with label tagging (its plane sample is
/// warped too), and the motion visible (the still frame differs).
#[test]
fn warped_rays_of_a_breathing_patient_match_the_cpu() {
    let b = phantom();
    let (hook, g) = breathing_hook(b);
    let mut s = check_warped("breathing", b, hook, g);
    let mut naive = s.clone();
    naive.quality = Quality::naive(s.quality.step_mm);
    compare("phantom-breathing-naive", b, &naive, 160, 132, GPU_CPU);
    let (lo, hi) = bounds(&b.cpu);
    s.clip = Some(ClipPlane::through_tool((lo + hi) * 0.5, Vec3::Z, &s.camera));
    s.tagging = Tagging::Labels;
    compare("phantom-breathing-clip-labels", b, &s, 320, 264, GPU_CPU);
}

/// Warped rays through measured fields (three grid fields on their own grids) match the CPU.
#[test]
fn warped_rays_through_measured_fields_match_the_cpu() {
    let b = phantom();
    let (hook, g) = measured_hook(b);
    check_warped("measured", b, hook, g);
}

/// A motion the GPU cannot draw (a surrogate model whose fields are neither one factored field
/// nor grid fields) is a named refusal, not a still picture.
#[test]
fn a_motion_the_gpu_cannot_draw_is_refused() {
    use std::sync::Arc;
    use stylet_physics::motion::{BreathingSettings, BreathingSignal, Surrogate, SyntheticField};
    let b = phantom();
    let settings = BreathingSettings::on();
    let a1 = Arc::new(SyntheticField::new(Arc::clone(&b.cpu.atlas), settings.motion).unwrap());
    let model = Arc::new(Surrogate {
        a1: a1.clone(),
        a2: Some(a1),
        a3: None,
        signal: BreathingSignal::new(settings.signal).unwrap().into(),
    });
    assert!(!stylet_render_gpu::draws_breathing(model.as_ref(), 1.0));
    let mut s = scene(&b.cpu, transfer_functions().swap_remove(0).1);
    s.motion = Some(stylet_render::scene::MotionHook { model, t_s: 1.0 });
    let err = renderer()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .render(ctx(), &b.gpu, &s, 64, 48)
        .unwrap_err();
    assert!(matches!(err, GpuError::Unsupported(_)), "{err}");
    assert!(err.to_string().contains("factored"), "{err}");
}
