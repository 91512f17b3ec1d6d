//! The haptic core against the thesis' experiments on the phantom: Fig. 3.12 (needle force
//! components), Fig. 3.13 (steering), Fig. 3.14 (palpation and probe over the ribs), stability,
//! NaN-freedom and determinism.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::common::default_phantom;
use proptest::prelude::*;
use stylet_atlas::Atlas;
use stylet_devices::run_headless;
use stylet_devices::script::{parse, scripted_simulation};
use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::{DeviceProfile, Gauge, ProbeKind, SimConfig, Simulation, TickInput, TickOutput, ToolSpec};

struct Run {
    ticks: Vec<(TickInput, TickOutput)>,
    sim: Simulation,
}

fn run_text(atlas: &Atlas, text: &str) -> Run {
    let script = parse(text).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let mut ticks = Vec::new();
    run_headless(&mut sim, &mut device, |i, o, _| ticks.push((i.clone(), *o)));
    Run { ticks, sim }
}

fn script_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("atlases/phantom/scripts")
        .join(name)
}

fn run_file(atlas: &Atlas, name: &str) -> Run {
    run_text(atlas, &std::fs::read_to_string(script_path(name)).unwrap())
}

fn label(atlas: &Atlas, name: &str) -> u16 {
    atlas.model.label_table().by_name(name).unwrap().id
}

/// Resistance along the insertion direction (N): what Fig. 3.12 plots.
fn along(o: &TickOutput, v: DVec3) -> f64 {
    -v.dot(o.insertion_dir)
}

/// Fig. 3.12: distinct cutting-force peaks at the skin, fascia and duct punctures, in that order;
/// no cutting force while retracting; friction grows with depth and changes sign on retraction.
#[test]
fn fig_3_12_needle_force_components() {
    let atlas = default_phantom();
    let r = run_file(atlas, "success-intercostal.txt");
    let (skin, fascia, duct, target) = (
        label(atlas, "skin"),
        label(atlas, "intercostal fascia"),
        label(atlas, "bile duct"),
        label(atlas, "right hepatic duct"),
    );
    // The peak while the tip is in a structure, and the cutting force 0.3 s after it left it.
    let peak = |labels: &[u16]| -> (f64, f64, f64) {
        let idx: Vec<usize> = (0..r.ticks.len())
            .filter(|&i| labels.contains(&r.ticks[i].1.tip_label) && r.ticks[i].1.inserted_mm > 0.0)
            .collect();
        assert!(!idx.is_empty(), "the tip never entered {labels:?}");
        let mut i = idx[0];
        for &j in &idx {
            if along(&r.ticks[j].1, r.ticks[j].1.components.cut) > along(&r.ticks[i].1, r.ticks[i].1.components.cut) {
                i = j;
            }
        }
        let best = along(&r.ticks[i].1, r.ticks[i].1.components.cut);
        let after = (i + 300).min(r.ticks.len() - 1);
        (
            r.ticks[i].1.time_s,
            best,
            along(&r.ticks[after].1, r.ticks[after].1.components.cut),
        )
    };
    let (t_skin, f_skin, after_skin) = peak(&[skin]);
    let (t_fascia, f_fascia, after_fascia) = peak(&[fascia]);
    let (t_duct, f_duct, after_duct) = peak(&[duct, target]);
    println!(
        "skin {f_skin:.2} N at {t_skin:.2} s → {after_skin:.2}; fascia {f_fascia:.2} N at {t_fascia:.2} s → {after_fascia:.2}; duct {f_duct:.2} N at {t_duct:.2} s → {after_duct:.2}"
    );
    assert!(
        t_skin < t_fascia && t_fascia < t_duct,
        "order skin {t_skin}, fascia {t_fascia}, duct {t_duct}"
    );
    assert!(
        f_skin > 2.0 && after_skin < 0.5 * f_skin,
        "skin peak {f_skin} → {after_skin}"
    );
    assert!(
        f_fascia > 1.0 && after_fascia < 0.5 * f_fascia,
        "fascia peak {f_fascia} → {after_fascia}"
    );
    assert!(
        f_duct > 0.4 && after_duct < 0.5 * f_duct,
        "duct peak {f_duct} → {after_duct}"
    );

    // Retraction (device moving out for 50 ms, so the cutting spring has unloaded): cutting force
    // exactly zero, friction negative (it now resists pulling out).
    let mut retracting = 0;
    let mut outward_run = 0;
    for w in r.ticks.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        let outward = (b.0.position_mm - a.0.position_mm).dot(b.1.insertion_dir) < -1e-6;
        outward_run = if outward { outward_run + 1 } else { 0 };
        if outward_run > 50 && b.1.inserted_mm > 5.0 {
            retracting += 1;
            assert_eq!(
                b.1.components.cut,
                DVec3::ZERO,
                "cutting force while retracting at {} s",
                b.1.time_s
            );
            assert!(
                along(&b.1, b.1.components.friction) < 0.0,
                "friction keeps its sign at {} s",
                b.1.time_s
            );
        }
    }
    assert!(retracting > 3000, "{retracting} retracting ticks");
    // Insertion (2.5–10.5 s): friction grows with depth (Pearson r > 0.95) to more than 0.5 N.
    let ins: Vec<(f64, f64)> = r
        .ticks
        .iter()
        .filter(|(_, o)| o.time_s > 2.5 && o.time_s < 10.5)
        .map(|(_, o)| (o.inserted_mm, along(o, o.components.friction)))
        .collect();
    let n = ins.len() as f64;
    let (mx, my) = (
        ins.iter().map(|p| p.0).sum::<f64>() / n,
        ins.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let cov: f64 = ins.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let (vx, vy): (f64, f64) = (
        ins.iter().map(|p| (p.0 - mx).powi(2)).sum(),
        ins.iter().map(|p| (p.1 - my).powi(2)).sum(),
    );
    let corr = cov / (vx * vy).sqrt();
    let max_fric = ins.iter().map(|p| p.1).fold(f64::MIN, f64::max);
    println!("friction vs depth: r = {corr:.3}, up to {max_fric:.2} N");
    assert!(corr > 0.95 && max_fric > 0.5, "r = {corr}, max {max_fric}");
    // The script ends with the needle out and the contrast given in the target.
    let last = r.ticks.last().unwrap().1;
    assert_eq!(last.inserted_mm, 0.0);
    assert!(last.contrast_ml >= 2.0);
    let stylet_out_in_target = r.ticks.iter().any(|(_, o)| !o.stylet_in && o.tip_label == target);
    assert!(stylet_out_in_target, "stylet removed in the target");
}

