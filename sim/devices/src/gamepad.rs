//! A gamepad as a six-axis input: its sticks, triggers and shoulder buttons become a deflection
//! that moves the tool by rate control ([`crate::rate`]), like a SpaceMouse cap.
//!
//! | control | moves the tool |
//! |---|---|
//! | left stick | sideways (right/left) and away/toward, in the view |
//! | right trigger / left trigger | down (into the patient) / up |
//! | right stick | tilts the tool's top the way the stick is pushed |
//! | right / left shoulder | twists the tool about the vertical |
//! | A (south) / B (east) | buttons 1 and 2 (recorded like a SpaceMouse's) |
//!
//! Axes are read as gilrs reports them: sticks in [−1, 1] with up and right positive, triggers in
//! [0, 1]. The deflection is in the device frame of [`crate::rate`] (x right, y away from the user,
//! z up) with full scale 1; the dead zone of [`RateSettings::GAMEPAD`] hides stick drift.

use stylet_physics::glam::DVec3;

use crate::rate::RateSettings;
use crate::spacemouse::Motion6;

/// Button 1 of the recorded button mask (the south face button, "A" on most pads).
pub const BUTTON_1: u32 = 1;
/// Button 2 (the east face button, "B").
pub const BUTTON_2: u32 = 2;

/// What a gamepad reports at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GamepadState {
    /// Left stick, right positive, [−1, 1].
    pub left_x: f64,
    /// Left stick, up (away from the user) positive, [−1, 1].
    pub left_y: f64,
    pub right_x: f64,
    pub right_y: f64,
    /// Analog triggers, released 0, fully pressed 1.
    pub left_trigger: f64,
    pub right_trigger: f64,
    pub left_shoulder: bool,
    pub right_shoulder: bool,
    pub south: bool,
    pub east: bool,
}

impl GamepadState {
    /// The deflection this state asks for (device frame, full scale 1). Values outside their
    /// range (a badly calibrated pad) and NaN count as the nearest limit and as rest.
    pub fn motion(&self) -> Motion6 {
        let stick = |v: f64| if v.is_nan() { 0.0 } else { v.clamp(-1.0, 1.0) };
        let trigger = |v: f64| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
        let twist = f64::from(u8::from(self.right_shoulder)) - f64::from(u8::from(self.left_shoulder));
        Motion6 {
            translation: DVec3::new(
                stick(self.left_x),
                stick(self.left_y),
                trigger(self.left_trigger) - trigger(self.right_trigger),
            ),
            // A rotation about +y turns the tool's top (+z) toward +x (right); about −x, away (+y).
            rotation: DVec3::new(-stick(self.right_y), stick(self.right_x), twist),
        }
    }

    /// The recorded button mask.
    pub fn buttons(&self) -> u32 {
        (if self.south { BUTTON_1 } else { 0 }) | (if self.east { BUTTON_2 } else { 0 })
    }
}

impl RateSettings {
    /// A gamepad: full scale 1, a 15 % dead zone (sticks rest a few per cent off centre), and the
    /// SpaceMouse's speeds, so a trainee who switches finds the same tool.
    pub const GAMEPAD: RateSettings = RateSettings {
        full_scale: 1.0,
        deadzone: 0.15,
        speed_mm_per_s: RateSettings::SPACEMOUSE.speed_mm_per_s,
        turn_deg_per_s: RateSettings::SPACEMOUSE.turn_deg_per_s,
    };
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rate::RatePose;
    use stylet_physics::glam::DQuat;

    /// Where one second of `state` takes the tool (from the origin, axis along +z, view = device).
    fn one_second(state: GamepadState) -> RatePose {
        let mut pose = RatePose::default();
        let m = state.motion();
        for _ in 0..1000 {
            pose.step(&RateSettings::GAMEPAD, DQuat::IDENTITY, m.translation, m.rotation, 1e-3);
        }
        pose
    }

    #[test]
    fn the_left_stick_and_triggers_move_the_tool_where_they_point() {
        let away = one_second(GamepadState {
            left_y: 1.0,
            ..Default::default()
        });
        assert!(
            (away.position_mm - DVec3::new(0.0, 40.0, 0.0)).length() < 1e-6,
            "{away:?}"
        );
        let right = one_second(GamepadState {
            left_x: 1.0,
            ..Default::default()
        });
        assert!((right.position_mm.x - 40.0).abs() < 1e-6, "{right:?}");
        let down = one_second(GamepadState {
            right_trigger: 1.0,
            ..Default::default()
        });
        assert!(
            (down.position_mm - DVec3::new(0.0, 0.0, -40.0)).length() < 1e-6,
            "{down:?}"
        );
        let up = one_second(GamepadState {
            left_trigger: 1.0,
            right_trigger: 1.0,
            ..Default::default()
        });
        assert_eq!(up.position_mm, DVec3::ZERO, "both triggers cancel");
    }

    #[test]
    fn the_right_stick_tilts_the_top_of_the_tool_the_way_it_is_pushed() {
        let top = |s: GamepadState| one_second(s).orientation * DVec3::Z;
        let right = top(GamepadState {
            right_x: 1.0,
            ..Default::default()
        });
        assert!(right.x > 0.6 && right.y.abs() < 1e-9, "{right}");
        let away = top(GamepadState {
            right_y: 1.0,
            ..Default::default()
        });
        assert!(away.y > 0.6 && away.x.abs() < 1e-9, "{away}");
        // 45°/s for one second.
        assert!((right.angle_between(DVec3::Z).to_degrees() - 45.0).abs() < 1e-6);
        let twisted = one_second(GamepadState {
            right_shoulder: true,
            ..Default::default()
        });
        let side = twisted.orientation * DVec3::X;
        assert!(
            side.y > 0.6,
            "the right shoulder turns anticlockwise seen from above: {side}"
        );
    }

    #[test]
    fn stick_drift_and_bad_values_do_not_move_the_tool() {
        let drift = one_second(GamepadState {
            left_x: 0.1,
            left_y: -0.12,
            right_x: 0.14,
            left_trigger: 0.05,
            ..Default::default()
        });
        assert_eq!(drift.position_mm, DVec3::ZERO);
        assert_eq!(drift.orientation, DQuat::IDENTITY);
        let bad = GamepadState {
            left_x: f64::NAN,
            left_y: 7.0,
            right_trigger: -3.0,
            ..Default::default()
        };
        assert_eq!(bad.motion().translation, DVec3::new(0.0, 1.0, 0.0));
    }

    #[test]
    fn face_buttons_are_recorded_as_buttons_1_and_2() {
        let s = GamepadState {
            south: true,
            ..Default::default()
        };
        assert_eq!(s.buttons(), 1);
        let s = GamepadState {
            south: true,
            east: true,
            ..Default::default()
        };
        assert_eq!(s.buttons(), 3);
        assert_eq!(GamepadState::default().buttons(), 0);
    }
}
