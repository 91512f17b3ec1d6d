//! Respiratory motion (thesis Chapter 5; docs/breathing.md): the synthetic motion on the phantom
//! and the real chest CT, its inversion, the sliding interface, the haptics of a needle in a
//! breathing liver, breath holds, determinism and replay.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use crate::common::{STYLET, default_phantom, imported_chest, ok, s};
use stylet_atlas::Atlas;
use stylet_devices::run_headless;
use stylet_devices::script::{parse, scripted_simulation};
use stylet_physics::glam::DVec3;
use stylet_physics::motion::{
    self, BreathingSettings, BreathingSignal, GridField, SignalParams, SpatialField, Surrogate, SyntheticField,
    SyntheticMotion,
};
use stylet_physics::{Grid, PunctureAtlas, Role, TickOutput};
use stylet_render::image::Tolerance;

/// The chest CT (512 × 512 × 133), loaded once from its import.
fn chest() -> &'static Atlas {
    static A: OnceLock<Atlas> = OnceLock::new();
    A.get_or_init(|| stylet_atlas::load(&imported_chest().0).unwrap())
}

/// The synthetic motion's a₁ on an atlas with the default parameters.
fn field(atlas: &Atlas) -> SyntheticField {
    SyntheticField::new(Arc::clone(&atlas.model), SyntheticMotion::default()).unwrap()
}

/// Voxel centres (world) whose partial label has `role`, every `stride`-th one.
fn voxels_with_role(atlas: &PunctureAtlas, role: Role, stride: usize) -> Vec<DVec3> {
    let table = atlas.label_table();
    let labels = atlas.partial_labels();
    labels
        .data()
        .iter()
        .enumerate()
        .filter(|&(_, &id)| id != 0 && table.get(id).is_some_and(|l| l.role == role))
        .step_by(stride)
        .map(|(i, _)| labels.grid().linear_to_world(i))
        .collect()
}

/// Voxel centres (world) inside bone (D_bone > 0) and outside the segmented soft structures
/// (a contrast-filled vessel is as dense as bone), every `stride`-th one.
fn bone_voxels(atlas: &PunctureAtlas, stride: usize) -> Vec<DVec3> {
    let d = atlas.bone_distance();
    let table = atlas.label_table();
    let labels = atlas.partial_labels().data();
    d.data()
        .iter()
        .enumerate()
        .filter(|&(i, &v)| {
            v > 0.0
                && table
                    .get(labels[i])
                    .is_none_or(|l| !matches!(l.role, Role::Organ | Role::Target | Role::Risk))
        })
        .step_by(stride)
        .map(|(i, _)| d.grid().linear_to_world(i))
        .collect()
}

/// The deepest breath of the first minute: the time of the largest g.
fn deepest_breath_s(signal: &BreathingSignal) -> f64 {
    (0..60_000)
        .map(|i| i as f64 * 1e-3)
        .max_by(|&a, &b| signal.g(a).total_cmp(&signal.g(b)))
        .unwrap()
}

/// Bone stays (< 0.5 mm at the deepest breath), the liver moves about the amplitude, and liver
/// tissue a few millimetres from a rib slides past it by more than the rib is thick.
fn bone_stays_and_the_liver_slides(name: &str, atlas: &Atlas) {
    let settings = BreathingSettings::on();
    let model = settings.build(&atlas.model).unwrap();
    let signal = BreathingSignal::new(settings.signal).unwrap();
    let t = deepest_breath_s(&signal);
    let depth = signal.g(t);
    let bone = bone_voxels(&atlas.model, 7);
    assert!(bone.len() > 1000, "{name}: {} bone voxels", bone.len());
    let bone_max = bone
        .iter()
        .map(|&x| model.displacement(x, t).length())
        .fold(0.0, f64::max);
    let liver = voxels_with_role(&atlas.model, Role::Organ, 11);
    let moves: Vec<f64> = liver.iter().map(|&x| model.displacement(x, t).length()).collect();
    let mean = moves.iter().sum::<f64>() / moves.len() as f64;
    // Liver within 10 mm of bone (outside the 3 mm margin and the 4 mm ramp: 7–10 mm away).
    let d_bone = atlas.model.bone_distance();
    let near: Vec<f64> = liver
        .iter()
        .zip(&moves)
        .filter(|&(&x, _)| (-10.0..-7.5).contains(&(d_bone.sample(x, -1000.0) as f64)))
        .map(|(_, &u)| u)
        .collect();
    let sliding = near.iter().filter(|&&u| u > 8.0).count();
    println!(
        "{name}: deepest breath g = {depth:.3} at {t:.2} s; bone ({} voxels) max {bone_max:.4} mm; liver ({} voxels) mean {mean:.2} mm; \
         {} liver voxels 7.5–10 mm from bone, {sliding} of them move > 8 mm",
        bone.len(),
        liver.len(),
        near.len()
    );
    assert!(bone_max < 0.5, "{name}: bone moved {bone_max} mm");
    let expected = settings.motion.amplitude_mm * depth * (1.0f64 + 0.3 * 0.3).sqrt();
    assert!(
        (mean - expected).abs() < 0.25 * expected,
        "{name}: the liver moves {mean} mm on average, the amplitude says {expected}"
    );
    assert!(
        near.len() > 20 && sliding * 2 > near.len(),
        "{name}: {sliding} of {} liver voxels near bone slide past it",
        near.len()
    );
}

#[test]
fn phantom_bone_stays_and_the_liver_slides_past_the_ribs() {
    bone_stays_and_the_liver_slides("phantom", default_phantom());
}

#[test]
fn chest_bone_stays_and_the_liver_slides_past_the_ribs() {
    bone_stays_and_the_liver_slides("chest", chest());
}

