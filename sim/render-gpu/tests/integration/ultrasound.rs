//! The GPU ultrasound against the CPU reference (`stylet_render::ultrasound::render`): every CT
//! storage variant with a vessel in colour Doppler and a needle, and the phantom beside its
//! planned path. Fails when there is no adapter (CI installs lavapipe).

use std::sync::Arc;

use crate::common::*;
use stylet_physics::glam::{Mat3, Quat, Vec3};
use stylet_physics::{Consequence, ProbeKind};
use stylet_render::consequences::{ConsequenceScene, FluidCollection};
use stylet_render::image::diff;
use stylet_render::synthetic::{RISK, TARGET};
use stylet_render::tools::{LineKind, LineShape, NeedleShape, ProbeShape};
use stylet_render::ultrasound::{
    EchoClass, EchoTable, FLAG_DOPPLER, FlowField, Sonogram, UltrasoundScene, UltrasoundSettings, render,
};
use stylet_render_gpu::GpuUltrasound;

/// Both sides run the same f32 loop; the shader compiler may fuse and reorder (and `ln`, `sqrt`
/// and `round` differ in the last bits), so display values agree to 0.02 on all but 0.5 % of the
/// samples, the mean difference stays under 0.002, and the flags (target, Doppler) and colours
/// agree on all but 0.5 % of the samples.
fn assert_agree(name: &str, cpu: &Sonogram, gpu: &Sonogram) {
    assert_eq!(cpu.bmode.len(), gpu.bmode.len());
    let n = cpu.bmode.len();
    let (mut sum, mut off, mut flags, mut colours) = (0.0f64, 0, 0, 0);
    for k in 0..n {
        let d = (cpu.bmode[k] - gpu.bmode[k]).abs();
        sum += d as f64;
        off += (d > 0.02) as usize;
        flags += (cpu.flags[k] != gpu.flags[k]) as usize;
        if cpu.flags[k] & gpu.flags[k] & FLAG_DOPPLER != 0 {
            let c = cpu.colour[k]
                .iter()
                .zip(&gpu.colour[k])
                .map(|(a, b)| a.abs_diff(*b))
                .max()
                .unwrap();
            colours += (c > 2) as usize;
        }
    }
    let mean = sum / n as f64;
    let d = diff(&cpu.to_image(320, 256), &gpu.to_image(320, 256)).unwrap();
    eprintln!(
        "{name}: mean |Δ| {mean:.2e}, {off} samples off by > 0.02, {flags} flags, {colours} colours differ of {n}; images {d}"
    );
    assert!(mean < 0.002, "{name}: mean {mean}");
    for (what, count) in [("display values", off), ("flags", flags), ("colours", colours)] {
        assert!(count * 200 <= n, "{name}: {count} of {n} samples differ in {what}");
    }
}

