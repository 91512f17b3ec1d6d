//! What a session file holds (docs/session-format.md): the header and end metadata, the channels
//! and their messages. Messages are CBOR (binary IEEE-754 floats: exact bits, never decimal text)
//! described by JSON Schemas, so MCAP tools such as Foxglove can open and plot them.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_bytes::ByteBuf;
use stylet_physics::motion::BreathingSettings;
use stylet_physics::seldinger::over_wire::OverWireKind;
use stylet_physics::wire::{WireDiameter, WireTip};
use stylet_physics::{ContrastSettings, DeformSettings, Event, Gauge, HandTool, ProbeKind, SettingsError, ToolSpec};

/// The session schema version this code writes; it reads every version since 1.
/// Version 2 (2026-11-28): tick blocks may round their forces and torques (codec
/// `stylet-columns-v2`, [`crate::outputs`]). Version 3 (2026-12-05): a session trained on a
/// force-feedback device may carry [`TOPIC_DEVICE_FORCES`] and the header's `hardware.*`. Version 4
/// (2026-12-05): a two-handed session's header names the second hand (`hand2.*`), its ticks carry
/// the second device's pose and force ([`HandRecord`]) and its events may be `tool2`.
pub const SCHEMA_VERSION: u32 = 4;
/// The oldest schema version this code reads.
pub const OLDEST_SCHEMA_VERSION: u32 = 1;
/// MCAP profile string of Stylet sessions.
pub const PROFILE: &str = "stylet-session";

/// Metadata record names.
pub const META_HEADER: &str = "stylet.session";
pub const META_END: &str = "stylet.session.end";

/// Channel topics.
pub const TOPIC_TICKS: &str = "/stylet/ticks";
pub const TOPIC_EVENTS: &str = "/stylet/events";
pub const TOPIC_DIGESTS: &str = "/stylet/digests";
pub const TOPIC_ANNOTATIONS: &str = "/stylet/annotations";
pub const TOPIC_PREVIEW: &str = "/stylet/preview";
/// The force a force-feedback device was sent ([`crate::device_forces`]); only in sessions
/// trained on one.
pub const TOPIC_DEVICE_FORCES: &str = "/stylet/device_forces";
/// Every topic a session may have.
pub const TOPICS: [&str; 6] = [
    TOPIC_TICKS,
    TOPIC_EVENTS,
    TOPIC_DIGESTS,
    TOPIC_ANNOTATIONS,
    TOPIC_PREVIEW,
    TOPIC_DEVICE_FORCES,
];

/// Message and schema encodings (MCAP registry names).
pub const MESSAGE_ENCODING: &str = "cbor";
pub const SCHEMA_ENCODING: &str = "jsonschema";

/// Codec name of tick blocks that hold every value exactly (see [`crate::codec`]).
pub const COLUMN_CODEC: &str = crate::codec::CODEC;
/// Codec name of tick blocks with rounded forces and torques and the digest of their exact bits.
pub const COLUMN_CODEC_ROUNDED: &str = crate::codec::CODEC_ROUNDED_OUTPUTS;

/// One tick as recorded: the device input (what replay needs) and the device output (what replay
/// checks).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickRecord {
    pub tick: u64,
    pub position_mm: [f64; 3],
    /// (w, x, y, z) as the device reported it.
    pub orientation: [f64; 4],
    pub buttons: u32,
    pub force_n: [f64; 3],
    pub torque_nmm: [f64; 3],
    pub tip_label: u16,
    pub inserted_mm: f64,
    /// The second device of a two-handed session: what it reported and the force it was given.
    pub second_hand: Option<HandRecord>,
}

/// The second hand of a tick as recorded: the device input (what replay needs) and its output
/// (what replay checks), every bit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandRecord {
    pub position_mm: [f64; 3],
    /// (w, x, y, z) as the device reported it.
    pub orientation: [f64; 4],
    pub buttons: u32,
    pub force_n: [f64; 3],
    pub torque_nmm: [f64; 3],
}

impl HandRecord {
    fn same_bits(&self, o: &HandRecord) -> bool {
        let f = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        self.buttons == o.buttons
            && f(&self.position_mm, &o.position_mm)
            && f(&self.orientation, &o.orientation)
            && f(&self.force_n, &o.force_n)
            && f(&self.torque_nmm, &o.torque_nmm)
    }
}

impl TickRecord {
    /// Bit-exact equality (NaN-safe, −0 ≠ +0).
    pub fn same_bits(&self, o: &TickRecord) -> bool {
        let f = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        let hands = match (&self.second_hand, &o.second_hand) {
            (None, None) => true,
            (Some(a), Some(b)) => a.same_bits(b),
            _ => false,
        };
        hands
            && self.tick == o.tick
            && self.buttons == o.buttons
            && self.tip_label == o.tip_label
            && f(&self.position_mm, &o.position_mm)
            && f(&self.orientation, &o.orientation)
            && f(&self.force_n, &o.force_n)
            && f(&self.torque_nmm, &o.torque_nmm)
            && self.inserted_mm.to_bits() == o.inserted_mm.to_bits()
    }
}

/// A recorded device pose that replay could not use (it would feed NaN into the physics), with
/// the tick it was recorded at.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseError {
    #[error("tick {tick}: position {position_mm:?} mm is not finite")]
    Position { tick: u64, position_mm: [f64; 3] },
    #[error("tick {tick}: orientation {orientation:?} is not finite")]
    Orientation { tick: u64, orientation: [f64; 4] },
    /// An orientation of (0, 0, 0, 0): no rotation at all.
    #[error("tick {tick}: orientation is all zero")]
    ZeroOrientation { tick: u64 },
}

/// Refuses ticks whose device pose replay could not use: a non-finite position or orientation, or
/// an all-zero orientation (no rotation at all), would feed NaN into the physics. Names the first
/// bad tick.
pub fn check_poses_finite(ticks: &[TickRecord]) -> Result<(), PoseError> {
    for t in ticks {
        let second = t.second_hand.map(|h| (h.position_mm, h.orientation));
        for (position_mm, orientation) in std::iter::once((t.position_mm, t.orientation)).chain(second) {
            if !position_mm.iter().all(|v| v.is_finite()) {
                return Err(PoseError::Position {
                    tick: t.tick,
                    position_mm,
                });
            }
            if !orientation.iter().all(|v| v.is_finite()) {
                return Err(PoseError::Orientation {
                    tick: t.tick,
                    orientation,
                });
            }
            if orientation.iter().all(|&v| v == 0.0) {
                return Err(PoseError::ZeroOrientation { tick: t.tick });
            }
        }
    }
    Ok(())
}