/// Thesis §5.4.1: the fixed point X⁺ = x − u(X, t) from X = x inverts a smooth field to within
/// 0.1 mm: a grid field with 15 mm of displacement whose gradient stays below ½, and the
/// synthetic motion inside the liver, away from the sliding interface.
#[test]
fn the_inverse_of_smooth_fields_misses_by_less_than_a_tenth_of_a_millimetre() {
    const ITERATIONS: u32 = 8;
    let affine = stylet_physics::Affine::from_spacing([4.0; 3], DVec3::splat(-200.0));
    let grid = Grid::new([101, 101, 101], affine).unwrap();
    let wave = |x: DVec3| {
        let k = std::f64::consts::TAU / 250.0;
        DVec3::new(
            3.0 * (k * x.z).sin(),
            4.0 * (k * x.x).cos(),
            -15.0 * (k * x.y).cos() * (0.5 + 0.5 * (k * x.x).sin()),
        )
    };
    let smooth = Surrogate {
        a1: Arc::new(GridField::sample(grid, wave)),
        a2: None,
        a3: None,
        signal: BreathingSignal::new(SignalParams::default()).unwrap().into(),
    };
    let points: Vec<DVec3> = (0..2000)
        .map(|i| {
            let f = |k: u64| ((i as u64 * 2_654_435_761 + k * 40_503) % 10_007) as f64 / 10_007.0;
            DVec3::new(f(1), f(2), f(3)) * 300.0 - DVec3::splat(150.0)
        })
        .collect();
    let times: Vec<f64> = (0..20).map(|i| i as f64 * 0.37).collect();
    let worst = times
        .iter()
        .map(|&t| motion::inversion_error_mm(&smooth, &points, t, ITERATIONS))
        .fold(0.0, f64::max);
    println!("grid field: worst inversion error {worst:.2e} mm after {ITERATIONS} steps");
    assert!(worst < 0.1, "grid field: {worst} mm");

    for (name, atlas) in [("phantom", default_phantom()), ("chest", chest())] {
        let model = BreathingSettings::on().build(&atlas.model).unwrap();
        let f = field(atlas);
        // Liver voxels whose whole way to the deepest breath's position (and a fifth beyond, with
        // 1 mm around) lies in fully moving tissue: where the liver would slide into a rib (the
        // synthetic motion does not stop at walls), the world point belongs to the rib and the
        // inverse rightly finds the rib.
        let interior: Vec<DVec3> = voxels_with_role(&atlas.model, Role::Organ, 23)
            .into_iter()
            .filter(|&x| {
                let u = f.at(x);
                let around = [
                    DVec3::ZERO,
                    DVec3::X,
                    DVec3::Y,
                    DVec3::Z,
                    -DVec3::X,
                    -DVec3::Y,
                    -DVec3::Z,
                ];
                (0..=30).all(|i| {
                    let p = x + u * (i as f64 * 0.04);
                    around.iter().all(|&e| f.mobility(p + e) == 1.0)
                })
            })
            .collect();
        let worst = times
            .iter()
            .map(|&t| motion::inversion_error_mm(model.as_ref(), &interior, t, ITERATIONS))
            .fold(0.0, f64::max);
        println!(
            "{name}: {} liver points, worst inversion error {worst:.2e} mm",
            interior.len()
        );
        assert!(interior.len() > 50, "{name}: {} interior points", interior.len());
        assert!(worst < 0.1, "{name}: {worst} mm");
    }
}

/// One tick of a run: what the device felt, the breathing clock, and the needle in
/// the world (its nodes moved by u(X, t)).
struct Tick {
    out: TickOutput,
    breath_s: f64,
    /// The needle's reference-space tip and its world nodes (none without a needle).
    tip_ref: Option<DVec3>,
    world_nodes: Vec<DVec3>,
}

fn run(atlas: &Atlas, text: &str) -> Vec<Tick> {
    let script = parse(text).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let mut ticks = Vec::new();
    run_headless(&mut sim, &mut device, |_, o, sim| {
        let t = sim.breath_time_s();
        let model = sim.motion();
        let (tip_ref, world_nodes) = match sim.needle() {
            Some(n) => (
                n.nodes().last().copied(),
                n.nodes().iter().map(|&x| x + model.displacement(x, t)).collect(),
            ),
            None => (None, Vec::new()),
        };
        ticks.push(Tick {
            out: *o,
            breath_s: t,
            tip_ref,
            world_nodes,
        });
    });
    ticks
}

/// The time of the peak of breathing cycle `k` (its end-inspiration).
fn peak_s(signal: &BreathingSignal, k: u64) -> f64 {
    let start = (0..600_000)
        .map(|i| i as f64 * 1e-3)
        .find(|&t| signal.phase(t).cycle == k)
        .unwrap();
    start + 0.5 * signal.phase(start).period_s
}

/// Thesis Fig. 5.11 analogue: a needle inserted into the liver during a breath hold, then left
/// there, held still, while the patient breathes. Its tip moves with the liver, its distal part
/// tilts, and the motion is periodic: every end-expiration finds the needle, its channel and the
/// force where they were (no drift, no cutting).
#[test]
fn a_needle_left_in_the_liver_tilts_with_breathing_and_stays_stable() {
    let atlas = default_phantom();
    let ticks = run(
        atlas,
        "stylet-script 1\nbreathing on\nend 26\nat 0 event breath-hold\nat 0 along intercostal-10-11 -15\n\
         at 1 along intercostal-10-11 -15\nat 7 along intercostal-10-11 80\nat 8 event breath-release\n\
         at 26 along intercostal-10-11 80\n",
    );
    let liver = atlas.model.label_table().by_name("liver").unwrap().id;
    let signal = BreathingSignal::new(BreathingSettings::on().signal).unwrap();
    let distal = |t: &Tick| {
        let n = &t.world_nodes;
        (n[n.len() - 1] - n[n.len() / 2]).normalize()
    };
    // During the hold (7–8 s) the tip settles by less than a hundredth of a millimetre.
    let held = &ticks[7999];
    assert!(
        ticks[7000..8000]
            .iter()
            .all(|t| (t.out.tip_mm - held.out.tip_mm).length() < 0.01)
    );
    assert_eq!(held.out.tip_label, liver);
    // Breathing from 8 s on: the end-expirations (g < 0.001) and end-inspirations (g > 0.9).
    let free = &ticks[8000..];
    let g = |t: &Tick| signal.g(t.breath_s);
    let ee: Vec<&Tick> = free.iter().filter(|t| g(t) < 1e-3).collect();
    let ei: Vec<&Tick> = free.iter().filter(|t| g(t) > 0.9).collect();
    assert!(
        ee.len() > 1000 && ei.len() > 500,
        "{} EE and {} EI ticks",
        ee.len(),
        ei.len()
    );
    let tip_range_z = free.iter().map(|t| t.out.tip_mm.z).fold(f64::MIN, f64::max)
        - free.iter().map(|t| t.out.tip_mm.z).fold(f64::MAX, f64::min);
    let tilt_deg = ei
        .iter()
        .map(|t| distal(t).angle_between(distal(held)).to_degrees())
        .fold(0.0, f64::max);
    let force_ee: Vec<f64> = ee.iter().map(|t| t.out.force_n.length()).collect();
    let ref_drift = ee
        .iter()
        .map(|t| (t.tip_ref.unwrap() - held.tip_ref.unwrap()).length())
        .fold(0.0, f64::max);
    let force_max = free.iter().map(|t| t.out.force_n.length()).fold(0.0, f64::max);
    println!(
        "tip moves {tip_range_z:.1} mm cranio-caudally; distal needle tilts {tilt_deg:.1}° at end-inspiration; \
         at end-expiration the reference tip is within {ref_drift:.3} mm of where it was held and the force \
         {:.2}–{:.2} N (held: {:.2} N); largest force {force_max:.2} N",
        force_ee.iter().cloned().fold(f64::MAX, f64::min),
        force_ee.iter().cloned().fold(0.0, f64::max),
        held.out.force_n.length()
    );
    assert!(tip_range_z > 8.0, "the tip moved {tip_range_z} mm");
    assert!(tilt_deg > 5.0, "the needle tilted {tilt_deg}°");
    assert!(ref_drift < 0.05, "the needle drifted {ref_drift} mm in the tissue");
    assert!(
        force_ee.iter().all(|f| (f - held.out.force_n.length()).abs() < 0.1),
        "end-expiration forces {force_ee:?}"
    );
    assert!(force_max.is_finite() && force_max <= stylet_physics::DeviceProfile::PREMIUM.max_force_n + 1e-9);
    assert!(free.iter().all(|t| t.out.tip_label == liver), "the tip left the liver");
    let inserted = held.out.inserted_mm;
    assert!(
        free.iter().all(|t| (t.out.inserted_mm - inserted).abs() < 2.0),
        "the needle cut on"
    );
}

