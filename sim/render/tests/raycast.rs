//! The CPU reference ray caster against docs/rendering.md "One ray" on small synthetic atlases:
//! geometry (a sphere is a disc of the right size), speed-ups that change work but not the
//! picture, the clipping plane and its tagging, jitter, determinism, half resolution and the
//! two hooks (deformed region J, motion warp).

use std::sync::Arc;

use stylet_physics::glam::{DVec3, Vec3};
use stylet_physics::motion::MotionModel;
use stylet_physics::{Affine, Grid, Volume};
use stylet_render::image::{Image, Tolerance, diff};
use stylet_render::raycast::{RenderOutput, render};
use stylet_render::scene::{Camera, ClipPlane, DeformedRegion, Light, MotionHook, Quality, Scene, Tagging};
use stylet_render::synthetic::{self, TARGET, TUMOUR_RGBA};
use stylet_render::tools::{NeedleShape, ToolState};
use stylet_render::transfer::{TransferFunction, Trapezoid};
use stylet_render::volume::RenderVolume;

const BONE_HU: f32 = 1000.0;
const SOFT_HU: f32 = 40.0;

/// The synthetic atlas of [`synthetic::atlas`], prepared for rendering.
fn atlas(n: usize, spacing: f64, ct: impl Fn(DVec3) -> f32, partial: impl Fn(DVec3) -> u16) -> RenderVolume {
    RenderVolume::new(Arc::new(synthetic::atlas(n, spacing, ct, partial)))
}

fn trapezoid(tissue: &str, hu: [f32; 4], rgb: [f32; 3], opacity: f32) -> Trapezoid {
    Trapezoid {
        tissue: tissue.into(),
        hu,
        rgb,
        opacity,
        weight: 1.0,
    }
}

/// Soft tissue faint and reddish, bone nearly opaque and white.
fn soft_and_bone() -> TransferFunction {
    TransferFunction::Trapezoids(vec![
        trapezoid("soft", [-200.0, 0.0, 100.0, 150.0], [0.8, 0.4, 0.3], 0.04),
        trapezoid("bone", [200.0, 400.0, 3000.0, 3100.0], [1.0, 1.0, 0.95], 0.6),
    ])
}

const BACKGROUND: Vec3 = Vec3::new(0.1, 0.2, 0.3);

fn background_px() -> [u8; 4] {
    let c = |v: f32| (v * 255.0).round() as u8;
    [c(BACKGROUND.x), c(BACKGROUND.y), c(BACKGROUND.z), 255]
}

/// A camera in front (+y, anterior) looking at the origin from 150 mm with a 30° field of view.
fn front_camera() -> Camera {
    Camera::orbit(Vec3::ZERO, 150.0, 0.0, 0.0, 30.0)
}

fn scene(transfer: TransferFunction, quality: Quality) -> Scene {
    let camera = front_camera();
    Scene {
        camera,
        transfer,
        light: Light::over_shoulder(&camera),
        clip: None,
        tagging: Tagging::Off,
        quality,
        tools: ToolState::default(),
        background: BACKGROUND,
        deformed: None,
        motion: None,
    }
}

fn exact() -> Quality {
    Quality {
        jitter: false,
        ..Quality::fast(0.5)
    }
}

/// A bone sphere of radius `r` mm at `c` (a 4 mm linear ramp across the surface, so the
/// trilinear iso-surface at 0 HU is the sphere) in air.
fn bone_sphere(c: DVec3, r: f64) -> impl Fn(DVec3) -> f32 {
    move |p| (((r - (p - c).length()) / 4.0).clamp(-1.0, 1.0) * BONE_HU as f64) as f32
}

/// A soft-tissue body (radius 42 mm) with a bone sphere of 18 mm inside, air around.
fn body_with_bone(p: DVec3) -> f32 {
    let r = p.length();
    if r < 18.0 {
        BONE_HU
    } else if r < 42.0 {
        SOFT_HU
    } else {
        -1000.0
    }
}