/// A block of consecutive ticks, column by column ([`crate::codec`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TickBlock {
    pub first_tick: u64,
    pub count: u32,
    pub codec: String,
    pub columns: BTreeMap<String, ByteBuf>,
    /// Codec v2 only: [`crate::outputs::OutputDigest`] of the block's exact forces and torques.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outputs_digest: Option<u64>,
}

/// An event message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EventRecord {
    pub tick: u64,
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gauge: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub length_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stylet_in: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ml: Option<f64>,
    /// `wire-in`: the wire as scripts write it, "<0.018|0.035> <j|straight>".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wire: Option<String>,
    /// `dilator-in`, `catheter-in`: the tool's size in French.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size_fr: Option<u32>,
}

/// A state digest message (Simulation::state_digest).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DigestRecord {
    pub tick: u64,
    pub digest: u64,
}

/// A free-text note (writer notes, instructor remarks).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnnotationRecord {
    pub tick: u64,
    pub text: String,
}

/// A decimated preview sample for plotting in MCAP tools (f32: a picture, not the record; the
/// exact values are in /stylet/ticks).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PreviewRecord {
    pub tick: u64,
    pub t_s: f32,
    pub position_mm: [f32; 3],
    pub force_n: [f32; 3],
    pub force_magnitude_n: f32,
    pub tip_label: u16,
    pub inserted_mm: f32,
}

impl EventRecord {
    pub fn from_event(tick: u64, e: &Event) -> Self {
        let mut r = EventRecord {
            tick,
            name: e.name().into(),
            tool: None,
            gauge: None,
            length_mm: None,
            stylet_in: None,
            ml: None,
            wire: None,
            size_fr: None,
        };
        match e {
            Event::SelectTool(spec) => {
                r.tool = Some(tool_kind(spec).into());
                if let ToolSpec::Needle {
                    gauge,
                    length_mm,
                    stylet_in,
                } = spec
                {
                    r.gauge = Some(gauge.number());
                    r.length_mm = Some(*length_mm);
                    r.stylet_in = Some(*stylet_in);
                }
            }
            Event::SecondTool(tool) => {
                r.tool = Some(tool.map_or("none", |t| tool_kind(&t.tool_spec())).into());
            }
            Event::ContrastInject { ml } => r.ml = Some(*ml),
            Event::WireIn { diameter, tip } => r.wire = Some(format!("{} {}", diameter.name(), tip.name())),
            Event::DilatorIn { size_fr } | Event::CatheterIn { size_fr } => r.size_fr = Some(u32::from(*size_fr)),
            _ => {}
        }
        r
    }

    /// The physics event, or why this record is not one.
    pub fn to_event(&self) -> Result<Event, EventError> {
        Ok(match self.name.as_str() {
            "tool" => Event::SelectTool(tool_from(
                self.tool.as_deref().ok_or(EventError::NoTool)?,
                self.gauge,
                self.length_mm,
                self.stylet_in,
            )?),
            "tool2" => Event::SecondTool(hand_tool_from(self.tool.as_deref().ok_or(EventError::NoTool)?)?),
            "stylet-remove" => Event::StyletRemove,
            "stylet-insert" => Event::StyletInsert,
            "xray-on" => Event::XrayOn,
            "xray-off" => Event::XrayOff,
            "contrast-inject" => Event::ContrastInject {
                ml: self.ml.ok_or(EventError::NoContrastVolume)?,
            },
            "breath-hold" => Event::BreathHold,
            "breath-release" => Event::BreathRelease,
            "wire-in" => wire_from(self.wire.as_deref().ok_or(EventError::NoWire)?)?,
            "needle-out" => Event::NeedleOut,
            "wire-out" => Event::WireOut,
            "dilator-in" => Event::DilatorIn {
                size_fr: self.size_of(OverWireKind::Dilator)?,
            },
            "dilator-out" => Event::DilatorOut,
            "catheter-in" => Event::CatheterIn {
                size_fr: self.size_of(OverWireKind::Catheter)?,
            },
            other => return Err(EventError::Unknown(other.to_string())),
        })
    }
}

impl EventRecord {
    /// The recorded size of a dilator or catheter, one `kind` comes in.
    fn size_of(&self, kind: OverWireKind) -> Result<u8, EventError> {
        let size = self.size_fr.ok_or(EventError::NoSize(kind.name()))?;
        match u8::try_from(size) {
            Ok(fr) if kind.offers(fr) => Ok(fr),
            _ => Err(EventError::Size {
                tool: kind.name(),
                size_fr: size,
            }),
        }
    }
}

/// The `wire-in` event of a recorded wire, "<0.018|0.035> <j|straight>".
fn wire_from(wire: &str) -> Result<Event, EventError> {
    let mut words = wire.split(' ');
    let diameter = words.next().and_then(WireDiameter::from_name);
    let tip = words.next().and_then(WireTip::from_name);
    match (diameter, tip, words.next()) {
        (Some(diameter), Some(tip), None) => Ok(Event::WireIn { diameter, tip }),
        _ => Err(EventError::Wire(wire.chars().take(40).collect())),
    }
}

/// Why an event record is not a physics event: an unknown name, a field its kind needs is
/// missing, or its tool is not one.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EventError {
    #[error("unknown event '{0}'")]
    Unknown(String),
    #[error("tool event without a tool")]
    NoTool,
    #[error("contrast event without ml")]
    NoContrastVolume,
    #[error("wire-in event without its wire")]
    NoWire,
    #[error("wire '{0}' is not \"<0.018|0.035> <j|straight>\"")]
    Wire(String),
    #[error("{0}-in event without its size")]
    NoSize(&'static str),
    #[error("there is no {size_fr} F {tool}")]
    Size { tool: &'static str, size_fr: u32 },
    #[error(transparent)]
    Tool(#[from] ToolError),
}

/// Why a recorded tool (in an event or the header's initial tool) is not a tool the physics
/// knows: an unknown kind, or a needle without a valid gauge, length or stylet state.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ToolError {
    #[error("unknown tool '{0}'")]
    Unknown(String),
    #[error("needle without gauge")]
    NoGauge,
    #[error("gauge {0} is not 16, 18, 20 or 22")]
    Gauge(u32),
    /// The length is missing, not finite or not positive.
    #[error("needle without a valid length")]
    NoLength,
    #[error("needle without stylet state")]
    NoStyletState,
    /// A needle (or another tool the second hand cannot hold) named for the second hand.
    #[error("the second hand holds a finger or a probe, not '{0}'")]
    NotForSecondHand(String),
}

fn tool_kind(spec: &ToolSpec) -> &'static str {
    match spec {
        ToolSpec::Needle { .. } => "needle",
        ToolSpec::Finger => "finger",
        ToolSpec::Probe(ProbeKind::Linear) => "probe-linear",
        ToolSpec::Probe(ProbeKind::Convex) => "probe-convex",
    }
}

