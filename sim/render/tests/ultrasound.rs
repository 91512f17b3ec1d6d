//! Simulated ultrasound (docs/ultrasound.md): a bone plate casts a shadow; speckle is fixed to
//! the tissue (the same pose gives the same frame, a moved probe the same speckle shifted, a new
//! seed new speckle); Doppler colour only inside vessels and only where the flow has a component
//! along the beam; the needle's bright echo with its shadow; a probe off the skin sees nothing;
//! determinism over thread counts; bad scenes refused.

use std::sync::Arc;

use stylet_atlas::EchoClass;
use stylet_physics::ProbeKind;
use stylet_physics::glam::{DVec3, Quat, Vec3};
use stylet_render::synthetic;
use stylet_render::tools::{LineKind, LineShape, NeedleShape, ProbeShape};
use stylet_render::ultrasound::{
    EchoTable, FLAG_DOPPLER, FlowField, Sonogram, UltrasoundScene, UltrasoundSettings, render,
};

const N: usize = 100;
const SPACING_MM: f64 = 1.0;
/// The vessel's label (synthetic::RISK) and the soft tissue's CT value.
const VESSEL: u16 = synthetic::RISK;
const TISSUE_HU: f32 = 50.0;

/// A linear probe at `position` looking along +z, its array along +x (the identity pose).
fn scene(position: Vec3, lines: u32, echo: EchoTable) -> UltrasoundScene {
    let mut settings = UltrasoundSettings::for_probe(ProbeKind::Linear);
    settings.lines = lines;
    settings.samples = 256;
    settings.depth_mm = 60.0;
    UltrasoundScene {
        probe: ProbeShape {
            kind: ProbeKind::Linear,
            position_mm: position,
            orientation: Quat::IDENTITY,
        },
        settings,
        seed: 42,
        time_s: 0.0,
        needle: None,
        lines: Vec::new(),
        echo: Arc::new(echo),
        doppler: None,
        guide_mm: None,
        outline_target: false,
        breathing: None,
        consequences: Default::default(),
    }
}

fn homogeneous() -> stylet_physics::PunctureAtlas {
    synthetic::atlas(N, SPACING_MM, |_| TISSUE_HU, |_| 0)
}

/// Mean display value of lines `lines` over samples `samples`.
fn mean(s: &Sonogram, lines: std::ops::Range<u32>, samples: std::ops::Range<u32>) -> f32 {
    let mut sum = 0.0;
    let mut n = 0;
    for i in lines {
        for j in samples.clone() {
            sum += s.bmode[s.at(i, j)];
            n += 1;
        }
    }
    sum / n as f32
}

/// Pearson correlation of two equally long series.
fn correlation(a: &[f32], b: &[f32]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (
        a.iter().map(|&v| v as f64).sum::<f64>() / n,
        b.iter().map(|&v| v as f64).sum::<f64>() / n,
    );
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (&x, &y) in a.iter().zip(b) {
        let (x, y) = (x as f64 - ma, y as f64 - mb);
        ab += x * y;
        aa += x * x;
        bb += y * y;
    }
    ab / (aa * bb).sqrt()
}

/// Lines `lines` of a frame as one series (samples 20 … 236).
fn series(s: &Sonogram, lines: std::ops::Range<u32>) -> Vec<f32> {
    lines
        .flat_map(|i| (20..236).map(move |j| s.bmode[s.at(i, j)]))
        .collect()
}