/// A body (radius 42 mm) of textured tissue, 40 ± 200 HU in blobs of a few millimetres, with a
/// bone sphere of 12 mm: under [`patchy`] cells turn occupied and empty every few millimetres,
/// so leaping's jumps land right before visible samples.
fn textured_body(p: DVec3) -> f32 {
    let r = p.length();
    if r < 12.0 {
        BONE_HU
    } else if r < 42.0 {
        (40.0 + 200.0 * (p.x / 4.0).sin() * (p.y / 5.0).sin() * (p.z / 3.0).sin()) as f32
    } else {
        -1000.0
    }
}

/// Only the texture's peaks (100 … 300 HU) and bone are visible.
fn patchy() -> TransferFunction {
    TransferFunction::Trapezoids(vec![
        trapezoid("peaks", [100.0, 150.0, 250.0, 300.0], [0.9, 0.5, 0.3], 0.3),
        trapezoid("bone", [500.0, 600.0, 3000.0, 3100.0], [1.0, 1.0, 0.95], 0.6),
    ])
}

fn count_not_background(img: &Image) -> usize {
    img.rgba.iter().filter(|&&p| p != background_px()).count()
}

#[test]
fn a_bone_sphere_is_a_disc_of_the_expected_radius() {
    let v = atlas(48, 2.0, bone_sphere(DVec3::ZERO, 25.0), |_| 0);
    let tf = TransferFunction::Trapezoids(vec![trapezoid("bone", [0.0, 1.0, 3000.0, 3001.0], [1.0; 3], 1.0)]);
    let out = render(&v, &scene(tf, exact()), 128, 128);
    // Silhouette of a sphere of radius R seen from distance D: angular radius asin(R/D).
    let r_px = (25.0f64 / 150.0).asin().tan() / 15f64.to_radians().tan() * 64.0;
    let want = std::f64::consts::PI * r_px * r_px;
    let got = count_not_background(&out.image) as f64;
    eprintln!("disc: {got} pixels, expected {want:.0}");
    assert!(
        (got / want - 1.0).abs() < 0.03,
        "disc of {got} pixels, expected {want:.0}"
    );
    // The corners are background, the centre is bone.
    assert_eq!(out.image.get(0, 0), background_px());
    assert_eq!(out.image.get(127, 127), background_px());
    let centre = out.image.get(64, 64);
    assert!(centre[0] > 100 && centre[0] == centre[1], "centre {centre:?}");
}

#[test]
fn speed_ups_change_the_work_not_the_picture() {
    let v = atlas(48, 2.0, textured_body, |_| 0);
    let run = |q: Quality| render(&v, &scene(patchy(), q), 96, 96);
    let base = Quality {
        ray_box: false,
        leaping: false,
        early_termination: false,
        ..exact()
    };
    let naive = run(base);
    let boxed = run(Quality { ray_box: true, ..base });
    // Ray/box removes only samples outside the volume (air): the same picture, exactly.
    assert_eq!(diff(&naive.image, &boxed.image).unwrap().max, 0);
    assert!(boxed.samples < naive.samples, "{} vs {}", boxed.samples, naive.samples);
    for cells in [16, 64, 128] {
        let leap = run(Quality {
            ray_box: true,
            leaping: true,
            occupancy_cells: cells,
            ..base
        });
        let d = diff(&boxed.image, &leap.image).unwrap();
        eprintln!("leaping {cells}³: {d}; samples {} vs {}", leap.samples, boxed.samples);
        // Leaping skips only samples that read α = 0 (cells, then voxel cubes): exactly.
        assert_eq!(d.max, 0, "leaping with {cells}³ cells: {d}");
        assert!(
            leap.samples < boxed.samples,
            "{cells}³: {} vs {}",
            leap.samples,
            boxed.samples
        );
    }
    // Leaping without ray/box (per-sample cell look-ups instead of the bricks): exact too.
    let leap_naive = run(Quality { leaping: true, ..base });
    assert_eq!(diff(&naive.image, &leap_naive.image).unwrap().max, 0);
    assert!(leap_naive.samples < naive.samples);
    let et = run(Quality {
        ray_box: true,
        early_termination: true,
        ..base
    });
    // Stopping at A ≥ 0.99 leaves at most 1 % of the remaining light: ≤ 3 grey levels.
    let d = diff(&boxed.image, &et.image).unwrap();
    eprintln!("early termination: {d}; samples {} vs {}", et.samples, boxed.samples);
    eprintln!("ray/box: samples {} vs naive {}", boxed.samples, naive.samples);
    let tol = Tolerance {
        mean: 0.5,
        p99: 3,
        max: 3,
    };
    assert!(tol.admits(&d), "early termination: {d}");
    assert!(et.samples < boxed.samples, "{} vs {}", et.samples, boxed.samples);
    // Everything on against everything off, naive rays from the eye.
    let fast = run(exact());
    let d = diff(&naive.image, &fast.image).unwrap();
    eprintln!("all on vs naive: {d}; samples {} vs {}", fast.samples, naive.samples);
    assert!(tol.admits(&d), "all speed-ups: {d}");
    assert!(
        fast.samples * 3 < naive.samples,
        "{} vs {}",
        fast.samples,
        naive.samples
    );
}

