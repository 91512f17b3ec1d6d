//! Keyboard and mouse controls: a mapping a person learns in a minute (docs/simulator.md
//! "Controls"), and the numeric-keypad commands of the thesis' workbench (§6.2.2).
//!
//! | input | does |
//! |---|---|
//! | W / S | move the tool away from / toward you |
//! | A / D | move it left / right |
//! | R / F | move it up / down |
//! | arrow keys | tilt the tool (up/down, left/right) |
//! | Shift | everything at a quarter of the speed (fine placement) |
//! | left drag | move the tool in the screen plane (0.2 mm per pixel) |
//! | right drag | aim it (0.25° per pixel) |
//! | wheel | advance / withdraw along the tool's axis (1 mm per notch, 0.2 with Shift) |
//! | keypad (or top-row) 1 2 3 4 | finger, linear probe, convex probe, needle 18 G |
//! | keypad 5 | stylet out / in |
//! | keypad 6 | inject 1 ml of contrast |
//! | keypad 7 | fluoroscopy on / off; keypad 8: one X-ray shot |
//! | keypad 9 | breath hold / release |
//! | keypad 0 | next view layout; keypad Enter (or Return): finish the session |
//! | keypad + (or N) | the drainage's next step: guide wire in, needle out, dilator in / out, catheter in, wire out |
//!
//! Keys are bound by physical key (NumLock and the layout do not matter): `window::keys`.
//!
//! The window turns its key and pointer events into a [`ControlInput`] per frame; what the
//! controls produce is a target pose and [`Command`]s for the live device, which resolves the
//! commands into events in the loop (`stylet_devices::command`); the session records them.

pub use stylet_devices::command::Command;
use stylet_devices::rate::{RatePose, RateSettings};
use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::needle::spec::Gauge;
use stylet_physics::wire::spec::WireDiameter;
use stylet_physics::{ProbeKind, ToolSpec};

/// Speeds of held keys (a key is full deflection).
pub const KEYS: RateSettings = RateSettings {
    full_scale: 1.0,
    deadzone: 0.0,
    speed_mm_per_s: 20.0,
    turn_deg_per_s: 30.0,
};
/// Mouse drag in the screen plane (mm per pixel).
pub const DRAG_MM_PER_PX: f64 = 0.2;
/// Right-drag aiming (degrees per pixel).
pub const AIM_DEG_PER_PX: f64 = 0.25;
/// Wheel advance (mm per notch).
pub const WHEEL_MM_PER_NOTCH: f64 = 1.0;
/// Speed factor with Shift held.
pub const FINE: f64 = 0.25;

/// The keys that move the tool, held or not.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HeldKeys {
    pub away: bool,
    pub toward: bool,
    pub left: bool,
    pub right: bool,
    pub up: bool,
    pub down: bool,
    pub tilt_up: bool,
    pub tilt_down: bool,
    pub tilt_left: bool,
    pub tilt_right: bool,
    pub fine: bool,
}

/// One frame of keyboard and pointer input.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ControlInput {
    pub held: HeldKeys,
    /// Left-button drag this frame (pixels; x right, y down on screen).
    pub drag_px: [f64; 2],
    /// Right-button drag this frame (pixels).
    pub aim_px: [f64; 2],
    /// Wheel notches this frame (> 0: away from you, into the patient).
    pub wheel_notches: f64,
}

fn axis(plus: bool, minus: bool) -> f64 {
    f64::from(u8::from(plus)) - f64::from(u8::from(minus))
}

/// Moves `pose` by one frame of input lasting `dt_s`, in the frame of `view` (the camera: device
/// x right, y away from the viewer, z up).
pub fn apply(input: &ControlInput, view: DQuat, pose: &mut RatePose, dt_s: f64) {
    let k = &input.held;
    let fine = if k.fine { FINE } else { 1.0 };
    let translation = DVec3::new(axis(k.right, k.left), axis(k.away, k.toward), axis(k.up, k.down)) * fine;
    let rotation = DVec3::new(axis(k.tilt_up, k.tilt_down), 0.0, axis(k.tilt_left, k.tilt_right)) * fine;
    pose.step(&KEYS, view, translation, rotation, dt_s);
    // Drag: screen right is the view's x, screen down its −z.
    let [dx, dy] = input.drag_px;
    pose.position_mm += view * DVec3::new(dx, 0.0, -dy) * (DRAG_MM_PER_PX * fine);
    let [ax, ay] = input.aim_px;
    if ax != 0.0 || ay != 0.0 {
        let yaw = DQuat::from_axis_angle(view * DVec3::Z, (-ax * AIM_DEG_PER_PX * fine).to_radians());
        let pitch = DQuat::from_axis_angle(view * DVec3::X, (-ay * AIM_DEG_PER_PX * fine).to_radians());
        pose.orientation = (yaw * pitch * pose.orientation).normalize();
    }
    if input.wheel_notches != 0.0 {
        let tool_axis = pose.orientation * DVec3::Z;
        pose.position_mm += tool_axis * (input.wheel_notches * WHEEL_MM_PER_NOTCH * fine);
    }
}

/// A numeric-keypad key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeypadKey {
    Digit(u8),
    Enter,
    /// The Seldinger exchange's next step.
    Plus,
}