/// The second hand's tool from its recorded kind (`none`: an empty hand).
fn hand_tool_from(kind: &str) -> Result<Option<HandTool>, ToolError> {
    match kind {
        "none" => Ok(None),
        "finger" | "probe-linear" | "probe-convex" => Ok(HandTool::from_tool_spec(tool_from(kind, None, None, None)?)),
        "needle" => Err(ToolError::NotForSecondHand(kind.to_string())),
        other => Err(ToolError::Unknown(other.chars().take(MAX_NAME_CHARS).collect())),
    }
}

fn tool_from(
    kind: &str,
    gauge: Option<u32>,
    length_mm: Option<f64>,
    stylet_in: Option<bool>,
) -> Result<ToolSpec, ToolError> {
    Ok(match kind {
        "needle" => {
            let g = gauge.ok_or(ToolError::NoGauge)?;
            ToolSpec::Needle {
                gauge: Gauge::from_number(g).ok_or(ToolError::Gauge(g))?,
                length_mm: length_mm
                    .filter(|l| l.is_finite() && *l > 0.0)
                    .ok_or(ToolError::NoLength)?,
                stylet_in: stylet_in.ok_or(ToolError::NoStyletState)?,
            }
        }
        "finger" => ToolSpec::Finger,
        "probe-linear" => ToolSpec::Probe(ProbeKind::Linear),
        "probe-convex" => ToolSpec::Probe(ProbeKind::Convex),
        other => return Err(ToolError::Unknown(other.to_string())),
    })
}

/// Longest identifier in a header (trainee, scenario, difficulty, device, session id, atlas hash,
/// software version, start time), in characters. Identifiers are ASCII names: what the service
/// stores and lists stays small whatever a file says.
pub const MAX_NAME_CHARS: usize = 64;
/// Longest free text in a header or end record (atlas name, end reason), in characters.
pub const MAX_TEXT_CHARS: usize = 256;
/// Longest annotation, in characters.
pub const MAX_NOTE_CHARS: usize = 2_000;

/// A text field of a session file longer than its limit: what a file says is kept bounded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("'{what}' is longer than {max_chars} characters")]
pub struct TextTooLong {
    /// Which field.
    pub what: String,
    pub max_chars: usize,
}

/// Refuses a text field longer than `max_chars` characters (checked on the byte length first, so
/// a huge field costs no more than its length check).
pub fn check_text(what: &str, v: &str, max_chars: usize) -> Result<(), TextTooLong> {
    if v.len() > 4 * max_chars || v.chars().count() > max_chars {
        return Err(TextTooLong {
            what: what.to_string(),
            max_chars,
        });
    }
    Ok(())
}

