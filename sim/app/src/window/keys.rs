//! Key bindings on physical keys: egui's `physical_key`, the key's place on the keyboard, whatever
//! NumLock, Shift or the layout make of it. With NumLock off (or Shift held, which inverts it) the
//! keypad's 8 arrives as the logical ArrowUp, yet its physical key is still Num8; egui reports the
//! keypad digits and the top-row digits as the same Num0–Num9 and both Enter keys as Enter, so
//! every keypad command also has its top-row key. Every key event of a frame counts, in order: a
//! key pressed and released between two frames still acts once.

use std::collections::HashSet;

use eframe::egui::{self, Key};

use crate::controls::{HeldKeys, KeypadKey};

/// What a bound key does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// A keypad command (tools, stylet, contrast, X-ray, breath hold, layout, finish, the
    /// drainage's next step).
    Keypad(KeypadKey),
    Away,
    Toward,
    Left,
    Right,
    Up,
    Down,
    TiltUp,
    TiltDown,
    TiltLeft,
    TiltRight,
    /// The X-ray foot pedal.
    Pedal,
}

/// The bindings, by physical key.
pub const BINDINGS: &[(Key, Action)] = &[
    (Key::Num0, Action::Keypad(KeypadKey::Digit(0))),
    (Key::Num1, Action::Keypad(KeypadKey::Digit(1))),
    (Key::Num2, Action::Keypad(KeypadKey::Digit(2))),
    (Key::Num3, Action::Keypad(KeypadKey::Digit(3))),
    (Key::Num4, Action::Keypad(KeypadKey::Digit(4))),
    (Key::Num5, Action::Keypad(KeypadKey::Digit(5))),
    (Key::Num6, Action::Keypad(KeypadKey::Digit(6))),
    (Key::Num7, Action::Keypad(KeypadKey::Digit(7))),
    (Key::Num8, Action::Keypad(KeypadKey::Digit(8))),
    (Key::Num9, Action::Keypad(KeypadKey::Digit(9))),
    (Key::Enter, Action::Keypad(KeypadKey::Enter)),
    (Key::Plus, Action::Keypad(KeypadKey::Plus)),
    (Key::N, Action::Keypad(KeypadKey::Plus)),
    (Key::W, Action::Away),
    (Key::S, Action::Toward),
    (Key::A, Action::Left),
    (Key::D, Action::Right),
    (Key::R, Action::Up),
    (Key::F, Action::Down),
    (Key::ArrowUp, Action::TiltUp),
    (Key::ArrowDown, Action::TiltDown),
    (Key::ArrowLeft, Action::TiltLeft),
    (Key::ArrowRight, Action::TiltRight),
    (Key::X, Action::Pedal),
];

fn action(k: Key) -> Option<Action> {
    BINDINGS.iter().find(|(b, _)| *b == k).map(|(_, a)| *a)
}

/// The keys of one frame: what is held (or was tapped during the frame), the keypad commands in
/// the order pressed, and the pedal.
#[derive(Debug, Default, PartialEq)]
pub struct KeyFrame {
    pub held: HeldKeys,
    pub commands: Vec<KeypadKey>,
    pub pedal: bool,
}

/// The physical keys down, kept across frames (egui keeps logical ones: a key pressed as Num9 and
/// released as PageUp, after Shift, would stay down for it and its next presses count as repeats).
#[derive(Debug, Default)]
pub struct Keyboard {
    down: HashSet<Key>,
}

