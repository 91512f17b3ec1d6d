//! The X-ray (docs/xray.md): analytic Beer–Lambert values of a water cylinder, a water slab and
//! an iodine step phantom in the C-arm's cone beam, the needle's steel, and a radiograph's
//! determinism.

use stylet_physics::glam::{DVec3, Vec3};
use stylet_render::synthetic;
use stylet_render::tools::{LineKind, LineShape, NeedleShape};
use stylet_render::xray::attenuation::{MU_STEEL_PER_MM, MU_WATER_PER_MM, iodine_mu_per_mm, mu_of_line};
use stylet_render::xray::needle::resolved_radius_and_mu;
use stylet_render::xray::{CArm, ContrastOverlay, Radiograph, XrayScene, render};

const N: usize = 160;
const SPACING_MM: f64 = 0.75;
const SIZE: u32 = 64;

fn scene(c_arm: CArm) -> XrayScene {
    XrayScene {
        c_arm,
        needle: None,
        lines: Vec::new(),
        contrast: None,
    }
}

/// The world ray of detector pixel (`col`, `row`): source and unit direction.
fn world_ray(arm: &CArm, col: u32, row: u32) -> (Vec3, Vec3) {
    let p = arm.projection(SIZE, SIZE);
    (p.source_mm, (p.pixel_mm(col, row) - p.source_mm).normalize())
}

/// A water cylinder of radius 40 mm along z in air, its rim voxels partial-volume (4 × 4
/// sub-samples in x–y), through the centre of a 120 mm cube.
#[test]
fn a_water_cylinder_attenuates_as_beer_lambert_says() {
    const R: f64 = 40.0;
    let atlas = synthetic::atlas(
        N,
        SPACING_MM,
        |p| {
            let mut inside = 0;
            for a in 0..4 {
                for b in 0..4 {
                    let q = p + DVec3::new((a as f64 - 1.5) * 0.1875, (b as f64 - 1.5) * 0.1875, 0.0);
                    inside += (q.x.hypot(q.y) < R) as i32;
                }
            }
            -1000.0 + 1000.0 * inside as f32 / 16.0
        },
        |_| 0,
    );
    let arm = CArm::posterior_anterior(Vec3::ZERO);
    let img = render(&atlas, &scene(arm), SIZE, SIZE).unwrap();
    let mut worst = 0.0f32;
    // Rows near the middle (the cube holds the cylinder ±60 mm in z), columns across it.
    for row in [28, 32, 36] {
        for col in 0..SIZE {
            let (s, d) = world_ray(&arm, col, row);
            // |(s + t d)_xy|² = R² → chord = (t₂ − t₁).
            let (sx, sy, dx, dy) = (s.x as f64, s.y as f64, d.x as f64, d.y as f64);
            let (qa, qb, qc) = (dx * dx + dy * dy, 2.0 * (sx * dx + sy * dy), sx * sx + sy * sy - R * R);
            let disc = qb * qb - 4.0 * qa * qc;
            let chord = if disc > 0.0 { disc.sqrt() / qa } else { 0.0 };
            let expected = MU_WATER_PER_MM as f64 * chord;
            let got = img.at(col, row) as f64;
            // Away from the rim (chord > 20 mm) within 0.5 %; at the rim within one voxel of water.
            if chord > 20.0 {
                let rel = (got - expected).abs() / expected;
                worst = worst.max(rel as f32);
                assert!(
                    rel < 0.005,
                    "pixel ({col}, {row}): a = {got:.5}, Beer–Lambert {expected:.5}"
                );
                // The transmitted fraction I/I₀ = e^{−a}.
                assert!(((-got).exp() - (-expected).exp()).abs() < 0.003);
            } else {
                assert!(
                    (got - expected).abs() < MU_WATER_PER_MM as f64 * 1.5,
                    "rim pixel ({col}, {row})"
                );
            }
        }
    }
    eprintln!("water cylinder: worst relative error {worst:.5}");
    // The centre: a ≈ 0.017 × 80 mm = 1.36, I/I₀ ≈ 0.257.
    let c = img.at(SIZE / 2, SIZE / 2);
    assert!((c - 1.36).abs() < 0.01, "centre a = {c}");
}

