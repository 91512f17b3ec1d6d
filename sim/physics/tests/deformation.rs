//! Tissue deformation (thesis Chapter 4): manufactured solutions, multigrid convergence, symmetry,
//! hard tissue, robustness and determinism of the solve.

use proptest::prelude::*;
use stylet_physics::deform::solver::{self, Level, Schedule};
use stylet_physics::deform::{self, DeformSettings, Lattice, Regulariser, ToolPoint};
use stylet_physics::glam::DVec3;
use stylet_physics::properties::ParamValue;
use stylet_physics::{Affine, Grid, PunctureAtlas, Role, synthetic_atlas};

const VESSEL: u16 = 11;

/// An 80³ atlas at 1 mm: soft tissue (40 HU) under air at z > 25 mm (the skin), a bone slab
/// (700 HU) at x ≥ 20 mm and a vessel (risk) tube along z at (x, y) = (−8, 0), radius 2 mm.
fn atlas() -> PunctureAtlas {
    let n = 80;
    let g = Grid::new([n; 3], Affine::from_spacing([1.0; 3], DVec3::splat(-39.5))).unwrap();
    let mut ct = vec![40.0f32; g.len()];
    let mut labels = vec![0u16; g.len()];
    for i in 0..g.len() {
        let [a, b, c] = g.unlinear(i);
        let p = g.voxel_to_world(a, b, c);
        if p.x >= 20.0 {
            ct[i] = 700.0;
        }
        if p.z > 25.0 {
            ct[i] = -1000.0;
        }
        if ((p.x + 8.0).powi(2) + p.y * p.y).sqrt() < 2.0 {
            labels[i] = VESSEL;
        }
    }
    synthetic_atlas::atlas_with(
        g,
        ct,
        labels,
        &[(VESSEL, "portal vein", Role::Risk)],
        ParamValue::Scalar(0.5),
    )
    .unwrap()
}

fn settings(cells: u32, levels: u32) -> DeformSettings {
    let mut s = DeformSettings::on();
    s.cells = cells;
    s.schedule.levels = levels;
    s
}

/// A finger-like push: a 3 × 3 patch of points at `at` pressed 4 mm along −z.
fn push(at: DVec3) -> Vec<ToolPoint> {
    let mut v = Vec::new();
    for a in -1..=1 {
        for b in -1..=1 {
            v.push(ToolPoint {
                reference_mm: at + DVec3::new(a as f64, b as f64, 0.0),
                displacement_mm: DVec3::new(0.0, 0.0, -4.0),
                radius_mm: 0.0,
            });
        }
    }
    v
}

fn max_diff(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (*x - *y).length()).fold(0.0, f64::max)
}