/// Front block (y 10 … 30, camera side) bone-red, back block (y −30 … −10) green.
fn two_blocks(p: DVec3) -> f32 {
    let in_xz = p.x.abs() < 20.0 && p.z.abs() < 20.0;
    if in_xz && (10.0..30.0).contains(&p.y) {
        BONE_HU
    } else if in_xz && (-30.0..-10.0).contains(&p.y) {
        300.0
    } else {
        -1000.0
    }
}

fn red_green() -> TransferFunction {
    TransferFunction::Trapezoids(vec![
        trapezoid("red", [800.0, 900.0, 1100.0, 1200.0], [1.0, 0.0, 0.0], 0.5),
        trapezoid("green", [200.0, 250.0, 350.0, 400.0], [0.0, 1.0, 0.0], 0.5),
    ])
}

fn reddish(p: [u8; 4]) -> bool {
    p[0] as i32 > p[1] as i32 + 30
}

#[test]
fn a_clipped_image_has_nothing_in_front_of_the_plane() {
    let v = atlas(48, 2.0, two_blocks, |_| 0);
    let mut s = scene(red_green(), exact());
    let open = render(&v, &s, 96, 96).image;
    let red_open = open.rgba.iter().filter(|&&p| reddish(p)).count();
    assert!(
        red_open > 500,
        "the front block shows without the plane ({red_open} pixels)"
    );
    // Visible half y ≤ 0: the front block is hidden, the back block shows through.
    s.clip = Some(ClipPlane {
        point_mm: Vec3::ZERO,
        normal: -Vec3::Y,
    });
    for q in [exact(), Quality::naive(0.5)] {
        s.quality = q;
        let clipped = render(&v, &s, 96, 96).image;
        let red = clipped.rgba.iter().filter(|&&p| reddish(p)).count();
        assert_eq!(red, 0, "{q:?}: front block visible in front of the plane");
        let green = clipped.rgba.iter().filter(|&&p| p[1] as i32 > p[0] as i32 + 30).count();
        assert!(green > 500, "the back block shows behind the plane ({green} pixels)");
    }
    // A plane whose visible half (y ≥ 60) lies behind the eye's view of the volume: every ray's
    // path through the volume is hidden, so every pixel is background.
    s.quality = exact();
    s.clip = Some(ClipPlane {
        point_mm: Vec3::new(0.0, 60.0, 0.0),
        normal: Vec3::Y,
    });
    let hidden = render(&v, &s, 64, 64);
    assert!(hidden.image.rgba.iter().all(|&p| p == background_px()));
    assert_eq!(hidden.samples, 0);
}

