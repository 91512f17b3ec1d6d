//! The script language's parser (grammar in docs/scripts.md). Line based; every error names the
//! line, the column and what was expected.

use stylet_physics::glam::DVec3;
use stylet_physics::seldinger::over_wire::OverWireKind;
use stylet_physics::wire::{WireDiameter, WireTip};
use stylet_physics::{DeviceProfile, Event, Gauge, HandTool, ProbeKind, ToolSpec};

/// A parse error: where and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}, column {column}: expected {expected}, found {found}")]
pub struct ParseError {
    pub line: usize,
    pub column: usize,
    pub expected: String,
    pub found: String,
}

/// A pose keyframe as written.
#[derive(Debug, Clone, PartialEq)]
pub enum PoseSpec {
    /// `pos X Y Z dir DX DY DZ [xaxis AX AY AZ]`
    Explicit {
        pos: DVec3,
        dir: DVec3,
        xaxis: Option<DVec3>,
    },
    /// `along PATH DEPTH [xaxis …]`: on the atlas' insertion path, DEPTH mm past the entry point.
    Along {
        path: String,
        depth_mm: f64,
        xaxis: Option<DVec3>,
    },
    /// `aim EX EY EZ TX TY TZ DEPTH [xaxis …]`: on the line entry → target, DEPTH mm past the entry.
    Aim {
        entry: DVec3,
        target: DVec3,
        depth_mm: f64,
        xaxis: Option<DVec3>,
    },
}

/// What happens at a time stamp.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    Pose(PoseSpec),
    /// Force control: press along the unit direction with the given force from now on.
    Press {
        dir: DVec3,
        force_n: f64,
    },
    Release,
    Event(Event),
}

/// Which device track a pose, press or release drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hand {
    /// The first hand's device (the needle hand): `at T pos …`.
    First,
    /// The second hand's device in a two-handed script: `at T hand2 pos …`.
    Second,
}

/// One `at` line.
#[derive(Debug, Clone, PartialEq)]
pub struct Timed {
    pub t_s: f64,
    /// Line in the script (1-based), for later errors (unknown path names).
    pub line: usize,
    /// The track a pose, press or release belongs to (events: [`Hand::First`]).
    pub hand: Hand,
    pub action: Action,
}

/// The second hand of a two-handed script (`tool2 …` and `device2 …` lines).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScriptHand {
    pub device: DeviceProfile,
    /// Its tool at tick 0 (`tool2 none`: empty).
    pub initial_tool: Option<HandTool>,
}

/// A parsed script.
#[derive(Debug, Clone, PartialEq)]
pub struct Script {
    pub version: u32,
    pub device: DeviceProfile,
    pub rate_hz: u32,
    pub initial_tool: ToolSpec,
    /// Script length (s); the last time stamp when absent.
    pub end_s: Option<f64>,
    pub items: Vec<Timed>,
    /// The world model's tissue deformation (`deformation on|off`, default off).
    pub deformation: stylet_physics::DeformSettings,
    /// The world model's respiratory motion (`breathing on|off [amplitude MM] [period S] [seed N]`,
    /// default off); the atlas' attached motion fills in the rest when the run starts.
    pub breathing: stylet_physics::motion::BreathingRequest,
    /// The second hand (`tool2 …`, `device2 …`); none: a one-handed script.
    pub second_hand: Option<ScriptHand>,
}

/// The script language version this parser reads.
pub const SCRIPT_VERSION: u32 = 1;
/// Longest script accepted (s of simulated time).
pub const MAX_DURATION_S: f64 = 3600.0;
/// Largest coordinate, depth or direction component accepted (mm): far beyond any patient, small
/// enough that lengths, interpolation and slerp never overflow into inf or NaN poses.
pub const MAX_COORD_MM: f64 = 1e6;

struct Tokens<'a> {
    line: usize,
    body: &'a str,
    toks: Vec<(usize, &'a str)>,
    pos: usize,
    line_len: usize,
}

impl<'a> Tokens<'a> {
    fn new(line: usize, text: &'a str) -> Self {
        let body = text.split('#').next().unwrap_or("");
        let mut toks = Vec::new();
        let mut start = None;
        for (i, ch) in body.char_indices() {
            if ch.is_whitespace() {
                if let Some(s) = start.take() {
                    toks.push((s, &body[s..i]));
                }
            } else if start.is_none() {
                start = Some(i);
            }
        }
        if let Some(s) = start {
            toks.push((s, &body[s..]));
        }
        Tokens {
            line,
            body,
            toks,
            pos: 0,
            line_len: body.trim_end().chars().count(),
        }
    }