/// Solves A u = g on an n³ lattice of [0, 1]³·30 mm with u on the border and g taken from the
/// exact field u*(x) = (sin, cos, sin products); returns the largest nodal error.
fn manufactured_error(reg: Regulariser, n: usize) -> f64 {
    let side_mm = 30.0;
    let lattice = Lattice {
        n,
        h_mm: side_mm / (n - 1) as f64,
        origin_mm: DVec3::ZERO,
    };
    let w = std::f64::consts::PI / side_mm;
    let exact = |p: DVec3| {
        DVec3::new(
            (w * p.x).sin() * (w * p.y).sin() * (w * p.z).cos(),
            (w * p.y).sin() * (w * p.z).cos(),
            (w * p.x).cos() * (w * p.z).sin(),
        )
    };
    // g = L u* evaluated analytically by finite differences of tiny step (≪ h: exact to 1e-7).
    let (mu, lm) = reg.lame();
    let e = 1e-3;
    let d2 = |a: DVec3, b: DVec3, p: DVec3| {
        (exact(p + a * e + b * e) - exact(p + a * e - b * e) - exact(p - a * e + b * e) + exact(p - a * e - b * e))
            / (4.0 * e * e)
    };
    let axes = [DVec3::X, DVec3::Y, DVec3::Z];
    let l_exact = |p: DVec3| {
        let lap = axes.iter().fold(DVec3::ZERO, |s, a| s + d2(*a, *a, p));
        let gd = DVec3::new(
            (0..3).map(|j| d2(DVec3::X, axes[j], p)[j]).sum(),
            (0..3).map(|j| d2(DVec3::Y, axes[j], p)[j]).sum(),
            (0..3).map(|j| d2(DVec3::Z, axes[j], p)[j]).sum(),
        );
        lap * mu + gd * lm
    };
    let mut u = vec![DVec3::ZERO; lattice.len()];
    let mut g = vec![DVec3::ZERO; lattice.len()];
    let mut fixed = vec![false; lattice.len()];
    for idx in 0..lattice.len() {
        let [i, j, k] = lattice.ijk(idx);
        let p = lattice.position(i, j, k);
        g[idx] = l_exact(p);
        if lattice.is_border(i, j, k) {
            fixed[idx] = true;
            u[idx] = exact(p);
        }
    }
    let finest = Level {
        lattice,
        fixed,
        f_mat: vec![1.0; lattice.len()].into(),
    };
    let levels = solver::hierarchy(finest, 3);
    let schedule = Schedule {
        levels: 3,
        cycles: 400,
        pre_steps: 3,
        post_steps: 3,
        coarsest_steps: 60,
        fed_cycle_steps: 0,
    };
    let mut c = solver::split(&u);
    solver::solve(&levels, reg, &schedule, &mut c, Some(&solver::split(&g)));
    let u = solver::join(&c);
    (0..lattice.len())
        .map(|idx| {
            let [i, j, k] = lattice.ijk(idx);
            (u[idx] - exact(lattice.position(i, j, k))).length()
        })
        .fold(0.0, f64::max)
}

#[test]
fn each_operator_solves_a_manufactured_solution_at_second_order() {
    for reg in [
        Regulariser::Diffusion,
        Regulariser::LinearElastic { poisson_ratio: 0.4 },
    ] {
        let errors: Vec<f64> = [9, 17, 33].iter().map(|&n| manufactured_error(reg, n)).collect();
        for w in errors.windows(2) {
            // h halves: second order means the error falls by ≈ 4.
            let order = (w[0] / w[1]).log2();
            assert!(order > 1.7, "{reg:?}: errors {errors:?}");
        }
        assert!(errors[2] < 3e-3, "{reg:?}: errors {errors:?}");
    }
}

/// The field after `frames` warm-started solves with the same tool points.
fn frames(atlas: &PunctureAtlas, s: &DeformSettings, points: &[ToolPoint], frames: usize) -> deform::DeformField {
    frames_at(atlas, s, points, frames, DVec3::new(-2.0, 3.0, 10.0))
}

fn frames_at(
    atlas: &PunctureAtlas,
    s: &DeformSettings,
    points: &[ToolPoint],
    frames: usize,
    centre: DVec3,
) -> deform::DeformField {
    let mut f = deform::solve(atlas, s, None, centre, points);
    for _ in 1..frames {
        f = deform::solve(atlas, s, Some(&f), centre, points);
    }
    f
}

#[test]
fn the_multigrid_schedule_converges_to_the_fully_converged_solve() {
    let atlas = atlas();
    let points = push(DVec3::new(-2.0, 3.0, 10.0));
    for reg in [
        Regulariser::Diffusion,
        Regulariser::LinearElastic { poisson_ratio: 0.45 },
    ] {
        let mut s = settings(32, 3);
        s.regulariser = reg;
        let mut converged = s;
        converged.schedule.cycles = 300;
        let reference = frames(&atlas, &converged, &points, 1);
        let err = |f: &deform::DeformField| max_diff(&f.displacements(), &reference.displacements());
        let e: Vec<f64> = [1, 5, 40, 150]
            .iter()
            .map(|&k| err(&frames(&atlas, &s, &points, k)))
            .collect();
        println!("{reg:?}: error after 1, 5, 40, 150 frames {e:?} mm");
        assert!(e.windows(2).all(|w| w[0] > w[1]) && e[3] < 5e-3, "{reg:?}: {e:?}");
        // The same number of finest-level steps without the coarse levels is much further off.
        let mut plain = s;
        plain.schedule.levels = 1;
        plain.schedule.coarsest_steps = s.schedule.pre_steps + s.schedule.post_steps;
        plain.schedule.fed_cycle_steps = 0;
        let e_plain = err(&frames(&atlas, &plain, &points, 40));
        assert!(
            e_plain > 3.0 * e[2],
            "{reg:?}: plain {e_plain} vs multigrid {} after 40 frames",
            e[2]
        );
    }
}