/// The command of a keypad key, if it has one.
pub fn keypad(key: KeypadKey) -> Option<Command> {
    Some(match key {
        KeypadKey::Digit(1) => Command::Tool(ToolSpec::Finger),
        KeypadKey::Digit(2) => Command::Tool(ToolSpec::Probe(ProbeKind::Linear)),
        KeypadKey::Digit(3) => Command::Tool(ToolSpec::Probe(ProbeKind::Convex)),
        KeypadKey::Digit(4) => Command::Tool(ToolSpec::Needle {
            gauge: Gauge::G18,
            length_mm: 150.0,
            stylet_in: true,
        }),
        KeypadKey::Digit(5) => Command::ToggleStylet,
        KeypadKey::Digit(6) => Command::Contrast { ml: 1.0 },
        KeypadKey::Digit(7) => Command::ToggleFluoroscopy,
        KeypadKey::Digit(8) => Command::XrayShot,
        KeypadKey::Digit(9) => Command::ToggleBreathHold,
        KeypadKey::Digit(0) => Command::NextLayout,
        KeypadKey::Enter => Command::Finish,
        // The window gives the wire its needle takes.
        KeypadKey::Plus => Command::NextStep {
            wire: WireDiameter::In035,
        },
        KeypadKey::Digit(_) => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_move_at_their_speed_and_shift_slows_them() {
        let mut p = RatePose::default();
        let away = ControlInput {
            held: HeldKeys {
                away: true,
                ..Default::default()
            },
            ..Default::default()
        };
        apply(&away, DQuat::IDENTITY, &mut p, 0.5);
        assert!((p.position_mm - DVec3::new(0.0, 10.0, 0.0)).length() < 1e-9);
        let mut q = RatePose::default();
        let fine = ControlInput {
            held: HeldKeys {
                left: true,
                fine: true,
                ..Default::default()
            },
            ..Default::default()
        };
        apply(&fine, DQuat::IDENTITY, &mut q, 1.0);
        assert!((q.position_mm - DVec3::new(-5.0, 0.0, 0.0)).length() < 1e-9);
        // Opposite keys cancel.
        let mut r = RatePose::default();
        let both = ControlInput {
            held: HeldKeys {
                up: true,
                down: true,
                ..Default::default()
            },
            ..Default::default()
        };
        apply(&both, DQuat::IDENTITY, &mut r, 1.0);
        assert_eq!(r.position_mm, DVec3::ZERO);
    }

    #[test]
    fn the_mouse_drags_in_the_screen_plane_aims_and_the_wheel_advances_along_the_tool() {
        let mut p = RatePose::default();
        let drag = ControlInput {
            drag_px: [10.0, 5.0],
            ..Default::default()
        };
        apply(&drag, DQuat::IDENTITY, &mut p, 0.016);
        // 10 px right, 5 px down: +2 mm x, −1 mm z.
        assert!((p.position_mm - DVec3::new(2.0, 0.0, -1.0)).length() < 1e-9);
        // The wheel: 3 notches along the tool's axis (+z here).
        let wheel = ControlInput {
            wheel_notches: 3.0,
            ..Default::default()
        };
        apply(&wheel, DQuat::IDENTITY, &mut p, 0.016);
        assert!((p.position_mm - DVec3::new(2.0, 0.0, 2.0)).length() < 1e-9);
        // Aiming 360 px to the side turns the axis by 90° about the view's vertical.
        let mut a = RatePose {
            orientation: DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2), // axis along +y
            ..Default::default()
        };
        let aim = ControlInput {
            aim_px: [360.0, 0.0],
            ..Default::default()
        };
        apply(&aim, DQuat::IDENTITY, &mut a, 0.016);
        let axis = a.orientation * DVec3::Z;
        assert!((axis - DVec3::X).length() < 1e-9, "{axis:?}");
        assert_eq!(a.position_mm, DVec3::ZERO);
    }

    #[test]
    fn the_keypad_sends_the_commands_of_the_thesis_workbench() {
        use stylet_devices::command::{Switches, resolve};
        use stylet_physics::Event;
        let mut s = Switches {
            stylet_in: true,
            xray_on: false,
            breath_hold: false,
            shot: false,
            next_step: None,
        };
        assert_eq!(
            keypad(KeypadKey::Digit(2)).map(|c| resolve(c, &mut s)),
            Some(vec![Event::SelectTool(ToolSpec::Probe(ProbeKind::Linear))])
        );
        assert_eq!(keypad(KeypadKey::Digit(5)), Some(Command::ToggleStylet));
        assert_eq!(keypad(KeypadKey::Digit(6)), Some(Command::Contrast { ml: 1.0 }));
        assert_eq!(keypad(KeypadKey::Digit(7)), Some(Command::ToggleFluoroscopy));
        assert_eq!(keypad(KeypadKey::Digit(8)), Some(Command::XrayShot));
        assert_eq!(keypad(KeypadKey::Digit(9)), Some(Command::ToggleBreathHold));
        assert_eq!(keypad(KeypadKey::Digit(0)), Some(Command::NextLayout));
        assert_eq!(keypad(KeypadKey::Enter), Some(Command::Finish));
        assert!(matches!(keypad(KeypadKey::Plus), Some(Command::NextStep { .. })));
        assert_eq!(keypad(KeypadKey::Digit(42)), None);
        assert!((0..=9).all(|d| keypad(KeypadKey::Digit(d)).is_some()));
    }
}