    /// 1-based character column of a byte offset.
    fn column_of(&self, byte: usize) -> usize {
        self.body[..byte].chars().count() + 1
    }

    fn err(&self, expected: impl Into<String>) -> ParseError {
        let (column, found) = match self.toks.get(self.pos) {
            Some((b, t)) => (self.column_of(*b), format!("'{t}'")),
            None => (self.line_len + 1, "end of line".to_string()),
        };
        ParseError {
            line: self.line,
            column,
            expected: expected.into(),
            found,
        }
    }

    fn peek(&self) -> Option<&'a str> {
        self.toks.get(self.pos).map(|t| t.1)
    }

    fn word(&mut self, expected: &str) -> Result<&'a str, ParseError> {
        match self.toks.get(self.pos) {
            Some((_, t)) => {
                self.pos += 1;
                Ok(t)
            }
            None => Err(self.err(expected)),
        }
    }

    fn keyword(&mut self, options: &[&str]) -> Result<&'a str, ParseError> {
        let expected = format!("one of {}", options.join(", "));
        match self.peek() {
            Some(t) if options.contains(&t) => {
                self.pos += 1;
                Ok(t)
            }
            _ => Err(self.err(expected)),
        }
    }

    fn number(&mut self, what: &str) -> Result<f64, ParseError> {
        match self
            .peek()
            .and_then(|t| t.parse::<f64>().ok())
            .filter(|v| v.is_finite())
        {
            Some(v) => {
                self.pos += 1;
                Ok(v)
            }
            None => Err(self.err(format!("a number ({what})"))),
        }
    }

    /// A coordinate, depth or direction component: finite and within ±[`MAX_COORD_MM`].
    fn bounded(&mut self, what: &str) -> Result<f64, ParseError> {
        let at = self.pos;
        let v = self.number(what)?;
        if v.abs() > MAX_COORD_MM {
            self.pos = at;
            return Err(self.err(format!("a number within ±{MAX_COORD_MM} ({what})")));
        }
        Ok(v)
    }

    fn vector(&mut self, what: &str) -> Result<DVec3, ParseError> {
        Ok(DVec3::new(
            self.bounded(&format!("{what} x"))?,
            self.bounded(&format!("{what} y"))?,
            self.bounded(&format!("{what} z"))?,
        ))
    }

    fn direction(&mut self, what: &str) -> Result<DVec3, ParseError> {
        let at = self.pos;
        let v = self.vector(what)?;
        match unit(v) {
            Some(u) => Ok(u),
            None => {
                self.pos = at;
                Err(self.err(format!("a non-zero {what} vector")))
            }
        }
    }

    fn end(&self) -> Result<(), ParseError> {
        if self.pos < self.toks.len() {
            Err(self.err("end of line"))
        } else {
            Ok(())
        }
    }

    fn optional_xaxis(&mut self) -> Result<Option<DVec3>, ParseError> {
        if self.peek() == Some("xaxis") {
            self.pos += 1;
            Ok(Some(self.direction("xaxis")?))
        } else {
            Ok(None)
        }
    }
}

/// `v` scaled to unit length, or `None` when it is (nearly) zero or not finite. Ordinary vectors
/// get glam's `normalize` (the bits scripts always produced); only when the squared length
/// overflows or underflows is `v` scaled by its largest component first.
pub fn unit(v: DVec3) -> Option<DVec3> {
    // The plain normalisation first: directions stay bit-identical to those recorded before this
    // check existed (scripted inputs must not change under the same script).
    let len = v.length();
    if len.is_finite() && len >= 1e-9 {
        return Some(v.normalize());
    }
    // Its square overflowed or underflowed: scale by the largest component first.
    let m = v.abs().max_element();
    if !(m.is_finite() && m > 0.0) {
        return None;
    }
    let s = v / m;
    let u = s / s.length();
    (m * s.length() >= 1e-9 && u.is_finite()).then_some(u)
}