/// Why a session header's metadata is not a header this code can replay: a field missing or
/// malformed (each names its metadata key), a value out of range, or world-model settings the
/// simulation would refuse. A file with such a header is not read at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HeaderError {
    #[error("session header lacks '{0}'")]
    Missing(String),
    #[error("session header '{0}' is not a number")]
    NotANumber(String),
    /// A number too large for its field.
    #[error("session header '{0}' is out of range")]
    OutOfRange(String),
    /// A real number's bits that are not hexadecimal.
    #[error("session header '{0}' is not hex")]
    NotHex(String),
    #[error("session header '{0}' is not true/false")]
    NotABool(String),
    /// A flag other than 0 or 1.
    #[error("session header '{0}' must be 0 or 1")]
    NotAFlag(String),
    /// A name the key does not allow (e.g. an unknown regulariser).
    #[error("session header '{key}' '{value}' is unknown")]
    UnknownValue { key: String, value: String },
    #[error("session header tick_rate_hz {0} is out of range")]
    TickRate(u64),
    /// An identifier that is empty or holds other characters than ASCII letters, digits, `.`,
    /// `_`, `-` and `@`.
    #[error("session header '{0}' must be 1–{MAX_NAME_CHARS} letters, digits or . _ - @")]
    NotAName(String),
    #[error("session header 'wall_clock_start' is not an RFC 3339 time")]
    WallClockStart,
    #[error(transparent)]
    TooLong(#[from] TextTooLong),
    /// The initial tool.
    #[error(transparent)]
    Tool(#[from] ToolError),
    /// World-model settings (`part`: deformation, contrast or breathing) that the simulation's
    /// own check refuses.
    #[error("session header {part}: {source}")]
    World { part: &'static str, source: SettingsError },
}

/// Session header: who, what, on which patient, with which software (written first, so it
/// survives any crash).
#[derive(Debug, Clone, PartialEq)]
pub struct SessionHeader {
    pub schema_version: u32,
    pub session_id: String,
    /// The trainee's account username on the scoring service.
    pub trainee: String,
    pub scenario: String,
    /// beginner, advanced or expert.
    pub difficulty: String,
    pub atlas_id: String,
    pub atlas_hash: String,
    pub software_version: String,
    pub physics_version: u32,
    pub tick_rate_hz: u32,
    pub seed: u64,
    /// Device profile name (stylet_physics::DeviceProfile).
    pub device: String,
    /// The tool at tick 0.
    pub initial_tool: ToolSpec,
    /// Wall-clock start, RFC 3339 UTC (metadata only: physics never reads it).
    pub wall_clock_start: String,
    /// The world model's tissue deformation (thesis Chapter 4): replay solves with exactly these
    /// settings. Files written before physics version 4 lack it and read as deformation off.
    pub deformation: DeformSettings,
    /// The world model's contrast agent (thesis §3.3): replay diffuses with exactly these
    /// settings. Files written before 2026-11-27 lack it; they ran the defaults and read so.
    pub contrast: ContrastSettings,
    /// The world model's respiratory motion (thesis Chapter 5): the synthetic motion's
    /// parameters and the breathing signal with its seed; replay rebuilds the same motion from
    /// the atlas. Files without it did not breathe.
    pub breathing: BreathingSettings,
    /// The force-feedback device the session was trained on, if any (metadata: physics and
    /// scoring never read it). Files without it were driven otherwise.
    pub hardware: Option<HardwareDevice>,
    /// The second hand of a two-handed session: the device profile that drove it and what it held
    /// at tick 0. Files without it were one-handed.
    pub second_hand: Option<SecondHandHeader>,
}

/// The second hand as the session header records it (`hand2.device`, `hand2.tool`).
#[derive(Debug, Clone, PartialEq)]
pub struct SecondHandHeader {
    /// Device profile name (stylet_physics::DeviceProfile) of the second device.
    pub device: String,
    /// The second hand's tool at tick 0 (`none`: empty).
    pub initial_tool: Option<HandTool>,
}

/// A force-feedback device as the session header records it.
#[derive(Debug, Clone, PartialEq)]
pub struct HardwareDevice {
    /// The vendor API: `openhaptics`, `dhd` or `haply`.
    pub backend: String,
    /// The vendor's model name.
    pub model: String,
    /// The limits its force guard enforced (N).
    pub max_force_n: f64,
    pub max_continuous_force_n: f64,
}

/// The largest force limit a header may give a device (N).
const MAX_HARDWARE_FORCE_N: f64 = 100.0;

impl SessionHeader {
    /// As MCAP metadata (strings; the needle length as exact f64 bits in hex).
    pub fn to_metadata(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        let mut put = |k: &str, v: String| {
            m.insert(k.to_string(), v);
        };
        put("schema_version", self.schema_version.to_string());
        put("session_id", self.session_id.clone());
        put("trainee", self.trainee.clone());
        put("scenario", self.scenario.clone());
        put("difficulty", self.difficulty.clone());
        put("atlas_id", self.atlas_id.clone());
        put("atlas_hash", self.atlas_hash.clone());
        put("software_version", self.software_version.clone());
        put("physics_version", self.physics_version.to_string());
        put("tick_rate_hz", self.tick_rate_hz.to_string());
        put("seed", self.seed.to_string());
        put("device", self.device.clone());
        put("tool", tool_kind(&self.initial_tool).into());
        if let ToolSpec::Needle {
            gauge,
            length_mm,
            stylet_in,
        } = self.initial_tool
        {
            put("tool_gauge", gauge.number().to_string());
            put("tool_length_mm_bits", format!("{:016x}", length_mm.to_bits()));
            put("tool_stylet_in", stylet_in.to_string());
        }
        put("wall_clock_start", self.wall_clock_start.clone());
        world::put_deformation(&self.deformation, &mut put);
        world::put_contrast(&self.contrast, &mut put);
        world::put_breathing(&self.breathing, &mut put);
        if let Some(h) = &self.hardware {
            put("hardware.backend", h.backend.clone());
            put("hardware.model", h.model.clone());
            put("hardware.max_force_n", h.max_force_n.to_string());
            put("hardware.max_continuous_force_n", h.max_continuous_force_n.to_string());
        }
        if let Some(h) = &self.second_hand {
            put("hand2.device", h.device.clone());
            put(
                "hand2.tool",
                h.initial_tool.map_or("none", |t| tool_kind(&t.tool_spec())).into(),
            );
        }
        m
    }

    /// The world model's settings for people, part by part ("deformation", "contrast",
    /// "breathing"): each setting's name and value as the header records it, reals decoded from
    /// their exact bits (`tau_bits` → `tau`, shortest round-trip form).
    pub fn world_settings(&self) -> Vec<(&'static str, Vec<(String, String)>)> {
        let metadata = self.to_metadata();
        ["deformation", "contrast", "breathing"]
            .into_iter()
            .map(|part| {
                let prefix = format!("world.{part}.");
                let settings = metadata
                    .iter()
                    .filter_map(|(k, v)| Some((k.strip_prefix(&prefix)?, v)))
                    .map(|(k, v)| match k.strip_suffix("_bits") {
                        Some(name) => {
                            let real = u64::from_str_radix(v, 16).map(f64::from_bits);
                            (name.to_string(), real.map_or_else(|_| v.clone(), |x| x.to_string()))
                        }
                        None => (k.to_string(), v.clone()),
                    })
                    .collect();
                (part, settings)
            })
            .collect()
    }

    /// From MCAP metadata; names the first missing or malformed field.
    pub fn from_metadata(m: &BTreeMap<String, String>) -> Result<Self, HeaderError> {
        let get = |k: &str| m.get(k).cloned().ok_or_else(|| HeaderError::Missing(k.to_string()));
        let num = |k: &str| -> Result<u64, HeaderError> {
            get(k)?
                .parse::<u64>()
                .map_err(|_| HeaderError::NotANumber(k.to_string()))
        };
        let small = |k: &str| -> Result<u32, HeaderError> {
            u32::try_from(num(k)?).map_err(|_| HeaderError::OutOfRange(k.to_string()))
        };
        let schema_version = small("schema_version")?;
        let tool = get("tool")?;
        let initial_tool = if tool == "needle" {
            let bits = u64::from_str_radix(&get("tool_length_mm_bits")?, 16)
                .map_err(|_| HeaderError::NotHex("tool_length_mm_bits".into()))?;
            let stylet = get("tool_stylet_in")?
                .parse::<bool>()
                .map_err(|_| HeaderError::NotABool("tool_stylet_in".into()))?;
            tool_from(
                "needle",
                Some(small("tool_gauge")?),
                Some(f64::from_bits(bits)),
                Some(stylet),
            )?
        } else {
            tool_from(&tool, None, None, None)?
        };
        let tick_rate_hz = num("tick_rate_hz")?;
        if !(1..=100_000).contains(&tick_rate_hz) {
            return Err(HeaderError::TickRate(tick_rate_hz));
        }
        let field = |k: &str, max_chars: usize| -> Result<String, HeaderError> {
            let v = get(k)?;
            check_text(k, &v, max_chars)?;
            Ok(v)
        };
        let name = |k: &str| -> Result<String, HeaderError> {
            let v = field(k, MAX_NAME_CHARS)?;
            if v.is_empty() || !v.chars().all(|c| c.is_ascii_alphanumeric() || "._-@".contains(c)) {
                return Err(HeaderError::NotAName(k.to_string()));
            }
            Ok(v)
        };
        let wall_clock_start = field("wall_clock_start", MAX_NAME_CHARS)?;
        let force = |k: &str| -> Result<f64, HeaderError> {
            let v: f64 = get(k)?.parse().map_err(|_| HeaderError::NotANumber(k.to_string()))?;
            if v > 0.0 && v <= MAX_HARDWARE_FORCE_N {
                Ok(v)
            } else {
                Err(HeaderError::OutOfRange(k.to_string()))
            }
        };
        let hardware = match m.contains_key("hardware.backend") {
            false => None,
            true => Some(HardwareDevice {
                backend: name("hardware.backend")?,
                model: field("hardware.model", MAX_TEXT_CHARS)?,
                max_force_n: force("hardware.max_force_n")?,
                max_continuous_force_n: force("hardware.max_continuous_force_n")?,
            }),
        };
        let second_hand = match m.contains_key("hand2.device") {
            false => None,
            true => Some(SecondHandHeader {
                device: name("hand2.device")?,
                initial_tool: hand_tool_from(&get("hand2.tool")?)?,
            }),
        };
        humantime::parse_rfc3339_weak(&wall_clock_start).map_err(|_| HeaderError::WallClockStart)?;
        Ok(SessionHeader {
            schema_version,
            session_id: name("session_id")?,
            trainee: name("trainee")?,
            scenario: name("scenario")?,
            difficulty: name("difficulty")?,
            atlas_id: field("atlas_id", MAX_TEXT_CHARS)?,
            atlas_hash: name("atlas_hash")?,
            software_version: field("software_version", MAX_NAME_CHARS)?,
            physics_version: small("physics_version")?,
            tick_rate_hz: tick_rate_hz as u32,
            seed: num("seed")?,
            device: name("device")?,
            initial_tool,
            wall_clock_start,
            deformation: world::get_deformation(m)?,
            contrast: world::get_contrast(m)?,
            breathing: world::get_breathing(m)?,
            hardware,
            second_hand,
        })
    }
}

/// The world model in the header: one metadata key per setting, `world.deformation.*`,
/// `world.contrast.*` and `world.breathing.*`, numbers
/// as decimal integers or, for real numbers, exact f64 bits in hex (so replay gets the same bits).
mod world {
    use std::collections::BTreeMap;

    use stylet_physics::motion::BreathingSettings;
    use stylet_physics::{ContrastSettings, DeformSettings, Regulariser};

    use super::HeaderError;

    const P: &str = "world.deformation.";

    pub fn put_deformation(d: &DeformSettings, put: &mut impl FnMut(&str, String)) {
        let mut int = |k: &str, v: u64| put(&format!("{P}{k}"), v.to_string());
        int("enabled", u64::from(d.enabled));
        int("cells", d.cells.into());
        int("every_ticks", d.every_ticks.into());
        int("latency_ticks", d.latency_ticks.into());
        int("levels", d.schedule.levels.into());
        int("cycles", d.schedule.cycles.into());
        int("pre_steps", d.schedule.pre_steps.into());
        int("post_steps", d.schedule.post_steps.into());
        int("coarsest_steps", d.schedule.coarsest_steps.into());
        int("fed_cycle_steps", d.schedule.fed_cycle_steps.into());
        let mut real = |k: &str, v: f64| put(&format!("{P}{k}_bits"), format!("{:016x}", v.to_bits()));
        real("spacing_mm", d.spacing_mm);
        real("material_k_per_hu", d.material_k_per_hu);
        real("material_s_hu", d.material_s_hu);
        match d.regulariser {
            Regulariser::Diffusion => put(&format!("{P}regulariser"), "diffusion".into()),
            Regulariser::LinearElastic { poisson_ratio } => {
                put(&format!("{P}regulariser"), "linear_elastic".into());
                put(
                    &format!("{P}poisson_ratio_bits"),
                    format!("{:016x}", poisson_ratio.to_bits()),
                );
            }
        }
    }

    /// One part of the world model in a header's metadata: the keys under `prefix`, whole numbers
    /// as decimal, reals as the hex of their bits (exact).
    struct WorldKeys<'a> {
        prefix: &'static str,
        map: &'a BTreeMap<String, String>,
    }

    impl WorldKeys<'_> {
        /// The full metadata key of `k`.
        fn key(&self, k: &str) -> String {
            format!("{}{k}", self.prefix)
        }
        fn get(&self, k: &str) -> Result<&String, HeaderError> {
            self.map
                .get(&self.key(k))
                .ok_or_else(|| HeaderError::Missing(self.key(k)))
        }
        fn int(&self, k: &str) -> Result<u32, HeaderError> {
            self.get(k)?
                .parse::<u32>()
                .map_err(|_| HeaderError::NotANumber(self.key(k)))
        }
        fn real(&self, k: &str) -> Result<f64, HeaderError> {
            let key = format!("{k}_bits");
            u64::from_str_radix(self.get(&key)?, 16)
                .map(f64::from_bits)
                .map_err(|_| HeaderError::NotHex(self.key(&key)))
        }
        /// A value of `k` that is not one of the names the key allows.
        fn unknown(&self, k: &str, value: &str) -> HeaderError {
            HeaderError::UnknownValue {
                key: self.key(k),
                value: value.to_string(),
            }
        }
    }

    /// The deformation settings of a header (off when the file has none), checked like the
    /// simulation checks them.
    pub fn get_deformation(m: &BTreeMap<String, String>) -> Result<DeformSettings, HeaderError> {
        if !m.contains_key(&format!("{P}enabled")) {
            return Ok(DeformSettings::off());
        }
        let keys = WorldKeys { prefix: P, map: m };
        let regulariser = match keys.get("regulariser")?.as_str() {
            "diffusion" => Regulariser::Diffusion,
            "linear_elastic" => Regulariser::LinearElastic {
                poisson_ratio: keys.real("poisson_ratio")?,
            },
            other => return Err(keys.unknown("regulariser", other)),
        };
        let enabled = match keys.int("enabled")? {
            0 => false,
            1 => true,
            _ => return Err(HeaderError::NotAFlag(keys.key("enabled"))),
        };
        let d = DeformSettings {
            enabled,
            cells: keys.int("cells")?,
            spacing_mm: keys.real("spacing_mm")?,
            every_ticks: keys.int("every_ticks")?,
            latency_ticks: keys.int("latency_ticks")?,
            regulariser,
            material_k_per_hu: keys.real("material_k_per_hu")?,
            material_s_hu: keys.real("material_s_hu")?,
            schedule: stylet_physics::deform::Schedule {
                levels: keys.int("levels")?,
                cycles: keys.int("cycles")?,
                pre_steps: keys.int("pre_steps")?,
                post_steps: keys.int("post_steps")?,
                coarsest_steps: keys.int("coarsest_steps")?,
                fed_cycle_steps: keys.int("fed_cycle_steps")?,
            },
        };
        d.validate().map_err(|e| HeaderError::World {
            part: "deformation",
            source: e,
        })?;
        Ok(d)
    }

    const C: &str = "world.contrast.";

    pub fn put_contrast(c: &ContrastSettings, put: &mut impl FnMut(&str, String)) {
        put(&format!("{C}update_every_ticks"), c.update_every_ticks.to_string());
        put(&format!("{C}steps_per_update"), c.steps_per_update.to_string());
        let mut real = |k: &str, v: f64| put(&format!("{C}{k}_bits"), format!("{:016x}", v.to_bits()));
        real("front_fraction", c.front_fraction);
        real("tau", c.tau);
        real("rate_ml_per_s", c.rate_ml_per_s);
        real("visible_fraction", c.visible_fraction);
        real("confirm_extent_mm", c.confirm_extent_mm);
        real("settle_s", c.settle_s);
    }

    /// The contrast settings of a header (the defaults when the file has none, as every session
    /// before they were recorded ran them), checked like the simulation checks them. Files of
    /// physics version 9 and before recorded the diffusion grid's size (`grid_nodes`) and no
    /// filling front: they read with the default front (their physics is not replayed).
    pub fn get_contrast(m: &BTreeMap<String, String>) -> Result<ContrastSettings, HeaderError> {
        if !m.keys().any(|k| k.starts_with(C)) {
            return Ok(ContrastSettings::default());
        }
        let keys = WorldKeys { prefix: C, map: m };
        let front_fraction = if m.contains_key(&keys.key("front_fraction_bits")) {
            keys.real("front_fraction")?
        } else {
            ContrastSettings::default().front_fraction
        };
        let c = ContrastSettings {
            front_fraction,
            update_every_ticks: keys.int("update_every_ticks")?,
            steps_per_update: keys.int("steps_per_update")?,
            tau: keys.real("tau")?,
            rate_ml_per_s: keys.real("rate_ml_per_s")?,
            visible_fraction: keys.real("visible_fraction")?,
            confirm_extent_mm: keys.real("confirm_extent_mm")?,
            settle_s: keys.real("settle_s")?,
        };
        c.validate().map_err(|e| HeaderError::World {
            part: "contrast",
            source: e,
        })?;
        Ok(c)
    }

    const B: &str = "world.breathing.";

    pub fn put_breathing(b: &BreathingSettings, put: &mut impl FnMut(&str, String)) {
        put(&format!("{B}enabled"), u64::from(b.enabled).to_string());
        // The synthetic motion's parameters are written either way (unused with measured fields,
        // which the atlas' content hash pins).
        put(
            &format!("{B}model"),
            if b.measured { "measured" } else { "synthetic" }.into(),
        );
        put(&format!("{B}power"), b.signal.power.to_string());
        put(&format!("{B}seed"), b.signal.seed.to_string());
        let mut real = |k: &str, v: f64| put(&format!("{B}{k}_bits"), format!("{:016x}", v.to_bits()));
        real("amplitude_mm", b.motion.amplitude_mm);
        real("anterior_ratio", b.motion.anterior_ratio);
        real("wall_mm", b.motion.wall_mm);
        real("bone_margin_mm", b.motion.bone_margin_mm);
        real("period_s", b.signal.period_s);
        real("period_jitter", b.signal.period_jitter);
        real("depth_jitter", b.signal.depth_jitter);
    }

    /// The breathing of a header (none when the file has none: it did not breathe), checked like
    /// the simulation checks it.
    pub fn get_breathing(m: &BTreeMap<String, String>) -> Result<BreathingSettings, HeaderError> {
        if !m.keys().any(|k| k.starts_with(B)) {
            return Ok(BreathingSettings::default());
        }
        let keys = WorldKeys { prefix: B, map: m };
        let measured = match keys.get("model")?.as_str() {
            "synthetic" => false,
            "measured" => true,
            other => return Err(keys.unknown("model", other)),
        };
        let enabled = match keys.int("enabled")? {
            0 => false,
            1 => true,
            _ => return Err(HeaderError::NotAFlag(keys.key("enabled"))),
        };
        let seed = keys
            .get("seed")?
            .parse::<u64>()
            .map_err(|_| HeaderError::NotANumber(keys.key("seed")))?;
        let b = BreathingSettings {
            enabled,
            motion: stylet_physics::motion::SyntheticMotion {
                amplitude_mm: keys.real("amplitude_mm")?,
                anterior_ratio: keys.real("anterior_ratio")?,
                wall_mm: keys.real("wall_mm")?,
                bone_margin_mm: keys.real("bone_margin_mm")?,
            },
            signal: stylet_physics::motion::SignalParams {
                period_s: keys.real("period_s")?,
                period_jitter: keys.real("period_jitter")?,
                depth_jitter: keys.real("depth_jitter")?,
                power: keys.int("power")?,
                seed,
            },
            measured,
        };
        b.validate().map_err(|e| HeaderError::World {
            part: "breathing",
            source: e,
        })?;
        Ok(b)
    }
}

