//! Commands from the window, the numeric keypad or the tablet page. The live device resolves
//! them into events *in the haptic loop*, against the state of the latest tick: a toggle always
//! toggles what the physics has now (two presses in one tick toggle twice), and a single X-ray
//! shot lasts exactly [`XRAY_SHOT_S`] of ticks whatever the window's frame rate.

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
}

impl Switches {
    pub fn of(out: &TickOutput, shot: bool) -> Switches {
        Switches {
            stylet_in: out.stylet_in,
            xray_on: out.xray_on,
            breath_hold: out.breath_hold,
            shot,
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
}
