//! The guide wire in the phantom's ducts (docs/seldinger.md): the channel built from the atlas'
//! duct labels, a J wire pushed on from where the planned path reaches its target duct; the
//! exchange in a session: the wire fed through the needle, the needle out over it, the access
//! lost, the steps refused out of order, and the replay.

use std::sync::Arc;

use crate::common::{default_phantom, phantom_script_text, record_script, score_session};
use stylet_devices::run_headless;
use stylet_devices::script::{parse, scripted_simulation};
use stylet_physics::glam::DVec3;
use stylet_physics::wire::{DuctChannel, GuideWire, WireDiameter, WireEvent, WireSpec, WireTip};
use stylet_physics::{Event, Refusal, Simulation, TickOutput};

/// The bile duct's wall puncture force in atlases/ptcd.toml (N).
const WALL_N: f64 = 0.6;

#[test]
fn a_j_wire_pushed_from_the_target_runs_on_in_the_phantoms_ducts() {
    let atlas = default_phantom();
    let model = &atlas.model;
    assert!(DuctChannel::of_tissue(model, "no_such_tissue").is_none());
    let channel = DuctChannel::of_tissue(model, "bile_duct").expect("the phantom has bile ducts");
    let path = atlas.guided_path().unwrap();
    let (entry, target) = (DVec3::from_array(path.entry_mm), DVec3::from_array(path.target_mm));
    let dir = (target - entry).normalize();
    assert!(channel.depth_mm(target) > 0.0, "the target is in the duct lumen");
    let mut wire = GuideWire::new(
        WireSpec::new(WireDiameter::In035, WireTip::J),
        target,
        dir,
        dir.any_orthonormal_vector(),
    );
    let mut events = Vec::new();
    for _ in 0..400 {
        events.extend(wire.advance(0.1, 0.0, &channel, WALL_N).event);
    }
    let in_ducts = wire.in_ducts_mm();
    println!(
        "tip {:?}, {in_ducts:.1} mm of 40 in the ducts, fold {:.1} mm, events {events:?}",
        wire.tip_mm(),
        wire.folded_mm()
    );
    assert!(!events.contains(&WireEvent::LeftDuct));
    assert!(channel.depth_mm(wire.tip_mm()) >= 0.0);
    assert!((in_ducts - 40.0).abs() < 1e-9, "{in_ducts} mm in the ducts");
}

/// Every tick of a phantom script: its inputs' events and its outputs.
fn run_script(atlas: &stylet_atlas::Atlas, text: &str) -> (Vec<(Vec<Event>, TickOutput)>, Simulation) {
    let script = parse(text).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let mut ticks = Vec::new();
    run_headless(&mut sim, &mut device, |i, o, _| ticks.push((i.events.clone(), *o)));
    (ticks, sim)
}

fn at(ticks: &[(Vec<Event>, TickOutput)], t_s: f64) -> &TickOutput {
    &ticks[(t_s * 1000.0) as usize].1
}