fn tangent_turn_deg(sim: &Simulation) -> f64 {
    let nodes = sim.needle().unwrap().path().nodes();
    let (a, b) = (nodes[1].tangent, nodes[nodes.len() - 1].tangent);
    a.angle_between(b).to_degrees()
}

/// Fig. 3.13: a straight push leaves a straight channel; angulating the needle after 30 mm bends
/// the needle, turns the tip and so the channel.
#[test]
fn fig_3_13_angulation_curves_the_path() {
    let atlas = default_phantom();
    // Entry in the right 10th/11th intercostal space; the straight push goes to the target.
    let (e, t) = ("152.6 1.5 15.9", "50.5 30 7.5");
    let straight = run_text(
        atlas,
        &format!("stylet-script 1\nend 10\nat 0 aim {e} {t} -10\nat 9 aim {e} {t} 90\n"),
    );
    let straight_turn = tangent_turn_deg(&straight.sim);
    // Angulated: at 30 mm the device pivots 20° about the entry (towards −z) while advancing.
    let tilted = "50.5 30 -30.0";
    let bent = run_text(
        atlas,
        &format!("stylet-script 1\nend 10\nat 0 aim {e} {t} -10\nat 4 aim {e} {t} 30\nat 9 aim {e} {tilted} 90\n"),
    );
    let bent_turn = tangent_turn_deg(&bent.sim);
    println!("path tangent turn: straight {straight_turn:.2}°, angulated {bent_turn:.2}°");
    let nodes = bent.sim.needle().unwrap().path().nodes();
    let z_turn = nodes[nodes.len() - 1].tangent.z - nodes[1].tangent.z;
    println!("tip tangent z changed by {z_turn:+.4} (the angulation points to −z)");
    assert!(straight_turn < 0.2, "straight push turned {straight_turn}°");
    assert!(
        bent_turn > 1.0 && bent_turn > 10.0 * straight_turn,
        "angulated push turned only {bent_turn}°"
    );
    // The channel turns towards the angulation.
    assert!(z_turn < 0.0, "the channel turned away from the angulation");
}