/// A cube of water, and on it an iodine step wedge of five steps (0, 5, 10, 20, 40 mg/ml,
/// 15 mm wide in x, 15 mm thick along the beam) as the contrast overlay: each step adds
/// (μ/ρ)_I·ρ_I × its thickness along the ray, exactly.
#[test]
fn an_iodine_step_phantom_gives_the_analytic_attenuation() {
    let atlas = synthetic::atlas(N, SPACING_MM, |_| 0.0, |_| 0);
    let steps_mg_per_ml = [0.0f32, 5.0, 10.0, 20.0, 40.0];
    let (step_w, thick) = (20usize, 20usize); // voxels: 15 mm × 15 mm
    let (x0, y0) = (30usize, 70usize);
    let mut voxels = Vec::new();
    for (s, &c) in steps_mg_per_ml.iter().enumerate() {
        for i in x0 + s * step_w..x0 + (s + 1) * step_w {
            for j in y0..y0 + thick {
                for k in 40..120 {
                    voxels.push(([i, j, k], iodine_mu_per_mm(c / 1000.0)));
                }
            }
        }
    }
    let overlay = ContrastOverlay::from_voxels(&voxels, [N; 3]).unwrap();
    let arm = CArm::posterior_anterior(Vec3::ZERO);
    let with = XrayScene {
        contrast: Some(overlay),
        ..scene(arm)
    };
    let (plain, iodine) = (
        render(&atlas, &scene(arm), SIZE, SIZE).unwrap(),
        render(&atlas, &with, SIZE, SIZE).unwrap(),
    );
    let grid = *atlas.ct().grid();
    for (s, &c) in steps_mg_per_ml.iter().enumerate() {
        // The pixel whose ray crosses the step's middle at the slab.
        let x_mid = grid.voxel_to_world(x0 + s * step_w + step_w / 2, 0, 0).x as f32;
        let col = (0..SIZE)
            .min_by_key(|&col| {
                let (o, d) = world_ray(&arm, col, SIZE / 2);
                let y = grid.voxel_to_world(0, y0 + thick / 2, 0).y as f32;
                let x = o.x + d.x * (y - o.y) / d.y;
                ((x - x_mid).abs() * 1000.0) as i64
            })
            .unwrap();
        let (_, d) = world_ray(&arm, col, SIZE / 2);
        // Water: the cube's N planes along y; iodine: the step's `thick` planes.
        let water = MU_WATER_PER_MM * N as f32 * SPACING_MM as f32 / d.y.abs();
        let iodine_a = iodine_mu_per_mm(c / 1000.0) * thick as f32 * SPACING_MM as f32 / d.y.abs();
        let (p, q) = (plain.at(col, SIZE / 2), iodine.at(col, SIZE / 2));
        assert!(
            (p - water).abs() < 1e-4 * water,
            "step {s}: water a = {p}, expected {water}"
        );
        assert!(
            ((q - p) - iodine_a).abs() < 2e-5 + 1e-3 * iodine_a,
            "step {s} ({c} mg/ml): iodine adds {}, expected {iodine_a}",
            q - p
        );
    }
    // 40 mg/ml over 15 mm: 1.942 cm²/g × 0.04 g/cm³ × 1.5 cm ≈ 0.117.
    assert!((iodine_mu_per_mm(0.04) * 15.0 - 0.1165).abs() < 1e-3);
}

/// The needle adds μ_steel × its chord, and nothing where the rays miss it.
/// The guide wire is steel, the dilator and catheter barium-filled polymer: each line darkens
/// the pixel its axis crosses by its μ' × 2r', and the catheter a good deal less than steel of
/// its size would.
#[test]
fn the_wire_dilator_and_catheter_are_visible_each_of_its_material() {
    let atlas = synthetic::atlas(64, 1.0, |p| if p.length() < 25.0 { 40.0 } else { -1000.0 }, |_| 0);
    let arm = CArm::posterior_anterior(Vec3::ZERO);
    let row = 36;
    let (o, d) = world_ray(&arm, SIZE / 2, row);
    let z = o.z + d.z * (0.0 - o.y) / d.y;
    let plain = render(&atlas, &scene(arm), SIZE, SIZE).unwrap();
    let pitch_mm = arm.pixel_at_isocenter_mm(SIZE, SIZE);
    let mut peaks = Vec::new();
    for (kind, diameter_mm) in [
        (LineKind::GuideWire, 0.889),
        (LineKind::Dilator, 8.0 / 3.0),
        (LineKind::Catheter, 8.0 / 3.0),
    ] {
        let with = XrayScene {
            lines: vec![LineShape {
                kind,
                nodes_mm: (0..=8).map(|i| Vec3::new(-20.0 + 5.0 * i as f32, 0.0, z)).collect(),
                diameter_mm,
            }],
            ..scene(arm)
        };
        let img = render(&atlas, &with, SIZE, SIZE).unwrap();
        let peak = img.at(SIZE / 2, row) - plain.at(SIZE / 2, row);
        let (r, mu) = resolved_radius_and_mu(diameter_mm, pitch_mm, mu_of_line(kind));
        assert!(
            (peak - mu * 2.0 * r).abs() < 1e-3 * peak,
            "{kind:?}: peak {peak}, expected {}",
            mu * 2.0 * r
        );
        // Nothing away from the line.
        assert_eq!(img.at(SIZE / 2, row - 10), plain.at(SIZE / 2, row - 10));
        peaks.push(peak);
    }
    println!("added attenuation at the axis: wire, dilator, catheter {peaks:?}");
    // Per pixel the 8 F catheter shows less than the 0.035" steel wire, but it shows.
    assert!(peaks[2] < peaks[0] && peaks[2] > 0.05 * peaks[0]);
    assert!(peaks[2] < peaks[1]);
}