#[test]
fn a_j_wire_fed_through_the_needle_runs_into_the_ducts_and_stays_when_the_needle_comes_out() {
    let atlas = default_phantom();
    let (ticks, sim) = run_script(atlas, &phantom_script_text("guide-wire.txt"));
    assert!(ticks.iter().all(|t| t.1.refused.is_none()), "no step refused");
    assert!(at(&ticks, 13.9).wire.is_none(), "no wire before wire-in");
    // Fed 190 mm by 26 s: 150 mm through the needle, 40 mm on into the ducts.
    let fed = at(&ticks, 26.5).wire.unwrap();
    println!("at 26.5 s: {fed:?}");
    assert!(fed.needle_in);
    assert_eq!(fed.in_needle_mm, 150.0);
    assert!((fed.out_mm - 40.0).abs() <= 0.5, "{} mm beyond the tip", fed.out_mm);
    assert!(fed.in_ducts_mm >= 39.0, "{} mm in the ducts", fed.in_ducts_mm);
    assert!(!fed.left_duct && !fed.access_lost);
    // The hand felt the wire's light resistance while feeding it (less than a newton), and the
    // needle stayed where the hand left it.
    let feeding: Vec<f64> = ticks[14_100..26_000]
        .iter()
        .map(|t| t.1.wire.unwrap().force_n)
        .collect();
    let most = feeding.iter().copied().fold(0.0, f64::max);
    assert!(most > 0.0 && most < 1.0, "wire resistance up to {most} N");
    let needle_tip = at(&ticks, 13.9).tip_mm;
    assert!(
        at(&ticks, 26.5).tip_mm.distance(needle_tip) < 1e-9,
        "the needle held still"
    );
    // The needle out over the wire: the wire stays where it was, still in the ducts, now from the
    // skin.
    let after = at(&ticks, 29.9).wire.unwrap();
    assert!(!after.needle_in && sim.needle().is_none());
    assert!(after.tip_mm.distance(fed.tip_mm) < 1e-9, "the wire's tip stayed");
    assert!(after.in_ducts_mm >= 39.0 && !after.access_lost);
    assert!(after.out_mm > 140.0, "{} mm from the skin", after.out_mm);
}

#[test]
fn a_wire_drawn_back_out_of_the_ducts_after_the_needle_loses_the_access() {
    let atlas = default_phantom();
    let (ticks, _) = run_script(atlas, &phantom_script_text("loss-of-access.txt"));
    assert!(ticks.iter().all(|t| t.1.refused.is_none()));
    let before = at(&ticks, 27.5).wire.unwrap();
    assert!(!before.needle_in && !before.access_lost && before.in_ducts_mm > 39.0);
    let lost_at = ticks
        .iter()
        .position(|t| t.1.wire.is_some_and(|w| w.access_lost))
        .expect("the access is lost");
    let end = ticks.last().unwrap().1.wire.unwrap();
    println!("access lost at {} s; at the end {end:?}", lost_at as f64 / 1000.0);
    assert!(lost_at > 27_500 && end.access_lost);
    assert!(end.in_ducts_mm < 1.0, "{} mm still in the ducts", end.in_ducts_mm);
}

/// Each step of the exchange is refused, and changes nothing, while its preconditions fail.
#[test]
fn steps_of_the_exchange_are_refused_until_their_preconditions_hold() {
    let atlas = default_phantom();
    // The needle on the planned path into the duct by 11 s; `early` lines before 1 s.
    let script = |gauge: u32, early: &str, lines: &str| {
        format!(
            "stylet-script 1\ndevice premium\ntool needle gauge {gauge} length 150 stylet in\nend 16\n\
             at 0 along intercostal-10-11 -15\n{early}at 1 along intercostal-10-11 -15\n\
             at 11 along intercostal-10-11 111\n{lines}"
        )
    };
    let refusals = |text: String| -> Vec<(f64, Refusal)> {
        let (ticks, _) = run_script(atlas, &text);
        ticks
            .iter()
            .filter_map(|t| t.1.refused.map(|r| (t.1.time_s, r)))
            .collect()
    };
    // A wire outside the patient, with the stylet in, through too fine a needle; then the order.
    assert_eq!(
        refusals(script(
            18,
            "at 0.5 event wire-in 0.035 j\n",
            "at 12 event wire-in 0.035 j\n"
        )),
        vec![(0.5, Refusal::NoNeedleInside), (12.0, Refusal::StyletIn)]
    );
    assert_eq!(
        refusals(script(
            22,
            "",
            "at 12 event stylet-remove\nat 13 event wire-in 0.035 j\nat 14 event wire-in 0.018 j\n"
        )),
        vec![(13.0, Refusal::WireTooThick)]
    );
    assert_eq!(
        refusals(script(
            18,
            "",
            "at 12 event needle-out\nat 12.5 event stylet-remove\nat 13 event wire-in 0.035 straight\n\
             at 13.5 event wire-in 0.035 j\nat 14 event needle-out\nat 14.5 event wire-out\n"
        )),
        vec![
            (12.0, Refusal::NoWire),
            (13.5, Refusal::WireAlreadyIn),
            (14.0, Refusal::WireNotFarEnough),
            (14.5, Refusal::NeedleStillIn),
        ]
    );
    for r in [Refusal::NoNeedleInside, Refusal::WireNotFarEnough, Refusal::NoDucts] {
        assert!(!r.message().is_empty());
    }
}