/// `breathing on|off [amplitude MM] [period S] [seed N]` (docs/breathing.md for the ranges).
fn parse_breathing(t: &mut Tokens) -> Result<stylet_physics::motion::BreathingRequest, ParseError> {
    let mut b = stylet_physics::motion::BreathingRequest {
        enabled: t.keyword(&["on", "off"])? == "on",
        ..Default::default()
    };
    while let Some(k) = t.peek() {
        let at = t.pos + 1;
        match k {
            "amplitude" => {
                t.pos += 1;
                let amplitude_mm = t.number("breathing amplitude in mm")?;
                let motion = stylet_physics::motion::SyntheticMotion {
                    amplitude_mm,
                    ..Default::default()
                };
                b.amplitude_mm = Some(amplitude_mm);
                if motion.validate().is_err() {
                    t.pos = at;
                    return Err(t.err("an amplitude of 0 … 50 mm"));
                }
            }
            "period" => {
                t.pos += 1;
                b.signal.period_s = t.number("breathing period in s")?;
                if b.signal.validate().is_err() {
                    t.pos = at;
                    return Err(t.err("a period of 1 … 20 s"));
                }
            }
            "seed" => {
                t.pos += 1;
                let v = t.number("breathing seed")?;
                if !(v >= 0.0 && v.fract() == 0.0 && v < 9.0e15) {
                    t.pos = at;
                    return Err(t.err("a whole seed of 0 … 9e15"));
                }
                b.signal.seed = v as u64;
            }
            _ => break,
        }
    }
    Ok(b)
}

fn parse_tool(t: &mut Tokens) -> Result<ToolSpec, ParseError> {
    match t.keyword(&["needle", "finger", "probe"])? {
        "finger" => Ok(ToolSpec::Finger),
        "probe" => match t.keyword(&["linear", "convex"])? {
            "linear" => Ok(ToolSpec::Probe(ProbeKind::Linear)),
            _ => Ok(ToolSpec::Probe(ProbeKind::Convex)),
        },
        _ => {
            let (mut gauge, mut length_mm, mut stylet_in) = (Gauge::G18, 150.0, true);
            while let Some(k) = t.peek() {
                match k {
                    "gauge" => {
                        t.pos += 1;
                        let at = t.pos;
                        let g = t.number("gauge 16, 18, 20 or 22")?;
                        gauge = match Gauge::from_number(g as u32).filter(|_| g.fract() == 0.0) {
                            Some(g) => g,
                            None => {
                                t.pos = at;
                                return Err(t.err("gauge 16, 18, 20 or 22"));
                            }
                        };
                    }
                    "length" => {
                        t.pos += 1;
                        let at = t.pos;
                        length_mm = t.number("needle length in mm")?;
                        if !(20.0..=400.0).contains(&length_mm) {
                            t.pos = at;
                            return Err(t.err("a needle length of 20 … 400 mm"));
                        }
                    }
                    "stylet" => {
                        t.pos += 1;
                        stylet_in = t.keyword(&["in", "out"])? == "in";
                    }
                    _ => return Err(t.err("gauge, length, stylet or end of line")),
                }
            }
            Ok(ToolSpec::Needle {
                gauge,
                length_mm,
                stylet_in,
            })
        }
    }
}

/// What the second hand holds: `finger`, `probe linear|convex` or `none`.
fn parse_hand_tool(t: &mut Tokens) -> Result<Option<HandTool>, ParseError> {
    Ok(match t.keyword(&["finger", "probe", "none"])? {
        "finger" => Some(HandTool::Finger),
        "probe" => match t.keyword(&["linear", "convex"])? {
            "linear" => Some(HandTool::Probe(ProbeKind::Linear)),
            _ => Some(HandTool::Probe(ProbeKind::Convex)),
        },
        _ => None,
    })
}

/// A dilator's or catheter's size in French, one `kind` comes in.
fn french(t: &mut Tokens, kind: OverWireKind) -> Result<u8, ParseError> {
    let at = t.pos;
    let v = t.number("size in French")?;
    if v.fract() == 0.0 && (1.0..=30.0).contains(&v) && kind.offers(v as u8) {
        return Ok(v as u8);
    }
    t.pos = at;
    Err(t.err(match kind {
        OverWireKind::Dilator => "a dilator of 6, 8, 10 or 12 F",
        OverWireKind::Catheter => "a catheter of 8 or 10 F",
    }))
}