#[test]
fn the_steel_needle_is_visible() {
    let atlas = synthetic::atlas(64, 1.0, |p| if p.length() < 25.0 { 40.0 } else { -1000.0 }, |_| 0);
    let arm = CArm::posterior_anterior(Vec3::ZERO);
    // The needle along x at the height where row 36's rays cross y = 0 (its axis is then hit
    // square on, the chord is the diameter).
    let row = 36;
    let (o, d) = world_ray(&arm, SIZE / 2, row);
    let z = o.z + d.z * (0.0 - o.y) / d.y;
    let needle = NeedleShape {
        nodes_mm: (0..=8).map(|i| Vec3::new(-20.0 + 5.0 * i as f32, 0.0, z)).collect(),
        diameter_mm: 1.27,
        hub_length_mm: 20.0,
        hub_diameter_mm: 4.0,
    };
    let with = XrayScene {
        needle: Some(needle),
        lines: Vec::new(),
        ..scene(arm)
    };
    let (plain, steel) = (
        render(&atlas, &scene(arm), SIZE, SIZE).unwrap(),
        render(&atlas, &with, SIZE, SIZE).unwrap(),
    );
    let added = |img: &Radiograph, base: &Radiograph, col: u32, row: u32| img.at(col, row) - base.at(col, row);
    // Pixels (3.5 mm at the isocentre) are wider than the 1.27 mm shaft: it is drawn one pixel
    // wide with its steel kept, so the centre ray sees μ'·2r' and the profile across the shaft
    // integrates to μ_steel·πr² (the steel per mm of shaft).
    let pitch_mm = arm.pixel_at_isocenter_mm(SIZE, SIZE);
    let (r, mu) = resolved_radius_and_mu(1.27, pitch_mm, MU_STEEL_PER_MM);
    let peak = added(&steel, &plain, SIZE / 2, row);
    assert!(
        (peak - mu * 2.0 * r).abs() < 1e-3 * peak,
        "peak {peak}, expected {}",
        mu * 2.0 * r
    );
    // A thin (22 G, 0.7 mm) needle running obliquely across the image leaves no gaps: every
    // column it crosses has a darkened pixel (drawn at its own 0.35 mm radius, most columns'
    // rays would pass beside it).
    let thin = XrayScene {
        needle: Some(NeedleShape {
            nodes_mm: (0..=8)
                .map(|i| Vec3::new(-20.0 + 5.0 * i as f32, 0.0, -12.0 + 3.0 * i as f32))
                .collect(),
            diameter_mm: 0.7,
            hub_length_mm: 20.0,
            hub_diameter_mm: 4.0,
        }),
        lines: Vec::new(),
        ..scene(arm)
    };
    let thin = render(&atlas, &thin, SIZE, SIZE).unwrap();
    let cols: Vec<u32> = (0..SIZE)
        .filter(|&c| {
            let (o, d) = world_ray(&arm, c, SIZE / 2);
            (o.x + d.x * (0.0 - o.y) / d.y).abs() < 18.0
        })
        .collect();
    assert!(cols.len() >= 8, "{cols:?}");
    for c in cols {
        assert!(
            (0..SIZE).any(|r| added(&thin, &plain, c, r) > 0.0),
            "column {c}: the needle has a gap"
        );
    }
    // Beyond the needle's ends (x > 20 mm at the isocentre) and far from its row: nothing.
    assert_eq!(added(&steel, &plain, 2, row), 0.0);
    assert_eq!(added(&steel, &plain, SIZE / 2, row + 8), 0.0);
}