/// Why a session end record's metadata cannot be read: a field missing or malformed, or a reason
/// too long. The reader treats it as damage.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EndError {
    #[error("session end lacks '{0}'")]
    Missing(String),
    #[error("session end '{0}' is not a number")]
    NotANumber(&'static str),
    #[error("session end '{0}' is not true/false")]
    NotABool(&'static str),
    #[error(transparent)]
    TooLong(#[from] TextTooLong),
}

/// What the writer says at the end (absent in a file cut by a crash).
#[derive(Debug, Clone, PartialEq)]
pub struct SessionEnd {
    pub ticks: u64,
    /// Ticks the 1 kHz loop produced but the full queue could not take.
    pub dropped_ticks: u64,
    pub complete: bool,
    pub reason: String,
}

impl SessionEnd {
    pub fn to_metadata(&self) -> BTreeMap<String, String> {
        BTreeMap::from([
            ("ticks".to_string(), self.ticks.to_string()),
            ("dropped_ticks".to_string(), self.dropped_ticks.to_string()),
            ("complete".to_string(), self.complete.to_string()),
            ("reason".to_string(), self.reason.clone()),
        ])
    }

    /// From MCAP metadata; names the first missing or malformed field.
    pub fn from_metadata(m: &BTreeMap<String, String>) -> Result<Self, EndError> {
        let get = |k: &str| m.get(k).cloned().ok_or_else(|| EndError::Missing(k.to_string()));
        Ok(SessionEnd {
            ticks: get("ticks")?.parse().map_err(|_| EndError::NotANumber("ticks"))?,
            dropped_ticks: get("dropped_ticks")?
                .parse()
                .map_err(|_| EndError::NotANumber("dropped_ticks"))?,
            complete: get("complete")?.parse().map_err(|_| EndError::NotABool("complete"))?,
            reason: {
                let r = get("reason")?;
                check_text("session end reason", &r, MAX_TEXT_CHARS)?;
                r
            },
        })
    }
}

/// JSON Schemas (2020-12) of the channels, stored as the files' MCAP schema records.
///
/// The messages are CBOR; each schema describes a message's JSON form as RFC 8949 §6.1 converts
/// it: a CBOR byte string becomes base64url text without padding, so the schema marks each byte
/// string `"contentEncoding": "base64url"`, and every other string is a CBOR text string. Every
/// field the writer puts in a message is declared, with its range, and nothing else is allowed
/// (`recorder/tests/sessions.rs` checks written and committed sessions against them).
pub fn json_schema(topic: &str) -> &'static str {
    match topic {
        TOPIC_TICKS => TICK_BLOCK_SCHEMA,
        TOPIC_EVENTS => EVENT_SCHEMA,
        TOPIC_DIGESTS => DIGEST_SCHEMA,
        TOPIC_ANNOTATIONS => ANNOTATION_SCHEMA,
        TOPIC_DEVICE_FORCES => DEVICE_FORCE_BLOCK_SCHEMA,
        _ => PREVIEW_SCHEMA,
    }
}

const TICK_BLOCK_SCHEMA: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "stylet.TickBlock",
  "description": "Up to 500 consecutive ticks, column by column (docs/session-format.md). The message is a CBOR map; each column is a CBOR byte string (base64url in the RFC 8949 JSON form). Codec stylet-columns-v1: f64 columns hold the zigzag residuals of the IEEE-754 bit patterns after the linear prediction 2*b[i-1]-b[i-2]; integer columns each value XOR the previous; the little-endian bytes are transposed into planes. f64 columns: pos_x_mm pos_y_mm pos_z_mm q_w q_x q_y q_z force_x_n force_y_n force_z_n torque_x_nmm torque_y_nmm torque_z_nmm inserted_mm (8 bytes per tick); u32 buttons (4); u16 tip_label (2). Two-handed sessions (schema 4): a block in which the second device reported at least one tick also has u8 hand2 (1 where the tick has a second hand, else 0), the f64 columns hand2_pos_x_mm hand2_pos_y_mm hand2_pos_z_mm hand2_q_w hand2_q_x hand2_q_y hand2_q_z hand2_force_x_n hand2_force_y_n hand2_force_z_n hand2_torque_x_nmm hand2_torque_y_nmm hand2_torque_z_nmm (exact in both codecs; 0 where the tick has none) and u32 hand2_buttons. Codec stylet-columns-v2: the same, except that the force and torque columns hold i64 step counts (2^16 per N, 2^12 per N*mm; zigzag residuals of the same prediction), and outputs_digest is the FNV-1a 64 of the block's exact forces and torques.",
  "type": "object",
  "properties": {
    "first_tick": {"type": "integer", "minimum": 0, "maximum": 18446744073709551615},
    "count": {"type": "integer", "minimum": 1, "maximum": 500},
    "codec": {"enum": ["stylet-columns-v1", "stylet-columns-v2"]},
    "columns": {
      "type": "object",
      "properties": {
        "pos_x_mm": {"$ref": "#/$defs/column"},
        "pos_y_mm": {"$ref": "#/$defs/column"},
        "pos_z_mm": {"$ref": "#/$defs/column"},
        "q_w": {"$ref": "#/$defs/column"},
        "q_x": {"$ref": "#/$defs/column"},
        "q_y": {"$ref": "#/$defs/column"},
        "q_z": {"$ref": "#/$defs/column"},
        "force_x_n": {"$ref": "#/$defs/column"},
        "force_y_n": {"$ref": "#/$defs/column"},
        "force_z_n": {"$ref": "#/$defs/column"},
        "torque_x_nmm": {"$ref": "#/$defs/column"},
        "torque_y_nmm": {"$ref": "#/$defs/column"},
        "torque_z_nmm": {"$ref": "#/$defs/column"},
        "inserted_mm": {"$ref": "#/$defs/column"},
        "buttons": {"$ref": "#/$defs/column"},
        "tip_label": {"$ref": "#/$defs/column"},
        "hand2": {"$ref": "#/$defs/column"},
        "hand2_pos_x_mm": {"$ref": "#/$defs/column"},
        "hand2_pos_y_mm": {"$ref": "#/$defs/column"},
        "hand2_pos_z_mm": {"$ref": "#/$defs/column"},
        "hand2_q_w": {"$ref": "#/$defs/column"},
        "hand2_q_x": {"$ref": "#/$defs/column"},
        "hand2_q_y": {"$ref": "#/$defs/column"},
        "hand2_q_z": {"$ref": "#/$defs/column"},
        "hand2_force_x_n": {"$ref": "#/$defs/column"},
        "hand2_force_y_n": {"$ref": "#/$defs/column"},
        "hand2_force_z_n": {"$ref": "#/$defs/column"},
        "hand2_torque_x_nmm": {"$ref": "#/$defs/column"},
        "hand2_torque_y_nmm": {"$ref": "#/$defs/column"},
        "hand2_torque_z_nmm": {"$ref": "#/$defs/column"},
        "hand2_buttons": {"$ref": "#/$defs/column"}
      },
      "dependentRequired": {"hand2": ["hand2_pos_x_mm", "hand2_pos_y_mm", "hand2_pos_z_mm", "hand2_q_w", "hand2_q_x", "hand2_q_y", "hand2_q_z", "hand2_force_x_n", "hand2_force_y_n", "hand2_force_z_n", "hand2_torque_x_nmm", "hand2_torque_y_nmm", "hand2_torque_z_nmm", "hand2_buttons"]},
      "required": ["pos_x_mm", "pos_y_mm", "pos_z_mm", "q_w", "q_x", "q_y", "q_z", "force_x_n", "force_y_n", "force_z_n", "torque_x_nmm", "torque_y_nmm", "torque_z_nmm", "inserted_mm", "buttons", "tip_label"],
      "additionalProperties": false
    },
    "outputs_digest": {"type": "integer", "minimum": 0, "maximum": 18446744073709551615}
  },
  "required": ["first_tick", "count", "codec", "columns"],
  "additionalProperties": false,
  "if": {"properties": {"codec": {"const": "stylet-columns-v2"}}},
  "then": {"required": ["outputs_digest"]},
  "else": {"not": {"required": ["outputs_digest"]}},
  "$defs": {
    "column": {
      "description": "A CBOR byte string: one encoded column of the block.",
      "type": "string",
      "contentEncoding": "base64url",
      "contentMediaType": "application/octet-stream"
    }
  }
}"##;