/// A scenario built for breath holds: a deep breather (25 mm, the top of Eccles' range), a
/// needle through a high intercostal space toward a point of the liver about 3 mm under the right
/// lung's base. Held at end-expiration (the CT's phase) the path stays in the liver; advanced to
/// arrive at an end-inspiration, the device's position maps 25 mm higher into the reference
/// patient (X = x − u), the needle bends toward it and its tip enters the lung.
const HIGH_ENTRY: [f64; 3] = [153.5, 2.8, 30.3];
const HIGH_TARGET: [f64; 3] = [60.0, 10.0, 89.0];

fn high_puncture(hold: bool, arrive_s: f64) -> String {
    let [ex, ey, ez] = HIGH_ENTRY;
    let [tx, ty, tz] = HIGH_TARGET;
    let depth = (DVec3::from(HIGH_TARGET) - DVec3::from(HIGH_ENTRY)).length();
    let aim = |d: f64| format!("aim {ex} {ey} {ez} {tx} {ty} {tz} {d}");
    format!(
        "stylet-script 1\nbreathing on amplitude 25\nend {end}\n{hold}at 0 {out}\nat 2 {out}\nat {arrive_s} {in_}\nat {stay} {in_}\nat {back} {out}\n",
        end = arrive_s + 6.0,
        hold = if hold { "at 0 event breath-hold\n" } else { "" },
        out = aim(-15.0),
        in_ = aim(depth),
        stay = arrive_s + 1.0,
        back = arrive_s + 5.5,
    )
}

/// The risk structures the needle tip entered, by name.
fn risks_entered(atlas: &Atlas, ticks: &[Tick]) -> Vec<String> {
    let table = atlas.model.label_table();
    let mut seen = Vec::new();
    for t in ticks {
        if let Some(l) = table.get(t.out.tip_label).filter(|l| l.role == Role::Risk)
            && !seen.contains(&l.name)
        {
            seen.push(l.name.clone());
        }
    }
    seen
}

#[test]
fn the_same_puncture_with_and_without_breath_hold_hits_different_structures() {
    let atlas = default_phantom();
    let signal = BreathingSignal::new(BreathingSettings::on().signal).unwrap();
    let arrive = (peak_s(&signal, 2) * 10.0).round() / 10.0;
    let held = risks_entered(atlas, &run(atlas, &high_puncture(true, arrive)));
    let free = risks_entered(atlas, &run(atlas, &high_puncture(false, arrive)));
    let still = risks_entered(
        atlas,
        &run(
            atlas,
            &high_puncture(true, arrive).replace("breathing on amplitude 25\n", ""),
        ),
    );
    println!("arriving at {arrive} s: held at end-expiration {held:?}, breathing {free:?}, no breathing {still:?}");
    assert!(
        held.is_empty() && still.is_empty(),
        "the path is not clear at end-expiration"
    );
    assert!(free.iter().any(|r| r == "right lung"), "breathing: {free:?}");
}

