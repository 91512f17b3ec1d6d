//! The fixed-step simulation: `step(tick input) → tick output`, 1 kHz by default (thesis §3.5–3.6;
//! docs/physics.md "The tick").
//!
//! Deterministic by construction: time is the tick count divided by the rate (no wall clock), no
//! threads, no hash maps, f64 throughout, transcendental functions through `libm` (glam's `libm`
//! feature), no fused multiply-add. The same inputs give the same bits; [`Simulation::state_digest`]
//! hashes the whole state so a replay can find the first tick where it diverges.

use std::sync::Arc;

use glam::{DQuat, DVec3};

use crate::complications::{self, Complications, ConsequenceVolumes, NeedleTip};
use crate::contact::ContactTool;
use crate::contrast::{ContrastAgent, ContrastSettings};
use crate::deform::{self, DeformSettings, DeformState};
use crate::device::DeviceProfile;
use crate::events::{Event, ToolSpec};
use crate::motion::{self, BreathingError, BreathingSettings, MotionModel, Static};
use crate::needle::spec::NeedleSpec;
use crate::needle::tool::NeedleTool;
use crate::second_hand::{HandOutput, HandPose, HandTool, SecondHand, SecondHandConfig, clamp_length};
use crate::seldinger::over_wire::OverWireKind;
use crate::seldinger::{Access, Refusal, WireOutput};
use crate::wire::WireSpec;
use crate::{LabelId, PunctureAtlas, SettingsError};

/// Version of the physics: bump it with every change that alters any output bit, so a replay
/// knows which physics graded a session.
pub const PHYSICS_VERSION: u32 = 13;

/// Default haptic rate.
pub const DEFAULT_TICK_RATE_HZ: u32 = 1000;

/// What the device reports for one tick.
#[derive(Debug, Clone, PartialEq)]
pub struct TickInput {
    /// Device position (mm, world space): the tool tip (for a needle, the tip of the rigid needle).
    pub position_mm: DVec3,
    /// Device orientation; the tool axis q_z = orientation · (0, 0, 1) points into the patient.
    pub orientation: DQuat,
    /// Button bits (device specific; recorded, not used by the physics).
    pub buttons: u32,
    pub events: Vec<Event>,
    /// The second device's pose in a two-handed session (the second hand holds its last pose
    /// while this is absent); ignored when the session has no second hand.
    pub second_hand: Option<HandPose>,
}

impl TickInput {
    pub fn pose(position_mm: DVec3, orientation: DQuat) -> Self {
        TickInput {
            position_mm,
            orientation,
            buttons: 0,
            events: Vec::new(),
            second_hand: None,
        }
    }
}

/// Force components before clamping, all at the handle (N).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ForceComponents {
    pub cut: DVec3,
    pub friction: DVec3,
    pub base: DVec3,
    pub skin: DVec3,
    pub slide: DVec3,
    pub bone: DVec3,
}