/// A convex probe on the synthetic body's anterior skin (y = −41.5 mm), its beam tilted 20°
/// toward +z so the vessel along z has flow along the beam, Doppler on, a needle across.
fn scene(both: &Both) -> UltrasoundScene {
    let tilt = Quat::from_rotation_x(20f32.to_radians());
    let beam = tilt * Vec3::Y;
    let lateral = Vec3::X;
    let orientation = Quat::from_mat3(&Mat3::from_cols(lateral, beam.cross(lateral), beam));
    let echo = EchoTable::new(&[(RISK, EchoClass::Vein)], &[TARGET]);
    let flow = Arc::new(FlowField::build(&both.cpu.atlas, &echo));
    let mut settings = UltrasoundSettings::for_probe(ProbeKind::Convex);
    settings.lines = 96;
    settings.samples = 256;
    settings.depth_mm = 80.0;
    UltrasoundScene {
        probe: ProbeShape {
            kind: ProbeKind::Convex,
            position_mm: Vec3::new(0.0, -41.5, 0.0),
            orientation,
        },
        settings,
        seed: 7,
        time_s: 0.1,
        needle: Some(NeedleShape {
            nodes_mm: (0..=8)
                .map(|k| Vec3::new(-30.0 + 7.5 * k as f32, -20.0 + 0.2 * (k * k) as f32, 12.0))
                .collect(),
            diameter_mm: 1.27,
            hub_length_mm: 20.0,
            hub_diameter_mm: 4.0,
        }),
        // Above the needle, a guide wire (steel) and a catheter (polymer) across the image (in
        // its plane: z = (y + 41.5) · tan 20°).
        lines: vec![
            LineShape {
                kind: LineKind::GuideWire,
                nodes_mm: vec![Vec3::new(-16.0, -26.0, 5.64), Vec3::new(-3.0, -25.0, 6.01)],
                diameter_mm: 0.889,
            },
            LineShape {
                kind: LineKind::Catheter,
                nodes_mm: vec![Vec3::new(3.0, -25.0, 6.01), Vec3::new(16.0, -26.0, 5.64)],
                diameter_mm: 2.67,
            },
        ],
        echo: Arc::new(echo),
        doppler: Some(flow),
        guide_mm: None,
        outline_target: true,
        breathing: None,
        // A haematoma around the needle's middle and a bile leak beside it.
        consequences: ConsequenceScene {
            collections: vec![
                FluidCollection {
                    kind: Consequence::Haematoma,
                    centre_mm: Vec3::new(0.0, -18.0, 12.0),
                    radius_mm: 8.0,
                },
                FluidCollection {
                    kind: Consequence::BileLeak,
                    centre_mm: Vec3::new(-18.0, -15.0, 12.0),
                    radius_mm: 5.0,
                },
            ],
            air_in_pleura: Vec::new(),
        },
    }
}

#[test]
fn gpu_ultrasound_matches_the_cpu_for_every_ct_storage() {
    let mut us = GpuUltrasound::new(ctx());
    for (name, both) in placements() {
        let s = scene(both);
        let cpu = render(&both.cpu.atlas, &s).unwrap();
        assert!(
            cpu.flags.iter().any(|f| f & FLAG_DOPPLER != 0),
            "{name}: the vessel is coloured"
        );
        let gpu = us.render(ctx(), &both.gpu, &s).unwrap();
        assert_agree(name, &cpu, &gpu);
        let without = UltrasoundScene {
            consequences: Default::default(),
            ..s.clone()
        };
        assert_ne!(
            render(&both.cpu.atlas, &without).unwrap().bmode,
            cpu.bmode,
            "{name}: the collections show"
        );
        // The wire and the catheter, each on its own, show.
        for kind in [LineKind::GuideWire, LineKind::Catheter] {
            let others = UltrasoundScene {
                lines: s.lines.iter().filter(|l| l.kind != kind).cloned().collect(),
                ..s.clone()
            };
            assert_ne!(
                render(&both.cpu.atlas, &others).unwrap().bmode,
                cpu.bmode,
                "{name}: the {kind:?} shows"
            );
            assert_agree(
                &format!("{name} without the {kind:?}"),
                &render(&both.cpu.atlas, &others).unwrap(),
                &us.render(ctx(), &both.gpu, &others).unwrap(),
            );
        }
        // The target marked as a lung: its surface's grain on both; air in its pleural space
        // takes it away on both.
        let lung = |air: Vec<u16>| UltrasoundScene {
            echo: Arc::new((*s.echo).clone().with_pleura(&[TARGET])),
            consequences: ConsequenceScene {
                air_in_pleura: air,
                ..s.consequences.clone()
            },
            ..s.clone()
        };
        for (what, scene) in [("sliding", lung(Vec::new())), ("still", lung(vec![TARGET]))] {
            let (c, g) = (
                render(&both.cpu.atlas, &scene).unwrap(),
                us.render(ctx(), &both.gpu, &scene).unwrap(),
            );
            assert_agree(&format!("{name} {what} lung"), &c, &g);
            assert_eq!(c.bmode == cpu.bmode, what == "still", "{name} {what}");
        }
        // B-mode only, no needle: the same.
        let plain = UltrasoundScene {
            needle: None,
            doppler: None,
            ..s
        };
        let (c, g) = (
            render(&both.cpu.atlas, &plain).unwrap(),
            us.render(ctx(), &both.gpu, &plain).unwrap(),
        );
        assert_agree(&format!("{name} B-mode"), &c, &g);
    }
}