/// Same seed, same bits; another seed, other cycles and other forces; breathing on or off
/// changes what the device feels; a breath hold freezes the motion where it is and the motion
/// resumes from there.
#[test]
fn breathing_is_deterministic_the_seed_matters_and_a_hold_freezes_it() {
    let atlas = default_phantom();
    let text = |breathing: &str, events: &str| {
        format!(
            "stylet-script 1\n{breathing}end 14\nat 0 along intercostal-10-11 -15\nat 1 along intercostal-10-11 -15\n\
             at 7 along intercostal-10-11 80\n{events}at 14 along intercostal-10-11 80\n"
        )
    };
    let forces = |ticks: &[Tick]| ticks.iter().map(|t| t.out.force_n).collect::<Vec<_>>();
    let a = run(atlas, &text("breathing on seed 5\n", ""));
    let b = run(atlas, &text("breathing on seed 5\n", ""));
    let c = run(atlas, &text("breathing on seed 6\n", ""));
    let off = run(atlas, &text("", ""));
    let bits = |v: &[DVec3]| {
        v.iter()
            .flat_map(|f| f.to_array().map(f64::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&forces(&a)), bits(&forces(&b)), "same seed, different forces");
    assert_ne!(forces(&a), forces(&c), "another seed changed nothing");
    assert_ne!(forces(&a), forces(&off), "breathing changed nothing");
    // A hold from 9 to 11 s: the breathing clock and the tip stand still, then go on.
    let held = run(
        atlas,
        &text(
            "breathing on seed 5\n",
            "at 9 event breath-hold\nat 11 event breath-release\n",
        ),
    );
    let (h0, h1) = (&held[9001], &held[10999]);
    assert_eq!(h0.breath_s, h1.breath_s);
    assert_eq!(h0.out.tip_mm, h1.out.tip_mm);
    assert!(held[11500].breath_s > h1.breath_s);
    // Released, it breathes on from the held phase: 2 s behind the run without a hold.
    let lag = a[9000].breath_s - held[11000].breath_s;
    assert!(lag.abs() < 2e-3, "the clock resumed {lag} s off");
}

/// Records script `text` on the atlas in `atlas_dir` as `work/name.mcap` with `stylet script run`,
/// scores it with `stylet score --json` and checks that its replay verified.
fn record_and_score(atlas_dir: &Path, work: &Path, name: &str, text: &str) -> serde_json::Value {
    let script = work.join(format!("{name}.txt"));
    std::fs::write(&script, text).unwrap();
    let session = work.join(format!("{name}.mcap"));
    ok(&[
        "script",
        "run",
        "--atlas",
        s(atlas_dir),
        "--script",
        s(&script),
        "--out",
        s(&session),
    ]);
    let r: serde_json::Value =
        serde_json::from_str(&ok(&["score", s(&session), "--atlas", s(atlas_dir), "--json"])).unwrap();
    assert_eq!(r["replay_verified"], true, "{name}: {}", r["divergence"]);
    r
}

/// A recorded session with breathing replays verified (bit for bit, digests included), and the
/// scoring sees the lung hit of free breathing and not that of the held breath.
#[test]
fn sessions_with_breathing_replay_verified_and_score_the_hits() {
    let dir = default_phantom().dir.as_path();
    let work = tempfile::tempdir().unwrap();
    let signal = BreathingSignal::new(BreathingSettings::on().signal).unwrap();
    let arrive = (peak_s(&signal, 2) * 10.0).round() / 10.0;
    let mut risk_hits = Vec::new();
    for (name, hold) in [("held", true), ("free", false)] {
        let r = record_and_score(dir, work.path(), name, &high_puncture(hold, arrive));
        risk_hits.push(r["metrics"]["risk_hits"].as_array().unwrap().len());
        // The breathing metrics: nothing breathed past a needle put in and left in a held
        // breath; the free breath carried tissue past it while it was in.
        let b = &r["metrics"]["breathing"];
        let (slide, breathing_s) = (
            b["tissue_slide_mm"].as_f64().unwrap(),
            b["needle_in_while_breathing_s"].as_f64().unwrap(),
        );
        println!(
            "{name}: risk hits {}, tissue slide {slide:.1} mm, needle in while breathing {breathing_s:.1} s",
            risk_hits.last().unwrap()
        );
        if hold {
            assert_eq!((slide, breathing_s), (0.0, 0.0), "{name}: {b}");
        } else {
            assert!(slide > 5.0 && breathing_s > 3.0, "{name}: {b}");
        }
    }
    assert_eq!(risk_hits[0], 0, "held breath: {risk_hits:?}");
    assert!(risk_hits[1] >= 1, "free breathing: {risk_hits:?}");
    // The phase the target was reached in, from the shipped successful puncture: held at
    // end-expiration, or breathing (then the rubric metric flags it).
    let base = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts/success-intercostal.txt"),
    )
    .unwrap();
    for (name, extra, phase, flag) in [
        (
            "hold",
            "breathing on\nat 0 event breath-hold\n",
            "held_end_expiration",
            0.0,
        ),
        ("breathe", "breathing on\n", "free_breathing", 1.0),
    ] {
        let text = base.replacen("end 20\n", &format!("end 20\n{extra}"), 1);
        let r = record_and_score(dir, work.path(), name, &text);
        assert_eq!(
            r["metrics"]["breathing"]["target_reached_phase"], phase,
            "{name}: {}",
            r["metrics"]["breathing"]
        );
        let m: stylet_scoring::metrics::Metrics = serde_json::from_value(r["metrics"].clone()).unwrap();
        assert_eq!(
            stylet_scoring::rubric::metric_value(&m, "target_reached_while_breathing"),
            Some(flag),
            "{name}"
        );
        assert_eq!(r["metrics"]["breathing"]["correct_phase"], "held_end_expiration");
        // The shipped rubric deducts it.
        let deducted = deduction(&r, "target_reached_while_breathing");
        println!(
            "{name}: score {}, deducted for the phase {deducted}",
            r["grade"]["score"]
        );
        assert_eq!(deducted > 0.0, flag == 1.0, "{name}: {}", r["grade"]);
    }
    // A scenario whose correct hold is end-inspiration: the same held-at-end-expiration
    // puncture is now outside it.
    let inspired = work.path().join("inspired");
    std::fs::create_dir_all(&inspired).unwrap();
    for f in ["ct.nii.gz", "labels.nii.gz"] {
        std::fs::copy(dir.join(f), inspired.join(f)).unwrap();
    }
    let manifest = std::fs::read_to_string(dir.join("atlas.toml")).unwrap();
    let with_hold = manifest.replacen(
        "name = \"success-intercostal\"\n",
        "name = \"success-intercostal\"\nhold_phase = \"end_inspiration\"\n",
        1,
    );
    assert_ne!(with_hold, manifest);
    std::fs::write(inspired.join("atlas.toml"), with_hold).unwrap();
    let text = base.replacen("end 20\n", "end 20\nbreathing on\nat 0 event breath-hold\n", 1);
    // The session's scenario is the script's name.
    let r = record_and_score(&inspired, work.path(), "success-intercostal", &text);
    let b = &r["metrics"]["breathing"];
    assert_eq!(b["correct_phase"], "held_end_inspiration", "{b}");
    assert_eq!(b["target_reached_phase"], "held_end_expiration", "{b}");
    assert!(deduction(&r, "target_reached_while_breathing") > 0.0, "{}", r["grade"]);
}

/// The points a score report's grade deducted for `metric` (0 when none).
fn deduction(report: &serde_json::Value, metric: &str) -> f64 {
    report["grade"]["deductions"]
        .as_array()
        .unwrap_or_else(|| panic!("no deductions in {}", report["grade"]))
        .iter()
        .filter(|d| d["metric"] == metric)
        .map(|d| d["points"].as_f64().unwrap())
        .fold(0.0, |a, b| a + b)
}