#[test]
fn tagging_colours_the_plane_per_eqs_3_2_4_and_3_2_5() {
    // Soft tissue everywhere in a 40 mm ball, the target a 12 mm ball at the centre (partial
    // label), a bone block at x 20 … 30 (heuristic label bone → risk class).
    let ct = |p: DVec3| {
        if (20.0..30.0).contains(&p.x) && p.z.abs() < 10.0 && p.y.abs() < 10.0 {
            BONE_HU
        } else if p.length() < 40.0 {
            SOFT_HU
        } else {
            -1000.0
        }
    };
    let v = atlas(48, 2.0, ct, |p| if p.length() < 12.0 { TARGET } else { 0 });
    let soft_rgb = [0.8f32, 0.4, 0.3];
    let bone_rgb = [1.0f32, 1.0, 0.95];
    // Opacity 1 on the plateaus: the plane sample alone makes the pixel opaque.
    let tf = TransferFunction::Trapezoids(vec![
        trapezoid("soft", [-100.0, 0.0, 100.0, 150.0], soft_rgb, 1.0),
        trapezoid("bone", [200.0, 400.0, 3000.0, 3100.0], bone_rgb, 1.0),
    ]);
    let mut s = scene(tf, exact());
    s.clip = Some(ClipPlane {
        point_mm: Vec3::ZERO,
        normal: -Vec3::Y,
    });
    let (w, h) = (96u32, 96u32);
    // Pixel of a world point on the plane y = 0.
    let pixel_of = |p: Vec3| {
        let (right, up, forward) = s.camera.basis();
        let d = p - s.camera.eye_mm;
        let tan_half = (s.camera.fov_y_deg.to_radians() * 0.5).tan();
        let x = d.dot(right) / d.dot(forward) / tan_half;
        let y = d.dot(up) / d.dot(forward) / tan_half;
        (((x + 1.0) * 0.5 * w as f32) as u32, ((1.0 - y) * 0.5 * h as f32) as u32)
    };
    let (tc, tr) = pixel_of(Vec3::ZERO);
    let (bc, br) = pixel_of(Vec3::new(25.0, 0.0, 0.0));
    let (oc, or) = pixel_of(Vec3::new(-25.0, 0.0, 0.0));
    let to8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as i32;
    let close = |got: [u8; 4], want: [f32; 3], what: &str| {
        for ch in 0..3 {
            assert!(
                (got[ch] as i32 - to8(want[ch])).abs() <= 1,
                "{what}: got {got:?}, want {want:?}"
            );
        }
    };

    s.tagging = Tagging::Risk;
    let img = render(&v, &s, w, h).image;
    // v₂ = 0.5·c(s) + (0, 0.5, 0, 0.5) on the target; + (0.5, 0, 0.2, 0.5) on risk (bone).
    close(
        img.get(tc, tr),
        [0.5 * soft_rgb[0], 0.5 * soft_rgb[1] + 0.5, 0.5 * soft_rgb[2]],
        "target",
    );
    close(
        img.get(bc, br),
        [0.5 * bone_rgb[0] + 0.5, 0.5 * bone_rgb[1], 0.5 * bone_rgb[2] + 0.2],
        "risk",
    );
    // Other labels: v₁ = c(s), unshaded.
    close(img.get(oc, or), soft_rgb, "other");

    s.tagging = Tagging::Labels;
    let img = render(&v, &s, w, h).image;
    let t = TUMOUR_RGBA.map(|c| c as f32 / 255.0);
    close(img.get(tc, tr), [t[0], t[1], t[2]], "target label colour");
    close(
        img.get(bc, br),
        [240.0 / 255.0, 240.0 / 255.0, 230.0 / 255.0],
        "bone label colour",
    );

    s.tagging = Tagging::Off;
    let img = render(&v, &s, w, h).image;
    close(img.get(tc, tr), soft_rgb, "tagging off");
}

#[test]
fn jitter_changes_pixels_but_not_the_mean_brightness() {
    let v = atlas(48, 2.0, body_with_bone, |_| 0);
    // A coarse step so the lattice's position matters.
    let plain = render(
        &v,
        &scene(
            soft_and_bone(),
            Quality {
                jitter: false,
                ..Quality::fast(2.0)
            },
        ),
        96,
        96,
    );
    let jittered = render(&v, &scene(soft_and_bone(), Quality::fast(2.0)), 96, 96);
    let d = diff(&plain.image, &jittered.image).unwrap();
    eprintln!("jitter: {d}");
    assert!(d.max > 0, "jitter changed nothing");
    let mean = |img: &Image| {
        img.rgba
            .iter()
            .map(|p| p[0] as f64 + p[1] as f64 + p[2] as f64)
            .sum::<f64>()
            / (3 * img.rgba.len()) as f64
    };
    let (a, b) = (mean(&plain.image), mean(&jittered.image));
    assert!((a - b).abs() < 1.0, "mean brightness {a:.2} vs {b:.2}");
}