#[test]
fn fed_cycles_converge_faster_than_plain_steps_for_diffusion() {
    let atlas = atlas();
    let points = push(DVec3::new(-2.0, 3.0, 10.0));
    let mut s = settings(32, 1);
    s.regulariser = Regulariser::Diffusion;
    s.schedule.coarsest_steps = 40;
    let mut converged = s;
    converged.schedule.levels = 3;
    converged.schedule.cycles = 300;
    let reference = frames(&atlas, &converged, &points, 1);
    let mut plain = s;
    plain.schedule.fed_cycle_steps = 0;
    let e_fed = max_diff(
        &frames(&atlas, &s, &points, 3).displacements(),
        &reference.displacements(),
    );
    let e_plain = max_diff(
        &frames(&atlas, &plain, &points, 3).displacements(),
        &reference.displacements(),
    );
    assert!(e_fed < 0.5 * e_plain, "FED {e_fed} vs plain {e_plain}");
}

#[test]
fn a_symmetric_load_gives_a_symmetric_field() {
    let atlas = atlas();
    let s = settings(32, 3);
    // The lattice centred on the origin has nodes at −16 … 16 mm: the 3 × 3 patch around node
    // 16 is symmetric in x and y.
    let points = push(DVec3::ZERO);
    let f = frames_at(&atlas, &s, &points, 10, DVec3::ZERO);
    let l = *f.lattice();
    assert_eq!(l.origin_mm, DVec3::splat(-16.0));
    let u = f.displacements();
    let m = l.n - 1;
    let mut worst: f64 = 0.0;
    for idx in 0..l.len() {
        let [i, j, k] = l.ijk(idx);
        let a = u[idx];
        let bx = u[l.index(m - i, j, k)];
        let by = u[l.index(i, m - j, k)];
        worst = worst.max((a.x + bx.x).abs() + (a.y - bx.y).abs() + (a.z - bx.z).abs());
        worst = worst.max((a.x - by.x).abs() + (a.y + by.y).abs() + (a.z - by.z).abs());
    }
    assert!(f.max_displacement_mm() > 3.9, "{}", f.max_displacement_mm());
    assert!(worst < 1e-9, "asymmetry {worst}");
}

#[test]
fn hard_tissue_stays_where_it_is() {
    let atlas = atlas();
    let s = settings(32, 3);
    let points = push(DVec3::new(16.0, 0.0, 10.0));
    let f = frames_at(&atlas, &s, &points, 10, DVec3::new(16.0, 0.0, 10.0));
    let l = *f.lattice();
    let (mut bone_nodes, mut moved_soft) = (0, 0);
    for idx in 0..l.len() {
        let [i, j, k] = l.ijk(idx);
        let p = l.position(i, j, k);
        if atlas.hu_at(p) >= 200.0 {
            bone_nodes += 1;
            assert_eq!(f.node(idx), DVec3::ZERO, "bone node at {p} moved");
        } else if f.node(idx).length() > 0.1 {
            moved_soft += 1;
        }
    }
    assert!(
        bone_nodes > 1000 && moved_soft > 100,
        "{bone_nodes} bone, {moved_soft} moved"
    );
}

