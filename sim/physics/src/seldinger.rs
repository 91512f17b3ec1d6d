//! The Seldinger exchange after the puncture (thesis §2.1; docs/seldinger.md "In a session"): the
//! guide wire through the needle, the needle out over the wire.
//!
//! [`Access`] holds what is in the patient once a wire goes in: the needle, held still where the
//! hand left it (until it comes out), and the wire, which the hand now feeds. The hand's feed is
//! its movement along the needle's axis since it took the wire, and the wire's roll its rotation
//! about that axis ([`Grip`]): device inputs like any other, so a recorded session replays the
//! wire bit for bit. The first length fed runs through the needle's lumen; past the tip the wire
//! follows the ducts ([`GuideWire`]). The hand feels the wire's axial resistance and a spring
//! holding it on the needle's line.
//!
//! Each step has preconditions the physics checks ([`Refusal`]): a wire needs a needle in the
//! patient with its stylet out and a lumen wide enough; the needle comes out only over a wire
//! [`NEEDLE_OUT_MIN_WIRE_MM`] beyond its tip. Once the needle is out, a wire drawn back until its
//! tip leaves the ducts has lost the access.

use std::sync::Arc;

use glam::{DQuat, DVec3};

use crate::needle::spec::Gauge;
use crate::needle::tool::NeedleTool;
use crate::properties::Param;
use crate::wire::{DuctChannel, GuideWire, NODE_MM, WireDiameter, WireEvent, WireSpec};
use crate::{DeviceProfile, PunctureAtlas};

/// Wire beyond the needle's tip before the needle may come out over it (mm): with less, the
/// needle would draw the wire out with it.
pub const NEEDLE_OUT_MIN_WIRE_MM: f64 = 20.0;
/// Friction of the wire in the needle's lumen (N per mm inside): smooth steel on a hydrophilic
/// coat, an estimate as the ducts' (docs/seldinger.md).
pub const LUMEN_FRICTION_N_PER_MM: f64 = 0.0005;

/// Why the physics refused a step of the exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// No needle in the patient for a wire to go through.
    NoNeedleInside,
    /// The stylet is still in the needle.
    StyletIn,
    /// The wire does not pass the needle's lumen.
    WireTooThick,
    /// A wire is in already.
    WireAlreadyIn,
    /// There is no wire in.
    NoWire,
    /// The needle is out already.
    NeedleAlreadyOut,
    /// The needle is still in: the wire comes out after it.
    NeedleStillIn,
    /// Too little wire beyond the needle's tip for the needle to come out over it.
    WireNotFarEnough,
    /// The patient's atlas has no duct labels for a wire to follow.
    NoDucts,
}

impl Refusal {
    /// What a trainee is told.
    pub fn message(self) -> &'static str {
        match self {
            Refusal::NoNeedleInside => "a guide wire goes in through a needle in the patient",
            Refusal::StyletIn => "take the stylet out before the guide wire",
            Refusal::WireTooThick => "this wire does not pass the needle: a 0.035\" wire needs an 18 G needle or wider",
            Refusal::WireAlreadyIn => "a guide wire is in already",
            Refusal::NoWire => "there is no guide wire in",
            Refusal::NeedleAlreadyOut => "the needle is out already",
            Refusal::NeedleStillIn => "take the needle out over the wire first",
            Refusal::WireNotFarEnough => {
                "advance the wire at least 20 mm beyond the needle's tip before the needle comes out"
            }
            Refusal::NoDucts => "this patient's atlas has no bile ducts for a wire to follow",
        }
    }
}

/// Whether a wire passes a needle's lumen: a 0.018″ wire passes every gauge Stylet has (the
/// 21–22 G Chiba needles of one-stick systems take it); a 0.035″ wire needs 18 G or wider.
pub fn passes(gauge: Gauge, wire: WireDiameter) -> bool {
    match wire {
        WireDiameter::In018 => true,
        WireDiameter::In035 => matches!(gauge, Gauge::G16 | Gauge::G18),
    }
}

/// The hand on the wire: where it took it, along which axis it feeds and from which rotation it
/// rolls (world space: the hand's own movement, whatever the breathing does).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grip {
    origin_mm: DVec3,
    axis: DVec3,
    zero_roll: DVec3,
    /// The feed of the previous tick (mm).
    feed_mm: f64,
}

impl Grip {
    /// The hand takes the wire at `position_mm`, feeding along the tool axis of `orientation`.
    pub fn new(position_mm: DVec3, orientation: DQuat) -> Grip {
        let axis = orientation * DVec3::Z;
        Grip {
            origin_mm: position_mm,
            axis,
            zero_roll: orientation * DVec3::X,
            feed_mm: 0.0,
        }
    }

    /// The hand's feed (mm along the axis since the grip) and roll (rad about the axis) at this
    /// pose.
    pub fn read(&self, position_mm: DVec3, orientation: DQuat) -> (f64, f64) {
        let feed = (position_mm - self.origin_mm).dot(self.axis);
        let x = orientation * DVec3::X;
        let x = x - self.axis * x.dot(self.axis);
        let roll = libm::atan2(self.zero_roll.cross(x).dot(self.axis), self.zero_roll.dot(x));
        (feed, roll)
    }

