//! GPU MPR against the CPU's (`stylet_render::mpr::render_spec`): the three standard planes and
//! the oblique plane along a needle, on the phantom (float CT) and the synthetic atlas (16-bit CT),
//! pixels and labels. Fails when there is no adapter (CI installs lavapipe).

use crate::common::*;
use stylet_physics::deform::{self, DeformSettings, ToolPoint};
use stylet_physics::glam::DVec3;
use stylet_render::image::{Tolerance, diff};
use stylet_render::mpr::{Plane, SliceSpec, Window, render_spec, render_spec_deformed, render_spec_moving};
use stylet_render_gpu::{CtFormat, GpuMpr};

/// Both sides compute the same f32 index frame, trilinear value, window and blend; only the
/// shader compiler's rounding (fused multiply-adds) differs. A grey level sitting on a .5
/// boundary may round the other way (1 level); a pixel centre on the exact half-voxel boundary
/// between two labels may pick the other label (its overlay colour and its neighbours' edge
/// flags change: a large but rare difference). Labels must agree on ≥ 99.9 % of pixels.
/// (Measured on lavapipe: identical on every slice here.)
const MPR: Tolerance = Tolerance {
    mean: 0.02,
    p99: 0,
    max: 255,
};

fn check(name: &str, both: &Both, spec: &SliceSpec) {
    let mut mpr = GpuMpr::new(ctx());
    let t = std::time::Instant::now();
    let gpu = mpr
        .render(ctx(), &both.gpu, spec)
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let t_gpu = t.elapsed().as_secs_f64();
    let cpu = render_spec(&both.cpu.atlas, spec).unwrap();
    let d = diff(&gpu.to_image(), &cpu.to_image()).unwrap();
    let n = gpu.labels.len();
    let label_diff = gpu.labels.iter().zip(&cpu.labels).filter(|(a, b)| a != b).count();
    let labelled = cpu.labels.iter().filter(|&&l| l != 0).count();
    println!(
        "{name} ({}×{}): {d}; labels differ on {label_diff} of {n} pixels ({labelled} labelled); GPU {:.0} ms",
        spec.width,
        spec.height,
        t_gpu * 1e3
    );
    let dir = std::env::temp_dir().join("stylet-gpu");
    std::fs::create_dir_all(&dir).unwrap();
    gpu.to_image()
        .write_png(&dir.join(format!("mpr-{name}-gpu.png")))
        .unwrap();
    cpu.to_image()
        .write_png(&dir.join(format!("mpr-{name}-cpu.png")))
        .unwrap();
    assert!(MPR.admits(&d), "{name}: {d}");
    assert!(
        label_diff * 1000 <= n,
        "{name}: labels differ on {label_diff} of {n} pixels"
    );
    // Not a blank image: the window shows tissue.
    let grey = gpu.rgb.iter().filter(|p| p[0] > 30 && p[0] < 225).count();
    assert!(grey * 10 > n, "{name}: only {grey} of {n} pixels show tissue");
}

fn slices(name: &str, both: &Both, centre: DVec3) {
    let atlas = &both.cpu.atlas;
    for plane in [Plane::Axial, Plane::Coronal, Plane::Sagittal] {
        let spec = SliceSpec::plane(atlas, plane, centre, Window::ABDOMEN, 256);
        check(&format!("{name}-{}", plane.name()), both, &spec);
    }
    // The oblique plane along a needle entering from anterior right, 30° off vertical.
    let tangent = DVec3::new(-0.4, -0.8, -0.45);
    let spec = SliceSpec::oblique_along_needle(centre, tangent, 0.8, 240, 200, Window::ABDOMEN).unwrap();
    check(&format!("{name}-oblique"), both, &spec);
}

#[test]
fn mpr_matches_the_cpu_on_the_phantom() {
    let b = phantom();
    let g = b.cpu.atlas.ct().grid();
    let (lo, hi) = g.world_bounds();
    slices("phantom", b, (lo + hi) * 0.5);
}