fn parse_event(t: &mut Tokens) -> Result<Event, ParseError> {
    let names = [
        "stylet-remove",
        "stylet-insert",
        "xray-on",
        "xray-off",
        "contrast-inject",
        "breath-hold",
        "breath-release",
        "wire-in",
        "needle-out",
        "wire-out",
        "dilator-in",
        "dilator-out",
        "catheter-in",
    ];
    Ok(match t.keyword(&names)? {
        "stylet-remove" => Event::StyletRemove,
        "stylet-insert" => Event::StyletInsert,
        "xray-on" => Event::XrayOn,
        "xray-off" => Event::XrayOff,
        "breath-hold" => Event::BreathHold,
        "breath-release" => Event::BreathRelease,
        "needle-out" => Event::NeedleOut,
        "wire-out" => Event::WireOut,
        "dilator-out" => Event::DilatorOut,
        "dilator-in" => Event::DilatorIn {
            size_fr: french(t, OverWireKind::Dilator)?,
        },
        "catheter-in" => Event::CatheterIn {
            size_fr: french(t, OverWireKind::Catheter)?,
        },
        "wire-in" => {
            let diameter = match t.keyword(&["0.018", "0.035"])? {
                "0.018" => WireDiameter::In018,
                _ => WireDiameter::In035,
            };
            let tip = match t.keyword(&["j", "straight"])? {
                "j" => WireTip::J,
                _ => WireTip::Straight,
            };
            Event::WireIn { diameter, tip }
        }
        _ => {
            let ml = if t.peek().is_some() {
                let at = t.pos;
                let v = t.number("contrast volume in ml")?;
                if !(v > 0.0 && v <= 100.0) {
                    t.pos = at;
                    return Err(t.err("a contrast volume of 0 … 100 ml"));
                }
                v
            } else {
                1.0
            };
            Event::ContrastInject { ml }
        }
    })
}

/// The action of an `at` line and the track it drives; `two_handed`: the script declared a
/// second hand (`tool2 …`), without which `hand2` and `tool2` actions are refused.
fn parse_action(t: &mut Tokens, two_handed: bool) -> Result<(Hand, Action), ParseError> {
    let mut hand = Hand::First;
    if matches!(t.peek(), Some("hand2" | "tool2")) && !two_handed {
        return Err(t.err("a 'tool2 …' line before the second hand's first action"));
    }
    if t.peek() == Some("hand2") {
        t.pos += 1;
        hand = Hand::Second;
        if !matches!(t.peek(), Some("pos" | "along" | "aim" | "press" | "release")) {
            return Err(t.err("one of pos, along, aim, press, release"));
        }
    }
    let a = match t.keyword(&[
        "pos", "along", "aim", "press", "release", "event", "tool", "tool2", "hand2",
    ])? {
        "pos" => {
            let pos = t.vector("position")?;
            t.keyword(&["dir"])?;
            let dir = t.direction("dir")?;
            let xaxis = t.optional_xaxis()?;
            Action::Pose(PoseSpec::Explicit { pos, dir, xaxis })
        }
        "along" => {
            let path = t.word("an insertion path name")?.to_string();
            let depth_mm = t.bounded("depth in mm past the entry point")?;
            let xaxis = t.optional_xaxis()?;
            Action::Pose(PoseSpec::Along { path, depth_mm, xaxis })
        }
        "aim" => {
            let entry = t.vector("entry point")?;
            let at = t.pos;
            let target = t.vector("target point")?;
            if (target - entry).length() < 1e-6 {
                t.pos = at;
                return Err(t.err("a target different from the entry point"));
            }
            let depth_mm = t.bounded("depth in mm past the entry point")?;
            let xaxis = t.optional_xaxis()?;
            Action::Pose(PoseSpec::Aim {
                entry,
                target,
                depth_mm,
                xaxis,
            })
        }
        "press" => {
            let dir = t.direction("press direction")?;
            let at = t.pos;
            let force_n = t.number("force in N")?;
            if !(force_n > 0.0 && force_n <= 50.0) {
                t.pos = at;
                return Err(t.err("a force of 0 … 50 N"));
            }
            Action::Press { dir, force_n }
        }
        "release" => Action::Release,
        "event" => Action::Event(parse_event(t)?),
        "tool2" => Action::Event(Event::SecondTool(parse_hand_tool(t)?)),
        _ => Action::Event(Event::SelectTool(parse_tool(t)?)),
    };
    t.end()?;
    Ok((hand, a))
}

