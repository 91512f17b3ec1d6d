//! A gamepad through gilrs (feature `gamepad`; on Linux gilrs reads evdev and needs libudev).
//!
//! Polled once per tick by the haptic loop without waiting, like the SpaceMouse: the events that
//! came since the last tick are taken (gilrs updates the pad's state as they are), then the pad's
//! state is read and mapped by [`crate::gamepad`].

use gilrs::{Axis, Button, GamepadId, Gilrs};

use crate::gamepad::GamepadState;
use crate::live::{SixAxisSource, SourceError};
use crate::spacemouse::Motion6;

/// Most events taken in one poll, so a flooding device cannot hold a tick.
const MAX_EVENTS_PER_POLL: usize = 64;

/// The first connected gamepad.
pub struct GilrsGamepad {
    gilrs: Gilrs,
    id: GamepadId,
    /// The pad's name as the system reports it.
    pub name: String,
}

impl GilrsGamepad {
    /// Opens the first connected gamepad, or says why there is none.
    pub fn open_first() -> Result<GilrsGamepad, SourceError> {
        let gilrs = Gilrs::new().map_err(|e| SourceError(format!("cannot read gamepads: {e}")))?;
        let Some((id, name)) = gilrs
            .gamepads()
            .find(|(_, pad)| pad.is_connected())
            .map(|(id, pad)| (id, pad.name().to_string()))
        else {
            return Err(SourceError(
                "no gamepad found (on Linux, check read access to /dev/input/event*: the input group)".into(),
            ));
        };
        Ok(GilrsGamepad { gilrs, id, name })
    }

    /// The pad's state now.
    fn state(&self) -> Result<GamepadState, SourceError> {
        let pad = self.gilrs.gamepad(self.id);
        if !pad.is_connected() {
            return Err(SourceError(format!("the gamepad {} was disconnected", self.name)));
        }
        let trigger = |b: Button| pad.button_data(b).map_or(0.0, |d| f64::from(d.value()));
        Ok(GamepadState {
            left_x: f64::from(pad.value(Axis::LeftStickX)),
            left_y: f64::from(pad.value(Axis::LeftStickY)),
            right_x: f64::from(pad.value(Axis::RightStickX)),
            right_y: f64::from(pad.value(Axis::RightStickY)),
            left_trigger: trigger(Button::LeftTrigger2),
            right_trigger: trigger(Button::RightTrigger2),
            left_shoulder: pad.is_pressed(Button::LeftTrigger),
            right_shoulder: pad.is_pressed(Button::RightTrigger),
            south: pad.is_pressed(Button::South),
            east: pad.is_pressed(Button::East),
        })
    }
}

impl SixAxisSource for GilrsGamepad {
    fn poll(&mut self) -> Result<(Motion6, u32), SourceError> {
        for _ in 0..MAX_EVENTS_PER_POLL {
            if self.gilrs.next_event().is_none() {
                break;
            }
        }
        let s = self.state()?;
        Ok((s.motion(), s.buttons()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without a gamepad (CI has none, nor /dev/input), opening one fails with a reason.
    #[test]
    fn no_gamepad_is_a_clear_error() {
        match GilrsGamepad::open_first() {
            Err(e) => assert!(
                e.0.contains("no gamepad found") || e.0.contains("cannot read gamepads"),
                "{e}"
            ),
            Ok(pad) => eprintln!("a gamepad is connected here: {}", pad.name),
        }
    }
}