/// The whole PTCD replays bit for bit, with the tissue deforming and the patient breathing: the
/// same script twice gives the same state digest every second, and a recorded session of it
/// replays with every digest matched.
#[test]
fn the_full_ptcd_replays_bit_for_bit() {
    let atlas = default_phantom();
    let text = phantom_script_text("full-ptcd.txt")
        .replace("device premium\n", "device premium\ndeformation on\nbreathing on\n");
    assert!(text.contains("breathing on"));
    let digests = || {
        let script = parse(&text).unwrap();
        let (mut sim, mut device) =
            scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
        let mut d = Vec::new();
        let mut placed = None;
        run_headless(&mut sim, &mut device, |_, o, s| {
            if o.tick % 1000 == 999 {
                d.push(s.state_digest());
            }
            placed = o.wire.and_then(|w| w.catheter);
        });
        (d, placed)
    };
    let (first, placed) = digests();
    assert!(placed.is_some_and(|c| c.drains()), "{placed:?}");
    assert_eq!(first, digests().0);
    let dir = tempfile::tempdir().unwrap();
    let path = record_script(atlas, dir.path(), "full-ptcd", "beginner", &text);
    let session = stylet_recorder::reader::verify(&path).unwrap();
    let (report, trace) = stylet_scoring::Scorer::new(atlas, stylet_scoring::Rubric::default_rubric(), None)
        .unwrap()
        .score_session_traced(&session)
        .unwrap();
    assert!(report.replay_verified, "{:?}", report.divergence);
    assert!(report.digests_checked > 50);
    // The review's timeline: the puncture, the wire, the dilator on it and off, the catheter,
    // each phase from its step's event (the script's times) to the next.
    use stylet_scoring::drainage::Step;
    let phases: Vec<(Step, f64, f64)> = trace
        .phases
        .iter()
        .map(|p| (p.step, (p.from_s * 10.0).round() / 10.0, (p.to_s * 10.0).round() / 10.0))
        .collect();
    assert_eq!(
        phases,
        [
            (Step::Puncture, 0.0, 14.0),
            (Step::Wire, 14.0, 29.0),
            (Step::Dilator, 29.0, 38.5),
            (Step::Wire, 38.5, 39.0),
            (Step::Catheter, 39.0, 54.0),
        ]
    );
    // Scored as documented (docs/metrics.md "Drainage"): the wire in the ducts, one pass of each
    // tool, the catheter draining through all six holes, fluoroscopy counted per step; nothing
    // in the reasons about the exchange.
    let d = report.metrics.drainage.clone().expect("a wire went in");
    println!("{d:?}\n{:?}", report.reasons);
    assert!(d.wire_reached_ducts && d.wire_in_ducts_max_mm > 39.0);
    assert!(!d.access_lost && !d.wire_left_duct);
    assert_eq!(
        (
            d.wire_attempts,
            d.dilator_attempts,
            d.catheter_attempts,
            d.refused_steps,
            d.wrong_branch_entries
        ),
        (1, 1, 1, 0, 0)
    );
    assert!(d.catheter_placed && d.drains() && d.pigtail_in_ducts);
    assert!(d.dilator_peak_force_n > d.catheter_peak_force_n && d.catheter_peak_force_n > 0.0);
    assert!((d.fluoroscopy_wire_s - 1.0).abs() < 0.01 && d.fluoroscopy_dilator_s == 0.0);
    assert!(d.fluoroscopy_catheter_s > 3.0 && d.fluoroscopy_puncture_s > 1.0);
    assert!(
        !report
            .reasons
            .iter()
            .any(|r| r.contains("catheter") || r.contains("guide wire"))
    );
    // Graded as the drainage exercise its scenario declares: it passes at beginner level, losing
    // only the palpation and ultrasound the script leaves out.
    assert_eq!(report.exercise, stylet_scoring::Exercise::Drainage);
    assert!(report.grade.passed, "{:?}", report.grade);
    assert_eq!(report.grade.score, 90.0, "{:?}", report.grade.deductions);
    // The official reader of session files reads the exchange's events.
    let py = std::process::Command::new(crate::common::python())
        .arg("-c")
        .arg(
            "import sys; sys.path.insert(0, sys.argv[1]); import stylet_session as s; \
             e = s.read_session(sys.argv[2]).events; \
             print([(n, w or f) for n, w, f in zip(e['name'], e['wire'], e['size_fr']) \
                    if n in ('wire-in', 'needle-out', 'dilator-in', 'catheter-in', 'wire-out')])",
        )
        .arg(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("recorder/python"))
        .arg(&path)
        .output()
        .unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    assert_eq!(
        String::from_utf8_lossy(&py.stdout).trim(),
        "[('wire-in', '0.035 j'), ('needle-out', None), ('dilator-in', 8), ('catheter-in', 8), ('wire-out', None)]"
    );
}