/// What one tick produces: the device's force and torque plus a summary of the tool state (the
/// full state — needle and path nodes, proxies — through [`Simulation::needle`] and
/// [`Simulation::contact`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TickOutput {
    pub tick: u64,
    pub time_s: f64,
    /// Force for the device (N), clamped to the device's maximum.
    pub force_n: DVec3,
    /// Torque for the device (N·mm), clamped; zero on 3-DOF devices.
    pub torque_nmm: DVec3,
    pub components: ForceComponents,
    /// Direction of insertion at the tip (d_l) while a needle is in the body, else the tool axis.
    pub insertion_dir: DVec3,
    /// Needle: label at the tip (l(x, d) as the needle feels it); contact tools: 0.
    pub tip_label: LabelId,
    /// Needle: inserted length along the channel (mm).
    pub inserted_mm: f64,
    /// Needle tip position (world, mm); contact tools: the device position.
    pub tip_mm: DVec3,
    /// Needle: tip depth under the skin surface D_skin (mm, negative outside).
    pub tip_depth_mm: f64,
    /// Contact tools: nodes touching the skin.
    pub contacts: u32,
    /// Contact tools: deepest indentation of a node (mm).
    pub indentation_mm: f64,
    pub stylet_in: bool,
    pub xray_on: bool,
    pub breath_hold: bool,
    /// Contrast asked for by injection events so far (ml).
    pub contrast_ml: f64,
    /// Contrast that entered the duct system so far (ml).
    pub contrast_in_ducts_ml: f64,
    /// Contrast delivered into tissue that is not a duct so far (ml): extravasation.
    pub extravasated_ml: f64,
    /// Filled duct length from where contrast entered the ducts (mm, max so far).
    pub contrast_extent_mm: f64,
    /// Largest tissue displacement of the deformation in effect (mm; thesis Chapter 4).
    pub tissue_displacement_mm: f64,
    /// Largest displacement of a segmented risk structure (mm): a vessel pushed aside.
    pub risk_displacement_mm: f64,
    /// The second hand's tool, in a two-handed session.
    pub second_hand: Option<HandOutput>,
    /// What wrong punctures have let out so far (ml): haematoma, pneumothorax, bile leak.
    pub consequences: ConsequenceVolumes,
    /// The guide wire, once one is in (the Seldinger exchange).
    pub wire: Option<WireOutput>,
    /// An event of this tick the physics refused, and why (the last if several).
    pub refused: Option<Refusal>,
}

/// The tool in hand.
#[derive(Debug, Clone)]
#[allow(
    clippy::large_enum_variant,
    reason = "one tool per simulation, replaced only when the trainee changes tools; the contact tool's fixed-size sample buffers stay inline for the 1 kHz tick"
)]
pub enum Tool {
    Needle(Box<NeedleTool>),
    Contact(ContactTool),
    /// A guide wire in, fed by the hand; the needle held still until it comes out over it.
    Seldinger(Box<Access>),
}

/// Simulation settings.
#[derive(Clone)]
pub struct SimConfig {
    pub tick_rate_hz: u32,
    pub device: DeviceProfile,
    pub tool: ToolSpec,
    /// The motion model when `breathing` is off (tests supply their own); with breathing on,
    /// [`Simulation::new`] builds it from `breathing` and the atlas.
    pub motion: Arc<dyn MotionModel>,
    /// Respiratory motion (part of the world model, recorded in the session header).
    pub breathing: BreathingSettings,
    pub contrast: ContrastSettings,
    /// Tissue deformation (part of the world model, recorded in the session header).
    pub deformation: DeformSettings,
    /// The second hand, for a session with two tools at once (none: one hand, as in the thesis).
    pub second_hand: Option<SecondHandConfig>,
    /// Run each deformation solve on a thread of its own (the live simulator). The bits are the
    /// same either way: a result enters at its fixed due tick, waited for if late.
    pub deform_in_background: bool,
}

impl SimConfig {
    pub fn new(device: DeviceProfile, tool: ToolSpec) -> Self {
        SimConfig {
            tick_rate_hz: DEFAULT_TICK_RATE_HZ,
            device,
            tool,
            motion: Arc::new(Static),
            breathing: BreathingSettings::default(),
            contrast: ContrastSettings::default(),
            deformation: DeformSettings::default(),
            second_hand: None,
            deform_in_background: false,
        }
    }
}

/// Why a simulation cannot start: a setting of its configuration out of range, or breathing the
/// atlas cannot provide. Breathing settings out of range are [`SimError::Settings`] too.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SimError {
    #[error(transparent)]
    Settings(#[from] SettingsError),
    #[error(transparent)]
    Breathing(BreathingError),
}

impl From<BreathingError> for SimError {
    fn from(e: BreathingError) -> Self {
        match e {
            BreathingError::Settings(s) => SimError::Settings(s),
            e => SimError::Breathing(e),
        }
    }
}