    /// The spring holding the hand on the needle's line (N): toward the axis through the grip.
    fn line_force(&self, position_mm: DVec3, kappa_n_per_mm: f64) -> DVec3 {
        let off = position_mm - self.origin_mm;
        let lateral = off - self.axis * off.dot(self.axis);
        -lateral * kappa_n_per_mm
    }

    fn digest_into(&self, mut put: impl FnMut(u64)) {
        for v in [self.origin_mm, self.axis, self.zero_roll] {
            for c in v.to_array() {
                put(c.to_bits());
            }
        }
        put(self.feed_mm.to_bits());
    }
}

/// One tick of the exchange.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WireOutput {
    /// Wire inside the needle's lumen (mm).
    pub in_needle_mm: f64,
    /// Wire in the patient beyond the needle's tip, or beyond the skin once the needle is out
    /// (mm, a fold included).
    pub out_mm: f64,
    /// Wire in the ducts' lumen (mm).
    pub in_ducts_mm: f64,
    /// The loop pushed into a blocked tip (mm).
    pub folded_mm: f64,
    /// The wire's tip (world, mm; the needle's tip while the wire is inside it).
    pub tip_mm: DVec3,
    /// The wire's axial resistance to the hand (N; positive against a push).
    pub force_n: f64,
    pub event: Option<WireEvent>,
    /// The tip went through a duct wall and is in the parenchyma.
    pub left_duct: bool,
    /// The needle is still in.
    pub needle_in: bool,
    /// The needle out, the wire was drawn back until its tip left the ducts.
    pub access_lost: bool,
}

/// What is in the patient once a wire goes in.
#[derive(Debug, Clone)]
pub struct Access {
    needle: Option<Box<NeedleTool>>,
    spec: WireSpec,
    grip: Grip,
    /// Wire inside the needle's lumen (mm), up to the needle's length.
    in_needle_mm: f64,
    /// The wire beyond the needle's tip (or, the needle out, beyond the skin); `None` while it
    /// is all inside the needle, or drawn out of the patient.
    wire: Option<GuideWire>,
    channel: Arc<DuctChannel>,
    /// The wire's tip was in the ducts since the needle came out.
    had_access: bool,
    access_lost: bool,
}

impl Access {
    /// Whether a wire of `spec` may go into `needle` (`has_ducts`: the atlas has ducts to
    /// follow).
    pub fn check_insert(needle: &NeedleTool, spec: &WireSpec, has_ducts: bool) -> Result<(), Refusal> {
        if needle.inserted_mm() <= 0.0 {
            return Err(Refusal::NoNeedleInside);
        }
        if needle.stylet_in() {
            return Err(Refusal::StyletIn);
        }
        if !passes(needle.spec().gauge, spec.diameter) {
            return Err(Refusal::WireTooThick);
        }
        if !has_ducts {
            return Err(Refusal::NoDucts);
        }
        Ok(())
    }

    /// The access of a wire of `spec` just entering `needle`'s hub, once
    /// [`Access::check_insert`] agreed.
    pub fn new(
        needle: Box<NeedleTool>,
        spec: WireSpec,
        channel: Arc<DuctChannel>,
        position_mm: DVec3,
        orientation: DQuat,
    ) -> Access {
        Access {
            needle: Some(needle),
            spec,
            grip: Grip::new(position_mm, orientation),
            in_needle_mm: 0.0,
            wire: None,
            channel,
            had_access: false,
            access_lost: false,
        }
    }

    /// The needle, while it is in.
    pub fn needle(&self) -> Option<&NeedleTool> {
        self.needle.as_deref()
    }

    /// The wire beyond the needle's tip (reference space).
    pub fn wire(&self) -> Option<&GuideWire> {
        self.wire.as_ref()
    }

    pub fn spec(&self) -> &WireSpec {
        &self.spec
    }

    /// Takes the needle out over the wire, which stays: its start is laid back along the
    /// needle's track to the skin.
    pub fn remove_needle(&mut self) -> Result<(), Refusal> {
        let Some(needle) = &self.needle else {
            return Err(Refusal::NeedleAlreadyOut);
        };
        let beyond_mm = self.wire.as_ref().map_or(0.0, GuideWire::out_mm);
        if beyond_mm < NEEDLE_OUT_MIN_WIRE_MM {
            return Err(Refusal::WireNotFarEnough);
        }
        let track: Vec<DVec3> = needle.path().nodes().iter().map(|n| n.pos).collect();
        if let Some(w) = &mut self.wire {
            w.lay_in_track(&track, &self.channel);
        }
        self.needle = None;
        self.in_needle_mm = 0.0;
        self.had_access = self.tip_in_ducts();
        Ok(())
    }

    /// Whether the wire may come out now (after the needle).
    pub fn may_remove_wire(&self) -> Result<(), Refusal> {
        if self.needle.is_some() {
            return Err(Refusal::NeedleStillIn);
        }
        Ok(())
    }