#[test]
fn a_vessel_pushed_aside_is_measured() {
    let atlas = atlas();
    let s = settings(32, 3);
    // Pressing beside the vessel at x = −8 moves it; pressing far away barely does.
    let at = |p: DVec3| frames_at(&atlas, &s, &push(p), 10, p);
    let near = at(DVec3::new(-5.0, 0.0, 10.0));
    let far = at(DVec3::new(10.0, 10.0, 10.0));
    assert!(near.risk_displacement_mm() > 1.0, "{}", near.risk_displacement_mm());
    assert!(far.risk_displacement_mm() < 0.5 * near.risk_displacement_mm());
}

#[test]
fn the_solve_gives_the_same_bits_on_one_and_two_threads() {
    let atlas = atlas();
    let s = settings(64, 3);
    let points = push(DVec3::new(-2.0, 3.0, 10.0));
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| frames(&atlas, &s, &points, 3))
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.digest(), b.digest());
    assert!(
        a.displacements()
            .iter()
            .zip(&b.displacements())
            .all(|(x, y)| x.to_array().map(f64::to_bits) == y.to_array().map(f64::to_bits))
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    /// Random tool points anywhere (inside bone, on the border, outside Ω_J) and random
    /// displacements: never NaN, never larger than the largest imposed displacement × 2.
    #[test]
    fn no_nan_under_random_tool_motion(
        pts in prop::collection::vec(((-30.0..30.0f64, -30.0..30.0f64, -10.0..30.0f64), (-8.0..8.0f64, -8.0..8.0f64, -8.0..8.0f64)), 0..40),
        centre in (-20.0..20.0f64, -20.0..20.0f64, 0.0..20.0f64),
    ) {
        let atlas = atlas();
        let s = settings(16, 2);
        let points: Vec<ToolPoint> = pts.iter().enumerate().map(|(i, (p, d))| ToolPoint {
            reference_mm: DVec3::new(p.0, p.1, p.2),
            displacement_mm: DVec3::new(d.0, d.1, d.2),
            radius_mm: (i % 3) as f64 * 1.5,
        }).collect();
        let c = DVec3::new(centre.0, centre.1, centre.2);
        let mut f = deform::solve(&atlas, &s, None, c, &points);
        for shift in 0..3 {
            f = deform::solve(&atlas, &s, Some(&f), c + DVec3::splat(shift as f64 * 3.0), &points);
        }
        let bound = points.iter().map(|p| p.displacement_mm.length()).fold(0.0, f64::max);
        prop_assert!(f.displacements().iter().all(|v| v.is_finite()));
        prop_assert!(f.max_displacement_mm() <= 2.0 * bound + 1e-9, "{} vs {bound}", f.max_displacement_mm());
    }
}

/// A finger pressed into the skin at z = 25 mm and held: outputs and state digests.
fn press(background: bool, deformation: DeformSettings) -> Vec<(stylet_physics::TickOutput, u64)> {
    use stylet_physics::glam::DQuat;
    use stylet_physics::{DeviceProfile, SimConfig, Simulation, TickInput, ToolSpec};
    let mut config = SimConfig::new(DeviceProfile::IDEAL, ToolSpec::Finger);
    config.deformation = deformation;
    config.deform_in_background = background;
    let mut sim = Simulation::new(std::sync::Arc::new(atlas()), config).unwrap();
    // The finger's axis points into the patient: −z.
    let q = DQuat::from_rotation_x(std::f64::consts::PI);
    (0..800)
        .map(|t| {
            let z = 28.0 - 8.0 * (t.min(400) as f64 / 400.0);
            let out = sim.step(&TickInput::pose(DVec3::new(-3.0, 2.0, z), q));
            (out, sim.state_digest())
        })
        .collect()
}