/// The simulation of one session on one atlas. A clone is an independent copy of the state (the
/// atlas is shared): stepping both with the same inputs gives the same outputs, bit for bit.
#[derive(Clone)]
pub struct Simulation {
    atlas: Arc<PunctureAtlas>,
    config: SimConfig,
    tool_spec: ToolSpec,
    tool: Tool,
    /// The tool in the other hand, in a two-handed session.
    second: Option<SecondHand>,
    tick: u64,
    /// Ticks breathed so far: the breathing clock stands still during a breath hold, so the
    /// motion resumes where it was held (t_breath = breath_ticks / rate).
    breath_ticks: u64,
    /// The breathing time the last tick's motion was evaluated at (what the views show).
    motion_time_s: f64,
    breath_hold: bool,
    xray_on: bool,
    contrast_ml: f64,
    contrast: ContrastAgent,
    complications: Complications,
    deformation: DeformState,
    /// Device position mapped to reference space on the previous tick (fixed point of §5.4.3).
    device_ref: Option<DVec3>,
    last_position: DVec3,
    last_orientation: DQuat,
}

impl Tool {
    /// The needle, in hand or held still while a wire goes through it.
    pub fn needle(&self) -> Option<&NeedleTool> {
        match self {
            Tool::Needle(n) => Some(n),
            Tool::Seldinger(a) => a.needle(),
            Tool::Contact(_) => None,
        }
    }
}

fn make_tool(spec: &ToolSpec) -> Tool {
    match *spec {
        ToolSpec::Needle {
            gauge,
            length_mm,
            stylet_in,
        } => Tool::Needle(Box::new(NeedleTool::new(NeedleSpec { gauge, length_mm }, stylet_in))),
        ToolSpec::Finger => Tool::Contact(HandTool::Finger.make()),
        ToolSpec::Probe(kind) => Tool::Contact(HandTool::Probe(kind).make()),
    }
}

impl Simulation {
    pub fn new(atlas: Arc<PunctureAtlas>, mut config: SimConfig) -> Result<Self, SimError> {
        if config.tick_rate_hz == 0 || config.tick_rate_hz > 100_000 {
            return Err(SettingsError::TickRate(config.tick_rate_hz).into());
        }
        if let ToolSpec::Needle { gauge, length_mm, .. } = config.tool {
            NeedleSpec { gauge, length_mm }.validate()?;
        }
        let tool_spec = config.tool;
        let contrast = ContrastAgent::new(&atlas, config.contrast)?;
        config.deformation.validate()?;
        if config.breathing.enabled {
            config.motion = config.breathing.build(&atlas)?;
        } else {
            config.breathing.validate()?;
        }
        Ok(Simulation {
            contrast,
            complications: Complications::new(&atlas),
            deformation: DeformState::new(config.deformation, config.deform_in_background),
            tool: make_tool(&tool_spec),
            second: config.second_hand.map(SecondHand::new),
            tool_spec,
            atlas,
            config,
            tick: 0,
            breath_ticks: 0,
            motion_time_s: 0.0,
            breath_hold: false,
            xray_on: false,
            contrast_ml: 0.0,
            device_ref: None,
            last_position: DVec3::ZERO,
            last_orientation: DQuat::IDENTITY,
        })
    }