/// Parses a script.
pub fn parse(text: &str) -> Result<Script, ParseError> {
    let mut script = Script {
        version: 0,
        device: DeviceProfile::PREMIUM,
        rate_hz: stylet_physics::DEFAULT_TICK_RATE_HZ,
        initial_tool: ToolSpec::Needle {
            gauge: Gauge::G18,
            length_mm: 150.0,
            stylet_in: true,
        },
        end_s: None,
        items: Vec::new(),
        deformation: stylet_physics::DeformSettings::default(),
        breathing: stylet_physics::motion::BreathingRequest::default(),
        second_hand: None,
    };
    // `device2` may come before or after `tool2`; the second device defaults to the first.
    let mut device2: Option<DeviceProfile> = None;
    let mut last_t = f64::NEG_INFINITY;
    for (n, raw) in text.lines().enumerate() {
        let mut t = Tokens::new(n + 1, raw);
        let Some(first) = t.peek() else { continue };
        if script.version == 0 {
            t.keyword(&["stylet-script"])?;
            let at = t.pos;
            let v = t.number("the script language version")?;
            if v != SCRIPT_VERSION as f64 {
                t.pos = at;
                return Err(t.err(format!("version {SCRIPT_VERSION}")));
            }
            t.end()?;
            script.version = SCRIPT_VERSION;
            continue;
        }
        match first {
            "device" => {
                t.pos += 1;
                let names: Vec<&str> = DeviceProfile::ALL.iter().map(|d| d.name).collect();
                let name = t.keyword(&names)?;
                script.device = DeviceProfile::by_name(name).expect("listed");
                t.end()?;
            }
            "rate" => {
                t.pos += 1;
                let at = t.pos;
                let r = t.number("tick rate in Hz")?;
                if !((100.0..=10_000.0).contains(&r) && r.fract() == 0.0) {
                    t.pos = at;
                    return Err(t.err("a whole tick rate of 100 … 10000 Hz"));
                }
                script.rate_hz = r as u32;
                t.end()?;
            }
            "tool" => {
                t.pos += 1;
                script.initial_tool = parse_tool(&mut t)?;
                t.end()?;
            }
            "tool2" => {
                t.pos += 1;
                let initial_tool = parse_hand_tool(&mut t)?;
                t.end()?;
                script.second_hand = Some(ScriptHand {
                    device: script.device,
                    initial_tool,
                });
            }
            "device2" => {
                t.pos += 1;
                let names: Vec<&str> = DeviceProfile::ALL.iter().map(|d| d.name).collect();
                let name = t.keyword(&names)?;
                device2 = Some(DeviceProfile::by_name(name).expect("listed"));
                t.end()?;
            }
            "deformation" => {
                t.pos += 1;
                script.deformation.enabled = t.keyword(&["on", "off"])? == "on";
                t.end()?;
            }
            "breathing" => {
                t.pos += 1;
                script.breathing = parse_breathing(&mut t)?;
                t.end()?;
            }
            "end" => {
                t.pos += 1;
                let at = t.pos;
                let e = t.number("script end time in s")?;
                if !(e > 0.0 && e <= MAX_DURATION_S) {
                    t.pos = at;
                    return Err(t.err(format!("an end time of 0 … {MAX_DURATION_S} s")));
                }
                script.end_s = Some(e);
                t.end()?;
            }
            "at" => {
                t.pos += 1;
                let at = t.pos;
                let ts = t.number("time in s")?;
                if !(0.0..=MAX_DURATION_S).contains(&ts) {
                    t.pos = at;
                    return Err(t.err(format!("a time of 0 … {MAX_DURATION_S} s")));
                }
                if ts < last_t {
                    t.pos = at;
                    return Err(t.err(format!("a time ≥ {last_t} s (time stamps must not decrease)")));
                }
                last_t = ts;
                let (hand, action) = parse_action(&mut t, script.second_hand.is_some())?;
                script.items.push(Timed {
                    t_s: ts,
                    line: n + 1,
                    hand,
                    action,
                });
            }
            _ => return Err(t.err("device, rate, tool, tool2, device2, deformation, breathing, end or at")),
        }
    }
    match (&mut script.second_hand, device2) {
        (Some(h), Some(d)) => h.device = d,
        (Some(h), None) => h.device = script.device,
        (None, Some(_)) => {
            let line = text
                .lines()
                .position(|l| l.split_whitespace().next() == Some("device2"))
                .map_or(1, |i| i + 1);
            return Err(ParseError {
                line,
                column: 1,
                expected: "a 'tool2 …' line with 'device2' (the second hand's tool)".into(),
                found: "no 'tool2' line".into(),
            });
        }
        (None, None) => {}
    }
    if script.version == 0 {
        return Err(ParseError {
            line: text.lines().count().max(1),
            column: 1,
            expected: format!("the header 'stylet-script {SCRIPT_VERSION}'"),
            found: "end of script".into(),
        });
    }
    if !script
        .items
        .iter()
        .any(|i| i.hand == Hand::First && matches!(i.action, Action::Pose(_)))
    {
        return Err(ParseError {
            line: text.lines().count().max(1),
            column: 1,
            expected: "at least one pose ('at T pos …', 'at T along …' or 'at T aim …')".into(),
            found: "end of script".into(),
        });
    }
    Ok(script)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_script_parses() {
        let s = parse(
            "stylet-script 1\n# a comment\ndevice touch\nrate 1000\ntool needle gauge 22 length 200 stylet out\nend 20\n\
             at 0 pos 1 2 3 dir 0 0 2\nat 1 along intercostal-10-11 -5 # trailing comment\n\
             at 2 aim 0 0 0 0 0 10 3 xaxis 1 0 0\nat 3 press 0 -1 0 1.5\nat 4 release\nat 5 event contrast-inject 2\n\
             at 5 event stylet-remove\nat 6 tool probe convex\n",
        )
        .unwrap();
        assert_eq!(s.device.name, "touch");
        assert_eq!(
            s.initial_tool,
            ToolSpec::Needle {
                gauge: Gauge::G22,
                length_mm: 200.0,
                stylet_in: false
            }
        );
        assert_eq!(s.end_s, Some(20.0));
        assert_eq!(s.items.len(), 8);
        assert_eq!(
            s.items[0].action,
            Action::Pose(PoseSpec::Explicit {
                pos: DVec3::new(1.0, 2.0, 3.0),
                dir: DVec3::Z,
                xaxis: None
            })
        );
        assert_eq!(s.items[4].action, Action::Release);
        assert_eq!(s.items[5].action, Action::Event(Event::ContrastInject { ml: 2.0 }));
        assert_eq!(
            s.items[7].action,
            Action::Event(Event::SelectTool(ToolSpec::Probe(ProbeKind::Convex)))
        );
    }

    fn err(text: &str) -> ParseError {
        parse(text).unwrap_err()
    }

    #[test]
    fn the_exchange_events_parse_and_a_bad_wire_is_named() {
        let s = parse(
            "stylet-script 1\nat 0 along p 0\nat 1 event wire-in 0.018 straight\nat 2 event needle-out\n\
             at 3 event wire-out\n",
        )
        .unwrap();
        let events: Vec<_> = s.items[1..].iter().map(|i| i.action.clone()).collect();
        assert_eq!(
            events,
            [
                Action::Event(Event::WireIn {
                    diameter: WireDiameter::In018,
                    tip: WireTip::Straight
                }),
                Action::Event(Event::NeedleOut),
                Action::Event(Event::WireOut),
            ]
        );
        let e = err("stylet-script 1\nat 0 along p 0\nat 1 event wire-in 0.038 j\n");
        assert_eq!((e.line, e.column), (3, 20));
        assert!(e.expected.contains("0.018, 0.035") && e.found == "'0.038'", "{e}");
        let e = err("stylet-script 1\nat 0 along p 0\nat 1 event wire-in 0.035\n");
        assert!(e.expected.contains("j, straight"), "{e}");
        let s = parse("stylet-script 1\nat 0 along p 0\nat 1 event dilator-in 12\nat 2 event dilator-out\nat 3 event catheter-in 10\n")
            .unwrap();
        let events: Vec<_> = s.items[1..].iter().map(|i| i.action.clone()).collect();
        assert_eq!(
            events,
            [
                Action::Event(Event::DilatorIn { size_fr: 12 }),
                Action::Event(Event::DilatorOut),
                Action::Event(Event::CatheterIn { size_fr: 10 }),
            ]
        );
        for (line, expected) in [
            ("dilator-in 7", "a dilator of 6, 8, 10 or 12 F"),
            ("dilator-in 8.5", "a dilator of 6, 8, 10 or 12 F"),
            ("catheter-in 12", "a catheter of 8 or 10 F"),
            ("catheter-in 1e9", "a catheter of 8 or 10 F"),
        ] {
            let e = err(&format!("stylet-script 1\nat 0 along p 0\nat 1 event {line}\n"));
            assert_eq!(
                (e.line, e.column, e.expected.as_str()),
                (3, line.find(' ').unwrap() + 13, expected),
                "{e}"
            );
        }
    }

    #[test]
    fn errors_name_line_column_and_expectation() {
        let e = err("stylet-script 1\nat 0 pos 1 2 x dir 0 0 1\n");
        assert_eq!((e.line, e.column), (2, 14));
        assert!(e.expected.contains("position z") && e.found == "'x'", "{e}");
        let e = err("stylet-script 1\nat 0 pos 1 2 3\n");
        assert_eq!((e.line, e.column, e.found.as_str()), (2, 15, "end of line"));
        assert!(e.expected.contains("dir"), "{e}");
        let e = err("stylet-script 1\nat 2 release\nat 1 release\n");
        assert_eq!(e.line, 3);
        assert!(e.expected.contains("must not decrease"), "{e}");
        let e = err("stylet-script 1\ntool needle gauge 17\n");
        assert!(e.expected.contains("gauge 16, 18, 20 or 22"), "{e}");
        let e = err("stylet-script 1\nat 0 event fireworks\n");
        assert!(e.expected.contains("stylet-remove") && e.found == "'fireworks'", "{e}");
        let e = err("stylet-script 2\n");
        assert!(e.expected.contains("version 1"), "{e}");
        let e = err("at 0 release\n");
        assert!(e.expected.contains("stylet-script"), "{e}");
        let e = err("stylet-script 1\nat 0 press 0 0 0 1\n");
        assert!(e.expected.contains("non-zero press direction"), "{e}");
        let e = err("stylet-script 1\nat 0 release extra\n");
        assert!(e.expected.contains("end of line"), "{e}");
        let e = err("stylet-script 1\n");
        assert!(e.expected.contains("at least one pose"), "{e}");
        assert_eq!(
            e.to_string(),
            format!("line 1, column 1: expected {}, found end of script", e.expected)
        );
    }

    /// Two-handed scripts: `tool2` declares the second hand (its device defaults to the first's),
    /// `hand2` lines go to its track; a second-hand action or `device2` without `tool2`, and a
    /// needle for the second hand, are refused with the line and what was expected.
    #[test]
    fn second_hand_lines_parse_and_misuse_is_named() {
        let s = parse(
            "stylet-script 1\ndevice touch\ntool2 probe convex\nat 0 pos 0 0 0 dir 0 0 1\n\
             at 0 hand2 pos 1 2 3 dir 0 0 -1\nat 1 hand2 press 0 0 -1 1.5\nat 2 tool2 none\nat 3 hand2 release\n",
        )
        .unwrap();
        let hand = s.second_hand.unwrap();
        assert_eq!(hand.initial_tool, Some(HandTool::Probe(ProbeKind::Convex)));
        assert_eq!(hand.device.name, "touch");
        let hands: Vec<Hand> = s.items.iter().map(|i| i.hand).collect();
        assert_eq!(
            hands,
            [Hand::First, Hand::Second, Hand::Second, Hand::First, Hand::Second]
        );
        assert_eq!(s.items[3].action, Action::Event(Event::SecondTool(None)));
        let s = parse("stylet-script 1\ndevice2 ideal\ntool2 finger\nat 0 pos 0 0 0 dir 0 0 1\n").unwrap();
        assert_eq!(s.second_hand.unwrap().device.name, "ideal");

        let e = err("stylet-script 1\nat 0 pos 0 0 0 dir 0 0 1\nat 1 hand2 pos 0 0 0 dir 0 0 1\n");
        assert_eq!((e.line, e.column), (3, 6));
        assert!(e.expected.contains("'tool2 …' line"), "{e}");
        let e = err("stylet-script 1\nat 0 pos 0 0 0 dir 0 0 1\nat 1 tool2 finger\n");
        assert!(e.expected.contains("'tool2 …' line"), "{e}");
        let e = err("stylet-script 1\ndevice2 touch\nat 0 pos 0 0 0 dir 0 0 1\n");
        assert_eq!(e.line, 2);
        assert!(e.found.contains("no 'tool2'"), "{e}");
        let e = err("stylet-script 1\ntool2 needle\n");
        assert!(
            e.expected.contains("finger, probe, none") && e.found == "'needle'",
            "{e}"
        );
        let e = err("stylet-script 1\ntool2 probe linear\nat 0 hand2 event xray-on\n");
        assert!(e.expected.contains("pos, along, aim, press, release"), "{e}");
        // The second hand's poses alone are not a script: the first hand needs one.
        let e = err("stylet-script 1\ntool2 probe linear\nat 0 hand2 pos 0 0 0 dir 0 0 1\n");
        assert!(e.expected.contains("at least one pose"), "{e}");
    }

    /// `breathing`: on with the defaults, or with amplitude, period and seed; bad values named.
    #[test]
    fn breathing_statements_parse_and_bad_values_are_named() {
        let s = parse("stylet-script 1\nbreathing on\nat 0 pos 0 0 0 dir 0 0 1\n").unwrap();
        assert_eq!(s.breathing, stylet_physics::motion::BreathingRequest::on());
        let s =
            parse("stylet-script 1\nbreathing on amplitude 18 period 5 seed 42\nat 0 pos 0 0 0 dir 0 0 1\n").unwrap();
        assert!(s.breathing.enabled);
        assert_eq!(
            (
                s.breathing.amplitude_mm,
                s.breathing.signal.period_s,
                s.breathing.signal.seed
            ),
            (Some(18.0), 5.0, 42)
        );
        let s = parse("stylet-script 1\nbreathing off\nat 0 pos 0 0 0 dir 0 0 1\n").unwrap();
        assert!(!s.breathing.enabled);
        let e = err("stylet-script 1\nbreathing on amplitude 80\n");
        assert_eq!((e.line, e.column), (2, 24));
        assert!(e.expected.contains("0 … 50 mm") && e.found == "'80'", "{e}");
        let e = err("stylet-script 1\nbreathing on period 0.2\n");
        assert!(e.expected.contains("1 … 20 s"), "{e}");
        let e = err("stylet-script 1\nbreathing on seed 1.5\n");
        assert!(e.expected.contains("whole seed"), "{e}");
        let e = err("stylet-script 1\nbreathing maybe\n");
        assert!(e.expected.contains("on, off"), "{e}");
        let e = err("stylet-script 1\nbreathing on depth 3\n");
        assert!(e.expected.contains("end of line") && e.found == "'depth'", "{e}");
    }

    /// Every number that becomes a pose is bounded, and the error says which: unbounded,
    /// `dir 1e300 …` normalises to NaN and `aim` with ±1e308 gives NaN poses that get recorded.
    #[test]
    fn huge_numbers_that_would_make_nan_poses_are_refused() {
        let e = err("stylet-script 1\nat 0 pos 0 0 0 dir 1e300 1e300 1e300\n");
        assert_eq!((e.line, e.column, e.found.as_str()), (2, 20, "'1e300'"), "{e}");
        assert!(e.expected.contains("within ±1000000 (dir x)"), "{e}");
        let e = err("stylet-script 1\nat 0 aim 1e308 0 0 -1e308 0 0 10\n");
        assert_eq!((e.line, e.column, e.found.as_str()), (2, 10, "'1e308'"), "{e}");
        assert!(e.expected.contains("entry point x"), "{e}");
        let e = err("stylet-script 1\nat 0 aim 0 0 0 0 -1e308 0 10\n");
        assert!(e.expected.contains("target point y") && e.found == "'-1e308'", "{e}");
        let e = err("stylet-script 1\nat 0 pos 0 0 2e6 dir 0 0 1\n");
        assert!(e.expected.contains("position z"), "{e}");
        let e = err("stylet-script 1\nat 0 along p 1e300\n");
        assert!(e.expected.contains("within ±1000000 (depth"), "{e}");
        let e = err("stylet-script 1\nat 0 pos 0 0 0 dir 0 0 1 xaxis 1e300 0 0\n");
        assert!(e.expected.contains("xaxis x"), "{e}");
        let e = err("stylet-script 1\nat 0 press 0 0 -1e300 1\n");
        assert!(e.expected.contains("press direction z"), "{e}");
        let e = err("stylet-script 1\nat 0 pos 0 0 0 dir 0 0 inf\n");
        assert!(e.expected.contains("a number (dir z)"), "{e}");
    }

    #[test]
    fn directions_normalise_without_overflow_or_underflow() {
        // Ordinary directions: exactly the bits of the plain normalisation scripts always used.
        let mut x = 0.123_456_789_f64;
        for _ in 0..1000 {
            let mut next = || {
                x = (x * 3.987_654_321 + 0.271_828).fract();
                x * 200.0 - 100.0
            };
            let v = DVec3::new(next(), next(), next());
            assert_eq!(
                unit(v).unwrap().to_array().map(f64::to_bits),
                v.normalize().to_array().map(f64::to_bits),
                "{v}"
            );
        }
        let big = unit(DVec3::splat(1e300)).unwrap();
        assert!((big - DVec3::ONE.normalize()).length() < 1e-15, "{big}");
        let tiny = unit(DVec3::new(3e-9, 4e-9, 0.0)).unwrap();
        assert!((tiny - DVec3::new(0.6, 0.8, 0.0)).length() < 1e-15, "{tiny}");
        assert_eq!(unit(DVec3::splat(1e-300)), None);
        assert_eq!(unit(DVec3::ZERO), None);
        assert_eq!(unit(DVec3::new(f64::NAN, 1.0, 0.0)), None);
        assert_eq!(unit(DVec3::new(f64::INFINITY, 1.0, 0.0)), None);
        // The extremes the parser lets through give unit directions.
        let s = parse("stylet-script 1\nat 0 pos 1e6 -1e6 1e6 dir 1e6 1e-6 -1e6 xaxis -1e6 1e6 1e6\n").unwrap();
        let Action::Pose(PoseSpec::Explicit { dir, xaxis, .. }) = &s.items[0].action else {
            panic!("not a pose")
        };
        assert!((dir.length() - 1.0).abs() < 1e-15 && (xaxis.unwrap().length() - 1.0).abs() < 1e-15);
    }
}