/// Mean indentation in ±3 mm windows around cranio-caudal positions.
fn windows(r: &Run, centres: &[f64]) -> Vec<f64> {
    centres
        .iter()
        .map(|&c| {
            let v: Vec<f64> = r
                .ticks
                .iter()
                .filter(|(i, o)| o.contacts > 0 && (i.position_mm.z - c).abs() < 3.0)
                .map(|(_, o)| o.indentation_mm)
                .collect();
            assert!(!v.is_empty(), "no contact around z = {c}");
            v.iter().sum::<f64>() / v.len() as f64
        })
        .collect()
}

/// Rib and intercostal positions of the phantom at the mid-axillary line (ribs 10, 9, 8 at
/// z = 28, 56, 84 mm; spaces halfway).
const OVER_RIBS: [f64; 3] = [28.0, 56.0, 84.0];
const BETWEEN_RIBS: [f64; 3] = [14.0, 42.0, 70.0];

fn rib_contrast(r: &Run) -> f64 {
    let mean = |v: Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    mean(windows(r, &BETWEEN_RIBS)) - mean(windows(r, &OVER_RIBS))
}

/// Fig. 3.14: pressed with a constant 1 N and swept cranio-caudally, the finger sinks deeper
/// between the ribs than over them, with the rib spacing in the trace; a probe sinks into the
/// intercostal spaces only when parallel to them.
#[test]
fn fig_3_14_palpation_and_probe_over_the_ribs() {
    let atlas = default_phantom();
    let finger = run_file(atlas, "palpation-sweep.txt");
    let over = windows(&finger, &OVER_RIBS);
    let between = windows(&finger, &BETWEEN_RIBS);
    println!("finger: over ribs {over:.2?} mm, between {between:.2?} mm");
    // Each space deeper than the rib below and above it.
    for k in 0..3 {
        assert!(
            between[k] > over[k] + 0.1,
            "space at {} vs rib at {}",
            BETWEEN_RIBS[k],
            OVER_RIBS[k]
        );
        if k > 0 {
            assert!(
                between[k] > over[k - 1] + 0.1,
                "space at {} vs rib at {}",
                BETWEEN_RIBS[k],
                OVER_RIBS[k - 1]
            );
        }
    }
    // The press holds about 1 N while sweeping.
    let f: Vec<f64> = finger
        .ticks
        .iter()
        .filter(|(i, _)| i.position_mm.z < 100.0 && i.position_mm.z > 0.0)
        .map(|(_, o)| along(o, o.force_n))
        .collect();
    let mean_f = f.iter().sum::<f64>() / f.len() as f64;
    assert!((mean_f - 1.0).abs() < 0.1, "mean press force {mean_f}");
    // Rib spacing in the trace: the detrended indentation over z = 0 … 95 mm (1 mm bins) repeats
    // with the rib pitch (28 mm at the mid-axillary line): its autocorrelation peaks there.
    let bins: Vec<f64> = (0..95)
        .map(|b| {
            let v: Vec<f64> = finger
                .ticks
                .iter()
                .filter(|(i, o)| o.contacts > 0 && i.position_mm.z >= b as f64 && i.position_mm.z < b as f64 + 1.0)
                .map(|(_, o)| o.indentation_mm)
                .collect();
            v.iter().sum::<f64>() / v.len().max(1) as f64
        })
        .collect();
    let n = bins.len() as f64;
    let (mx, my) = ((n - 1.0) / 2.0, bins.iter().sum::<f64>() / n);
    let slope = bins
        .iter()
        .enumerate()
        .map(|(i, y)| (i as f64 - mx) * (y - my))
        .sum::<f64>()
        / bins
            .iter()
            .enumerate()
            .map(|(i, _)| (i as f64 - mx).powi(2))
            .sum::<f64>();
    let detrended: Vec<f64> = bins
        .iter()
        .enumerate()
        .map(|(i, y)| y - my - slope * (i as f64 - mx))
        .collect();
    let auto = |lag: usize| -> f64 {
        (0..detrended.len() - lag)
            .map(|i| detrended[i] * detrended[i + lag])
            .sum::<f64>()
            / (detrended.len() - lag) as f64
    };
    let best = (15..45).max_by(|&a, &b| auto(a).total_cmp(&auto(b))).unwrap();
    println!("finger trace repeats every {best} mm");
    assert!(
        (23..=33).contains(&best),
        "the trace repeats every {best} mm, the ribs every 28 mm"
    );

    let parallel_run = run_file(atlas, "probe-parallel.txt");
    let across_run = run_file(atlas, "probe-across.txt");
    let parallel = rib_contrast(&parallel_run);
    let across = rib_contrast(&across_run);
    // The figure (thesis Fig. 3.14): indentation along the sweep, ribs marked; a test artefact.
    use stylet_dashboard::plot::{LineChart, Series, palette, write_chart};
    let trace = |r: &Run| -> Vec<(f64, f64)> {
        r.ticks
            .iter()
            .filter(|(i, o)| o.contacts > 0 && i.position_mm.z < 110.0)
            .map(|(i, o)| (i.position_mm.z, o.indentation_mm))
            .collect()
    };
    let chart = LineChart {
        title: "Palpation and probing over the right ribs, 1 N press (phantom, mid-axillary line)".into(),
        x_label: "cranio-caudal position z (mm)".into(),
        y_label: "indentation under the skin (mm)".into(),
        series: vec![
            Series {
                name: "finger".into(),
                color: palette::SKIN,
                bold: true,
                dashed: false,
                dots: false,
                points: trace(&finger),
            },
            Series {
                name: "linear probe parallel to the ribs".into(),
                color: palette::FRICTION,
                bold: false,
                dashed: false,
                dots: false,
                points: trace(&parallel_run),
            },
            Series {
                name: "linear probe across the ribs".into(),
                color: palette::BONE,
                bold: false,
                dashed: false,
                dots: false,
                points: trace(&across_run),
            },
        ],
        markers: [(0.0, "rib 11"), (28.0, "rib 10"), (56.0, "rib 9"), (84.0, "rib 8")]
            .iter()
            .map(|(z, n)| (*z, n.to_string()))
            .collect(),
        ..Default::default()
    };
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fig-3-14-palpation.png");
    write_chart(&chart, &out, (1200, 600)).unwrap();
    println!("figure written to {}", out.display());
    println!("probe: contrast parallel {parallel:.2} mm, across {across:.2} mm");
    assert!(
        parallel > 0.25,
        "parallel probe sinks only {parallel} mm deeper between the ribs"
    );
    assert!(
        across.abs() < 0.1 && parallel > 3.0 * across.abs(),
        "across {across} vs parallel {parallel}"
    );
}

