//! The Seldinger exchange after the puncture (thesis §2.1; docs/seldinger.md "In a session"): the
//! guide wire through the needle, the needle out over the wire, the dilator and the drainage
//! catheter over the wire, the wire out and the catheter's pigtail formed.
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
//! tip leaves the ducts has lost the access. A dilator or catheter goes on the wire only once the
//! needle is out ([`over_wire`]); the wire comes out of a catheter, which then forms its pigtail
//! ([`pigtail`]).

pub mod over_wire;
pub mod pigtail;

use std::sync::Arc;

use glam::{DQuat, DVec3};

use crate::needle::spec::Gauge;
use crate::needle::tool::NeedleTool;
use crate::properties::Param;
use crate::wire::{DuctChannel, GuideWire, NODE_MM, WireDiameter, WireEvent, WireSpec};
use crate::{DeviceProfile, PunctureAtlas};
use over_wire::{FR_PER_MM, OverWire, OverWireKind, Tract};
use pigtail::{DRAINAGE_HOLES, Pigtail};

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
    /// A dilator or catheter of a size Stylet does not have.
    NoSuchSize(OverWireKind),
    /// A dilator or catheter is on the wire already.
    ToolOnWire,
    /// No dilator on the wire to take out.
    NoDilator,
    /// The dilator is still on the wire.
    DilatorStillIn,
    /// The catheter is in place: its wire is out and nothing more goes over it.
    CatheterPlaced,
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
            Refusal::NoSuchSize(OverWireKind::Dilator) => "dilators come in 6, 8, 10 and 12 F",
            Refusal::NoSuchSize(OverWireKind::Catheter) => "drainage catheters come in 8 and 10 F",
            Refusal::ToolOnWire => "take the dilator or catheter on the wire off first",
            Refusal::NoDilator => "there is no dilator on the wire",
            Refusal::DilatorStillIn => "take the dilator out over the wire first",
            Refusal::CatheterPlaced => "the catheter is in place and its wire is out",
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

    /// The hand takes another tool on the same wire at this pose: the roll's reference carries
    /// over, so the wire does not turn when the hand changes its hold.
    pub fn regrip(&self, position_mm: DVec3, orientation: DQuat) -> Grip {
        let mut grip = Grip::new(position_mm, orientation);
        let keep = self.zero_roll - grip.axis * self.zero_roll.dot(grip.axis);
        if let Some(zero) = keep.try_normalize() {
            grip.zero_roll = zero;
        }
        grip
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

/// A dilator or catheter on the wire in a tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OverWireOutput {
    pub kind: OverWireKind,
    pub size_fr: u8,
    /// Its tip along the wire from the skin (mm).
    pub inserted_mm: f64,
    /// The force its tip needs to open the tract this tick (N).
    pub opening_n: f64,
    /// Its tip (world, mm).
    pub tip_mm: DVec3,
}

/// The drainage catheter once its wire is out and its pigtail formed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CatheterOutput {
    pub size_fr: u8,
    /// Drainage holes in the ducts' lumen, of [`DRAINAGE_HOLES`].
    pub holes_in_ducts: u8,
    /// The pigtail's loop centre lies in the ducts.
    pub pigtail_in_ducts: bool,
    /// The loop's radius (mm; smaller than nominal where the duct is narrow).
    pub loop_radius_mm: f64,
    /// The catheter's tip (world, mm).
    pub tip_mm: DVec3,
}