    pub fn atlas(&self) -> &PunctureAtlas {
        &self.atlas
    }
    /// The atlas, shared (for work beside the loop, such as building its ducts' channel).
    pub fn shared_atlas(&self) -> Arc<PunctureAtlas> {
        Arc::clone(&self.atlas)
    }
    pub fn tick(&self) -> u64 {
        self.tick
    }
    pub fn tool_spec(&self) -> &ToolSpec {
        &self.tool_spec
    }
    pub fn device(&self) -> &DeviceProfile {
        &self.config.device
    }
    pub fn tick_rate_hz(&self) -> u32 {
        self.config.tick_rate_hz
    }
    /// The needle, in hand or held still while a wire goes through it.
    pub fn needle(&self) -> Option<&NeedleTool> {
        self.tool.needle()
    }
    /// The exchange over a guide wire, once a wire is in.
    pub fn access(&self) -> Option<&Access> {
        match &self.tool {
            Tool::Seldinger(a) => Some(a),
            _ => None,
        }
    }
    /// The contrast agent (eqs. 3.3.1–3.3.2).
    pub fn contrast(&self) -> &ContrastAgent {
        &self.contrast
    }
    /// What wrong punctures did to the patient.
    pub fn complications(&self) -> &Complications {
        &self.complications
    }
    /// Runs later deformation solves on a thread of their own (or inline): the bits stay the same.
    pub fn set_deform_in_background(&mut self, background: bool) {
        self.config.deform_in_background = background;
        self.deformation.set_background(background);
    }
    /// The tissue deformation in effect (thesis Chapter 4).
    pub fn deformation(&self) -> &DeformState {
        &self.deformation
    }
    pub fn config(&self) -> &SimConfig {
        &self.config
    }
    /// The motion model u(X, t) in effect (identity without breathing).
    pub fn motion(&self) -> &Arc<dyn MotionModel> {
        &self.config.motion
    }
    /// The breathing clock t (s) the next tick's motion is evaluated at.
    pub fn breath_time_s(&self) -> f64 {
        self.breath_ticks as f64 / self.config.tick_rate_hz as f64
    }
    /// The breathing time at which the last tick evaluated the motion: the patient the views of
    /// that tick show is X + u(X, t) at this t.
    pub fn motion_time_s(&self) -> f64 {
        self.motion_time_s
    }
    /// Whether the patient breathes (a motion model from the world model is in effect).
    pub fn breathes(&self) -> bool {
        self.config.breathing.enabled
    }
    /// Whether the patient holds their breath.
    pub fn breath_hold(&self) -> bool {
        self.breath_hold
    }
    pub fn contact(&self) -> Option<&ContactTool> {
        match &self.tool {
            Tool::Contact(c) => Some(c),
            _ => None,
        }
    }
    /// The second hand, in a two-handed session.
    pub fn second_hand(&self) -> Option<&SecondHand> {
        self.second.as_ref()
    }

    /// Applies one event with the hand at this pose (world); a step of the exchange whose
    /// preconditions do not hold is refused and changes nothing.
    fn apply(&mut self, e: &Event, position_mm: DVec3, orientation: DQuat) -> Result<(), Refusal> {
        match e {
            Event::SelectTool(spec) => {
                self.tool_spec = *spec;
                self.tool = make_tool(spec);
            }
            Event::SecondTool(tool) => {
                if let Some(h) = &mut self.second {
                    h.select(*tool);
                }
            }
            Event::StyletRemove => {
                if let Tool::Needle(n) = &mut self.tool {
                    n.set_stylet(false);
                }
            }
            Event::WireIn { diameter, tip } => {
                let spec = WireSpec::new(*diameter, *tip);
                let channel = match &self.tool {
                    Tool::Needle(n) => {
                        let channel = self.atlas.duct_channel();
                        Access::check_insert(n, &spec, channel.is_some())?;
                        channel.expect("checked")
                    }
                    Tool::Seldinger(_) => return Err(Refusal::WireAlreadyIn),
                    Tool::Contact(_) => return Err(Refusal::NoNeedleInside),
                };
                let held = std::mem::replace(&mut self.tool, make_tool(&ToolSpec::Finger));
                if let Tool::Needle(n) = held {
                    self.tool = Tool::Seldinger(Box::new(Access::new(n, spec, channel, position_mm, orientation)));
                }
            }
            Event::NeedleOut => match &mut self.tool {
                Tool::Seldinger(a) => a.remove_needle()?,
                _ => return Err(Refusal::NoWire),
            },
            Event::WireOut => match &mut self.tool {
                Tool::Seldinger(a) => {
                    if !a.remove_wire()? {
                        self.tool = make_tool(&self.tool_spec);
                    }
                }
                _ => return Err(Refusal::NoWire),
            },
            Event::DilatorIn { size_fr } | Event::CatheterIn { size_fr } => {
                let kind = if matches!(e, Event::DilatorIn { .. }) {
                    OverWireKind::Dilator
                } else {
                    OverWireKind::Catheter
                };
                match &mut self.tool {
                    Tool::Seldinger(a) => a.put_on_wire(&self.atlas, kind, *size_fr, position_mm, orientation)?,
                    _ => return Err(Refusal::NoWire),
                }
            }
            Event::DilatorOut => match &mut self.tool {
                Tool::Seldinger(a) => a.remove_dilator(position_mm, orientation)?,
                _ => return Err(Refusal::NoDilator),
            },
            Event::StyletInsert => {
                if let Tool::Needle(n) = &mut self.tool {
                    n.set_stylet(true);
                }
            }
            Event::XrayOn => self.xray_on = true,
            Event::XrayOff => self.xray_on = false,
            Event::ContrastInject { ml } => {
                if ml.is_finite() && *ml > 0.0 {
                    self.contrast_ml += ml;
                    self.contrast.inject(*ml);
                }
            }
            Event::BreathHold => self.breath_hold = true,
            Event::BreathRelease => self.breath_hold = false,
        }
        Ok(())
    }