/// The device handle lets go inside the body and follows the computed force (a 50 g handle with
/// light damping, semi-implicit Euler): it settles, never runs away, never turns NaN.
#[test]
fn a_released_needle_stays_bounded() {
    let atlas = default_phantom();
    let mut r = run_text(
        atlas,
        "stylet-script 1\ndevice touch\nend 6\nat 0 along intercostal-10-11 -10\nat 5 along intercostal-10-11 60\nat 6 along intercostal-10-11 60\n",
    );
    let (last_in, last_out) = r.ticks.last().cloned().unwrap();
    assert!(last_out.inserted_mm > 50.0);
    let (mass_kg, damping_ns_per_m) = (0.05, 2.0);
    let mut x = last_in.position_mm;
    let mut v = DVec3::ZERO; // mm/s
    let q = last_in.orientation;
    let mut out = last_out;
    let dt = 1.0 / r.sim.tick_rate_hz() as f64;
    let start = x;
    let mut trail = Vec::new();
    for _ in 0..10_000 {
        // a [mm/s²] = F/m ·1000 − (b/m) v
        let a = out.force_n * (1000.0 / mass_kg) - v * (damping_ns_per_m / mass_kg);
        v += a * dt;
        x += v * dt;
        out = r.sim.step(&TickInput::pose(x, q));
        assert!(out.force_n.is_finite() && x.is_finite(), "NaN");
        assert!(out.force_n.length() <= r.sim.device().max_force_n + 1e-9);
        assert!(
            (x - start).length() < 10.0,
            "handle ran {} mm away",
            (x - start).length()
        );
        trail.push(x);
    }
    // No drift out of the body: the second half of the 10 s stays where the first half ended.
    let mid = trail[trail.len() / 2];
    let late = trail[trail.len() / 2..]
        .iter()
        .map(|p| p.distance(mid))
        .fold(0.0, f64::max);
    println!(
        "released needle: {:.2} mm from the start after 10 s, {late:.2} mm of motion in the last 5 s",
        (x - start).length()
    );
    assert!(late < 2.0, "still moving {late} mm in the last 5 s");
    assert!(out.inserted_mm > 45.0, "the needle slid out to {} mm", out.inserted_mm);
    r.ticks.clear();
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Random poses, including garbage (NaN, zero quaternions), with every tool: never NaN.
    #[test]
    fn random_poses_never_give_nan(
        tool in 0usize..4,
        steps in prop::collection::vec(((-250.0f64..250.0, -250.0f64..250.0, -200.0f64..200.0), (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0), 0u8..20), 1..60),
    ) {
        let atlas = default_phantom();
        let spec = [
            ToolSpec::Needle { gauge: Gauge::G22, length_mm: 150.0, stylet_in: true },
            ToolSpec::Finger,
            ToolSpec::Probe(ProbeKind::Linear),
            ToolSpec::Probe(ProbeKind::Convex),
        ][tool];
        let mut sim = Simulation::new(Arc::clone(&atlas.model), SimConfig::new(DeviceProfile::PREMIUM, spec)).unwrap();
        let entry = DVec3::new(152.6, 1.5, 15.9);
        for ((x, y, z), (a, b, c, d), kind) in steps {
            // Mostly near the entry (so the needle goes in), sometimes anywhere, sometimes garbage.
            let p = match kind {
                0 => DVec3::new(f64::NAN, y, z),
                1..=3 => DVec3::new(x, y, z),
                _ => entry + DVec3::new(x, y, z) * 0.05 - DVec3::X * (kind as f64),
            };
            let q = if kind == 4 { DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0) } else { DQuat::from_xyzw(a, b, c, d) };
            for _ in 0..20 {
                let o = sim.step(&TickInput::pose(p, q));
                prop_assert!(o.force_n.is_finite() && o.torque_nmm.is_finite() && o.tip_mm.is_finite());
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Random scripts — keyframes anywhere around the patient, presses, tool changes, events —
    /// run without NaN and within the device's limits.
    #[test]
    fn random_scripts_never_give_nan(
        keys in prop::collection::vec((
            (-220.0f64..220.0, -220.0f64..220.0, -180.0f64..180.0),
            (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0),
            0u8..12,
        ), 2..8),
    ) {
        let atlas = default_phantom();
        let mut text = String::from("stylet-script 1\ndevice touch\n");
        let mut t = 0.0;
        for ((x, y, z), (a, b, c), kind) in keys {
            let dir = if (a * a + b * b + c * c) < 1e-6 { (0.0, 0.0, 1.0) } else { (a, b, c) };
            text += &format!("at {t} pos {x} {y} {z} dir {} {} {}\n", dir.0, dir.1, dir.2);
            text += match kind {
                0..=5 => "",
                6 => "at T press 0 0 1 2\n",
                7 => "at T release\n",
                8 => "at T tool finger\n",
                9 => "at T tool probe convex\n",
                10 => "at T event stylet-remove\n",
                _ => "at T tool needle gauge 16 length 100\n",
            }
            .replace('T', &t.to_string())
            .as_str();
            t += 0.05;
        }
        let r = run_text(atlas, &text);
        let max = r.sim.device().max_force_n;
        for (_, o) in &r.ticks {
            prop_assert!(o.force_n.is_finite() && o.torque_nmm.is_finite() && o.tip_mm.is_finite());
            prop_assert!(o.force_n.length() <= max + 1e-9);
        }
    }
}

/// The same script twice gives the same bits; so do two simulations in parallel threads.
#[test]
fn runs_are_bit_identical_alone_and_in_parallel() {
    let atlas = default_phantom();
    let text = std::fs::read_to_string(script_path("two-attempts.txt")).unwrap();
    let bits = |r: &Run| -> Vec<u64> {
        r.ticks
            .iter()
            .flat_map(|(_, o)| [o.force_n.x, o.force_n.y, o.force_n.z, o.torque_nmm.x, o.inserted_mm].map(f64::to_bits))
            .collect()
    };
    let alone = run_text(atlas, &text);
    let digest = alone.sim.state_digest();
    let (a, b) = std::thread::scope(|s| {
        let h1 = s.spawn(|| run_text(atlas, &text));
        let h2 = s.spawn(|| run_text(atlas, &text));
        (h1.join().unwrap(), h2.join().unwrap())
    });
    assert_eq!(bits(&alone), bits(&a));
    assert_eq!(bits(&alone), bits(&b));
    assert_eq!(digest, a.sim.state_digest());
    assert_eq!(digest, b.sim.state_digest());
}

/// The device runs each example script without error; each gives what its name says.
#[test]
fn example_scripts_do_what_their_names_say() {
    let atlas = default_phantom();
    let visited = |r: &Run, name: &str| {
        let id = label(atlas, name);
        r.ticks.iter().any(|(_, o)| o.tip_label == id && o.inserted_mm > 0.0)
    };
    let lung = run_file(atlas, "lung-hit.txt");
    assert!(visited(&lung, "right lung"), "lung-hit.txt never reaches the lung");
    let vessel = run_file(atlas, "vessel-hit.txt");
    assert!(visited(&vessel, "portal vein") && !visited(&vessel, "right hepatic duct"));
    let two = run_file(atlas, "two-attempts.txt");
    // Two entries: the channel empties once between them.
    let entries = two
        .ticks
        .windows(2)
        .filter(|w| w[0].1.inserted_mm == 0.0 && w[1].1.inserted_mm > 0.0)
        .count();
    assert_eq!(entries, 2, "two-attempts.txt enters {entries} times");
    assert!(visited(&two, "right hepatic duct"));
    let ok = run_file(atlas, "success-intercostal.txt");
    assert!(visited(&ok, "right hepatic duct") && !visited(&ok, "right lung") && !visited(&ok, "portal vein"));
}

/// The real CT's example script reaches the synthetic right hepatic duct between ribs 10 and 11,
/// where the stylet comes out and the contrast goes in.
#[test]
fn real_ct_success_script_reaches_the_target() {
    let data = stylet_testkit::real_ct_data();
    let dir = tempfile::tempdir().unwrap();
    let recipe = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/ts-abdomen/recipe.toml");
    stylet_atlas::import::import(&recipe, &data.join("ts-example-abdomen"), dir.path()).unwrap();
    let atlas = stylet_atlas::load(dir.path()).unwrap();
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/ts-abdomen/scripts/success-intercostal.txt"),
    )
    .unwrap();
    let r = run_text(&atlas, &text);
    let target = label(&atlas, "right hepatic duct");
    let risks: Vec<u16> = atlas
        .model
        .label_table()
        .with_role(stylet_physics::Role::Risk)
        .map(|l| l.id)
        .collect();
    assert!(
        r.ticks
            .iter()
            .any(|(_, o)| !o.stylet_in && o.tip_label == target && o.contrast_ml > 0.0),
        "contrast in the target"
    );
    assert!(
        !r.ticks
            .iter()
            .any(|(_, o)| o.inserted_mm > 0.0 && risks.contains(&o.tip_label)),
        "a risk structure was hit"
    );
    assert!(
        !r.ticks
            .iter()
            .any(|(_, o)| o.inserted_mm > 0.0 && o.tip_label == label(&atlas, "bone")),
        "bone was hit"
    );
}
