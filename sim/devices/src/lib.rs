//! Input devices for the simulator (docs/devices.md, docs/architecture.md): the [`Device`] trait
//! and its backends: the scripted device and its script language ([`script`]), which drives
//! reproducible, faster-than-real-time runs; the live device the window drives ([`live`]);
//! SpaceMouse reports ([`spacemouse`]) and rate control ([`rate`]); gamepads ([`gamepad`], read
//! through gilrs with the feature `gamepad`); raw-HID device profiles ([`hid_profile`]);
//! force-feedback devices through their vendors' APIs ([`haptic`]); two devices driving the two
//! hands of one session ([`two_hands`]).

pub mod command;
pub mod gamepad;
#[cfg(feature = "gamepad")]
pub mod gilrs_pad;
pub mod haptic;
#[cfg(feature = "hid")]
pub mod hid;
pub mod hid_profile;
pub mod live;
pub mod rate;
pub mod script;
pub mod spacemouse;
pub mod two_hands;

use stylet_physics::{Simulation, TickInput, TickOutput};

/// A source of tick inputs. `last` is the previous tick's output (force feedback for devices
/// that react to it); `None` ends the run.
pub trait Device {
    fn next(&mut self, tick: u64, last: Option<&TickOutput>) -> Option<TickInput>;

    /// What the device did besides moving the tool since the last call (a clutch pressed,
    /// forces held or clamped), as lines for the session's notes; the physics never sees them.
    fn notes(&mut self) -> Vec<String> {
        Vec::new()
    }

    /// A force-feedback device's latest force as sent, and what its guard did, when the tick
    /// read it (metadata for the session; the physics never sees it).
    fn device_force(&self) -> Option<haptic::Guarded> {
        None
    }
}

/// Runs a simulation against a device until the device ends, as fast as the CPU allows, calling
/// `on_tick` with each input, output and the simulation (for the full tool state).
pub fn run_headless(
    sim: &mut Simulation,
    device: &mut dyn Device,
    mut on_tick: impl FnMut(&TickInput, &TickOutput, &Simulation),
) -> u64 {
    let mut last: Option<TickOutput> = None;
    let mut ticks = 0;
    while let Some(input) = device.next(sim.tick(), last.as_ref()) {
        let out = sim.step(&input);
        on_tick(&input, &out, sim);
        last = Some(out);
        ticks += 1;
    }
    ticks
}