/// The moments of a needle left in the phantom's liver (as in the Fig. 5.11 test) at the first
/// end-inspiration after the hold and at the end-expiration pause after it, with the same run
/// once more without breathing at the end-inspiration tick.
fn moments(atlas: &Atlas) -> [stylet_render::views::Moment; 3] {
    use stylet_render::views::{Moment, SessionLabels};
    let signal = BreathingSignal::new(BreathingSettings::on().signal).unwrap();
    let c0 = signal.phase(0.0);
    let ei_tick = ((8.0 + 0.5 * c0.period_s) * 1000.0).round() as u64;
    let ee_tick = ((8.0 + 0.92 * c0.period_s) * 1000.0).round() as u64;
    let labels = SessionLabels {
        scenario: "ptcd".into(),
        difficulty: stylet_scoring::Difficulty::Beginner,
        seed: 1,
    };
    let text = |breathing: &str| {
        format!(
            "stylet-script 1\n{breathing}end 14\nat 0 event breath-hold\nat 0 along intercostal-10-11 -15\n\
             at 1 along intercostal-10-11 -15\nat 7 along intercostal-10-11 80\nat 8 event breath-release\n\
             at 14 along intercostal-10-11 80\n"
        )
    };
    let mut out: [Option<Moment>; 3] = [None, None, None];
    for (breathing, picks) in [
        ("breathing on\n", vec![(ei_tick, 0), (ee_tick, 1)]),
        ("", vec![(ei_tick, 2)]),
    ] {
        let script = parse(&text(breathing)).unwrap();
        let (mut sim, mut device) =
            scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
        run_headless(&mut sim, &mut device, |i, o, sim| {
            for &(tick, slot) in &picks {
                if o.tick == tick {
                    out[slot] = Some(Moment::of_simulation(sim, i, o, &labels));
                }
            }
        });
    }
    out.map(|m| m.unwrap())
}

/// The views of a breathing moment (docs/breathing.md): slices invert u per pixel and the 3D view
/// warps its rays, so end-inspiration differs from end-expiration where the liver is and not
/// where the ribs are; end-expiration is the CT; the needle is drawn where the liver took it;
/// widening the ray box and the leaping cells by the motion's bound keeps the picture.
#[test]
fn views_of_a_breathing_patient_show_the_motion() {
    use stylet_render::image::{Tolerance, diff};
    use stylet_render::mpr::{Plane, SliceSpec, Window};
    use stylet_render::scene::Quality;
    use stylet_render::views;
    let atlas = default_phantom();
    let [ei, ee, still] = moments(atlas);
    assert!(ei.breathing.is_some() && still.breathing.is_none());
    let path = atlas.planned_paths()[0].clone();
    let spec = SliceSpec::plane(&atlas.model, Plane::Coronal, path.target_mm, Window::ABDOMEN, 200);
    let slice = |m: &views::Moment| {
        stylet_render::mpr::render_spec_moving(&atlas.model, &spec, m.breathing.as_ref(), None).unwrap()
    };
    let (s_ei, s_ee, s_still) = (slice(&ei), slice(&ee), slice(&still));
    let liver = atlas.model.label_table().by_name("liver").unwrap().id;
    let changed = |a: &stylet_render::mpr::MprImage, b: &stylet_render::mpr::MprImage| {
        a.rgb.iter().zip(&b.rgb).filter(|(p, q)| p != q).count()
    };
    let moved = changed(&s_ei, &s_still);
    let d_ei = diff(&s_ei.to_image(), &s_still.to_image()).unwrap();
    let d_ee = diff(&s_ee.to_image(), &s_still.to_image()).unwrap();
    // Pixels of the slice whose point stays: in bone outside any segmented soft structure.
    let d_bone = atlas.model.bone_distance();
    let bone_changed = (0..spec.height)
        .flat_map(|r| (0..spec.width).map(move |c| (c, r)))
        .filter(|&(c, r)| {
            let x = spec.world(c as f64, r as f64);
            d_bone.sample(x, -1000.0) > 2.0 && s_still.labels[r * spec.width + c] == 0
        })
        .filter(|&(c, r)| s_ei.rgb[r * spec.width + c] != s_still.rgb[r * spec.width + c])
        .count();
    let liver_px = s_still.labels.iter().filter(|&&l| l == liver).count();
    println!(
        "coronal slice {} × {}: {moved} pixels differ at end-inspiration ({d_ei}), end-expiration {d_ee}, \
         {bone_changed} bone pixels changed; {liver_px} liver pixels",
        spec.width, spec.height
    );
    assert!(moved > liver_px / 10, "end-inspiration changed {moved} pixels");
    // At g = 0 exactly (the start of a cycle) the slice is the CT's, up to a grey level of
    // rounding; at the end-expiration pause (g ≈ 0.004, under 0.05 mm) it is close to it: the
    // differences sit on sharp edges and label outlines, far below end-inspiration's.
    let hook = stylet_render::scene::MotionHook {
        model: Arc::clone(&ee.breathing.as_ref().unwrap().model),
        t_s: 0.0,
    };
    let at_zero = stylet_render::mpr::render_spec_moving(&atlas.model, &spec, Some(&hook), None).unwrap();
    let d_zero = diff(&at_zero.to_image(), &s_still.to_image()).unwrap();
    println!("g = 0: {d_zero}");
    assert!(d_zero.max <= 1, "at g = 0 the slice is not the CT's: {d_zero}");
    assert!(
        d_ee.mean * 5.0 < d_ei.mean,
        "end-expiration {d_ee}, end-inspiration {d_ei}"
    );
    // The needle is drawn where the liver took it: its tip node lower at end-inspiration.
    let tip = |m: &views::Moment| *m.tools.needle.as_ref().unwrap().nodes_mm.last().unwrap();
    assert!(tip(&still).z - tip(&ei).z > 8.0, "tip {} vs {}", tip(&ei), tip(&still));

    // 3D: warped rays differ from the still patient; the speed-ups keep the picture.
    let volume = stylet_render::volume::RenderVolume::new(Arc::clone(&atlas.model));
    let step = views::default_step_mm(atlas);
    let scene = |m: &views::Moment| {
        views::scene_3d(
            atlas,
            Some(m),
            stylet_render::presets::Preset::Soft,
            stylet_render::scene::Tagging::Labels,
            step,
        )
        .unwrap()
    };
    let (w, h) = (160, 132);
    let fast = stylet_render::raycast::render(&volume, &scene(&ei), w, h).image;
    let mut naive_scene = scene(&ei);
    naive_scene.quality = Quality::naive(step);
    let naive = stylet_render::raycast::render(&volume, &naive_scene, w, h).image;
    let still_img = stylet_render::raycast::render(&volume, &scene(&still), w, h).image;
    let d_speed = diff(&fast, &naive).unwrap();
    let d_motion = diff(&fast, &still_img).unwrap();
    println!("3D {w} × {h}: warped fast vs warped naive {d_speed}; warped vs still {d_motion}");
    // The warp takes one fixed-point step per sample from the previous sample's X (eqs.
    // 5.4.1–5.4.2), so a ray that visits more samples (no leaping, no box) ends its fixed points
    // a little differently: a grey level or two, never a structure gained or lost.
    let same = Tolerance {
        mean: 0.15,
        p99: 2,
        max: 16,
    };
    assert!(
        same.admits(&d_speed),
        "the speed-ups changed the warped picture: {d_speed}"
    );
    assert!(d_motion.mean > 0.5, "breathing did not change the 3D view: {d_motion}");
}