#[test]
fn renders_are_bit_identical_on_any_thread_count() {
    let v = atlas(40, 2.5, body_with_bone, |_| 0);
    let mut s = scene(soft_and_bone(), Quality::fast(0.7));
    s.clip = Some(ClipPlane::through_tool(
        Vec3::new(5.0, 0.0, 0.0),
        Vec3::new(0.3, -1.0, 0.2),
        &s.camera,
    ));
    s.tagging = Tagging::Risk;
    let a = render(&v, &s, 80, 64);
    let b = render(&v, &s, 80, 64);
    assert_eq!(a, b);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let c: RenderOutput = pool.install(|| render(&v, &s, 80, 64));
        assert_eq!(a, c, "{threads} threads");
    }
}

#[test]
fn half_resolution_is_close_to_full_resolution() {
    let v = atlas(48, 2.0, body_with_bone, |_| 0);
    let full = render(&v, &scene(soft_and_bone(), exact()), 128, 96);
    let half = render(
        &v,
        &scene(
            soft_and_bone(),
            Quality {
                half_resolution: true,
                ..exact()
            },
        ),
        128,
        96,
    );
    assert_eq!((half.image.width, half.image.height), (128, 96));
    let d = diff(&full.image, &half.image).unwrap();
    eprintln!("half resolution: {d}");
    // Edges blur by a pixel: small mean, larger differences only along silhouettes.
    // (Measured: mean 1.9, 99th percentile 10, max 19.)
    let tol = Tolerance {
        mean: 2.5,
        p99: 16,
        max: 40,
    };
    assert!(tol.admits(&d), "half resolution: {d}");
    assert!(half.samples * 3 < full.samples, "{} vs {}", half.samples, full.samples);
}

#[test]
fn a_deformed_region_replaces_the_ct_inside_its_grid() {
    let v = atlas(48, 2.0, body_with_bone, |_| 0);
    let base = scene(soft_and_bone(), exact());
    let plain = render(&v, &base, 96, 96);
    // J = the CT itself: the same image but for the blend's rounding. J is read in f32; the
    // CT's 16-bit records blend each slice in fixed point, which moves a sample by up to 1/256
    // voxel across the slice (docs/rendering.md "Sampling"), a level here and there along this
    // atlas's sharp bone edges. (Measured: mean 0.072, 99th percentile 1, max 4.)
    let mut s = base.clone();
    s.deformed = Some(DeformedRegion {
        volume: Arc::new(v.atlas.ct().clone()),
    });
    let same = render(&v, &s, 96, 96);
    let d = diff(&plain.image, &same.image).unwrap();
    let rounding = Tolerance {
        mean: 0.15,
        p99: 1,
        max: 8,
    };
    assert!(rounding.admits(&d), "J = CT: {d}");
    // J filled with bone in air beside the body (x −44 … −34, z 30 … 40 mm: more than 42 mm from
    // the centre) but inside the CT's box: with leaping on, Ω_J counts as occupied, so it shows.
    let g = Grid::new([6, 6, 6], Affine::from_spacing([2.0; 3], DVec3::new(-44.0, -4.0, 30.0))).unwrap();
    s.deformed = Some(DeformedRegion {
        volume: Arc::new(Volume::filled(g, BONE_HU)),
    });
    let with = render(&v, &s, 96, 96);
    let changed: Vec<(u32, u32)> = (0..96u32)
        .flat_map(|r| (0..96u32).map(move |c| (c, r)))
        .filter(|&(c, r)| plain.image.get(c, r) != with.image.get(c, r))
        .collect();
    assert!(
        changed.len() > 30,
        "the bone region changed only {} pixels",
        changed.len()
    );
    // … and only where J is on screen: the image half and the upper half its centre falls in.
    let (right, _, _) = s.camera.basis();
    let j_on_right = right.dot(Vec3::new(-39.0, 1.0, 35.0)) > 0.0;
    assert!(
        changed.iter().all(|&(c, r)| (c >= 48) == j_on_right && r < 48),
        "changes outside the region's part of the image"
    );
}

