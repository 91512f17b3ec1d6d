//! Commands from the window, the numeric keypad or the tablet page. The live device resolves
//! them into events *in the haptic loop*, against the state of the latest tick: a toggle always
//! toggles what the physics has now (two presses in one tick toggle twice), and a single X-ray
//! shot lasts exactly [`XRAY_SHOT_S`] of ticks whatever the window's frame rate. The next step
//! of the Seldinger exchange is likewise what the latest tick's exchange calls for
//! ([`ExchangeStep::next`]), so the trainee does the steps in order with one key.

use stylet_physics::seldinger::over_wire::OverWireKind;
use stylet_physics::wire::spec::{WireDiameter, WireTip};
use stylet_physics::{Event, TickOutput, ToolSpec};

/// Length of a single X-ray shot (s).
pub const XRAY_SHOT_S: f64 = 0.1;

/// What the trainee asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    Tool(ToolSpec),
    ToggleStylet,
    Contrast {
        ml: f64,
    },
    ToggleFluoroscopy,
    /// One short exposure, unless fluoroscopy is already on.
    XrayShot,
    ToggleBreathHold,
    /// The next step of the Seldinger exchange ([`ExchangeStep`]); `wire` is the guide wire the
    /// needle in hand takes (the window knows its gauge).
    NextStep {
        wire: WireDiameter,
    },
    /// The window's own: the next view layout (no event).
    NextLayout,
    /// The window's own: end the session (no event).
    Finish,
}

/// The switches a command toggles, as the latest tick left them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Switches {
    pub stylet_in: bool,
    pub xray_on: bool,
    pub breath_hold: bool,
    /// Whether the X-ray is on for a single shot (not fluoroscopy).
    pub shot: bool,
    /// The exchange's next step; taken by the first [`Command::NextStep`] of the tick.
    pub next_step: Option<ExchangeStep>,
}

impl Switches {
    /// `dilated`: a dilator has been on the wire in this session (the catheter comes next).
    pub fn of(out: &TickOutput, shot: bool, dilated: bool) -> Switches {
        Switches {
            stylet_in: out.stylet_in,
            xray_on: out.xray_on,
            breath_hold: out.breath_hold,
            shot,
            next_step: ExchangeStep::next(out, dilated),
        }
    }
}

/// A step of the Seldinger exchange (docs/seldinger.md "In the simulator"), in the order done:
/// the wire through the needle, the needle out over it, the tract dilated, the catheter over the
/// wire, the wire out. Feeding, drawing back and rolling the thing in hand is the device's
/// motion along its axis; the steps are events the physics checks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExchangeStep {
    WireIn,
    NeedleOut,
    DilatorIn,
    DilatorOut,
    CatheterIn,
    WireOut,
}

/// Whether a dilator is on the wire at the tick `out` (once seen, the next bare wire takes the
/// catheter).
pub fn dilator_on(out: &TickOutput) -> bool {
    out.wire
        .and_then(|w| w.over_wire)
        .is_some_and(|t| t.kind == OverWireKind::Dilator)
}

/// The dilator and catheter the simulator's steps take (F): 8 F, the usual first drain.
pub const EXCHANGE_SIZE_FR: u8 = 8;

impl ExchangeStep {
    /// What the exchange calls for after the tick `out`, `None` when nothing does: before the
    /// needle is in with its stylet out, and once the catheter is placed. `dilated`: a dilator
    /// has been on the wire, so a bare wire with the needle out takes the catheter next.
    pub fn next(out: &TickOutput, dilated: bool) -> Option<ExchangeStep> {
        let Some(w) = out.wire else {
            return (out.inserted_mm > 0.0 && !out.stylet_in).then_some(ExchangeStep::WireIn);
        };
        if w.catheter.is_some() || !w.wire_in {
            return None;
        }
        Some(match w.over_wire.map(|t| t.kind) {
            Some(OverWireKind::Dilator) => ExchangeStep::DilatorOut,
            Some(OverWireKind::Catheter) => ExchangeStep::WireOut,
            None if w.needle_in => ExchangeStep::NeedleOut,
            None if dilated => ExchangeStep::CatheterIn,
            None => ExchangeStep::DilatorIn,
        })
    }

    /// The step's event; a wire goes in J-tipped (it leads with its bend into the ducts).
    pub fn event(self, wire: WireDiameter) -> Event {
        match self {
            ExchangeStep::WireIn => Event::WireIn {
                diameter: wire,
                tip: WireTip::J,
            },
            ExchangeStep::NeedleOut => Event::NeedleOut,
            ExchangeStep::DilatorIn => Event::DilatorIn {
                size_fr: EXCHANGE_SIZE_FR,
            },
            ExchangeStep::DilatorOut => Event::DilatorOut,
            ExchangeStep::CatheterIn => Event::CatheterIn {
                size_fr: EXCHANGE_SIZE_FR,
            },
            ExchangeStep::WireOut => Event::WireOut,
        }
    }

    /// What the trainee is offered, in words.
    pub fn label(self) -> &'static str {
        match self {
            ExchangeStep::WireIn => "guide wire in through the needle",
            ExchangeStep::NeedleOut => "needle out over the wire",
            ExchangeStep::DilatorIn => "dilator on the wire",
            ExchangeStep::DilatorOut => "dilator out",
            ExchangeStep::CatheterIn => "drainage catheter on the wire",
            ExchangeStep::WireOut => "wire out: the pigtail forms",
        }
    }
}