#[test]
fn mpr_matches_the_cpu_on_a_16_bit_ct() {
    let b = small();
    assert_eq!(b.gpu.ct_format(), CtFormat::Int16);
    slices("small", b, DVec3::new(20.0, 5.0, 10.0));
}

#[test]
fn mpr_matches_the_cpu_on_a_float_ct() {
    let b = small_float();
    assert_eq!(b.gpu.ct_format(), CtFormat::Float32);
    slices("float", b, DVec3::new(20.0, 5.0, 10.0));
}

#[test]
fn mpr_matches_the_cpu_with_the_ct_in_a_texture_or_a_buffer() {
    for (name, b) in placements() {
        let spec = SliceSpec::oblique_along_needle(
            DVec3::new(20.0, 5.0, 10.0),
            DVec3::new(-0.4, -0.8, -0.45),
            0.7,
            120,
            100,
            Window::ABDOMEN,
        )
        .unwrap();
        check(&format!("placement-{name}"), b, &spec);
    }
}

#[test]
fn a_bad_slice_is_a_named_error() {
    let b = small();
    let mut spec = SliceSpec::plane(&b.cpu.atlas, Plane::Axial, DVec3::ZERO, Window::ABDOMEN, 64);
    spec.width = 0;
    let mut mpr = GpuMpr::new(ctx());
    assert!(matches!(
        mpr.render(ctx(), &b.gpu, &spec),
        Err(stylet_render_gpu::GpuError::Invalid(_))
    ));
}

/// A deformed moment: the GPU slice reads the CT and the labels at each pixel's reference point
/// and colours the displacement as the CPU's `render_spec_deformed` does. The fixed point runs in
/// `f32` on the GPU and `f64` on the CPU, so reference points differ by ~10⁻⁵ mm: a grey level or
/// a colour channel on a .5 boundary may round the other way, and a pixel on a label boundary may
/// pick the other label.
#[test]
fn a_deformed_slice_matches_the_cpu() {
    let b = phantom();
    let atlas = &b.cpu.atlas;
    // The anterior skin above (20, ·, 20): the first voxel from anterior that is not air.
    let skin_y = (0..400)
        .map(|i| 200.0 - 0.5 * f64::from(i))
        .find(|&y| atlas.hu_at(DVec3::new(20.0, y, 20.0)) > -300.0)
        .expect("skin above the body");
    // A fingertip-sized patch pressed 5 mm in, held for ten frames.
    let mut points = Vec::new();
    for dx in [-3.0, 0.0, 3.0] {
        for dz in [-3.0, 0.0, 3.0] {
            points.push(ToolPoint {
                reference_mm: DVec3::new(20.0 + dx, skin_y, 20.0 + dz),
                displacement_mm: DVec3::new(0.0, -5.0, 0.0),
                radius_mm: 1.5,
            });
        }
    }
    let s = DeformSettings::on();
    let centre = DVec3::new(20.0, skin_y - 5.0, 20.0);
    let mut field = deform::solve(atlas, &s, None, centre, &points);
    for _ in 0..9 {
        field = deform::solve(atlas, &s, Some(&field), centre, &points);
    }
    assert!(field.max_displacement_mm() > 4.0, "{}", field.max_displacement_mm());
    let mut mpr = GpuMpr::new(ctx());
    for (name, spec) in [
        (
            "axial",
            SliceSpec::plane(atlas, Plane::Axial, centre, Window::ABDOMEN, 256),
        ),
        (
            "sagittal",
            SliceSpec::plane(atlas, Plane::Sagittal, centre, Window::ABDOMEN, 256),
        ),
        (
            "oblique",
            SliceSpec::oblique_along_needle(centre, DVec3::new(0.2, -1.0, 0.1), 0.25, 240, 200, Window::ABDOMEN)
                .unwrap(),
        ),
    ] {
        let gpu = mpr
            .render_deformed(ctx(), &b.gpu, &spec, &field)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let cpu = render_spec_deformed(atlas, &spec, &field).unwrap();
        let undeformed = render_spec(atlas, &spec).unwrap();
        let d = diff(&gpu.to_image(), &cpu.to_image()).unwrap();
        let moved = diff(&undeformed.to_image(), &cpu.to_image()).unwrap();
        let n = gpu.labels.len();
        let label_diff = gpu.labels.iter().zip(&cpu.labels).filter(|(a, b)| a != b).count();
        println!("deformed {name}: GPU vs CPU {d}, labels differ on {label_diff} of {n}; deformed vs not {moved}");
        let dir = std::env::temp_dir().join("stylet-gpu");
        std::fs::create_dir_all(&dir).unwrap();
        gpu.to_image()
            .write_png(&dir.join(format!("mpr-deformed-{name}-gpu.png")))
            .unwrap();
        cpu.to_image()
            .write_png(&dir.join(format!("mpr-deformed-{name}-cpu.png")))
            .unwrap();
        // The deformation shows (colour map, moved tissue): hundreds of pixels change clearly.
        let changed = (undeformed.rgb.iter().zip(&cpu.rgb))
            .filter(|(a, b)| (0..3).any(|k| a[k].abs_diff(b[k]) > 20))
            .count();
        assert!(
            changed > 200,
            "{name}: the deformation changes only {changed} pixels: {moved}"
        );
        assert!(DEFORMED.admits(&d), "{name}: {d}");
        assert!(
            label_diff * 1000 <= n,
            "{name}: labels differ on {label_diff} of {n} pixels"
        );
    }
}