impl Keyboard {
    /// Reads every key event of a frame in order. A key pressed during the frame counts as held
    /// for this frame even when it was released again, so no tap is lost; a press of a key
    /// already down is the system's auto-repeat and commands nothing (holding 6 must not keep
    /// injecting contrast). Releases always count, also while `typing` (a text field has the
    /// keys, which then act on nothing), so no key sticks.
    pub fn frame(&mut self, events: &[egui::Event], typing: bool, fine: bool) -> KeyFrame {
        let mut tapped = HashSet::new();
        let mut commands = Vec::new();
        for e in events {
            match e {
                egui::Event::Key {
                    key,
                    physical_key,
                    pressed,
                    ..
                } => {
                    // Synthetic events (tests, some platforms) may carry no physical key.
                    let k = physical_key.unwrap_or(*key);
                    if *pressed {
                        if self.down.insert(k) && !typing {
                            tapped.insert(k);
                            if let Some(Action::Keypad(p)) = action(k) {
                                commands.push(p);
                            }
                        }
                    } else {
                        self.down.remove(&k);
                    }
                }
                // Releases while another window has the focus never arrive.
                egui::Event::WindowFocused(false) => self.down.clear(),
                _ => {}
            }
        }
        let on = |a: Action| {
            !typing
                && BINDINGS
                    .iter()
                    .any(|(k, b)| *b == a && (self.down.contains(k) || tapped.contains(k)))
        };
        KeyFrame {
            held: HeldKeys {
                away: on(Action::Away),
                toward: on(Action::Toward),
                left: on(Action::Left),
                right: on(Action::Right),
                up: on(Action::Up),
                down: on(Action::Down),
                tilt_up: on(Action::TiltUp),
                tilt_down: on(Action::TiltDown),
                tilt_left: on(Action::TiltLeft),
                tilt_right: on(Action::TiltRight),
                fine,
            },
            commands,
            pedal: on(Action::Pedal),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(logical: Key, physical: Option<Key>, pressed: bool) -> egui::Event {
        egui::Event::Key {
            key: logical,
            physical_key: physical,
            pressed,
            repeat: false,
            modifiers: egui::Modifiers::NONE,
        }
    }

    #[test]
    fn keypad_digits_command_with_numlock_off_and_do_not_tilt() {
        let mut k = Keyboard::default();
        // NumLock off: keypad 4 is the logical ArrowLeft on the physical Num4.
        let f = k.frame(&[key(Key::ArrowLeft, Some(Key::Num4), true)], false, false);
        assert_eq!(f.commands, [KeypadKey::Digit(4)]);
        assert!(!f.held.tilt_left, "keypad 4 must not tilt the tool");
        let f = k.frame(&[key(Key::ArrowLeft, Some(Key::Num4), false)], false, false);
        assert!(f.commands.is_empty() && f.held == HeldKeys::default());
        // The real arrow key still tilts.
        let f = k.frame(&[key(Key::ArrowLeft, Some(Key::ArrowLeft), true)], false, false);
        assert!(f.held.tilt_left && f.commands.is_empty());
    }

    #[test]
    fn a_release_under_another_logical_key_does_not_stick() {
        let mut k = Keyboard::default();
        let f = k.frame(&[key(Key::Num9, Some(Key::Num9), true)], false, false);
        assert_eq!(f.commands, [KeypadKey::Digit(9)]);
        // Shift pressed meanwhile: the release comes as PageUp.
        k.frame(&[key(Key::PageUp, Some(Key::Num9), false)], false, false);
        let f = k.frame(&[key(Key::Num9, Some(Key::Num9), true)], false, false);
        assert_eq!(f.commands, [KeypadKey::Digit(9)], "the next press is a press");
    }

    #[test]
    fn every_press_of_a_frame_counts_and_taps_are_not_lost() {
        let mut k = Keyboard::default();
        let f = k.frame(
            &[
                key(Key::Num6, Some(Key::Num6), true),
                key(Key::Num6, Some(Key::Num6), false),
                key(Key::Num6, Some(Key::Num6), true),
                key(Key::Num6, Some(Key::Num6), false),
                key(Key::X, Some(Key::X), true),
                key(Key::X, Some(Key::X), false),
                key(Key::Enter, Some(Key::Enter), true),
            ],
            false,
            false,
        );
        assert_eq!(f.commands, [KeypadKey::Digit(6), KeypadKey::Digit(6), KeypadKey::Enter]);
        assert!(f.pedal, "a pedal tap within one frame takes its X-ray");
        let f = k.frame(&[], false, false);
        assert!(!f.pedal);
    }

    #[test]
    fn auto_repeat_commands_nothing_and_focus_loss_releases_everything() {
        let mut k = Keyboard::default();
        k.frame(&[key(Key::Num6, Some(Key::Num6), true)], false, false);
        let f = k.frame(&[key(Key::Num6, Some(Key::Num6), true)], false, false);
        assert!(f.commands.is_empty(), "holding 6 injects once");
        let f = k.frame(&[key(Key::W, Some(Key::W), true)], false, false);
        assert!(f.held.away);
        let f = k.frame(&[egui::Event::WindowFocused(false)], false, false);
        assert!(!f.held.away);
    }

    #[test]
    fn top_row_digits_and_events_without_a_physical_key_work_and_typing_commands_nothing() {
        let mut k = Keyboard::default();
        let f = k.frame(&[key(Key::Num3, None, true)], false, false);
        assert_eq!(f.commands, [KeypadKey::Digit(3)]);
        let f = k.frame(&[key(Key::Num3, None, false), key(Key::Num5, None, true)], true, false);
        assert!(f.commands.is_empty() && !f.held.away);
        // The release of a key pressed while typing still counts, so the next press commands.
        k.frame(&[key(Key::Num5, None, false)], true, false);
        let f = k.frame(&[key(Key::Num5, None, true)], false, false);
        assert_eq!(f.commands, [KeypadKey::Digit(5)]);
    }
}