    /// One tick. Non-finite positions or orientations (a glitching device) are replaced by the
    /// last valid pose, and orientations are normalised, so no input can put NaN into the state.
    pub fn step(&mut self, input: &TickInput) -> TickOutput {
        let x_world = if input.position_mm.is_finite() {
            input.position_mm
        } else {
            self.last_position
        };
        let q = input.orientation;
        let q = if q.is_finite() && q.length_squared() > 1e-12 {
            q.normalize()
        } else {
            self.last_orientation
        };
        self.last_position = x_world;
        self.last_orientation = q;
        let mut refused = None;
        for e in &input.events {
            if let Err(r) = self.apply(e, x_world, q) {
                refused = Some(r);
            }
        }

        let t_breath = self.breath_time_s();
        self.motion_time_s = t_breath;
        let model = self.config.motion.clone();
        // u(·, t) of this tick: the signal worked out once for its six evaluations.
        let u_at = model.at_time(t_breath);
        // One fixed-point step of the inverse, X⁺ = x − u(X, t) (thesis §5.4.3), relaxed where u
        // is steep.
        let x_ref = motion::device_step(&*u_at, x_world, self.device_ref.unwrap_or(x_world));
        self.device_ref = Some(x_ref);
        let device = self.config.device;
        let atlas = self.atlas.clone();

        let mut out = TickOutput {
            tick: self.tick,
            time_s: self.tick as f64 / self.config.tick_rate_hz as f64,
            force_n: DVec3::ZERO,
            torque_nmm: DVec3::ZERO,
            components: ForceComponents::default(),
            insertion_dir: q * DVec3::Z,
            tip_label: 0,
            inserted_mm: 0.0,
            tip_mm: x_world,
            tip_depth_mm: 0.0,
            contacts: 0,
            indentation_mm: 0.0,
            stylet_in: false,
            xray_on: self.xray_on,
            breath_hold: self.breath_hold,
            contrast_ml: self.contrast_ml,
            contrast_in_ducts_ml: 0.0,
            extravasated_ml: 0.0,
            contrast_extent_mm: 0.0,
            tissue_displacement_mm: 0.0,
            risk_displacement_mm: 0.0,
            second_hand: None,
            consequences: ConsequenceVolumes::default(),
            wire: None,
            refused,
        };
        let (force, torque) = match &mut self.tool {
            Tool::Needle(n) => {
                let tip_ref = n.path().tip().map_or(x_ref, |t| t.pos);
                let r = motion::gradient_of(&*u_at, tip_ref);
                let correct = |d: DVec3| motion::correct_direction(&r, d);
                let f = n.step(&atlas, x_ref, q, &correct, &device);
                out.components.cut = f.cut;
                out.components.friction = f.friction;
                out.components.base = f.base;
                if let Some(t) = n.path().tip() {
                    out.insertion_dir = t.tangent;
                }
                let tip = needle_summary(n, &atlas, &*u_at, &mut out);
                self.complications.observe(self.tick, Some(tip));
                (f.cut + f.friction + f.base, f.torque)
            }
            Tool::Seldinger(a) => {
                let (wire, force) = a.step(&atlas, x_world, q, &device, |p| p + u_at(p));
                let tip = a.needle().map(|n| needle_summary(n, &atlas, &*u_at, &mut out));
                self.complications.observe(self.tick, tip);
                out.wire = Some(wire);
                (force, DVec3::ZERO)
            }
            Tool::Contact(c) => {
                let f = c.step(&atlas, x_ref, q);
                out.components.skin = f.skin;
                out.components.slide = f.slide;
                out.components.bone = f.bone;
                out.contacts = f.contacts as u32;
                out.indentation_mm = c.nodes().iter().map(|n| n.depth_mm).fold(0.0, f64::max);
                self.complications.observe(self.tick, None);
                (f.skin + f.slide + f.bone, f.torque)
            }
        };
        out.force_n = clamp_length(force, device.max_force_n);
        out.torque_nmm = clamp_length(torque, device.max_torque_nmm);
        // The second hand after the first, on the same tissue and the same motion.
        if let Some(h) = &mut self.second {
            out.second_hand = Some(h.step(&atlas, &*u_at, input.second_hand.as_ref()));
        }
        self.tick += 1;
        // Contrast at its sub-rate: through a needle in the body with the stylet out.
        let every = self.config.contrast.update_every_ticks;
        if self.tick.is_multiple_of(u64::from(every)) {
            let tip = match (&self.tool, self.needle()) {
                (_, Some(n)) if !n.stylet_in() && n.inserted_mm() > 0.0 => n.nodes().last().copied(),
                (Tool::Seldinger(a), None) => a.catheter_outlet(),
                _ => None,
            };
            self.contrast
                .update(&atlas, tip, f64::from(every) / f64::from(self.config.tick_rate_hz));
        }
        if self.tick.is_multiple_of(complications::UPDATE_EVERY_TICKS) {
            let dt_s = complications::UPDATE_EVERY_TICKS as f64 / f64::from(self.config.tick_rate_hz);
            let needle = self.tool.needle().map(NeedleTool::nodes);
            self.complications.update(dt_s, needle);
        }
        out.consequences = self.complications.volumes();
        let tally = self.contrast.tally();
        out.contrast_in_ducts_ml = tally.in_ducts_ml;
        out.extravasated_ml = tally.extravasated_ml;
        out.contrast_extent_mm = self.contrast.filled_extent_mm();
        // Deformation at its sub-rate with a fixed latency: enter what is due, then start the
        // solve for the tool as it is now.
        self.deformation.enter_due(self.tick);
        if self.deformation.launch_due(self.tick) {
            let (mut centre, mut points) = match &self.tool {
                Tool::Needle(n) => {
                    let centre = n.path().tip().map_or(x_ref, |t| t.pos);
                    let step = 0.5 * self.config.deformation.spacing_mm;
                    (centre, deform::tool_points::needle_points(n, step))
                }
                Tool::Contact(c) => (x_ref, deform::tool_points::contact_points(c)),
                Tool::Seldinger(a) => match a.needle() {
                    Some(n) => {
                        let centre = n.path().tip().map_or(x_ref, |t| t.pos);
                        let step = 0.5 * self.config.deformation.spacing_mm;
                        (centre, deform::tool_points::needle_points(n, step))
                    }
                    None => (x_ref, Vec::new()),
                },
            };
            // Both hands' contacts in one solve, on a lattice midway between the tools: a probe
            // pressed beside the entry point deforms the tissue the needle then enters.
            if let Some(h) = &self.second
                && let (Some(c), Some(x2)) = (h.contact(), h.reference_position())
            {
                centre = (centre + x2) * 0.5;
                points.extend(deform::tool_points::contact_points(c));
            }
            self.deformation.launch(&atlas, self.tick, centre, points);
        }
        if let Some(f) = self.deformation.field() {
            out.tissue_displacement_mm = f.max_displacement_mm();
            out.risk_displacement_mm = f.risk_displacement_mm();
        }
        if !self.breath_hold {
            self.breath_ticks += 1;
        }
        out
    }