/// `stylet render` draws a moment of a breathing session on the CPU and on the GPU (lavapipe on
/// CI): the slice, the 3D view and the radiograph, the GPU's pictures close to the CPU's.
#[test]
fn the_cli_draws_a_breathing_session_on_both_renderers() {
    let dir = default_phantom().dir.as_path();
    let work = tempfile::tempdir().unwrap();
    let script = work.path().join("b.txt");
    std::fs::write(
        &script,
        "stylet-script 1\nbreathing on\nend 6\nat 0 along intercostal-10-11 -15\nat 5 along intercostal-10-11 60\n",
    )
    .unwrap();
    let session = work.path().join("b.mcap");
    ok(&[
        "script",
        "run",
        "--atlas",
        s(dir),
        "--script",
        s(&script),
        "--out",
        s(&session),
    ]);
    for (view, size, tolerance) in [
        (
            "coronal",
            "200x160",
            Tolerance {
                mean: 0.05,
                p99: 0,
                max: 255,
            },
        ),
        (
            "3d",
            "160x128",
            Tolerance {
                mean: 0.1,
                p99: 1,
                max: 64,
            },
        ),
        (
            "xray",
            "128x128",
            Tolerance {
                mean: 0.05,
                p99: 1,
                max: 8,
            },
        ),
    ] {
        let draw = |renderer: &str| {
            let png = work.path().join(format!("{view}{renderer}.png"));
            ok(&[
                "render",
                "--atlas",
                s(dir),
                "--session",
                s(&session),
                "--at",
                "2.2",
                "--view",
                view,
                "--size",
                size,
                renderer,
                "--out",
                s(&png),
            ]);
            stylet_render::image::Image::read_png(&png).unwrap()
        };
        let (cpu, gpu) = (draw("--cpu"), draw("--gpu"));
        let d = stylet_render::image::diff(&gpu, &cpu).unwrap();
        println!("{view}: GPU against CPU {d}");
        assert!(tolerance.admits(&d), "{view}: {d}");
    }
}

/// The radiograph of a breathing moment (docs/breathing.md "Views"): each ray's samples read the
/// reference patient, so at g = 0 it is the still radiograph (up to the rounding of the index of
/// a plane crossing), and at end-inspiration the diaphragm and the liver have moved in it.
#[test]
fn the_radiograph_of_a_breathing_patient_moves() {
    use stylet_render::views;
    use stylet_render::xray::render_moving;
    let atlas = default_phantom();
    let [ei, _, still] = moments(atlas);
    let scenario = atlas.manifest.scenarios.first();
    let (scene, _) = views::xray_scene(atlas, Some(&ei), scenario, None, None).unwrap();
    let (w, h) = (128, 128);
    let plain = render_moving(&atlas.model, &scene, None, w, h).unwrap();
    let same = stylet_render::xray::render(&atlas.model, &scene, w, h).unwrap();
    assert_eq!(plain, same, "without breathing render_moving is render");
    let hook = stylet_render::scene::MotionHook {
        model: Arc::clone(&ei.breathing.as_ref().unwrap().model),
        t_s: 0.0,
    };
    let at_zero = render_moving(&atlas.model, &scene, Some(&hook), w, h).unwrap();
    let moving = render_moving(&atlas.model, &scene, ei.breathing.as_ref(), w, h).unwrap();
    let top = plain.attenuation.iter().cloned().fold(0.0f32, f32::max);
    let worst = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max) / top;
    let changed = moving
        .attenuation
        .iter()
        .zip(&plain.attenuation)
        .filter(|(x, y)| (*x - *y).abs() > 0.01 * top)
        .count();
    println!(
        "radiograph {w} × {h}: at g = 0 off by {:.1e} of the largest attenuation; end-inspiration changes {changed} pixels by > 1 %",
        worst(&at_zero.attenuation, &plain.attenuation)
    );
    assert!(worst(&at_zero.attenuation, &plain.attenuation) < 1e-4);
    assert!(changed > 200, "end-inspiration changed {changed} pixels");
    // The same moment without breathing drew the still needle: the scene differs only by it.
    assert!(still.breathing.is_none());
}

/// Atlases carry their breathing motion (docs/breathing.md "Atlases"): `stylet atlas phantom`
/// attaches the synthetic motion by default and `stylet atlas inspect` reports its inversion
/// error; `--no-breathing` leaves it out and a breathing script is then refused by name; a
/// script's `breathing on` takes the atlas' amplitude unless it gives one; a bad `[breathing]`
/// is refused at load, naming the field.
#[test]
fn atlases_carry_their_breathing_motion_and_report_its_inverse() {
    let work = tempfile::tempdir().unwrap();
    let (with, without) = (work.path().join("with"), work.path().join("without"));
    crate::common::phantom_atlas(&with, "128,128,100", "3");
    ok(&[
        "atlas",
        "phantom",
        "--out",
        s(&without),
        "--dims",
        "128,128,100",
        "--spacing",
        "3",
        "--no-breathing",
    ]);
    let inspect = |dir: &Path| -> serde_json::Value {
        serde_json::from_str(&ok(&["atlas", "inspect", s(dir), "--json"])).unwrap()
    };
    let b = &inspect(&with)["breathing"];
    println!("attached: {b}");
    assert_eq!(b["motion"], "synthetic");
    assert_eq!(b["amplitude_mm"], 12.0);
    let inv = &b["inversion"];
    assert!(inv["worst_mm"].as_f64().unwrap() < 0.1, "{inv}");
    assert!(inv["points"].as_u64().unwrap() > 1000, "{inv}");
    assert_eq!(inv["iterations"], 8);
    let b = &inspect(&without)["breathing"];
    assert_eq!(b["motion"], "none");
    assert!(b["inversion"].is_null());

    let script = work.path().join("b.txt");
    std::fs::write(
        &script,
        "stylet-script 1\nbreathing on\nend 1\nat 0 along intercostal-10-11 -15\nat 1 along intercostal-10-11 10\n",
    )
    .unwrap();
    let run = |atlas: &Path, out: &Path| {
        STYLET
            .command()
            .args([
                "script",
                "run",
                "--atlas",
                s(atlas),
                "--script",
                s(&script),
                "--out",
                s(out),
            ])
            .output()
            .unwrap()
    };
    let refused = run(&without, &work.path().join("none.mcap"));
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success() && err.contains("no breathing motion"),
        "{err}"
    );
    assert!(!work.path().join("none.mcap").exists());

    // The atlas' amplitude is the session's.
    let manifest = with.join("atlas.toml");
    let text = std::fs::read_to_string(&manifest).unwrap();
    std::fs::write(&manifest, text.replace("amplitude_mm = 12.0", "amplitude_mm = 20.0")).unwrap();
    let session = work.path().join("deep.mcap");
    assert!(run(&with, &session).status.success());
    let header = stylet_recorder::reader::read_header(&std::fs::read(&session).unwrap()).unwrap();
    assert!(header.breathing.enabled);
    assert_eq!(header.breathing.motion.amplitude_mm, 20.0);

    // A bad [breathing] is refused at load, by name.
    std::fs::write(&manifest, text.replace("amplitude_mm = 12.0", "amplitude_mm = 80.0")).unwrap();
    let out = STYLET.command().args(["atlas", "inspect", s(&with)]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("amplitude") && err.contains("80"),
        "{err}"
    );
    std::fs::write(&manifest, text.replace("motion = \"synthetic\"", "motion = \"wobbly\"")).unwrap();
    let out = STYLET.command().args(["atlas", "inspect", s(&with)]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("wobbly"), "{err}");
}