#[test]
fn a_bone_plate_echoes_brightly_and_casts_a_shadow() {
    // Soft tissue, and a 5 mm bone plate under the left half of the array (x < −3 mm) at
    // z = −15 … −10 mm; the probe at z = −40 mm sees the plate 25 mm deep.
    let atlas = synthetic::atlas(
        N,
        SPACING_MM,
        |p| {
            if p.x < -3.0 && (-15.0..-10.0).contains(&p.z) {
                1000.0
            } else {
                TISSUE_HU
            }
        },
        |_| 0,
    );
    let s = render(&atlas, &scene(Vec3::new(0.0, 0.0, -40.0), 128, EchoTable::default())).unwrap();
    let (left, right) = (8..48, 80..120);
    // Beneath the plate (35 … 55 mm deep: samples 150 … 234): dark on the left, tissue on the right.
    let (shadow, lit) = (mean(&s, left.clone(), 150..234), mean(&s, right.clone(), 150..234));
    assert!(lit > 0.3, "the tissue beside the plate is seen: {lit}");
    assert!(shadow < 0.05, "behind bone lies a shadow: {shadow} (beside it {lit})");
    // The plate's front face: the brightest sample of each left line, 25 mm deep (sample ≈ 106).
    for i in left {
        let brightest = (0..256)
            .max_by(|&a, &b| s.bmode[s.at(i, a)].total_cmp(&s.bmode[s.at(i, b)]))
            .unwrap();
        assert!(
            (104..=108).contains(&brightest),
            "line {i}: brightest at sample {brightest}"
        );
        // Tissue shows about 0.43; the interface, smeared over the samples of one voxel, > 0.7.
        assert!(s.bmode[s.at(i, brightest)] > 0.7, "{}", s.bmode[s.at(i, brightest)]);
    }
    // Above the plate both halves look alike (the same tissue).
    let (l, r) = (mean(&s, 8..48, 20..90), mean(&s, 80..120, 20..90));
    assert!((l - r).abs() < 0.03, "{l} {r}");
}

#[test]
fn speckle_is_fixed_to_the_tissue_not_to_the_probe() {
    let atlas = homogeneous();
    let lines = 128;
    let at = Vec3::new(0.0, 0.0, -40.0);
    let a = render(&atlas, &scene(at, lines, EchoTable::default())).unwrap();
    // The same pose: the same frame, bit for bit.
    let again = render(&atlas, &scene(at, lines, EchoTable::default())).unwrap();
    assert!(
        a.bmode
            .iter()
            .zip(&again.bmode)
            .all(|(x, y)| x.to_bits() == y.to_bits())
    );
    // The probe moved 16 line spacings (5 mm) along its array: line i now sees what line i + 16
    // saw, the same speckle shifted.
    let spacing_mm = 40.0 / lines as f32;
    let moved = render(
        &atlas,
        &scene(at + Vec3::X * (16.0 * spacing_mm), lines, EchoTable::default()),
    )
    .unwrap();
    let shifted = correlation(&series(&moved, 4..100), &series(&a, 20..116));
    assert!(
        shifted > 0.99,
        "the moved probe sees the same speckle shifted: r = {shifted}"
    );
    // Compared line for line (not shifted), the moved frame is not the same picture: the speckle
    // did not travel with the probe.
    let unshifted = correlation(&series(&moved, 4..100), &series(&a, 4..100));
    assert!(unshifted < 0.3, "r = {unshifted}");
    // Another session seed: other speckle.
    let mut other = scene(at, lines, EchoTable::default());
    other.seed = 43;
    let b = render(&atlas, &other).unwrap();
    let r = correlation(&series(&b, 4..124), &series(&a, 4..124));
    assert!(r < 0.3, "another seed, other speckle: r = {r}");
}

/// Homogeneous tissue with a vessel tube (radius 6 mm, label [`VESSEL`]) through the centre
/// along `axis`.
fn with_vessel(axis: DVec3) -> stylet_physics::PunctureAtlas {
    let axis = axis.normalize();
    synthetic::atlas(
        N,
        SPACING_MM,
        |_| TISSUE_HU,
        move |p| {
            let radial = p - axis * p.dot(axis);
            if radial.length() < 6.0 { VESSEL } else { 0 }
        },
    )
}

fn doppler_scene(atlas: &stylet_physics::PunctureAtlas, class: EchoClass) -> UltrasoundScene {
    let echo = EchoTable::new(&[(VESSEL, class)], &[]);
    let flow = Arc::new(FlowField::build(atlas, &echo));
    let mut s = scene(Vec3::new(0.0, 0.0, -40.0), 128, echo);
    s.doppler = Some(flow);
    s
}