/// A uniform displacement u = (8, 0, 0) mm.
struct Shift;
impl MotionModel for Shift {
    fn displacement(&self, _x_ref: DVec3, _t_s: f64) -> DVec3 {
        DVec3::new(8.0, 0.0, 0.0)
    }
}

#[test]
fn the_motion_warp_moves_what_is_drawn() {
    let v = atlas(48, 2.0, bone_sphere(DVec3::ZERO, 15.0), |_| 0);
    let tf = TransferFunction::Trapezoids(vec![trapezoid("bone", [0.0, 1.0, 3000.0, 3001.0], [1.0; 3], 1.0)]);
    let base = scene(tf, exact());
    let plain = render(&v, &base, 96, 96);
    let mut s = base.clone();
    s.motion = Some(MotionHook {
        model: Arc::new(stylet_physics::motion::Static),
        t_s: 0.0,
    });
    let still = render(&v, &s, 96, 96);
    let d = diff(&plain.image, &still.image).unwrap();
    assert!(d.max <= 2 && d.mean < 0.05, "a static motion model: {d}");
    s.motion = Some(MotionHook {
        model: Arc::new(Shift),
        t_s: 0.0,
    });
    let moved = render(&v, &s, 96, 96);
    let centroid = |img: &Image| {
        let (mut sx, mut n) = (0.0f64, 0.0f64);
        for r in 0..img.height {
            for c in 0..img.width {
                if img.get(c, r) != background_px() {
                    sx += c as f64;
                    n += 1.0;
                }
            }
        }
        sx / n
    };
    // The reference sphere at X = 0 is drawn at x = X + u = +8 mm: 8 mm at 150 mm along the
    // camera's right axis is 8·right.x / 150 / tan 15° · 48 px.
    let (right, _, _) = base.camera.basis();
    let want = 8.0 * right.x as f64 / 150.0 / 15f64.to_radians().tan() * 48.0;
    let shift = centroid(&moved.image) - centroid(&plain.image);
    assert!((shift - want).abs() < 1.0, "moved by {shift:.2} px, expected {want:.2}");
}

fn needle(nodes: &[[f32; 3]]) -> NeedleShape {
    NeedleShape {
        nodes_mm: nodes.iter().map(|&p| Vec3::from_array(p)).collect(),
        diameter_mm: 1.5,
        hub_length_mm: 20.0,
        hub_diameter_mm: 4.0,
    }
}

#[test]
fn the_needle_occludes_the_volume_behind_it() {
    let body = atlas(48, 2.0, body_with_bone, |_| 0);
    let empty = atlas(48, 2.0, |_| -1000.0, |_| 0);
    let mut s = scene(soft_and_bone(), exact());
    let without = render(&body, &s, 96, 96).image;
    // A needle across the view in front of the body (y = 45 mm; the body ends at 42 mm): the
    // centre ray meets it first.
    s.tools.needle = Some(needle(&[[-30.0, 45.0, 0.0], [0.0, 45.0, 0.0], [30.0, 45.0, 0.0]]));
    let with = render(&body, &s, 96, 96).image;
    let alone = render(&empty, &s, 96, 96).image;
    let (c, r) = (48, 48);
    assert_ne!(without.get(c, r), background_px(), "the body shows at the centre");
    assert_ne!(with.get(c, r), without.get(c, r), "the needle shows at the centre");
    // Nothing of the volume behind the needle reaches the pixel: it is the needle's own colour.
    assert_eq!(with.get(c, r), alone.get(c, r));
    // Away from the needle the picture is unchanged.
    assert_eq!(with.get(48, 10), without.get(48, 10));
}

