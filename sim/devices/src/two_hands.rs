//! Two devices driving one session (docs/physics.md "Two hands"): the first device drives the
//! first hand (the needle hand), the second device the second hand (the probe hand). Any two
//! [`Device`]s combine: two force-feedback devices, a force-feedback device and a SpaceMouse, a
//! SpaceMouse and the keyboard and mouse, two scripts.
//!
//! Each device is given its own tool's output as its `last`: the second device sees the second
//! hand's force and torque where a one-handed device sees the first hand's, so a force-feedback
//! device in either hand feels its own tool and a force-controlled script presses against its own
//! contact. The second device's tool changes select the second hand's tool.

use stylet_physics::{Event, HandPose, HandTool, TickInput, TickOutput};

use crate::Device;

/// The first and second hand's devices as one.
pub struct TwoHands {
    first: Box<dyn Device + Send>,
    second: Box<dyn Device + Send>,
    /// Notes of the second device's tool changes the second hand cannot make (a needle).
    notes: Vec<String>,
}

impl TwoHands {
    pub fn new(first: Box<dyn Device + Send>, second: Box<dyn Device + Send>) -> Self {
        TwoHands {
            first,
            second,
            notes: Vec::new(),
        }
    }
}

/// What the second device is shown of the last tick: the second hand's force and torque, contacts
/// and indentation in the places a one-handed device reads its tool's (the window's hints read
/// the probe hand's tool the same way).
pub fn second_hand_view(out: &TickOutput) -> TickOutput {
    let hand = out.second_hand.unwrap_or_default();
    TickOutput {
        force_n: hand.force_n,
        torque_nmm: hand.torque_nmm,
        components: stylet_physics::ForceComponents {
            skin: hand.skin_n,
            slide: hand.slide_n,
            bone: hand.bone_n,
            ..Default::default()
        },
        insertion_dir: hand.orientation * stylet_physics::glam::DVec3::Z,
        tip_label: 0,
        inserted_mm: 0.0,
        tip_mm: hand.position_mm,
        tip_depth_mm: 0.0,
        contacts: hand.contacts,
        indentation_mm: hand.indentation_mm,
        second_hand: None,
        ..*out
    }
}

impl Device for TwoHands {
    /// Ends when either device ends: one session, both hands.
    fn next(&mut self, tick: u64, last: Option<&TickOutput>) -> Option<TickInput> {
        let mut input = self.first.next(tick, last)?;
        let second_last = last.map(second_hand_view);
        let second = self.second.next(tick, second_last.as_ref())?;
        input.second_hand = Some(HandPose {
            position_mm: second.position_mm,
            orientation: second.orientation,
            buttons: second.buttons,
        });
        for e in second.events {
            match e {
                Event::SelectTool(spec) => match HandTool::from_tool_spec(spec) {
                    Some(tool) => input.events.push(Event::SecondTool(Some(tool))),
                    None => self
                        .notes
                        .push(format!("hand 2: the second hand cannot take the {}", spec.name())),
                },
                Event::SecondTool(_) => {}
                other => input.events.push(other),
            }
        }
        Some(input)
    }

    fn notes(&mut self) -> Vec<String> {
        let mut notes = self.first.notes();
        notes.extend(self.second.notes().into_iter().map(|n| format!("hand 2: {n}")));
        notes.append(&mut self.notes);
        notes
    }

