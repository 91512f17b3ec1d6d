use std::f64::consts::PI;

use glam::DVec3;

use super::*;
use crate::grid::{Affine, Grid};

/// Puncture force of a dilated duct's wall (N; atlases/ptcd.toml's bile duct).
const WALL_N: f64 = 0.6;
const LUMEN_MM: f64 = 2.5;

/// Distance of `p` from the segment a–b.
fn to_segment(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
    (p - (a + ab * t)).length()
}

/// A channel of 2.5 mm radius around the polyline segments, on a 0.5 mm grid.
fn channel(segments: &[(DVec3, DVec3)]) -> DuctChannel {
    let (g, lumen) = lumen(segments);
    DuctChannel::new(&g, &lumen)
}

/// The grid of [`channel`] and its lumen voxels.
fn lumen(segments: &[(DVec3, DVec3)]) -> (Grid, Vec<bool>) {
    let n = [200, 180, 24];
    let origin = DVec3::new(-50.0, -45.0, -5.75);
    let g = Grid::new(n, Affine::from_spacing([0.5; 3], origin)).unwrap();
    let lumen: Vec<bool> = (0..g.len())
        .map(|i| {
            let [a, b, c] = g.unlinear(i);
            let p = g.voxel_to_world(a, b, c);
            segments.iter().any(|&(s, e)| to_segment(p, s, e) < LUMEN_MM)
        })
        .collect();
    (g, lumen)
}

/// A duct along +x that splits at the origin into branches 35° up (+y) and down (−y).
fn y_ducts() -> DuctChannel {
    let a = 35f64.to_radians();
    let (sin, cos) = (libm::sin(a), libm::cos(a));
    let o = DVec3::ZERO;
    channel(&[
        (DVec3::new(-45.0, 0.0, 0.0), o),
        (o, DVec3::new(40.0 * cos, 40.0 * sin, 0.0)),
        (o, DVec3::new(40.0 * cos, -40.0 * sin, 0.0)),
    ])
}

fn wire(tip: WireTip, diameter: WireDiameter) -> GuideWire {
    GuideWire::new(
        WireSpec::new(diameter, tip),
        DVec3::new(-40.0, 0.0, 0.0),
        DVec3::X,
        DVec3::Y,
    )
}

/// Pushes `mm` in 0.1 mm steps (a hand at 100 mm/s and 1 kHz), keeping the largest force and
/// the events.
fn push(w: &mut GuideWire, mm: f64, roll: f64, c: &DuctChannel) -> (f64, Vec<WireEvent>) {
    let (mut max_n, mut events) = (0.0f64, Vec::new());
    for _ in 0..(mm / 0.1).round() as usize {
        let s = w.advance(0.1, roll, c, WALL_N);
        max_n = max_n.max(s.force_n);
        events.extend(s.event);
    }
    (max_n, events)
}

#[test]
fn the_wire_numbers_follow_their_sources() {
    let s = WireSpec::new(WireDiameter::In035, WireTip::Straight);
    // 9.5 GPa · π · 0.889⁴ / 64.
    assert!(
        (s.body_rigidity_nmm2() - 291.3).abs() < 0.5,
        "{}",
        s.body_rigidity_nmm2()
    );
    // 1 g at 10 mm for 45°: 0.00981 · 100 / (2 · π/4).
    assert!(
        (s.tip_rigidity_nmm2() - 0.6243).abs() < 1e-3,
        "{}",
        s.tip_rigidity_nmm2()
    );
    // The body over 30 mm buckles above a duct wall's 0.6 N, the floppy tip far below.
    assert!(s.push_limit_n(30.0) > WALL_N && s.push_limit_n(0.0) < 0.01);
    let thin = WireSpec::new(WireDiameter::In018, WireTip::Straight);
    assert!(thin.push_limit_n(100.0) < WALL_N);
    assert!(s.validate().is_ok());
    let bad = WireSpec {
        tip_load_g: f64::NAN,
        ..s
    };
    assert!(bad.validate().unwrap_err().to_string().contains("tip load NaN g"));
}