#[test]
fn a_background_solve_enters_at_the_same_tick_with_the_same_bits() {
    let s = settings(32, 3);
    let inline = press(false, s);
    let background = press(true, s);
    assert_eq!(inline, background);
    let last = inline.last().unwrap().0;
    assert!(last.indentation_mm > 1.0, "{}", last.indentation_mm);
    assert!(last.tissue_displacement_mm > 1.0, "{}", last.tissue_displacement_mm);
    // The field enters `latency_ticks` after the solve starts, never earlier.
    let first = inline.iter().position(|(o, _)| o.tissue_displacement_mm > 0.0).unwrap() as u64;
    // (Tick t ends at time t + 1, when due results enter.)
    assert_eq!((first + 1) % u64::from(s.every_ticks), 0);
    // Deformation is state: the digests differ from a run without it; the forces do not.
    let off = press(false, DeformSettings::off());
    assert_ne!(off.last().unwrap().1, inline.last().unwrap().1);
    assert!(off.iter().zip(&inline).all(|(a, b)| a.0.force_n == b.0.force_n));
}

/// A probe face (8 × 4 contact patches of 3 mm, 5 mm apart) pressed 4 mm for 3 s of frames while
/// sliding: the field stays bounded by what is imposed. (With coarse constraints by injection
/// alone the cycle once diverged to 1e14 mm on such a face.)
#[test]
fn a_pressed_probe_face_stays_bounded_while_it_slides() {
    let atlas = atlas();
    let s = settings(32, 3);
    let face = |y0: f64| -> Vec<ToolPoint> {
        let mut v = Vec::new();
        for iy in 0..4 {
            for ix in 0..8 {
                v.push(ToolPoint {
                    reference_mm: DVec3::new(-17.5 + 5.0 * ix as f64, y0 - 5.0 + 10.0 / 3.0 * iy as f64, 25.0),
                    displacement_mm: DVec3::new(0.3, 0.0, -4.0),
                    radius_mm: 3.0,
                });
            }
        }
        v
    };
    let mut f = deform::solve(&atlas, &s, None, DVec3::new(0.0, -10.0, 20.0), &face(-10.0));
    for frame in 0..30 {
        let y = -10.0 + frame as f64;
        f = deform::solve(&atlas, &s, Some(&f), DVec3::new(0.0, y, 20.0), &face(y));
        let max = f.max_displacement_mm();
        assert!(max <= 4.02, "frame {frame}: {max} mm");
    }
    assert!(f.max_displacement_mm() > 3.9);
}

/// The bits of three frames per regulariser, pinned: a faster solver (vector kernels, separable
/// prolongation, cached levels) must give exactly these, or it changes the physics and bumps
/// `PHYSICS_VERSION` (recorded sessions replay against them).
#[test]
fn the_solve_keeps_its_bits() {
    let atlas = atlas();
    let points = push(DVec3::new(-2.0, 3.0, 10.0));
    // The schedule of physics version 4's first default (three levels, 40 coarsest steps) for
    // both regularisers, and today's default.
    let mut elastic = settings(64, 3);
    elastic.schedule.coarsest_steps = 40;
    let mut diffusion = elastic;
    diffusion.cells = 32;
    diffusion.regulariser = Regulariser::Diffusion;
    let mut got = Vec::new();
    for s in [elastic, diffusion, DeformSettings::on()] {
        let f = frames(&atlas, &s, &points, 3);
        // The tool moves 3 mm: the lattice shifts and the warm start is copied across.
        let moved: Vec<ToolPoint> = points
            .iter()
            .map(|p| ToolPoint {
                reference_mm: p.reference_mm + DVec3::new(3.0, 0.0, 0.0),
                ..*p
            })
            .collect();
        let g = deform::solve(&atlas, &s, Some(&f), DVec3::new(9.0, 3.0, 10.0), &moved);
        got.push((f.digest(), g.digest()));
    }
    assert_eq!(got, PINNED, "{got:x?}");
}
const PINNED: [(u64, u64); 3] = [
    (0xcf8d0bcc14509d43, 0x5dea0f8081ca1be5),
    (0x76d176f241ac047f, 0x54d1c75da1d16bcb),
    (0xd1cdfd83eb564f01, 0x7b5b0c9ba6a59c99),
];