    /// The first hand's force-feedback device (the session records one device's forces).
    fn device_force(&self) -> Option<crate::haptic::Guarded> {
        self.first.device_force()
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use stylet_physics::{DeviceProfile, SecondHandConfig, SimConfig, Simulation, ToolSpec};

    use super::*;
    use crate::run_headless;
    use crate::script::{ScriptedDevice, parse};

    /// A soft slab under air at z > 0 with a flat skin.
    fn atlas() -> Arc<stylet_physics::PunctureAtlas> {
        use stylet_physics::glam::DVec3;
        use stylet_physics::{Affine, Grid, synthetic_atlas};
        let n = 60;
        let g = Grid::new([n; 3], Affine::from_spacing([1.0; 3], DVec3::splat(-29.5))).unwrap();
        let mut ct = vec![40.0f32; g.len()];
        for (i, v) in ct.iter_mut().enumerate() {
            let [a, b, c] = g.unlinear(i);
            if g.voxel_to_world(a, b, c).z > 0.0 {
                *v = -1000.0;
            }
        }
        let labels = vec![0u16; g.len()];
        Arc::new(
            synthetic_atlas::atlas_with(g, ct, labels, &[], stylet_physics::properties::ParamValue::Scalar(0.5))
                .unwrap(),
        )
    }

    const FIRST: &str = "stylet-script 1\ntool finger\nend 2\nat 0 pos -10 0 5 dir 0 0 -1\nat 0.2 press 0 0 -1 1\n";
    const SECOND: &str =
        "stylet-script 1\ntool probe linear\nend 2\nat 0 pos 10 0 5 dir 0 0 -1\nat 0.2 press 0 0 -1 2\n";
    const BOTH: &str = "stylet-script 1\ntool finger\ntool2 probe linear\nend 2\n\
        at 0 pos -10 0 5 dir 0 0 -1\nat 0 hand2 pos 10 0 5 dir 0 0 -1\n\
        at 0.2 press 0 0 -1 1\nat 0.2 hand2 press 0 0 -1 2\n";

    fn sim() -> Simulation {
        let mut config = SimConfig::new(DeviceProfile::PREMIUM, ToolSpec::Finger);
        config.second_hand = Some(SecondHandConfig {
            device: DeviceProfile::PREMIUM,
            tool: Some(HandTool::Probe(stylet_physics::ProbeKind::Linear)),
        });
        Simulation::new(atlas(), config).unwrap()
    }

    fn run(device: &mut dyn Device) -> Vec<(TickInput, TickOutput)> {
        let mut sim = sim();
        let mut ticks = Vec::new();
        run_headless(&mut sim, device, |i, o, _| ticks.push((i.clone(), *o)));
        ticks
    }

    /// Two one-handed devices combined drive the session exactly as one two-handed script with
    /// the same tracks, and each presses against its own tool's force: the finger settles at
    /// 1 N, the probe in the other hand at 2 N.
    #[test]
    fn two_devices_drive_both_hands_and_each_feels_its_own_tool() {
        let device = |text: &str| Box::new(ScriptedDevice::new(&parse(text).unwrap(), &[]).unwrap());
        let mut two = TwoHands::new(device(FIRST), device(SECOND));
        let combined = run(&mut two);
        let scripted = run(&mut *device(BOTH));
        assert_eq!(combined.len(), 2000);
        assert_eq!(combined, scripted);
        let (_, last) = combined.last().unwrap();
        let hand = last.second_hand.unwrap();
        assert!((last.force_n.z - 1.0).abs() < 0.05, "first hand {:?}", last.force_n);
        assert!((hand.force_n.z - 2.0).abs() < 0.1, "second hand {:?}", hand.force_n);
    }

    /// The second device's tool changes select the second hand's tool; a needle is refused with
    /// a note, and the other events pass through.
    #[test]
    fn the_second_devices_tool_changes_are_the_second_hands() {
        let second = "stylet-script 1\ntool probe linear\nend 1\nat 0 pos 10 0 5 dir 0 0 -1\n\
            at 0.1 tool finger\nat 0.2 tool needle\nat 0.3 event xray-on\n";
        let device = |text: &str| Box::new(ScriptedDevice::new(&parse(text).unwrap(), &[]).unwrap());
        let mut two = TwoHands::new(device(FIRST), device(second));
        let events: Vec<Event> = run(&mut two).into_iter().flat_map(|(i, _)| i.events).collect();
        assert_eq!(events, [Event::SecondTool(Some(HandTool::Finger)), Event::XrayOn]);
        assert_eq!(two.notes(), ["hand 2: the second hand cannot take the needle"]);
    }
}