/// The J's roll decides the branch: bent toward +y it takes the upper branch, turned half a
/// turn the lower; the tip stays in the lumen all along.
#[test]
fn the_j_tip_takes_the_branch_it_is_turned_toward() {
    let c = y_ducts();
    for (roll, side) in [(0.0, 1.0), (PI, -1.0)] {
        let mut w = wire(WireTip::J, WireDiameter::In035);
        for _ in 0..70 {
            push(&mut w, 1.0, roll, &c);
            assert!(
                c.depth_mm(w.tip_mm()) >= 0.0,
                "roll {roll}: tip {:?} left the lumen",
                w.tip_mm()
            );
        }
        let tip = w.tip_mm();
        assert!(tip.x > 15.0 && tip.y * side > 10.0, "roll {roll}: tip at {tip:?}");
        assert!(!w.left_duct());
        assert!((w.in_ducts_mm() - 70.0).abs() < 1.0, "{}", w.in_ducts_mm());
    }
}

/// With the hilum up the upper branch of the Y, a J turned into it goes the right way; turned
/// into the lower branch it runs away from the hilum: one wrong-branch entry.
#[test]
fn a_j_turned_into_the_branch_away_from_the_hilum_enters_a_wrong_branch() {
    let a = 35f64.to_radians();
    let upper_end = DVec3::new(40.0 * libm::cos(a), 40.0 * libm::sin(a), 0.0);
    let o = DVec3::ZERO;
    let (g, lumen) = lumen(&[
        (DVec3::new(-45.0, 0.0, 0.0), o),
        (o, upper_end),
        (o, DVec3::new(upper_end.x, -upper_end.y, 0.0)),
    ]);
    let c = DuctChannel::with_hilum_at(&g, &lumen, upper_end);
    for (roll, entries) in [(0.0, 0), (PI, 1)] {
        let mut w = wire(WireTip::J, WireDiameter::In035);
        let mut watch = WrongBranchWatch::default();
        for _ in 0..70 {
            push(&mut w, 1.0, roll, &c);
            watch.observe(c.from_hilum_mm(w.tip_mm()));
        }
        assert_eq!(watch.entries(), entries, "roll {roll}: tip at {:?}", w.tip_mm());
    }
    // The hilum is where it was put, and the stem's foot is about 40 + 45 mm from it.
    let foot = c.from_hilum_mm(DVec3::new(-44.0, 0.0, 0.0)).unwrap();
    assert!((83.0..90.0).contains(&foot), "{foot}");
}

/// A straight floppy tip follows a curving duct: the walls turn it, the hand feels them a little.
#[test]
fn a_straight_tip_follows_a_curving_duct() {
    // A quarter circle of 30 mm radius from (−40, −30) heading +x to (−10, 0) heading +y, drawn
    // as chords.
    let centre = DVec3::new(-40.0, 0.0, 0.0);
    let arc: Vec<DVec3> = (0..=12)
        .map(|i| {
            let a = -PI / 2.0 + PI / 2.0 * f64::from(i) / 12.0;
            centre + DVec3::new(30.0 * libm::cos(a), 30.0 * libm::sin(a), 0.0)
        })
        .collect();
    let mut segs: Vec<(DVec3, DVec3)> = arc.windows(2).map(|w| (w[0], w[1])).collect();
    segs.push((DVec3::new(-45.0, -30.0, 0.0), arc[0]));
    segs.push((arc[12], DVec3::new(-10.0, 40.0, 0.0)));
    let c = channel(&segs);
    let mut w = GuideWire::new(
        WireSpec::new(WireDiameter::In035, WireTip::Straight),
        DVec3::new(-43.0, -30.0, 0.0),
        DVec3::X,
        DVec3::Y,
    );
    let (max_n, events) = push(&mut w, 75.0, 0.0, &c);
    let tip = w.tip_mm();
    assert!(tip.y > 15.0 && (tip.x + 10.0).abs() < LUMEN_MM, "tip at {tip:?}");
    assert!(w.tip_dir().y > 0.9, "{:?}", w.tip_dir());
    assert!(events.is_empty() && w.folded_mm() == 0.0, "{events:?}");
    assert!(max_n > 0.0 && max_n < 0.05, "{max_n} N");
}