/// The events of `command`, updating `s` as they take effect (so the next command of the same
/// tick sees them). A shot sets `s.shot`; the device ends it.
pub fn resolve(command: Command, s: &mut Switches) -> Vec<Event> {
    match command {
        Command::Tool(t) => vec![Event::SelectTool(t)],
        Command::ToggleStylet => {
            s.stylet_in = !s.stylet_in;
            vec![if s.stylet_in {
                Event::StyletInsert
            } else {
                Event::StyletRemove
            }]
        }
        Command::Contrast { ml } => vec![Event::ContrastInject { ml }],
        Command::ToggleFluoroscopy => {
            s.xray_on = !s.xray_on;
            s.shot = false;
            vec![if s.xray_on { Event::XrayOn } else { Event::XrayOff }]
        }
        Command::XrayShot if s.xray_on => Vec::new(),
        Command::XrayShot => {
            s.xray_on = true;
            s.shot = true;
            vec![Event::XrayOn]
        }
        Command::ToggleBreathHold => {
            s.breath_hold = !s.breath_hold;
            vec![if s.breath_hold {
                Event::BreathHold
            } else {
                Event::BreathRelease
            }]
        }
        Command::NextStep { wire } => s.next_step.take().map(|step| step.event(wire)).into_iter().collect(),
        Command::NextLayout | Command::Finish => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toggles_follow_the_state_and_two_presses_toggle_twice() {
        let mut s = Switches {
            stylet_in: true,
            xray_on: false,
            breath_hold: false,
            shot: false,
            next_step: None,
        };
        assert_eq!(resolve(Command::ToggleStylet, &mut s), vec![Event::StyletRemove]);
        assert_eq!(resolve(Command::ToggleStylet, &mut s), vec![Event::StyletInsert]);
        assert_eq!(resolve(Command::XrayShot, &mut s), vec![Event::XrayOn]);
        assert!(s.shot);
        // A shot while the X-ray is on does nothing; fluoroscopy switches it off.
        assert!(resolve(Command::XrayShot, &mut s).is_empty());
        assert_eq!(resolve(Command::ToggleFluoroscopy, &mut s), vec![Event::XrayOff]);
        assert!(!s.shot);
        assert_eq!(resolve(Command::ToggleBreathHold, &mut s), vec![Event::BreathHold]);
        assert!(resolve(Command::Finish, &mut s).is_empty());
    }

    #[test]
    fn the_exchange_is_offered_step_by_step_in_order() {
        use stylet_physics::glam::DVec3;
        use stylet_physics::seldinger::{CatheterOutput, OverWireOutput, WireOutput};
        let next = ExchangeStep::next;
        // The needle outside, or in with its stylet: no step yet.
        let mut out = TickOutput {
            stylet_in: true,
            ..TickOutput::default()
        };
        assert_eq!(next(&out, false), None);
        out.inserted_mm = 90.0;
        assert_eq!(next(&out, false), None);
        out.stylet_in = false;
        assert_eq!(next(&out, false), Some(ExchangeStep::WireIn));
        let wire = WireOutput {
            needle_in: true,
            wire_in: true,
            ..WireOutput::default()
        };
        out.wire = Some(wire);
        assert_eq!(next(&out, false), Some(ExchangeStep::NeedleOut));
        let bare = WireOutput {
            needle_in: false,
            ..wire
        };
        out.wire = Some(bare);
        assert_eq!(next(&out, false), Some(ExchangeStep::DilatorIn));
        let on = |kind| OverWireOutput {
            kind,
            size_fr: 8,
            inserted_mm: 100.0,
            opening_n: 0.0,
            tip_mm: DVec3::ZERO,
        };
        out.wire = Some(WireOutput {
            over_wire: Some(on(OverWireKind::Dilator)),
            ..bare
        });
        assert_eq!(next(&out, false), Some(ExchangeStep::DilatorOut));
        out.wire = Some(bare);
        assert_eq!(next(&out, true), Some(ExchangeStep::CatheterIn));
        out.wire = Some(WireOutput {
            over_wire: Some(on(OverWireKind::Catheter)),
            ..bare
        });
        assert_eq!(next(&out, true), Some(ExchangeStep::WireOut));
        out.wire = Some(WireOutput {
            wire_in: false,
            catheter: Some(CatheterOutput {
                size_fr: 8,
                holes_in_ducts: 6,
                pigtail_in_ducts: true,
                loop_radius_mm: 2.5,
                tip_mm: DVec3::ZERO,
            }),
            ..bare
        });
        assert_eq!(next(&out, true), None);
    }

    #[test]
    fn one_step_per_tick_however_often_the_key_is_pressed() {
        let mut s = Switches {
            stylet_in: false,
            xray_on: false,
            breath_hold: false,
            shot: false,
            next_step: Some(ExchangeStep::WireIn),
        };
        let press = Command::NextStep {
            wire: WireDiameter::In035,
        };
        assert_eq!(
            resolve(press, &mut s),
            vec![Event::WireIn {
                diameter: WireDiameter::In035,
                tip: WireTip::J
            }]
        );
        // The second press of the same tick would act on a state the physics has not made yet.
        assert!(resolve(press, &mut s).is_empty());
        assert_eq!(
            ExchangeStep::CatheterIn.event(WireDiameter::In035),
            Event::CatheterIn {
                size_fr: EXCHANGE_SIZE_FR
            }
        );
    }
}