#[test]
fn a_radiograph_is_a_pure_function_of_its_inputs() {
    let atlas = synthetic::atlas(48, 1.5, |p| if p.length() < 30.0 { 60.0 } else { -1000.0 }, |_| 0);
    let mut arm = CArm::posterior_anterior(Vec3::ZERO);
    arm.lao_deg = 30.0;
    arm.cranial_deg = -15.0;
    let a = render(&atlas, &scene(arm), 40, 30).unwrap();
    let b = render(&atlas, &scene(arm), 40, 30).unwrap();
    assert_eq!(
        a.attenuation.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        b.attenuation.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    // A body sphere at the isocentre projects to a round shadow at any angle: darkest at the
    // image centre (between pixels 19–20 and 14–15).
    let darkest = (0..40 * 30)
        .max_by(|&i, &j| a.attenuation[i].total_cmp(&a.attenuation[j]))
        .unwrap();
    let (col, row) = (darkest % 40, darkest / 40);
    assert!(
        (19..=20).contains(&col) && (14..=15).contains(&row),
        "darkest at ({col}, {row})"
    );
    // 60 mm of 60 HU tissue: a ≈ 0.017 × 1.06 × 60 ≈ 1.08.
    assert!(
        (a.attenuation[darkest] - 1.08).abs() < 0.02,
        "{}",
        a.attenuation[darkest]
    );
}

/// Bit-identical on one thread and on four (every pixel a pure function of the inputs).
#[test]
fn the_thread_count_does_not_change_a_bit() {
    let atlas = synthetic::atlas(
        40,
        2.0,
        |p| if p.length() < 30.0 { 60.0 + p.x as f32 } else { -1000.0 },
        |_| 0,
    );
    let mut arm = CArm::posterior_anterior(Vec3::new(1.0, 2.0, -3.0));
    arm.lao_deg = -25.0;
    let draw = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| render(&atlas, &scene(arm), 48, 40).unwrap())
            .attenuation
            .iter()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(draw(1), draw(4));
}

/// Where things land, for the operator at the monitor: at PA a dense marker on the patient's
/// right shows on the image's left and a superior one in the upper half; seen from the patient's
/// left (LAO 90) anterior is on the image's left, from the right (RAO 90) on its right.
#[test]
fn markers_land_where_the_operator_expects_them() {
    let marker = |c: DVec3| move |p: DVec3| if (p - c).length() < 6.0 { 3000.0 } else { 0.0 };
    let darkest_col_row = |img: &Radiograph| {
        let i = (0..img.attenuation.len())
            .max_by(|&i, &j| img.attenuation[i].total_cmp(&img.attenuation[j]))
            .unwrap();
        (i as u32 % img.width, i as u32 / img.width)
    };
    let right = synthetic::atlas(64, 1.5, marker(DVec3::new(30.0, 0.0, 0.0)), |_| 0);
    let pa = render(&right, &scene(CArm::posterior_anterior(Vec3::ZERO)), SIZE, SIZE).unwrap();
    assert!(
        darkest_col_row(&pa).0 < SIZE / 2,
        "patient's right must be on the image's left"
    );
    let superior = synthetic::atlas(64, 1.5, marker(DVec3::new(0.0, 0.0, 30.0)), |_| 0);
    let pa = render(&superior, &scene(CArm::posterior_anterior(Vec3::ZERO)), SIZE, SIZE).unwrap();
    assert!(darkest_col_row(&pa).1 < SIZE / 2, "superior must be up");
    let anterior = synthetic::atlas(64, 1.5, marker(DVec3::new(0.0, 30.0, 0.0)), |_| 0);
    let mut arm = CArm::posterior_anterior(Vec3::ZERO);
    arm.lao_deg = 90.0;
    let lao = render(&anterior, &scene(arm), SIZE, SIZE).unwrap();
    assert!(darkest_col_row(&lao).0 < SIZE / 2, "LAO 90: anterior on the left");
    arm.lao_deg = -90.0;
    let rao = render(&anterior, &scene(arm), SIZE, SIZE).unwrap();
    assert!(darkest_col_row(&rao).0 >= SIZE / 2, "RAO 90: anterior on the right");
}

#[test]
fn bad_scenes_are_refused_with_the_reason() {
    let atlas = synthetic::atlas(8, 1.0, |_| 0.0, |_| 0);
    let mut arm = CArm::posterior_anterior(Vec3::ZERO);
    assert!(
        render(&atlas, &scene(arm), 0, 10)
            .unwrap_err()
            .to_string()
            .contains("pixels")
    );
    arm.lao_deg = f32::NAN;
    assert!(
        render(&atlas, &scene(arm), 10, 10)
            .unwrap_err()
            .to_string()
            .contains("lao_deg")
    );
    // An isocentre far from the patient; an overlay bigger than its values or outside the CT.
    let far = CArm::posterior_anterior(Vec3::new(0.0, 5000.0, 0.0));
    assert!(
        render(&atlas, &scene(far), 10, 10)
            .unwrap_err()
            .to_string()
            .contains("isocentre")
    );
    let ok = CArm::posterior_anterior(Vec3::ZERO);
    for overlay in [
        ContrastOverlay {
            origin: [0, 0, 0],
            dims: [2, 2, 2],
            mu_per_mm: vec![0.1; 7],
        },
        ContrastOverlay {
            origin: [7, 0, 0],
            dims: [2, 1, 1],
            mu_per_mm: vec![0.1; 2],
        },
    ] {
        let bad = XrayScene {
            contrast: Some(overlay),
            ..scene(ok)
        };
        assert!(
            render(&atlas, &bad, 10, 10)
                .unwrap_err()
                .to_string()
                .contains("overlay")
        );
    }
}