#[test]
fn doppler_colours_only_vessels_and_only_flow_along_the_beam() {
    // A vein at 45° to the beam, in the image plane.
    let atlas = with_vessel(DVec3::new(1.0, 0.0, 1.0));
    let s = render(&atlas, &doppler_scene(&atlas, EchoClass::Vein)).unwrap();
    let labels = atlas.partial_labels();
    let (mut coloured, mut grey) = (0, 0.0);
    for i in 0..s.geometry.lines {
        for j in 0..s.geometry.samples {
            let k = s.at(i, j);
            if s.flags[k] & FLAG_DOPPLER == 0 {
                continue;
            }
            coloured += 1;
            let x = s.geometry.sample_point(i, j).as_dvec3();
            assert_eq!(labels.nearest(x, 0), VESSEL, "colour outside the vessel at {x}");
            let [r, _, b] = s.colour[k];
            assert!(r == 0 && b == 255, "a vein is blue→cyan: {:?}", s.colour[k]);
            grey += s.bmode[k];
        }
    }
    assert!(coloured > 500, "the vein is coloured: {coloured} samples");
    // Under the colour, the vessel is anechoic (dark but for its walls).
    assert!(grey / (coloured as f32) < 0.2, "{}", grey / coloured as f32);
    // An artery is red→yellow.
    let s = render(&atlas, &doppler_scene(&atlas, EchoClass::Artery)).unwrap();
    let k = (0..s.flags.len())
        .find(|&k| s.flags[k] & FLAG_DOPPLER != 0)
        .expect("coloured");
    assert_eq!((s.colour[k][0], s.colour[k][2]), (255, 0));
    // A vessel crossing the image plane at right angles to the beam: no Doppler shift, no colour.
    let across = with_vessel(DVec3::Y);
    let s = render(&across, &doppler_scene(&across, EchoClass::Vein)).unwrap();
    assert!(s.flags.iter().all(|f| f & FLAG_DOPPLER == 0));
    // Without the Doppler flag, no colour at all.
    let mut plain = doppler_scene(&atlas, EchoClass::Vein);
    plain.doppler = None;
    assert!(
        render(&atlas, &plain)
            .unwrap()
            .flags
            .iter()
            .all(|f| f & FLAG_DOPPLER == 0)
    );
}

#[test]
fn the_needle_is_a_bright_line_with_a_shadow_and_only_in_the_beam() {
    let atlas = homogeneous();
    let at = Vec3::new(0.0, 0.0, -40.0);
    let needle = |y: f32| NeedleShape {
        // Across the image 20 mm deep, slightly tilted.
        nodes_mm: vec![Vec3::new(-30.0, y, -22.0), Vec3::new(30.0, y, -18.0)],
        diameter_mm: 1.27,
        hub_length_mm: 20.0,
        hub_diameter_mm: 4.0,
    };
    let plain = render(&atlas, &scene(at, 128, EchoTable::default())).unwrap();
    let mut with = scene(at, 128, EchoTable::default());
    with.needle = Some(needle(0.0));
    let s = render(&atlas, &with).unwrap();
    for i in 10..118 {
        let brightest = (0..256)
            .max_by(|&a, &b| s.bmode[s.at(i, a)].total_cmp(&s.bmode[s.at(i, b)]))
            .unwrap();
        let depth_mm = (brightest as f32 + 0.5) * 60.0 / 256.0;
        let x = -20.0 + (i as f32 + 0.5) * 40.0 / 128.0;
        let shaft_mm = 20.0 + x / 15.0 - 1.27 / 2.0 - 1.0;
        assert!(
            (depth_mm - shaft_mm).abs() < 1.0,
            "line {i}: brightest at {depth_mm} mm, shaft at {shaft_mm}"
        );
        assert!(s.bmode[s.at(i, brightest)] > 0.9);
    }
    // Beneath it, the shadow (deeper than the comet tail).
    let (under, free) = (mean(&s, 10..118, 150..250), mean(&plain, 10..118, 150..250));
    assert!(under < free - 0.15, "shadow {under} vs {free}");
    // 3 mm out of the image plane (beyond the beam's thickness) it is not seen.
    let mut off = scene(at, 128, EchoTable::default());
    off.needle = Some(needle(3.0));
    let o = render(&atlas, &off).unwrap();
    assert!(o.bmode.iter().zip(&plain.bmode).all(|(a, b)| a == b));
}

