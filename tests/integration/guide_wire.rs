//! The guide wire in the phantom's ducts (docs/seldinger.md): the channel built from the atlas'
//! duct labels, a J wire pushed on from where the planned path reaches its target duct.

use crate::common::default_phantom;
use stylet_physics::glam::DVec3;
use stylet_physics::wire::{DuctChannel, GuideWire, WireDiameter, WireEvent, WireSpec, WireTip};

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
    let in_ducts = wire.in_ducts_mm(&channel);
    println!(
        "tip {:?}, {in_ducts:.1} mm of 40 in the ducts, fold {:.1} mm, events {events:?}",
        wire.tip_mm(),
        wire.folded_mm()
    );
    assert!(!events.contains(&WireEvent::LeftDuct));
    assert!(channel.depth_mm(wire.tip_mm()) >= 0.0);
    assert!((in_ducts - 40.0).abs() < 1e-9, "{in_ducts} mm in the ducts");
}