const EVENT_SCHEMA: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "stylet.Event",
  "description": "An event of a tick (names as in docs/scripts.md). A CBOR map; fields other than tick and name are present only for the events that use them: tool, gauge, length_mm, stylet_in for a tool change, tool for the second hand's tool change (tool2; none: the hand puts its tool down), ml for a contrast injection, wire for a guide wire put in (wire-in), size_fr for a dilator or drainage catheter put on the wire (dilator-in: 6, 8, 10, 12; catheter-in: 8, 10).",
  "type": "object",
  "properties": {
    "tick": {"type": "integer", "minimum": 0, "maximum": 18446744073709551615},
    "name": {"type": "string", "maxLength": 64},
    "tool": {"enum": ["needle", "finger", "probe-linear", "probe-convex", "none"]},
    "gauge": {"type": "integer", "minimum": 0, "maximum": 4294967295},
    "length_mm": {"type": "number"},
    "stylet_in": {"type": "boolean"},
    "ml": {"type": "number"},
    "wire": {"enum": ["0.018 j", "0.018 straight", "0.035 j", "0.035 straight"]},
    "size_fr": {"enum": [6, 8, 10, 12]}
  },
  "required": ["tick", "name"],
  "additionalProperties": false
}"##;

const DIGEST_SCHEMA: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "stylet.Digest",
  "description": "FNV-1a 64 over the bits of the whole physics state after the tick (a CBOR map).",
  "type": "object",
  "properties": {
    "tick": {"type": "integer", "minimum": 0, "maximum": 18446744073709551615},
    "digest": {"type": "integer", "minimum": 0, "maximum": 18446744073709551615}
  },
  "required": ["tick", "digest"],
  "additionalProperties": false
}"##;