/// The exchange's instruments across the image 20 mm deep: the guide wire (steel) echoes as
/// brightly as the needle with a shadow but no comet tail (a solid wire has no lumen to ring in);
/// a catheter (polymer) echoes faintly and casts almost no shadow; out of the beam's thickness
/// neither is seen.
#[test]
fn the_wire_and_catheter_are_echogenic_lines() {
    let atlas = homogeneous();
    let at = Vec3::new(0.0, 0.0, -40.0);
    let line = |kind, y: f32, diameter_mm| LineShape {
        kind,
        nodes_mm: vec![Vec3::new(-30.0, y, -20.0), Vec3::new(30.0, y, -20.0)],
        diameter_mm,
    };
    let with = |lines: Vec<LineShape>| {
        let mut s = scene(at, 128, EchoTable::default());
        s.lines = lines;
        render(&atlas, &s).unwrap()
    };
    let plain = render(&atlas, &scene(at, 128, EchoTable::default())).unwrap();
    let wire = with(vec![line(LineKind::GuideWire, 0.0, 0.889)]);
    let catheter = with(vec![line(LineKind::Catheter, 0.0, 2.67)]);
    // The brightest sample of each line from 15 to 21 mm deep (the lines' near walls, widened
    // by the beam's thickness), averaged over the lines.
    let peak = |s: &Sonogram| {
        let lines = 10..118u32;
        let per_line = lines
            .clone()
            .map(|i| (64..90).map(|j| s.bmode[s.at(i, j)]).fold(0.0f32, f32::max));
        per_line.sum::<f32>() / lines.len() as f32
    };
    let lines = 10..118;
    let (w, c, p) = (peak(&wire), peak(&catheter), peak(&plain));
    assert!(
        w > 0.85 && w > c + 0.1 && c > p + 0.1,
        "wire {w}, catheter {c}, tissue {p}"
    );
    // Behind the wire its shadow; behind the catheter nearly the tissue's grey.
    let deep = 150..250;
    let (w_deep, c_deep, p_deep) = (
        mean(&wire, lines.clone(), deep.clone()),
        mean(&catheter, lines.clone(), deep.clone()),
        mean(&plain, lines.clone(), deep),
    );
    assert!(
        w_deep < p_deep - 0.15 && (c_deep - p_deep).abs() < 0.03,
        "{w_deep} {c_deep} {p_deep}"
    );
    // No comet tail under the wire: just below it the image is darker, not brighter, than
    // tissue — unlike the needle's.
    let needle = {
        let mut s = scene(at, 128, EchoTable::default());
        s.needle = Some(NeedleShape {
            nodes_mm: vec![Vec3::new(-30.0, 0.0, -20.0), Vec3::new(30.0, 0.0, -20.0)],
            diameter_mm: 0.889,
            hub_length_mm: 20.0,
            hub_diameter_mm: 4.0,
        });
        render(&atlas, &s).unwrap()
    };
    let tail = 85..100;
    let (w_tail, n_tail) = (
        mean(&wire, lines.clone(), tail.clone()),
        mean(&needle, lines.clone(), tail),
    );
    assert!(n_tail > w_tail + 0.1, "needle's tail {n_tail}, wire's {w_tail}");
    // 3 mm out of the image plane: not seen.
    let off = with(vec![
        line(LineKind::GuideWire, 3.0, 0.889),
        line(LineKind::Catheter, -3.0, 2.67),
    ]);
    assert!(off.bmode.iter().zip(&plain.bmode).all(|(a, b)| a == b));
}

#[test]
fn a_probe_off_the_skin_sees_nothing() {
    // Air above z = −20 mm; the probe 15 mm above the skin (beyond the gel layer).
    let atlas = synthetic::atlas(N, SPACING_MM, |p| if p.z < -20.0 { -1000.0 } else { TISSUE_HU }, |_| 0);
    let lifted = render(&atlas, &scene(Vec3::new(0.0, 0.0, -35.0), 64, EchoTable::default())).unwrap();
    let brightest = lifted.bmode.iter().fold(0.0f32, |m, &v| m.max(v));
    assert!(
        brightest < 0.01,
        "a lifted probe shows nothing, not even the air's edge: {brightest}"
    );
    // 5 mm above the skin the gel bridges the gap: the tissue is seen.
    let gel = render(&atlas, &scene(Vec3::new(0.0, 0.0, -25.0), 64, EchoTable::default())).unwrap();
    assert!(mean(&gel, 0..64, 80..256) > 0.3);
}