    fn tip_in_ducts(&self) -> bool {
        self.wire
            .as_ref()
            .is_some_and(|w| !w.left_duct() && self.channel.depth_mm(w.tip_mm()) >= 0.0)
    }

    /// One tick: the hand at this pose (world) feeds and rolls the wire; `to_world` maps a
    /// reference-space point to where the breathing patient has it now. Returns the wire's state
    /// and the force on the hand (N, world).
    pub fn step(
        &mut self,
        atlas: &PunctureAtlas,
        position_mm: DVec3,
        orientation: DQuat,
        device: &DeviceProfile,
        to_world: impl Fn(DVec3) -> DVec3,
    ) -> (WireOutput, DVec3) {
        let (feed_mm, roll_rad) = self.grip.read(position_mm, orientation);
        let delta_mm = feed_mm - self.grip.feed_mm;
        self.grip.feed_mm = feed_mm;
        // What the hand moves the wire by beyond the needle's tip (or the skin, the needle out).
        let mut rest_mm = delta_mm;
        let mut force_n = 0.0;
        if let Some(needle) = &self.needle {
            // Through the lumen first; what reaches past the tip goes on as the wire.
            if self.wire.is_none() {
                let length_mm = needle.spec().length_mm;
                let inside = self.in_needle_mm + rest_mm;
                self.in_needle_mm = inside.clamp(0.0, length_mm);
                rest_mm = (inside - length_mm).max(0.0);
                if rest_mm > 0.0 {
                    let tip = *needle.nodes().last().expect("needle has nodes");
                    let dir = needle.tangents().last().copied().unwrap_or(DVec3::Z);
                    let up = self.grip.zero_roll;
                    self.wire = Some(GuideWire::from_needle(self.spec, tip, dir, up, &self.channel));
                }
            }
            // Sliding friction in the lumen, against the way the hand moves the wire.
            let sliding = if delta_mm > 0.0 {
                1.0
            } else if delta_mm < 0.0 {
                -1.0
            } else {
                0.0
            };
            force_n = self.in_needle_mm * LUMEN_FRICTION_N_PER_MM * sliding;
        }
        let mut event = None;
        if let Some(w) = &mut self.wire {
            // Only a push can puncture a wall.
            let wall_n = if rest_mm > 0.0 { wall_puncture_n(atlas, w) } else { 0.0 };
            let step = w.advance(rest_mm, roll_rad, &self.channel, wall_n);
            event = step.event;
            force_n += step.force_n;
            // Drawn back into the needle (the wire is in its lumen again), or out of the skin.
            if w.out_mm() < NODE_MM && rest_mm < 0.0 {
                self.wire = None;
            }
        }
        if self.needle.is_none() {
            let in_ducts = self.tip_in_ducts();
            if self.had_access && !in_ducts && !self.wire.as_ref().is_some_and(GuideWire::left_duct) {
                self.access_lost = true;
            }
            self.had_access |= in_ducts;
        }
        let axial = -self.grip.axis * force_n;
        let force = axial + self.grip.line_force(position_mm, device.base_kappa_n_per_mm);
        (self.output(force_n, event, to_world), force)
    }

    /// The wire's state as [`Access::step`] reports it.
    pub fn output(&self, force_n: f64, event: Option<WireEvent>, to_world: impl Fn(DVec3) -> DVec3) -> WireOutput {
        let needle_tip = self.needle.as_ref().and_then(|n| n.nodes().last().copied());
        let tip = match (&self.wire, needle_tip) {
            (Some(w), _) => w.tip_mm(),
            (None, Some(t)) => t,
            (None, None) => DVec3::ZERO,
        };
        WireOutput {
            in_needle_mm: self.in_needle_mm,
            out_mm: self.wire.as_ref().map_or(0.0, GuideWire::out_mm),
            in_ducts_mm: self.wire.as_ref().map_or(0.0, GuideWire::in_ducts_mm),
            folded_mm: self.wire.as_ref().map_or(0.0, GuideWire::folded_mm),
            tip_mm: to_world(tip),
            force_n,
            event,
            left_duct: self.wire.as_ref().is_some_and(GuideWire::left_duct),
            needle_in: self.needle.is_some(),
            access_lost: self.access_lost,
        }
    }

    /// Feeds the bits of the whole state to `put` (the simulation's digest).
    pub fn digest_into(&self, mut put: impl FnMut(u64)) {
        self.grip.digest_into(&mut put);
        put(self.in_needle_mm.to_bits());
        put(u64::from(self.needle.is_some()) | u64::from(self.had_access) << 1 | u64::from(self.access_lost) << 2);
        if let Some(w) = &self.wire {
            w.digest_into(&mut put);
        }
    }
}

/// The force that punctures the wall ahead of the wire's tip (N): the cutting threshold of the
/// tissue a millimetre beyond it.
fn wall_puncture_n(atlas: &PunctureAtlas, wire: &GuideWire) -> f64 {
    let ahead = wire.tip_mm() + wire.tip_dir();
    let depth_mm = f64::from(atlas.skin_distance().sample(ahead, -1000.0));
    atlas.param_at(ahead, depth_mm, Param::CutThresholdN)
}