/// Eqs. 4.2.2–4.2.3 at the tip: a needle pressed on the skin without cutting it pushes the skin
/// point it touched along the needle by as far as the device is past the needle's tip (the
/// cutting spring's extension Δd): the skin tents.
#[test]
fn a_needle_pressing_on_the_skin_tents_it_by_the_cutting_springs_extension() {
    use stylet_physics::glam::DQuat;
    use stylet_physics::{DeviceProfile, Gauge, SimConfig, Simulation, TickInput, ToolSpec};
    let config = SimConfig::new(
        DeviceProfile::IDEAL,
        ToolSpec::Needle {
            gauge: Gauge::G18,
            length_mm: 150.0,
            stylet_in: true,
        },
    );
    let mut sim = Simulation::new(std::sync::Arc::new(atlas()), config).unwrap();
    // The needle points into the patient (−z); the skin is at z = 25 mm.
    let q = DQuat::from_rotation_x(std::f64::consts::PI);
    let mut at = |z: f64| {
        let out = sim.step(&TickInput::pose(DVec3::new(-3.0, 2.0, z), q));
        let needle = sim.needle().unwrap();
        let points = deform::tool_points::needle_points(needle, 0.5);
        let channel_tip = needle.path().tip().copied();
        (out, points, needle.nodes().last().copied().unwrap(), channel_tip)
    };
    for t in 0..=200 {
        at(30.0 - 5.3 * f64::from(t) / 200.0);
    }
    // 0.3 mm past the skin: under the cutting threshold of this atlas (0.5 N), nothing cut.
    let (out, points, tip, channel_tip) = at(24.7);
    let cut_n = out.components.cut.length();
    assert!(cut_n > 0.0 && cut_n < 0.5, "{cut_n}");
    assert_eq!(points.len(), 1, "the tip rests on the skin");
    let past_mm = tip.z - 24.7;
    assert!(past_mm > 0.2, "{past_mm}");
    // ũ = (needle tip − channel tip) + the shaft's stick offset + Δd, all along −z.
    let channel_tip = channel_tip.unwrap();
    let expected = (tip - channel_tip.pos) + channel_tip.tangent * (channel_tip.offset_mm + past_mm);
    let u = points[0].displacement_mm;
    assert!((u - expected).length() < 1e-12, "{u} vs {expected}");
    assert!(u.x.abs() < 1e-9 && u.y.abs() < 1e-9 && -u.z >= past_mm, "{u}");
}

/// A two-handed run on the atlas above: the first hand holds an 18 G needle over the skin and
/// advances it 6 mm into the tissue at (−3, 2); the second hand presses a finger 5 mm into the
/// skin 12 mm beside it from tick 100 on (or holds nothing). Outputs and state digests.
fn two_hands(
    background: bool,
    second: Option<stylet_physics::HandTool>,
    second_device: stylet_physics::DeviceProfile,
) -> Vec<(stylet_physics::TickOutput, u64)> {
    use stylet_physics::glam::DQuat;
    use stylet_physics::{
        DeviceProfile, Gauge, HandPose, SecondHandConfig, SimConfig, Simulation, TickInput, ToolSpec,
    };
    let needle = ToolSpec::Needle {
        gauge: Gauge::G18,
        length_mm: 150.0,
        stylet_in: true,
    };
    let mut config = SimConfig::new(DeviceProfile::PREMIUM, needle);
    config.deformation = settings(32, 3);
    config.deform_in_background = background;
    config.second_hand = Some(SecondHandConfig {
        device: second_device,
        tool: second,
    });
    let mut sim = Simulation::new(std::sync::Arc::new(atlas()), config).unwrap();
    let down = DQuat::from_rotation_x(std::f64::consts::PI);
    (0u64..900)
        .map(|t| {
            let depth = 6.0 * (t.saturating_sub(300).min(500) as f64 / 500.0);
            let mut input = TickInput::pose(DVec3::new(-3.0, 2.0, 25.5 - depth), down);
            input.second_hand = (t >= 100).then(|| HandPose {
                position_mm: DVec3::new(9.0, 2.0, 28.0 - 8.0 * ((t - 100).min(200) as f64 / 200.0)),
                orientation: down,
                buttons: 0,
            });
            let out = sim.step(&input);
            (out, sim.state_digest())
        })
        .collect()
}