    /// FNV-1a 64 over the bits of the whole physics state (tool, channel, friction, proxies,
    /// flags, clocks): equal digests ⇔ (with overwhelming probability) equal states.
    pub fn state_digest(&self) -> u64 {
        let mut h = Fnv::new();
        h.u64(self.tick);
        h.u64(self.breath_ticks);
        h.u64(u64::from(self.breath_hold) | u64::from(self.xray_on) << 1);
        h.f64(self.contrast_ml);
        self.contrast.digest_into(|v| h.u64(v));
        self.complications.digest_into(|v| h.u64(v));
        self.deformation.digest_into(|v| h.u64(v));
        h.vec(self.last_position);
        for v in self.last_orientation.to_array() {
            h.f64(v);
        }
        if let Some(x) = self.device_ref {
            h.vec(x);
        }
        match &self.tool {
            Tool::Needle(n) => digest_needle(&mut h, n),
            Tool::Seldinger(a) => {
                h.u64(4);
                if let Some(n) = a.needle() {
                    digest_needle(&mut h, n);
                }
                a.digest_into(|v| h.u64(v));
            }
            Tool::Contact(c) => {
                h.u64(3);
                for node in c.nodes() {
                    h.vec(node.pos);
                    h.vec(node.proxy);
                    h.vec(node.surface);
                    h.u64(u64::from(node.in_contact));
                }
            }
        }
        // One-handed sessions hash exactly what they always did.
        if let Some(second) = &self.second {
            h.u64(0x5ec0_4d4a_4e44);
            second.digest_into(|v| h.u64(v));
        }
        h.0
    }
}