/// The ultrasound of a breathing moment (docs/breathing.md "Views"): each sample reads the
/// tissue at its reference point, so at g = 0 it is the still image bit for bit, and at
/// end-inspiration the liver has moved under the probe (the probe and the needle stay in the
/// world).
#[test]
fn the_ultrasound_of_a_breathing_patient_moves() {
    use stylet_render::ultrasound::{EchoTable, render};
    use stylet_render::views;
    let atlas = default_phantom();
    let [ei, _, still] = moments(atlas);
    let echo = Arc::new(EchoTable::of_atlas(atlas));
    let scene = |m: &views::Moment| {
        views::ultrasound_scene(
            atlas,
            Some(m),
            Some(stylet_physics::ProbeKind::Convex),
            stylet_scoring::Difficulty::Beginner,
            Arc::clone(&echo),
            None,
        )
        .unwrap()
    };
    let (s_ei, s_still) = (scene(&ei), scene(&still));
    assert!(s_ei.breathing.is_some() && s_still.breathing.is_none());
    let plain = render(&atlas.model, &s_still).unwrap();
    let at_zero = stylet_render::ultrasound::UltrasoundScene {
        breathing: Some(stylet_render::scene::MotionHook {
            model: Arc::clone(&ei.breathing.as_ref().unwrap().model),
            t_s: 0.0,
        }),
        ..s_still.clone()
    };
    assert_eq!(
        render(&atlas.model, &at_zero).unwrap().bmode,
        plain.bmode,
        "g = 0 is the still image"
    );
    let moving = render(&atlas.model, &s_ei).unwrap();
    let changed = moving
        .bmode
        .iter()
        .zip(&plain.bmode)
        .filter(|(a, b)| (*a - *b).abs() > 0.05)
        .count();
    println!(
        "end-inspiration: {changed} of {} samples changed by more than 0.05",
        plain.bmode.len()
    );
    assert!(changed * 20 > plain.bmode.len(), "only {changed} samples changed");
}