const ANNOTATION_SCHEMA: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "stylet.Annotation",
  "description": "A writer note (queue overflow, recovery; a CBOR map).",
  "type": "object",
  "properties": {
    "tick": {"type": "integer", "minimum": 0, "maximum": 18446744073709551615},
    "text": {"type": "string", "maxLength": 2000}
  },
  "required": ["tick", "text"],
  "additionalProperties": false
}"##;

const DEVICE_FORCE_BLOCK_SCHEMA: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "stylet.DeviceForceBlock",
  "description": "Up to 500 consecutive ticks of a force-feedback device, column by column (docs/session-format.md 'Device forces'): per tick the force its servo loop last sent when the tick read the device, and its force guard's flags. Metadata: replay never reads it. The message is a CBOR map; each column is a CBOR byte string (base64url in the RFC 8949 JSON form). sent_x_n sent_y_n sent_z_n: i64 step counts, 2^16 per N, as zigzag residuals of the prediction 2*v[i-1]-v[i-2], little-endian bytes transposed into planes (8 bytes per tick); guard: u8 flags (1 held, 2 watchdog, 4 waiting to engage, 8 not finite, 16 ramping, 32 clamped, 64 continuous limit), each XOR the previous (1 byte per tick).",
  "type": "object",
  "properties": {
    "first_tick": {"type": "integer", "minimum": 0, "maximum": 18446744073709551615},
    "count": {"type": "integer", "minimum": 1, "maximum": 500},
    "columns": {
      "type": "object",
      "properties": {
        "sent_x_n": {"type": "string", "contentEncoding": "base64url"},
        "sent_y_n": {"type": "string", "contentEncoding": "base64url"},
        "sent_z_n": {"type": "string", "contentEncoding": "base64url"},
        "guard": {"type": "string", "contentEncoding": "base64url"}
      },
      "required": ["sent_x_n", "sent_y_n", "sent_z_n", "guard"],
      "additionalProperties": false
    }
  },
  "required": ["first_tick", "count", "columns"],
  "additionalProperties": false
}"##;