/// Fills the needle's part of a tick's output (tip, label, depth, stylet) and says where its tip
/// is for the complications.
fn needle_summary(
    n: &NeedleTool,
    atlas: &PunctureAtlas,
    u_at: &dyn Fn(DVec3) -> DVec3,
    out: &mut TickOutput,
) -> NeedleTip {
    let tip = *n.nodes().last().expect("needle has nodes");
    out.tip_mm = tip + u_at(tip);
    out.tip_label = n.tip_label();
    out.inserted_mm = n.inserted_mm();
    out.tip_depth_mm = atlas.skin_distance().sample(tip, -1000.0) as f64;
    out.stylet_in = n.stylet_in();
    NeedleTip {
        label: out.tip_label,
        tip_mm: tip,
        inserted_mm: out.inserted_mm,
        outer_diameter_mm: n.spec().gauge.outer_diameter_mm(),
    }
}

/// The needle's part of the state digest.
fn digest_needle(h: &mut Fnv, n: &NeedleTool) {
    h.u64(1 + u64::from(n.stylet_in()));
    for (p, t) in n.nodes().iter().zip(n.tangents()) {
        h.vec(*p);
        h.vec(*t);
    }
    // The channel, then the part cut earlier and retracted from (it decides whether a re-advance
    // meets the cutting threshold).
    for nodes in [n.path().nodes(), n.path().ahead()] {
        h.u64(nodes.len() as u64);
        for node in nodes {
            h.vec(node.pos);
            h.vec(node.tangent);
            h.f64(node.offset_mm);
            h.f64(node.stiffness_n_per_mm);
            h.f64(node.friction_max_n);
        }
    }
    h.f64(n.friction_n());
    if let Some(x) = n.last_device_mm() {
        h.vec(x);
    }
}

struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    fn u64(&mut self, v: u64) {
        for b in v.to_le_bytes() {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn vec(&mut self, v: DVec3) {
        self.f64(v.x);
        self.f64(v.y);
        self.f64(v.z);
    }
}