/// A dead end: the floppy tip folds (the hand feels its small buckling load); pushed on until the
/// fold has taken up the floppy tip, the body leads and a straight tip goes through the wall; a J
/// turns at the wall and coils in the duct, and a thin 0.018″ wire never pushes hard enough. Drawn back, the wire is in the
/// duct again.
#[test]
fn a_blocked_tip_folds_and_only_a_hard_pushed_straight_tip_leaves_the_duct() {
    let c = channel(&[(DVec3::new(-45.0, 0.0, 0.0), DVec3::new(0.0, 0.0, 0.0))]);
    let mut w = wire(WireTip::Straight, WireDiameter::In035);
    let (_, events) = push(&mut w, 44.0, 0.0, &c);
    assert_eq!(events, [WireEvent::Blocked], "{:?}", w.tip_mm());
    let (folding_n, events) = push(&mut w, 10.0, 0.0, &c);
    assert!(events.is_empty() && w.folded_mm() > 5.0 && !w.left_duct());
    assert!(folding_n < 0.05, "{folding_n} N");
    let (hard_n, events) = push(&mut w, 30.0, 0.0, &c);
    assert_eq!(events, [WireEvent::LeftDuct]);
    assert!(hard_n >= WALL_N, "{hard_n} N");
    assert!(w.left_duct() && c.depth_mm(w.tip_mm()) < 0.0);
    // Drawn back: the fold first, then the tip back into the duct.
    let mut back = Vec::new();
    for _ in 0..600 {
        back.extend(w.advance(-0.1, 0.0, &c, WALL_N).event);
    }
    assert_eq!(back, [WireEvent::BackInDuct]);
    assert!(!w.left_duct() && w.folded_mm() == 0.0);

    for (tip, diameter) in [
        (WireTip::J, WireDiameter::In035),
        (WireTip::Straight, WireDiameter::In018),
    ] {
        let mut w = wire(tip, diameter);
        let (_, events) = push(&mut w, 120.0, 0.0, &c);
        assert!(!events.contains(&WireEvent::LeftDuct), "{tip:?} {diameter:?}");
        assert!(
            !w.left_duct() && w.folded_mm() > 0.0 && c.depth_mm(w.tip_mm()) >= 0.0,
            "{tip:?} {diameter:?}: {:?}, folded {} mm",
            w.tip_mm(),
            w.folded_mm()
        );
        assert!((w.out_mm() - 120.0).abs() < 1e-9);
    }
}

/// The same pushes, pulls and rolls give the same wire, bit for bit.
#[test]
fn the_wire_is_deterministic() {
    let c = y_ducts();
    let run = || {
        let mut w = wire(WireTip::J, WireDiameter::In035);
        let mut forces = Vec::new();
        for i in 0..2000u32 {
            let delta = if i % 7 == 0 { -0.13 } else { 0.11 };
            forces.push(w.advance(delta, f64::from(i) * 0.003, &c, WALL_N).force_n.to_bits());
        }
        let nodes: Vec<[u64; 3]> = w.nodes().iter().map(|p| p.to_array().map(f64::to_bits)).collect();
        (nodes, forces, w.folded_mm().to_bits())
    };
    assert_eq!(run(), run());
}

/// A damaged input moves the hub at most [`MAX_MOVE_MM`] a call; NaN moves nothing.
#[test]
fn one_call_moves_the_wire_a_bounded_length() {
    let c = y_ducts();
    let mut w = wire(WireTip::Straight, WireDiameter::In035);
    w.advance(1e300, 0.0, &c, WALL_N);
    assert_eq!(w.out_mm(), MAX_MOVE_MM);
    w.advance(f64::NAN, f64::NAN, &c, WALL_N);
    assert_eq!(w.out_mm(), MAX_MOVE_MM);
}