/// The over-the-wire steps are refused, and change nothing, out of order.
#[test]
fn the_dilator_and_catheter_go_on_the_wire_only_in_order() {
    let atlas = default_phantom();
    let extra = "at 20 event dilator-in 8\nat 28.5 event dilator-out\nat 33 event catheter-in 8\n\
                 at 34 event wire-out\nat 40 event dilator-in 8\nat 52 event catheter-in 10";
    // Each line in its place in time (a script's lines run in order).
    let script = phantom_script_text("full-ptcd.txt");
    let (head, mut timed): (Vec<&str>, Vec<&str>) = script.lines().partition(|l| !l.starts_with("at "));
    timed.extend(extra.lines().map(str::trim));
    let time = |l: &str| l.split_whitespace().nth(1).unwrap().parse::<f64>().unwrap();
    timed.sort_by(|a, b| time(a).total_cmp(&time(b)));
    let text = [head, timed].concat().join("\n");
    let (ticks, _) = run_script(atlas, &text);
    let refused: Vec<_> = ticks
        .iter()
        .filter_map(|t| t.1.refused.map(|r| (t.1.time_s, r)))
        .collect();
    assert_eq!(
        refused,
        vec![
            (20.0, Refusal::NeedleStillIn),
            (28.5, Refusal::NoDilator),
            (33.0, Refusal::DilatorStillIn),
            (34.0, Refusal::DilatorStillIn),
            (40.0, Refusal::ToolOnWire),
            (52.0, Refusal::CatheterPlaced),
        ]
    );
    let c = ticks.last().unwrap().1.wire.unwrap().catheter.unwrap();
    assert!(c.drains() && c.size_fr == 8);
}

/// The whole PTCD: the dilator widens the tract into the duct, the catheter follows it over the
/// wire against less resistance, the wire comes out and the pigtail forms in the ducts with every
/// drainage hole inside; contrast through the catheter reaches the ducts.
#[test]
fn a_full_ptcd_ends_with_a_pigtail_draining_the_ducts() {
    let atlas = default_phantom();
    let (ticks, sim) = run_script(atlas, &phantom_script_text("full-ptcd.txt"));
    let refused: Vec<_> = ticks
        .iter()
        .filter_map(|t| t.1.refused.map(|r| (t.1.time_s, r)))
        .collect();
    assert!(refused.is_empty(), "{refused:?}");
    let wired = at(&ticks, 28.5).wire.unwrap();
    println!("wire after the needle: {wired:?}");
    let dilating = at(&ticks, 34.9).wire.unwrap();
    println!("dilator: {:?}", dilating.over_wire);
    let peak = |from_s: f64, to_s: f64| {
        ticks[(from_s * 1000.0) as usize..(to_s * 1000.0) as usize]
            .iter()
            .map(|t| t.1.wire.unwrap().force_n)
            .fold(0.0, f64::max)
    };
    let (dilator_n, catheter_n) = (peak(29.0, 35.0), peak(39.0, 46.0));
    let catheter = at(&ticks, 45.9).wire.unwrap();
    println!(
        "dilator up to {dilator_n:.2} N, catheter up to {catheter_n:.2} N; {:?}",
        catheter.over_wire
    );
    let placed = ticks.last().unwrap().1;
    println!(
        "placed: {:?}; contrast in ducts {} ml",
        placed.wire.unwrap().catheter,
        placed.contrast_in_ducts_ml
    );
    let c = placed.wire.unwrap().catheter.expect("the catheter is placed");
    assert!(c.drains() && c.pigtail_in_ducts);
    assert!(sim.access().is_some_and(|a| a.pigtail().is_some()));
}

