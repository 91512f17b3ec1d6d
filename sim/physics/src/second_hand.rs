//! The second hand: an ultrasound probe (or a palpating finger) held while the first hand works
//! the needle, as an interventional radiologist punctures under live ultrasound guidance (thesis
//! chapter 7 names the one-tool-at-a-time set-up as its main weakness; docs/physics.md "Two
//! hands").
//!
//! The second hand holds a contact tool or nothing, never a needle: the needle stays in the first
//! hand, so every needle metric reads one needle. Its tool is stepped in the same tick as the
//! first hand's, after it, on the same tissue: its contacts enter the same deformation solve, and
//! its device gets its own force, clamped to its own device's limits.

use glam::{DQuat, DVec3};

use crate::PunctureAtlas;
use crate::contact::{ContactFriction, ContactPattern, ContactTool};
use crate::device::DeviceProfile;
use crate::events::{ProbeKind, ToolSpec};
use crate::motion;

/// What the second hand can hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HandTool {
    Finger,
    Probe(ProbeKind),
}

impl HandTool {
    /// The same tool as a first-hand tool.
    pub fn tool_spec(self) -> ToolSpec {
        match self {
            HandTool::Finger => ToolSpec::Finger,
            HandTool::Probe(k) => ToolSpec::Probe(k),
        }
    }

    /// The second-hand tool of a first-hand tool; `None` for a needle.
    pub fn from_tool_spec(spec: ToolSpec) -> Option<HandTool> {
        match spec {
            ToolSpec::Finger => Some(HandTool::Finger),
            ToolSpec::Probe(k) => Some(HandTool::Probe(k)),
            ToolSpec::Needle { .. } => None,
        }
    }

    /// A fresh contact tool of this kind (with either hand).
    pub(crate) fn make(self) -> ContactTool {
        match self {
            HandTool::Finger => ContactTool::new(ContactPattern::fingertip(), ContactFriction::FINGER),
            HandTool::Probe(ProbeKind::Linear) => {
                ContactTool::new(ContactPattern::linear_probe(), ContactFriction::PROBE_WITH_GEL)
            }
            HandTool::Probe(ProbeKind::Convex) => {
                ContactTool::new(ContactPattern::convex_probe(), ContactFriction::PROBE_WITH_GEL)
            }
        }
    }
}

/// A session's second hand: the device that drives it and what it holds at tick 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SecondHandConfig {
    pub device: DeviceProfile,
    pub tool: Option<HandTool>,
}

/// The second device's report for one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandPose {
    /// Device position (mm, world space): the tool's reference point, as for the first hand.
    pub position_mm: DVec3,
    /// The tool axis q · (0, 0, 1) points into the patient.
    pub orientation: DQuat,
    /// Button bits (recorded, not used by the physics).
    pub buttons: u32,
}

/// What one tick gives the second hand.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HandOutput {
    /// Force for the second device (N), clamped to its maximum.
    pub force_n: DVec3,
    /// Torque for the second device (N·mm), clamped.
    pub torque_nmm: DVec3,
    pub skin_n: DVec3,
    pub slide_n: DVec3,
    pub bone_n: DVec3,
    /// Nodes touching the skin.
    pub contacts: u32,
    /// Deepest indentation of a node (mm).
    pub indentation_mm: f64,
    /// The pose the tool was stepped with (world; the last valid one when the input glitched).
    pub position_mm: DVec3,
    pub orientation: DQuat,
    /// Whether the hand holds a tool this tick.
    pub holding: bool,
}

/// The second hand's state.
#[derive(Debug, Clone)]
pub struct SecondHand {
    device: DeviceProfile,
    spec: Option<HandTool>,
    tool: Option<ContactTool>,
    /// The device position mapped to reference space on the previous tick (§5.4.3).
    device_ref: Option<DVec3>,
    last_position: DVec3,
    last_orientation: DQuat,
}