const PREVIEW_SCHEMA: &str = r##"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "stylet.Preview",
  "description": "A 50 Hz preview sample in f32 for plotting in MCAP tools (a CBOR map); the exact record is /stylet/ticks. A force that is not finite (stored exactly in its tick block) is null in the RFC 8949 JSON form.",
  "type": "object",
  "properties": {
    "tick": {"type": "integer", "minimum": 0, "maximum": 18446744073709551615},
    "t_s": {"type": "number"},
    "position_mm": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
    "force_n": {"type": "array", "items": {"type": ["number", "null"]}, "minItems": 3, "maxItems": 3},
    "force_magnitude_n": {"type": ["number", "null"]},
    "tip_label": {"type": "integer", "minimum": 0, "maximum": 65535},
    "inserted_mm": {"type": "number"}
  },
  "required": ["tick", "t_s", "position_mm", "force_n", "force_magnitude_n", "tip_label", "inserted_mm"],
  "additionalProperties": false
}"##;

/// CBOR encoding of a message.
pub fn to_cbor<T: Serialize>(v: &T) -> Vec<u8> {
    let mut out = Vec::new();
    ciborium::into_writer(v, &mut out).expect("serialising to memory cannot fail");
    out
}

/// A message that is not the CBOR of its type, with the decoder's reason.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("bad CBOR message: {0}")]
pub struct CborError(pub String);

/// CBOR decoding with a recursion limit (hostile nesting) and a clear error.
pub fn from_cbor<T: for<'de> Deserialize<'de>>(bytes: &[u8]) -> Result<T, CborError> {
    ciborium::de::from_reader_with_recursion_limit(bytes, 16).map_err(|e| CborError(e.to_string()))
}