impl CatheterOutput {
    /// Every drainage hole drains the ducts.
    pub fn drains(&self) -> bool {
        usize::from(self.holes_in_ducts) == DRAINAGE_HOLES
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
    /// A dilator or catheter on the wire.
    pub over_wire: Option<OverWireOutput>,
    /// The catheter in place, its pigtail formed.
    pub catheter: Option<CatheterOutput>,
    /// The wire is in (false once it came out of the catheter).
    pub wire_in: bool,
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
    /// The needle's size (French), for the tract it made and the over-the-wire tools' forces.
    needle_fr: f64,
    /// The tract along the wire, from when the needle came out.
    tract: Option<Tract>,
    /// The dilator or catheter the hand holds on the wire.
    on_wire: Option<OverWire>,
    /// The catheter in place, its wire out.
    pigtail: Option<(u8, Pigtail)>,
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
        let needle_fr = needle.spec().gauge.outer_diameter_mm() * FR_PER_MM;
        Access {
            needle: Some(needle),
            spec,
            grip: Grip::new(position_mm, orientation),
            in_needle_mm: 0.0,
            wire: None,
            channel,
            had_access: false,
            access_lost: false,
            needle_fr,
            tract: None,
            on_wire: None,
            pigtail: None,
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

    /// The ducts the wire follows.
    pub fn channel(&self) -> &DuctChannel {
        &self.channel
    }

    /// Takes the needle out over the wire, which stays: its start is laid back along the
    /// needle's track to the skin, and the needle leaves a tract of its size.
    pub fn remove_needle(&mut self) -> Result<(), Refusal> {
        let Some(needle) = &self.needle else {
            return Err(Refusal::NeedleAlreadyOut);
        };
        let beyond_mm = self.wire.as_ref().map_or(0.0, GuideWire::out_mm);
        if beyond_mm < NEEDLE_OUT_MIN_WIRE_MM {
            return Err(Refusal::WireNotFarEnough);
        }
        let track: Vec<DVec3> = needle.path().nodes().iter().map(|n| n.pos).collect();
        let track_mm: f64 = track.windows(2).map(|w| w[0].distance(w[1])).sum();
        if let Some(w) = &mut self.wire {
            w.lay_in_track(&track, &self.channel);
        }
        self.needle = None;
        self.in_needle_mm = 0.0;
        self.had_access = self.tip_in_ducts();
        let wire_fr = self.spec.diameter.mm() * FR_PER_MM;
        self.tract = Some(Tract::new(self.needle_fr, track_mm, wire_fr));
        Ok(())
    }

    /// A dilator or catheter of `size_fr` slides onto the wire at the skin; the hand at this pose
    /// holds it from now on. Needs the needle out, a wire beyond the skin and nothing else on it.
    pub fn put_on_wire(
        &mut self,
        atlas: &PunctureAtlas,
        kind: OverWireKind,
        size_fr: u8,
        position_mm: DVec3,
        orientation: DQuat,
    ) -> Result<(), Refusal> {
        self.check_open()?;
        if !kind.offers(size_fr) {
            return Err(Refusal::NoSuchSize(kind));
        }
        if self.needle.is_some() {
            return Err(Refusal::NeedleStillIn);
        }
        match &self.on_wire {
            Some(t) if t.kind == OverWireKind::Dilator && kind == OverWireKind::Catheter => {
                return Err(Refusal::DilatorStillIn);
            }
            Some(_) => return Err(Refusal::ToolOnWire),
            None => {}
        }
        let Some(wire) = &self.wire else {
            return Err(Refusal::NoWire);
        };
        self.on_wire = Some(OverWire::new(kind, size_fr, atlas, wire.nodes(), self.needle_fr));
        self.grip = self.grip.regrip(position_mm, orientation);
        Ok(())
    }

    /// The dilator out over the wire; the hand at this pose holds the wire again.
    pub fn remove_dilator(&mut self, position_mm: DVec3, orientation: DQuat) -> Result<(), Refusal> {
        self.check_open()?;
        if !self.on_wire.as_ref().is_some_and(|t| t.kind == OverWireKind::Dilator) {
            return Err(Refusal::NoDilator);
        }
        self.on_wire = None;
        self.grip = self.grip.regrip(position_mm, orientation);
        Ok(())
    }

    /// The wire out of the catheter on it, whose pigtail forms where its tip lies; the hand lets
    /// go. `Ok(false)`: no catheter on the wire, the wire may come out as it is (after the
    /// needle, with no dilator on it).
    pub fn remove_wire(&mut self) -> Result<bool, Refusal> {
        self.check_open()?;
        if self.needle.is_some() {
            return Err(Refusal::NeedleStillIn);
        }
        match self.on_wire.take() {
            None => Ok(false),
            Some(t) if t.kind == OverWireKind::Dilator => {
                self.on_wire = Some(t);
                Err(Refusal::DilatorStillIn)
            }
            Some(catheter) => {
                let path = self.wire.as_ref().map(|w| w.nodes().to_vec()).unwrap_or_default();
                let pigtail = Pigtail::form(
                    &path,
                    catheter.inserted_mm(),
                    catheter.diameter_mm(),
                    &self.channel,
                    self.grip.zero_roll,
                );
                self.pigtail = Some((catheter.size_fr, pigtail));
                self.wire = None;
                Ok(true)
            }
        }
    }

    /// Nothing more happens once the catheter is in place.
    fn check_open(&self) -> Result<(), Refusal> {
        if self.pigtail.is_some() {
            return Err(Refusal::CatheterPlaced);
        }
        Ok(())
    }

    /// The placed catheter's pigtail (reference space).
    pub fn pigtail(&self) -> Option<&Pigtail> {
        self.pigtail.as_ref().map(|(_, p)| p)
    }

    /// The placed catheter: its size (French) and its pigtail (reference space).
    pub fn placed_catheter(&self) -> Option<(u8, &Pigtail)> {
        self.pigtail.as_ref().map(|(fr, p)| (*fr, p))
    }

    /// The dilator or catheter on the wire.
    pub fn on_wire(&self) -> Option<&OverWire> {
        self.on_wire.as_ref()
    }

    /// Where contrast injected now leaves the instruments (reference space): the placed
    /// catheter's tip; `None` while nothing open is in (a needle's own outlet is its tip).
    pub fn catheter_outlet(&self) -> Option<DVec3> {
        self.pigtail().map(Pigtail::tip_mm)
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
        if self.pigtail.is_some() {
            // The catheter in place: the hand holds nothing.
            return (self.output(0.0, None, None, to_world), DVec3::ZERO);
        }
        if let Some(tool) = &mut self.on_wire {
            // The hand moves the dilator or catheter; the wire stays.
            let tract = self
                .tract
                .as_mut()
                .expect("a tool goes on the wire only once the needle is out");
            let step = tool.step(delta_mm, tract, self.needle_fr);
            let axial = -self.grip.axis * step.force_n;
            let force = axial + self.grip.line_force(position_mm, device.base_kappa_n_per_mm);
            return (self.output(step.force_n, None, Some(step.opening_n), to_world), force);
        }
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
        (self.output(force_n, event, None, to_world), force)
    }

    /// The wire's state as [`Access::step`] reports it (`opening_n`: the tool on the wire
    /// opening the tract this tick).
    pub fn output(
        &self,
        force_n: f64,
        event: Option<WireEvent>,
        opening_n: Option<f64>,
        to_world: impl Fn(DVec3) -> DVec3,
    ) -> WireOutput {
        let needle_tip = self.needle.as_ref().and_then(|n| n.nodes().last().copied());
        let tip = match (&self.wire, needle_tip) {
            (Some(w), _) => w.tip_mm(),
            (None, Some(t)) => t,
            (None, None) => DVec3::ZERO,
        };
        let over_wire = match (&self.on_wire, &self.wire) {
            (Some(t), Some(w)) => Some(OverWireOutput {
                kind: t.kind,
                size_fr: t.size_fr,
                inserted_mm: t.inserted_mm(),
                opening_n: opening_n.unwrap_or(0.0),
                tip_mm: to_world(over_wire::point_at(w.nodes(), t.inserted_mm()).0),
            }),
            _ => None,
        };
        let catheter = self.pigtail.as_ref().map(|(size_fr, p)| CatheterOutput {
            size_fr: *size_fr,
            holes_in_ducts: p.holes_inside() as u8,
            pigtail_in_ducts: self.channel.depth_mm(p.centre_mm) >= 0.0,
            loop_radius_mm: p.radius_mm,
            tip_mm: to_world(p.tip_mm()),
        });
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
            over_wire,
            catheter,
            wire_in: self.pigtail.is_none(),
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
        if let Some(t) = &self.tract {
            t.digest_into(&mut put);
        }
        if let Some(t) = &self.on_wire {
            t.digest_into(&mut put);
        }
        if let Some((_, p)) = &self.pigtail {
            p.digest_into(&mut put);
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