/// A convex probe on a curved flank images to the edges of its fan: the coupling gel bridges the
/// air beyond the plane tangent to the face's centre, and each outer line's own recess behind it.
#[test]
fn a_convex_probe_on_a_curved_flank_images_to_the_edges_of_its_fan() {
    // Skin: a cylinder of radius 150 mm along y, its top at z = −40; the face 0.5 mm into it.
    let atlas = synthetic::atlas(
        N,
        2.0,
        |p| {
            if p.x * p.x + (p.z - 110.0) * (p.z - 110.0) <= 150.0 * 150.0 {
                TISSUE_HU
            } else {
                -1000.0
            }
        },
        |_| 0,
    );
    let mut s = scene(Vec3::new(0.0, 0.0, -39.5), 128, EchoTable::default());
    s.probe.kind = ProbeKind::Convex;
    let f = render(&atlas, &s).unwrap();
    for i in 0..128 {
        let m = mean(&f, i..i + 1, 100..256);
        assert!(m > 0.2, "line {i} is black under the skin, 23 … 60 mm deep: {m}");
    }
}

/// A line that leaves the CT's box goes on in the tissue on the box's face: no black wedge with a
/// straight edge where the image plane meets the box.
#[test]
fn a_line_that_leaves_the_ct_fades_as_tissue_does() {
    let atlas = homogeneous();
    let mut s = scene(Vec3::new(0.0, 0.0, -45.0), 128, EchoTable::default());
    s.probe.kind = ProbeKind::Convex;
    s.settings = UltrasoundSettings {
        lines: 128,
        ..UltrasoundSettings::for_probe(ProbeKind::Convex)
    };
    let f = render(&atlas, &s).unwrap();
    let samples = s.settings.samples;
    for i in 0..128 {
        let m = mean(&f, i..i + 1, samples * 2 / 15..samples);
        assert!(m > 0.2, "line {i}, 20 … 150 mm deep: {m}");
    }
}