/// A line longer than the shader's chunk of 256 samples and not a multiple of it (the last
/// chunk partly filled), and a single line: what carries from sample to sample (transmission,
/// gel, the needle's shadow) carries across chunks as on the CPU.
#[test]
fn gpu_ultrasound_carries_the_line_across_chunks() {
    let (name, both) = &placements()[0];
    let mut us = GpuUltrasound::new(ctx());
    for (lines, samples) in [(96, 700), (1, 257)] {
        let mut s = scene(both);
        s.settings.lines = lines;
        s.settings.samples = samples;
        let cpu = render(&both.cpu.atlas, &s).unwrap();
        let gpu = us.render(ctx(), &both.gpu, &s).unwrap();
        assert_agree(&format!("{name}, {lines} × {samples}"), &cpu, &gpu);
    }
}

#[test]
fn gpu_ultrasound_matches_the_cpu_on_the_phantom() {
    let both = phantom();
    let atlas = &both.cpu.atlas;
    let scenario = stylet_atlas::ScenarioFile::ptcd();
    let classes = stylet_atlas::manifest::echo_classes(&scenario.labels, &scenario.tissues);
    let echo = EchoTable::new(&classes, &[]);
    let (entry, target) = (
        stylet_physics::glam::DVec3::new(152.6, 1.5, 15.9),
        stylet_physics::glam::DVec3::new(50.5, 30.0, 7.5),
    );
    let probe = stylet_render::ultrasound::probe::facing_path(atlas, ProbeKind::Convex, entry, target).unwrap();
    let flow = Arc::new(FlowField::build(atlas, &echo));
    let s = UltrasoundScene {
        probe,
        settings: UltrasoundSettings::for_probe(ProbeKind::Convex),
        seed: 3,
        time_s: 0.0,
        needle: None,
        lines: Vec::new(),
        echo: Arc::new(echo),
        doppler: Some(flow),
        guide_mm: None,
        outline_target: false,
        breathing: None,
        consequences: Default::default(),
    };
    let cpu = render(atlas, &s).unwrap();
    let mut us = GpuUltrasound::new(ctx());
    let t = std::time::Instant::now();
    let gpu = us.render(ctx(), &both.gpu, &s).unwrap();
    eprintln!("phantom 256 × 512 on {}: {:?}", ctx().adapter().name, t.elapsed());
    assert_agree("phantom", &cpu, &gpu);

    // The breathing phantom at its deepest breath: each sample read at its reference point, on
    // both renderers; the liver has moved under the probe.
    let (hook, g) = breathing_hook(both);
    let moving = UltrasoundScene {
        breathing: Some(hook),
        ..s.clone()
    };
    let cpu_moving = render(atlas, &moving).unwrap();
    let gpu_moving = us.render(ctx(), &both.gpu, &moving).unwrap();
    assert_agree(&format!("phantom breathing (g = {g:.3})"), &cpu_moving, &gpu_moving);
    let changed = cpu_moving
        .bmode
        .iter()
        .zip(&cpu.bmode)
        .filter(|(a, b)| (*a - *b).abs() > 0.05)
        .count();
    eprintln!(
        "breathing changed {changed} of {} samples by more than 0.05",
        cpu.bmode.len()
    );
    assert!(changed * 10 > cpu.bmode.len(), "only {changed} samples changed");
}

#[test]
fn gpu_ultrasound_refuses_what_the_cpu_refuses() {
    let both = small();
    let mut us = GpuUltrasound::new(ctx());
    let mut s = scene(both);
    s.settings.lines = 0;
    let e = us.render(ctx(), &both.gpu, &s).unwrap_err().to_string();
    assert!(e.contains("lines"), "{e}");
    let mut s = scene(both);
    s.probe.position_mm.y = f32::NAN;
    assert!(
        us.render(ctx(), &both.gpu, &s)
            .unwrap_err()
            .to_string()
            .contains("pose")
    );
}