/// A catheter pushed too short a way: its pigtail forms in the liver, its holes outside the duct.
#[test]
fn a_catheter_left_short_forms_its_pigtail_outside_the_ducts() {
    let atlas = default_phantom();
    let (ticks, _) = run_script(atlas, &phantom_script_text("catheter-outside.txt"));
    assert!(ticks.iter().all(|t| t.1.refused.is_none()));
    let c = ticks
        .last()
        .unwrap()
        .1
        .wire
        .unwrap()
        .catheter
        .expect("the catheter is placed");
    println!("{c:?}");
    assert!(!c.drains() && !c.pigtail_in_ducts, "{c:?}");
}

/// The views see the exchange's instruments: the wire alone once the needle is out, the catheter
/// on it as far as its tip while it is pushed, the placed catheter with its loop once the wire is
/// out; each darkens the radiograph where it lies.
#[test]
fn the_wire_and_catheter_are_drawn_where_the_physics_has_them() {
    use stylet_render::tools::{LineKind, ToolState};
    use stylet_render::xray::{CArm, XrayScene, render};
    let atlas = default_phantom();
    let script = parse(&phantom_script_text("full-ptcd.txt")).unwrap();
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
    let mut states = Vec::new();
    run_headless(&mut sim, &mut device, |i, o, s| {
        if [28_000, 45_999, 53_000].contains(&o.tick) {
            states.push((*o, ToolState::from_simulation(s, i)));
        }
    });
    let kinds = |t: &ToolState| t.lines.iter().map(|l| l.kind).collect::<Vec<_>>();
    assert_eq!(kinds(&states[0].1), [LineKind::GuideWire]);
    assert_eq!(kinds(&states[1].1), [LineKind::GuideWire, LineKind::Catheter]);
    assert_eq!(kinds(&states[2].1), [LineKind::Catheter]);
    // The wire ends at the physics' tip; the catheter on it at its tip.
    let (out, wire) = (&states[1].0.wire.unwrap(), &states[1].1.lines);
    let end = |i: usize| wire[i].nodes_mm.last().unwrap().as_dvec3();
    assert!(end(0).distance(out.tip_mm) < 1e-3, "{:?} vs {:?}", end(0), out.tip_mm);
    assert!(end(1).distance(out.over_wire.unwrap().tip_mm) < 1e-3);
    let placed = &states[2].1.lines[0];
    let c = states[2].0.wire.unwrap().catheter.unwrap();
    assert!(placed.nodes_mm.last().unwrap().as_dvec3().distance(c.tip_mm) < 1e-3);
    assert!(placed.nodes_mm.len() < 200, "{} nodes", placed.nodes_mm.len());
    // Each darkens the radiograph.
    let arm = CArm::posterior_anterior(c.tip_mm.as_vec3());
    let bare = XrayScene {
        c_arm: arm,
        needle: None,
        lines: Vec::new(),
        contrast: None,
    };
    let plain = render(&atlas.model, &bare, 128, 128).unwrap();
    for (_, tools) in &states {
        let with = XrayScene {
            lines: tools.lines.clone(),
            ..bare.clone()
        };
        let img = render(&atlas.model, &with, 128, 128).unwrap();
        let added = (0..128 * 128)
            .map(|i| img.at(i % 128, i / 128) - plain.at(i % 128, i / 128))
            .fold(0.0f32, f32::max);
        assert!(added > 0.01, "{:?}: {added}", kinds(tools));
    }
}