#[test]
fn two_hands_step_on_one_tissue_each_device_gets_its_tools_force_and_replay_is_bit_identical() {
    use stylet_physics::{DeviceProfile, HandTool};
    let finger = Some(HandTool::Finger);
    let run = two_hands(false, finger, DeviceProfile::PREMIUM);
    // The same inputs give the same bits, with the solve inline or on its own thread.
    assert_eq!(run, two_hands(false, finger, DeviceProfile::PREMIUM));
    assert_eq!(run, two_hands(true, finger, DeviceProfile::PREMIUM));
    // Each device gets its own tool's force: the finger pushes back on the second hand (+z)
    // while the needle, still above the skin at tick 250, feels nothing.
    let (at_250, _) = &run[250];
    let hand = at_250.second_hand.expect("a two-handed tick reports the second hand");
    assert!(hand.holding && hand.contacts > 0 && hand.force_n.z > 0.5, "{hand:?}");
    assert_eq!(at_250.force_n, DVec3::ZERO);
    let (last, _) = run.last().unwrap();
    assert!(last.inserted_mm > 0.0 && last.force_n.length() > 0.0, "{last:?}");
    // The finger's press enters the deformation solve beside the needle's: with an empty second
    // hand the field is the needle's alone, smaller.
    let empty = two_hands(false, None, DeviceProfile::PREMIUM);
    assert!(
        empty
            .iter()
            .all(|(o, _)| o.second_hand.is_some_and(|h| !h.holding && h.force_n == DVec3::ZERO))
    );
    let pressed = run[250].0.tissue_displacement_mm;
    assert!(pressed > 2.0, "the finger alone deforms the tissue: {pressed} mm");
    assert_eq!(empty[250].0.tissue_displacement_mm, 0.0);
    // The second hand's force is clamped to its own device: the Touch's 3.3 N.
    let touch = two_hands(false, finger, DeviceProfile::TOUCH);
    let peak = touch
        .iter()
        .filter_map(|(o, _)| o.second_hand)
        .map(|h| h.force_n.length())
        .fold(0.0, f64::max);
    let unclamped = run
        .iter()
        .filter_map(|(o, _)| o.second_hand)
        .map(|h| h.force_n.length())
        .fold(0.0, f64::max);
    assert!(
        unclamped > 3.3 && peak <= 3.3 + 1e-12,
        "{unclamped} N on the Premium, {peak} N on the Touch"
    );
}

#[test]
fn a_one_handed_run_hashes_as_before_and_a_second_hand_changes_the_digest() {
    use stylet_physics::glam::DQuat;
    use stylet_physics::{DeviceProfile, HandTool, SecondHandConfig, SimConfig, Simulation, TickInput, ToolSpec};
    let run = |second: Option<SecondHandConfig>| {
        let mut config = SimConfig::new(DeviceProfile::IDEAL, ToolSpec::Finger);
        config.second_hand = second;
        let mut sim = Simulation::new(std::sync::Arc::new(atlas()), config).unwrap();
        let q = DQuat::from_rotation_x(std::f64::consts::PI);
        for t in 0..50 {
            sim.step(&TickInput::pose(DVec3::new(-3.0, 2.0, 27.0 - 0.05 * t as f64), q));
        }
        sim.state_digest()
    };
    // Pinned: the digest of this one-handed run before two hands existed (re-pinned at physics
    // version 12, whose contrast tally counts the washout; the second hand still adds nothing).
    assert_eq!(run(None), 0x4515_1042_c5c2_aeb0);
    let two = run(Some(SecondHandConfig {
        device: DeviceProfile::IDEAL,
        tool: Some(HandTool::Probe(stylet_physics::ProbeKind::Convex)),
    }));
    assert_ne!(two, run(None));
}