impl SecondHand {
    pub fn new(config: SecondHandConfig) -> Self {
        SecondHand {
            device: config.device,
            spec: config.tool,
            tool: config.tool.map(HandTool::make),
            device_ref: None,
            last_position: DVec3::ZERO,
            last_orientation: DQuat::IDENTITY,
        }
    }

    pub fn device(&self) -> &DeviceProfile {
        &self.device
    }
    pub fn tool_spec(&self) -> Option<HandTool> {
        self.spec
    }
    pub fn contact(&self) -> Option<&ContactTool> {
        self.tool.as_ref()
    }
    /// The last pose the hand was stepped with (world).
    pub fn pose(&self) -> (DVec3, DQuat) {
        (self.last_position, self.last_orientation)
    }
    /// The device position in reference space on the last tick.
    pub fn reference_position(&self) -> Option<DVec3> {
        self.device_ref
    }

    /// Puts the tool down and takes `tool` (a fresh contact state, like a first-hand change).
    pub fn select(&mut self, tool: Option<HandTool>) {
        self.spec = tool;
        self.tool = tool.map(HandTool::make);
    }

    /// One tick: the pose (the last valid one when `pose` is absent or not finite) mapped to
    /// reference space by one fixed-point step, then the contact tool's haptic step.
    pub fn step(
        &mut self,
        atlas: &PunctureAtlas,
        u_at: &dyn Fn(DVec3) -> DVec3,
        pose: Option<&HandPose>,
    ) -> HandOutput {
        if let Some(p) = pose {
            if p.position_mm.is_finite() {
                self.last_position = p.position_mm;
            }
            let q = p.orientation;
            if q.is_finite() && q.length_squared() > 1e-12 {
                self.last_orientation = q.normalize();
            }
        }
        let (x_world, q) = (self.last_position, self.last_orientation);
        let x_ref = motion::device_step(u_at, x_world, self.device_ref.unwrap_or(x_world));
        self.device_ref = Some(x_ref);
        let mut out = HandOutput {
            position_mm: x_world,
            orientation: q,
            ..HandOutput::default()
        };
        if let Some(c) = &mut self.tool {
            let f = c.step(atlas, x_ref, q);
            out.skin_n = f.skin;
            out.slide_n = f.slide;
            out.bone_n = f.bone;
            out.contacts = f.contacts as u32;
            out.indentation_mm = c.nodes().iter().map(|n| n.depth_mm).fold(0.0, f64::max);
            out.force_n = clamp_length(f.skin + f.slide + f.bone, self.device.max_force_n);
            out.torque_nmm = clamp_length(f.torque, self.device.max_torque_nmm);
            out.holding = true;
        }
        out
    }

    /// Feeds every bit of the state to `h` (for the simulation's state digest).
    pub fn digest_into(&self, mut h: impl FnMut(u64)) {
        h(match self.spec {
            None => 0,
            Some(HandTool::Finger) => 1,
            Some(HandTool::Probe(ProbeKind::Linear)) => 2,
            Some(HandTool::Probe(ProbeKind::Convex)) => 3,
        });
        let bits = |v: DVec3| v.to_array().map(f64::to_bits);
        let mut words: Vec<u64> = bits(self.last_position).to_vec();
        if let Some(x) = self.device_ref {
            words.extend(bits(x));
        }
        for node in self.tool.iter().flat_map(|c| c.nodes()) {
            words.extend(bits(node.pos));
            words.extend(bits(node.proxy));
            words.extend(bits(node.surface));
            words.push(u64::from(node.in_contact));
        }
        words.extend(self.last_orientation.to_array().map(f64::to_bits));
        for w in words {
            h(w);
        }
    }
}

/// `v` shortened to length `max` when longer.
pub(crate) fn clamp_length(v: DVec3, max: f64) -> DVec3 {
    let l = v.length();
    if l > max && l > 0.0 { v * (max / l) } else { v }
}