/// Each failure script is graded with its own plain reason.
#[test]
fn each_failed_exchange_gets_its_reason() {
    let atlas = default_phantom();
    let dir = tempfile::tempdir().unwrap();
    for (name, reason) in [
        (
            "catheter-outside",
            "The catheter's side holes lie outside the duct (4 of 6): bile would leak.",
        ),
        (
            "loss-of-access",
            "The guide wire was drawn back out of the ducts after the needle came out: the access was lost.",
        ),
    ] {
        let path = record_script(
            atlas,
            dir.path(),
            name,
            "beginner",
            &phantom_script_text(&format!("{name}.txt")),
        );
        let report = score_session(atlas, &path);
        assert!(report.replay_verified, "{name}: {:?}", report.divergence);
        println!("{name}: {:?}", report.reasons);
        assert!(
            report.reasons.iter().any(|r| r.starts_with(reason)),
            "{name}: {:?}",
            report.reasons
        );
        // A drain that leaks, or none placed, fails the drainage exercise, whatever the puncture.
        assert_eq!(report.exercise, stylet_scoring::Exercise::Drainage);
        assert!(!report.grade.passed, "{name}: {:?}", report.grade);
        let unmet: Vec<&str> = report.grade.unmet.iter().map(|u| u.metric.as_str()).collect();
        let expected: &[&str] = if name == "loss-of-access" {
            &["catheter_not_placed"]
        } else {
            &["catheter_holes_outside_ducts"]
        };
        assert_eq!(unmet, expected, "{name}");
        let d = report.metrics.drainage.unwrap();
        assert_eq!(d.access_lost, name == "loss-of-access");
        assert_eq!(d.catheter_placed, name == "catheter-outside");
        assert!(!d.drains());
    }
}

/// From the target in the right hepatic duct a J wire runs toward the hilum (the common bile
/// duct's widest point) for 20 mm, to the confluence; fed on, it crosses into the left hepatic duct,
/// away from the hilum: one wrong-branch entry, whichever way its J is turned.
#[test]
fn a_wire_fed_across_the_confluence_enters_a_wrong_branch() {
    use stylet_physics::wire::WrongBranchWatch;
    let atlas = default_phantom();
    let channel = DuctChannel::of_tissue(&atlas.model, "bile_duct").expect("the phantom has bile ducts");
    let path = atlas.guided_path().unwrap();
    let (entry, target) = (DVec3::from_array(path.entry_mm), DVec3::from_array(path.target_mm));
    let dir = (target - entry).normalize();
    let start_mm = channel.from_hilum_mm(target).expect("the target is in the ducts");
    for roll in [0.0, std::f64::consts::PI] {
        let mut wire = GuideWire::new(
            WireSpec::new(WireDiameter::In035, WireTip::J),
            target,
            dir,
            dir.any_orthonormal_vector(),
        );
        let mut watch = WrongBranchWatch::default();
        let mut nearest_mm = start_mm;
        for step in 1..=600 {
            wire.advance(0.1, roll, &channel, WALL_N);
            let d = channel.from_hilum_mm(wire.tip_mm());
            nearest_mm = nearest_mm.min(d.unwrap_or(f64::INFINITY));
            watch.observe(d);
            if step == 250 {
                assert_eq!(watch.entries(), 0, "roll {roll}: 25 mm in");
            }
        }
        let tip = wire.tip_mm();
        println!("roll {roll}: {start_mm:.1} mm from the hilum, nearest {nearest_mm:.1}, tip {tip:?}");
        assert!(
            start_mm - nearest_mm > 15.0,
            "roll {roll}: the wire first went toward the hilum"
        );
        assert_eq!(watch.entries(), 1, "roll {roll}: tip {tip:?}");
        // The left hepatic duct runs from the confluence (x ≈ 29 mm) to the patient's left.
        assert!(tip.x < 12.0, "roll {roll}: tip {tip:?}");
    }
}