/// GPU against CPU for deformed slices (see `a_deformed_slice_matches_the_cpu`).
const DEFORMED: Tolerance = Tolerance {
    mean: 0.05,
    p99: 1,
    max: 255,
};

/// The coronal slice through the phantom's centre at the moment of `hook` on both renderers:
/// the GPU matches the CPU's `render_spec_moving` and differs from the still slice.
fn check_moving_slice(name: &str, hook: &stylet_render::scene::MotionHook, g: f64) {
    let both = phantom();
    let atlas = &both.cpu.atlas;
    assert!(stylet_render_gpu::draws_breathing(hook.model.as_ref(), hook.t_s));
    let (lo, hi) = atlas.ct().grid().world_bounds();
    let spec = SliceSpec::plane(atlas, Plane::Coronal, (lo + hi) * 0.5, Window::ABDOMEN, 256);
    let mut mpr = GpuMpr::new(ctx());
    let gpu = mpr.render_moving(ctx(), &both.gpu, &spec, Some(hook), None).unwrap();
    let cpu = render_spec_moving(atlas, &spec, Some(hook), None).unwrap();
    let d = diff(&gpu.to_image(), &cpu.to_image()).unwrap();
    let label_diff = gpu.labels.iter().zip(&cpu.labels).filter(|(a, b)| a != b).count();
    let still = mpr.render(ctx(), &both.gpu, &spec).unwrap();
    let moved = gpu.rgb.iter().zip(&still.rgb).filter(|(a, b)| a != b).count();
    println!("{name} coronal (g = {g:.3}): {d}; labels differ on {label_diff}; {moved} pixels moved");
    let dir = std::env::temp_dir().join("stylet-gpu");
    std::fs::create_dir_all(&dir).unwrap();
    gpu.to_image()
        .write_png(&dir.join(format!("mpr-{name}-gpu.png")))
        .unwrap();
    assert!(MPR.admits(&d), "{d}");
    assert!(label_diff * 1000 <= gpu.labels.len(), "labels differ on {label_diff}");
    assert!(moved > 2000, "only {moved} pixels moved with the breath");
}

/// A slice of the breathing phantom (each pixel's world point inverted through u(X, t), thesis
/// §5.4.1): the synthetic motion, one factored field.
#[test]
fn a_breathing_slice_matches_the_cpu() {
    let (hook, g) = breathing_hook(phantom());
    check_moving_slice("breathing", &hook, g);
}

/// A slice of the phantom breathing with measured fields (three grid fields, each on its own
/// grid, weighted by g, g′ and 1).
#[test]
fn a_slice_breathing_with_measured_fields_matches_the_cpu() {
    let (hook, g) = measured_hook(phantom());
    check_moving_slice("measured", &hook, g);
}