/// Measured motion (docs/breathing.md "Measured motion"): a displacement field written in
/// ITK's convention and a surrogate signal CSV are attached to an atlas, checked and pinned by
/// its content hash; a breathing session then moves with them and replays verified; bad files are
/// refused by name and leave the atlas as it was.
#[test]
fn measured_fields_and_a_surrogate_signal_drive_a_session() {
    use stylet_atlas::nifti_io::write_displacement_field;
    let work = tempfile::tempdir().unwrap();
    let atlas_dir = work.path().join("atlas");
    crate::common::phantom_atlas(&atlas_dir, "128,128,100", "3");
    let atlas = stylet_atlas::load(&atlas_dir).unwrap();
    let hash_before = atlas.content_hash.clone();
    let manifest_before = std::fs::read_to_string(atlas_dir.join("atlas.toml")).unwrap();
    // A smooth field around the liver: 10 mm caudal and 3 mm anterior at its centre.
    let liver = voxels_with_role(&atlas.model, Role::Organ, 7);
    let centre = liver.iter().fold(DVec3::ZERO, |a, &x| a + x) / liver.len() as f64;
    let grid = Grid::new(
        [48, 48, 40],
        stylet_physics::Affine::from_spacing([8.0; 3], atlas.model.ct().grid().world_bounds().0),
    )
    .unwrap();
    let u = move |x: DVec3| DVec3::new(0.0, 3.0, -10.0) * (-(x - centre).length_squared() / (2.0 * 60.0 * 60.0)).exp();
    let field = GridField::sample(grid, u);
    let a1 = work.path().join("a1.nii.gz");
    write_displacement_field(&a1, &field, "test a1").unwrap();
    // A 5 s breath sampled at 10 Hz for 20 s.
    let signal = work.path().join("signal.csv");
    let mut csv = String::from("time_s,g\n");
    for k in 0..=200 {
        let t = k as f64 * 0.1;
        csv += &format!("{t:.1},{:.6}\n", (std::f64::consts::PI * t / 5.0).sin().powi(2));
    }
    std::fs::write(&signal, &csv).unwrap();

    // Bad files first: each refused by name, the atlas unchanged.
    let attach = |args: &[&str]| {
        let mut all = vec!["atlas", "attach-motion", s(&atlas_dir)];
        all.extend_from_slice(args);
        STYLET.command().args(&all).output().unwrap()
    };
    let ct = atlas_dir.join("ct.nii.gz");
    let bad_csv = work.path().join("bad.csv");
    std::fs::write(&bad_csv, "time_s,g\n0,0\n1,0.5\n1,0.7\n").unwrap();
    for (args, want) in [
        (vec!["--a1", s(&ct)], "(x, y, z, 1, 3)"),
        (vec!["--a1", s(&a1), "--signal", s(&bad_csv)], "does not follow"),
        (vec!["--a1", s(&work.path().join("missing.nii.gz"))], "missing.nii.gz"),
    ] {
        let out = attach(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(want), "{args:?}: {err}");
        assert_eq!(
            std::fs::read_to_string(atlas_dir.join("atlas.toml")).unwrap(),
            manifest_before
        );
    }

    let out = attach(&["--a1", s(&a1), "--signal", s(&signal)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let summary: serde_json::Value = serde_json::from_str(&ok(&["atlas", "inspect", s(&atlas_dir), "--json"])).unwrap();
    let b = &summary["breathing"];
    println!("measured: {b}");
    assert_eq!(b["motion"], "measured");
    let files: Vec<String> = serde_json::from_value(b["files"].clone()).unwrap();
    assert!(
        files.len() == 2 && files[0].starts_with("motion/a1-") && files[1].starts_with("motion/signal-"),
        "{files:?}"
    );
    assert!(b["inversion"]["worst_mm"].as_f64().unwrap() < 0.1, "{b}");
    assert_ne!(
        summary["content_hash"],
        hash_before.as_str(),
        "the fields are part of the atlas"
    );

    // A session breathes with them and replays verified; an amplitude of its own is refused.
    let measured = stylet_atlas::load(&atlas_dir).unwrap();
    let model = BreathingSettings {
        enabled: true,
        measured: true,
        ..Default::default()
    }
    .build(&measured.model)
    .unwrap();
    // At t = 2.5 s the signal is at its peak (g = 1): the liver's centre moved by the field
    // (trilinear on its 8 mm grid).
    let moved = model.displacement(centre, 2.5);
    assert!((moved - u(centre)).length() < 0.2, "{moved} against {}", u(centre));
    assert_eq!(model.displacement(centre, 0.0), DVec3::ZERO);
    let text =
        "stylet-script 1\nbreathing on\nend 6\nat 0 along intercostal-10-11 -15\nat 5 along intercostal-10-11 60\n";
    let r = record_and_score(&atlas_dir, work.path(), "measured", text);
    assert!(r["metrics"]["breathing"].is_object(), "{}", r["metrics"]);
    let header =
        stylet_recorder::reader::read_header(&std::fs::read(work.path().join("measured.mcap")).unwrap()).unwrap();
    assert!(header.breathing.enabled && header.breathing.measured);
    // `stylet render` draws a moment of it on the CPU and on the GPU (the fields as textures).
    for view in ["coronal", "3d"] {
        let draw = |renderer: &str| {
            let png = work.path().join(format!("measured-{view}{renderer}.png"));
            ok(&[
                "render",
                "--atlas",
                s(&atlas_dir),
                "--session",
                s(&work.path().join("measured.mcap")),
                "--at",
                "2.5",
                "--view",
                view,
                "--size",
                "160x120",
                renderer,
                "--out",
                s(&png),
            ]);
            stylet_render::image::Image::read_png(&png).unwrap()
        };
        let d = stylet_render::image::diff(&draw("--gpu"), &draw("--cpu")).unwrap();
        println!("measured {view}: GPU against CPU {d}");
        assert!(
            Tolerance {
                mean: 0.05,
                p99: 1,
                max: 40
            }
            .admits(&d),
            "{view}: {d}"
        );
    }
    let script = work.path().join("amp.txt");
    std::fs::write(&script, text.replace("breathing on", "breathing on amplitude 20")).unwrap();
    let out = STYLET
        .command()
        .args([
            "script",
            "run",
            "--atlas",
            s(&atlas_dir),
            "--script",
            s(&script),
            "--out",
            s(&work.path().join("amp.mcap")),
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("measured"), "{err}");

    // Attaching again replaces the files: the ones named before are removed once the atlas
    // loads with the new ones, never overwritten on the way.
    let a1_half = work.path().join("a1-half.nii.gz");
    write_displacement_field(&a1_half, &GridField::sample(grid, move |x| u(x) * 0.5), "half").unwrap();
    let out = attach(&["--a1", s(&a1_half)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let mut left: Vec<String> = std::fs::read_dir(atlas_dir.join("motion"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert!(
        left.len() == 1 && left[0].starts_with("a1-") && !files[0].ends_with(&left[0]),
        "{left:?}"
    );
    let halved = BreathingSettings {
        enabled: true,
        measured: true,
        ..Default::default()
    }
    .build(&stylet_atlas::load(&atlas_dir).unwrap().model)
    .unwrap();
    // Without a signal the seeded Lujan waveform drives it (g peaks at 1 each breath): the
    // liver's centre now moves by half the first field at most.
    let peak_mm = (0..400)
        .map(|k| halved.displacement(centre, k as f64 * 0.05).length())
        .fold(0.0, f64::max);
    let half_mm = 0.5 * u(centre).length();
    assert!((peak_mm - half_mm).abs() < 0.3, "{peak_mm} against {half_mm}");
}

/// The needle through the sliding interface while the patient breathes (the default phantom's
/// shipped success script with `breathing on`): the device's step to reference space is relaxed
/// where u is steep (`motion::device_step`), so the force never alternates tick by tick (as the
/// plain fixed-point step did in the intercostal wall: 8 N one tick, 0 the next, for 0.45 s,
/// which the scoring counted as 7 redirections), and the session scores no redirection.
#[test]
fn a_needle_through_the_sliding_interface_feels_no_buzz() {
    let atlas = default_phantom();
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts/success-intercostal.txt"),
    )
    .unwrap()
    .replace("end 20", "breathing on\nend 20");
    let script = parse(&text).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let mut forces = Vec::new();
    let mut in_ramp = 0;
    run_headless(&mut sim, &mut device, |_, o, sim| {
        forces.push(o.force_n);
        // Ticks whose tip is where the motion is steep (the ramps of the mobility map).
        let u = sim.motion().at_time(sim.breath_time_s());
        if let Some(tip) = sim.needle().and_then(|n| n.nodes().last().copied())
            && (u(tip + DVec3::X) - u(tip)).length() > 0.5
        {
            in_ramp += 1;
        }
    });
    // A tick-by-tick alternation: two successive changes of more than 2 N in opposite directions.
    let alternations = forces
        .windows(3)
        .filter(|w| {
            let (a, b) = (w[1] - w[0], w[2] - w[1]);
            a.length() > 2.0 && b.length() > 2.0 && a.dot(b) < 0.0
        })
        .count();
    println!("{in_ramp} ticks with the tip where u is steep; {alternations} alternations");
    assert!(
        in_ramp > 100,
        "the script never takes the tip through a ramp ({in_ramp} ticks)"
    );
    assert_eq!(alternations, 0);
    let work = tempfile::tempdir().unwrap();
    let r = record_and_score(&atlas.dir, work.path(), "success-intercostal", &text);
    assert_eq!(r["metrics"]["redirections"], 0, "{}", r["metrics"]);
}