#[test]
fn the_needle_shadow_darkens_what_lies_under_it() {
    let v = atlas(48, 2.0, body_with_bone, |_| 0);
    let tf = TransferFunction::Trapezoids(vec![
        trapezoid("soft", [-200.0, 0.0, 100.0, 150.0], [0.8, 0.4, 0.3], 0.4),
        trapezoid("bone", [200.0, 400.0, 3000.0, 3100.0], [1.0, 1.0, 0.95], 0.6),
    ]);
    let mut s = scene(tf, exact());
    // Seen from the front and above; light straight from above; the needle lies 13 mm above
    // the body's top, so its shadow falls on the top surface along y ≈ 0.
    s.camera = Camera::orbit(Vec3::ZERO, 150.0, 0.0, 50.0, 30.0);
    s.light = Light {
        toward_light: Vec3::Z,
        ..Light::over_shoulder(&s.camera)
    };
    let no_needle = render(&v, &s, 96, 96).image;
    s.tools.needle = Some(needle(&[[-20.0, 0.0, 55.0], [0.0, 0.0, 55.0], [20.0, 0.0, 55.0]]));
    let shadowed = render(&v, &s, 96, 96).image;
    s.light.shadow_in = 1.0;
    let unshadowed = render(&v, &s, 96, 96).image;
    let mut darker = 0;
    for (i, (a, b)) in shadowed.rgba.iter().zip(&unshadowed.rgba).enumerate() {
        if a != b {
            // The shadow only darkens, and only where the needle itself is not drawn.
            assert!((0..3).all(|ch| a[ch] <= b[ch]), "pixel {i}: {a:?} brighter than {b:?}");
            assert_eq!(*b, no_needle.rgba[i], "pixel {i}: shadow on a tool pixel");
            darker += 1;
        }
    }
    eprintln!("needle shadow: {darker} pixels darker");
    assert!(darker > 20, "only {darker} pixels in the needle's shadow");
    // The shadow lies under the needle: the same columns as the needle (x −20 … 20 mm, and the
    // hub beyond −20), not far to the sides.
    let cols: Vec<u32> = (0..shadowed.rgba.len())
        .filter(|&i| shadowed.rgba[i] != unshadowed.rgba[i])
        .map(|i| i as u32 % 96)
        .collect();
    let px_per_mm = 48.0 / (150.0 * 15f32.to_radians().tan());
    let half_width = ((40.0 + 2.0) * px_per_mm) as u32 + 4;
    assert!(
        cols.iter().all(|&c| c.abs_diff(48) <= half_width),
        "shadow columns {cols:?}"
    );
}

#[test]
fn a_bad_step_neither_hangs_nor_panics() {
    let v = atlas(24, 4.0, body_with_bone, |_| 0);
    let good = render(
        &v,
        &scene(
            soft_and_bone(),
            Quality {
                step_mm: 1.0,
                ..exact()
            },
        ),
        32,
        32,
    );
    for step_mm in [f32::NAN, 0.0, -2.0, f32::INFINITY] {
        let out = render(&v, &scene(soft_and_bone(), Quality { step_mm, ..exact() }), 32, 32);
        // Not a positive finite number: the march uses 1 mm.
        assert_eq!(out, good, "step {step_mm}");
    }
    let tiny = render(
        &v,
        &scene(
            soft_and_bone(),
            Quality {
                step_mm: 1e-30,
                ..exact()
            },
        ),
        8,
        8,
    );
    let floor = render(
        &v,
        &scene(
            soft_and_bone(),
            Quality {
                step_mm: 0.01,
                ..exact()
            },
        ),
        8,
        8,
    );
    assert_eq!(tiny, floor);
}

/// A needle across the body, casting its shadow on what lies behind it.
fn needle_through_body() -> ToolState {
    let nodes: Vec<Vec3> = (0..11).map(|j| Vec3::new(-50.0 + 6.0 * j as f32, 30.0, 10.0)).collect();
    ToolState {
        needle: Some(NeedleShape {
            nodes_mm: nodes,
            diameter_mm: 2.0,
            hub_length_mm: 20.0,
            hub_diameter_mm: 6.0,
        }),
        ..Default::default()
    }
}