#[test]
fn frames_are_identical_on_any_number_of_threads_and_scan_convert_to_the_fan() {
    let atlas = with_vessel(DVec3::new(1.0, 0.0, 1.0));
    let mut s = doppler_scene(&atlas, EchoClass::Artery);
    s.probe.kind = ProbeKind::Convex;
    s.probe.position_mm = Vec3::new(0.0, 0.0, -45.0);
    s.settings.lines = 96;
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let three = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
    let a = one.install(|| render(&atlas, &s).unwrap());
    let b = three.install(|| render(&atlas, &s).unwrap());
    assert!(a.bmode.iter().zip(&b.bmode).all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_eq!(a.colour, b.colour);
    let (ia, ib) = (
        one.install(|| a.to_image(320, 256)),
        three.install(|| b.to_image(320, 256)),
    );
    assert_eq!(ia.rgba, ib.rgba);
    // The fan: black outside the sector (the top corners), image inside (the middle).
    assert_eq!(ia.get(2, 2), [0, 0, 0, 255]);
    assert_eq!(ia.get(317, 2), [0, 0, 0, 255]);
    let middle = ia.get(160, 100);
    assert!(middle[0] > 20 || middle[2] > 20, "{middle:?}");
}

#[test]
fn bad_scenes_are_refused_with_the_problem_named() {
    let atlas = homogeneous();
    let base = scene(Vec3::new(0.0, 0.0, -40.0), 64, EchoTable::default());
    type Break = Box<dyn Fn(&mut UltrasoundScene)>;
    let cases: Vec<(&str, Break)> = vec![
        ("lines", Box::new(|s| s.settings.lines = 0)),
        ("samples", Box::new(|s| s.settings.samples = 100_000)),
        ("depth", Box::new(|s| s.settings.depth_mm = f32::NAN)),
        ("frequency", Box::new(|s| s.settings.frequency_mhz = 0.0)),
        ("dynamic range", Box::new(|s| s.settings.dynamic_range_db = 1.0)),
        ("pose", Box::new(|s| s.probe.position_mm.x = f32::INFINITY)),
        (
            "pose",
            Box::new(|s| s.probe.orientation = Quat::from_xyzw(0.0, 0.0, 0.0, 0.0)),
        ),
        (
            "needle",
            Box::new(|s| {
                s.needle = Some(NeedleShape {
                    nodes_mm: vec![Vec3::ZERO, Vec3::NAN],
                    diameter_mm: 1.0,
                    hub_length_mm: 1.0,
                    hub_diameter_mm: 1.0,
                })
            }),
        ),
        (
            "guide wire",
            Box::new(|s| {
                s.lines = vec![LineShape {
                    kind: LineKind::GuideWire,
                    nodes_mm: vec![Vec3::ZERO, Vec3::X],
                    diameter_mm: -1.0,
                }]
            }),
        ),
        (
            "guide wire",
            Box::new(|s| {
                s.lines = vec![
                    LineShape {
                        kind: LineKind::Catheter,
                        nodes_mm: vec![Vec3::ZERO, Vec3::X],
                        diameter_mm: 2.0,
                    };
                    5
                ]
            }),
        ),
        ("time", Box::new(|s| s.time_s = f64::NAN)),
    ];
    for (word, break_it) in cases {
        let mut s = base.clone();
        break_it(&mut s);
        let e = render(&atlas, &s).expect_err(word).to_string();
        assert!(e.contains(word), "{word}: {e}");
    }
}

/// Soft tissue over an aerated lung (−850 HU, label [`LUNG`]) from 30 mm under the probe: the
/// pleural line. Marked as a lung, its surface gets the grain that slides with it (docs/ultrasound.md
/// "Consequences of a wrong puncture"); with air in its pleural space the grain is gone and the
/// frame is the plain one, bit for bit.
#[test]
fn a_sliding_lung_surface_has_grain_and_a_pneumothorax_takes_it_away() {
    const LUNG: u16 = synthetic::RISK;
    let atlas = synthetic::atlas(
        N,
        SPACING_MM,
        |p| if p.z >= -10.0 { -850.0 } else { TISSUE_HU },
        |p| if p.z >= -10.0 { LUNG } else { 0 },
    );
    let at = Vec3::new(0.0, 0.0, -40.0);
    let plain = render(&atlas, &scene(at, 128, EchoTable::default())).unwrap();
    let lung = || EchoTable::default().with_pleura(&[LUNG]);
    let sliding = render(&atlas, &scene(at, 128, lung())).unwrap();
    let mut pneumothorax = scene(at, 128, lung());
    pneumothorax.consequences.air_in_pleura = vec![LUNG];
    let still = render(&atlas, &pneumothorax).unwrap();
    assert!(
        plain
            .bmode
            .iter()
            .zip(&still.bmode)
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
    // Above the pleura nothing changes; at it (30 mm: samples ≈ 128), the grain.
    let (above, pleura) = (0..120, 124..136);
    for i in 0..128 {
        for j in above.clone() {
            assert_eq!(
                plain.bmode[plain.at(i, j)].to_bits(),
                sliding.bmode[sliding.at(i, j)].to_bits()
            );
        }
    }
    // Each line's pleural band (the line and the millimetre of lung under it): brighter with the
    // grain, and unevenly so from line to line.
    let band = |s: &Sonogram| -> Vec<f32> { (8..120).map(|i| mean(s, i..i + 1, pleura.clone())).collect() };
    let spread = |v: &[f32]| {
        let m = v.iter().sum::<f32>() / v.len() as f32;
        (
            m,
            (v.iter().map(|p| (p - m) * (p - m)).sum::<f32>() / v.len() as f32).sqrt(),
        )
    };
    let ((grain_mean, grain), (plain_mean, smooth)) = (spread(&band(&sliding)), spread(&band(&plain)));
    println!("pleural band: sliding {grain_mean:.3} ± {grain:.4}, plain {plain_mean:.3} ± {smooth:.4}");
    assert!(grain_mean > plain_mean + 0.03, "{grain_mean} {plain_mean}");
    assert!(grain > 1.5 * smooth, "{grain} {smooth}");
}