/// The lanes and the rays marched in turn (three or two with the lanes; two without them, as on
/// a CPU without AVX2) against one sample at a time, one ray after the other.
#[test]
fn lanes_draw_the_pixels_of_one_sample_at_a_time() {
    use stylet_render::raycast::{Lanes, render_with};
    // Integer values (16-bit records: the AVX2 kernel) and fractional ones (f32 records: only
    // the placing of points runs on lanes).
    let integral = atlas(48, 2.0, body_with_bone, |_| 0);
    let fractional = atlas(48, 2.0, textured_body, |_| 0);
    for (name, v) in [("integral", &integral), ("fractional", &fractional)] {
        for (tf_name, tf) in [("soft and bone", soft_and_bone()), ("patchy", patchy())] {
            let plain = scene(tf, Quality::fast(0.5));
            let clipped = Scene {
                clip: Some(ClipPlane {
                    point_mm: Vec3::new(0.0, 10.0, 0.0),
                    normal: Vec3::new(0.0, -1.0, 0.2).normalize(),
                }),
                tools: needle_through_body(),
                ..plain.clone()
            };
            let exact_early = Scene {
                quality: Quality {
                    early_termination: true,
                    ..exact()
                },
                ..clipped.clone()
            };
            let half = Scene {
                quality: Quality {
                    half_resolution: true,
                    ..plain.quality
                },
                ..plain.clone()
            };
            // Tiles are 15 pixels wide: with the lanes a row of a tile goes as five threes. The
            // last tile's rows at width 80: three and two; 76: a pixel marched alone; 79: two
            // pairs; 81: two threes.
            for (what, s, (w, h)) in [
                ("plain", &plain, (80, 72)),
                ("plain, a last tile of one", &plain, (76, 71)),
                ("plain, a last tile of four", &plain, (79, 71)),
                ("plain, a last tile of six", &plain, (81, 71)),
                ("clip and needle", &clipped, (80, 72)),
                ("no jitter", &exact_early, (80, 72)),
                ("half", &half, (80, 72)),
            ] {
                let b = render_with(v, s, w, h, Lanes::OneAtATime);
                assert!(
                    count_not_background(&b.image) > 500,
                    "{name}, {tf_name}, {what}: an empty picture"
                );
                for lanes in [Lanes::Auto, Lanes::PairsWithoutSimd] {
                    let a = render_with(v, s, w, h, lanes);
                    assert_eq!(a.image, b.image, "{name}, {tf_name}, {what}: {lanes:?} changed pixels");
                    assert_eq!(
                        a.samples, b.samples,
                        "{name}, {tf_name}, {what}: {lanes:?} counted other samples"
                    );
                }
            }
        }
    }
}

/// The 3D overview's cut shows the anatomy: its pixels fall into many clearly different colours
/// (skin, fat, liver, bone, lung, vessels, the target), not one flat skin colour with the tags.
#[test]
fn the_overview_cut_shows_the_anatomy_in_its_colours() {
    let dir = tempfile::tempdir().unwrap();
    let p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
        dims: [128, 128, 100],
        spacing_mm: [3.0, 3.0, 3.0],
        ..Default::default()
    })
    .unwrap();
    stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
    let atlas = stylet_atlas::load(dir.path()).unwrap();
    let path = atlas.planned_paths().into_iter().next().expect("a planned path");
    let volume = RenderVolume::new(Arc::clone(&atlas.model));
    let spec = stylet_render::overview::OverviewSpec {
        tip_paths: Vec::new(),
        planned: Some((path.entry_mm, path.target_mm)),
        corridor: None,
        frame: 0,
    };
    let image = stylet_render::overview::render(&atlas, &volume, &spec, 320, 240).unwrap();
    if let Some(out) = std::env::var_os("STYLET_OVERVIEW_PNG") {
        image.write_png(std::path::Path::new(&out)).unwrap();
    }
    // Colours (to 32 levels a channel) covering at least 1 % of the frame each, black left out.
    let mut counts = std::collections::BTreeMap::new();
    for px in &image.rgba {
        if px[0] < 16 && px[1] < 16 && px[2] < 16 {
            continue;
        }
        *counts.entry([px[0] / 32, px[1] / 32, px[2] / 32]).or_insert(0u32) += 1;
    }
    let common = counts
        .values()
        .filter(|&&n| n as usize * 100 >= image.rgba.len())
        .count();
    assert!(common >= 8, "{common} colours cover 1 % of the frame each: {counts:?}");
}
