//! A device driven from the user interface: the window (keyboard, mouse, tablet page) sets the
//! pose it wants, queues events and commands; the haptic loop takes them each tick.
//!
//! The loop never waits for the window: it reads the shared state with `try_lock`, and when the
//! window holds the lock it keeps moving toward the last target it saw (events and commands stay
//! queued for the next tick; none is lost). The window updates its target once per frame; the
//! tool follows it tick by tick at a bounded speed ([`FOLLOW_MM_PER_S`], [`FOLLOW_DEG_PER_S`]), so
//! the physics sees smooth motion, not a jump every 16 ticks. Commands are resolved into events
//! here, against the latest tick ([`crate::command`]). The force of each tick goes back to the
//! window, for devices that cannot display force themselves.
//!
//! With a six-axis source (a SpaceMouse, [`SixAxisSource`]) the loop moves the pose itself by
//! rate control, tick by tick in the window's view, and hands the pose back for display; the
//! window then only sends events, commands and the view.

use std::sync::{Arc, Mutex};

use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::{Event, TickInput, TickOutput};

use crate::Device;
use crate::command::{Command, Switches, XRAY_SHOT_S, resolve};
use crate::rate::{RatePose, RateSettings};
use crate::spacemouse::Motion6;

/// Fastest the tool follows the window's target (mm/s).
pub const FOLLOW_MM_PER_S: f64 = 150.0;
/// Fastest the tool turns toward the window's target (degrees/s).
pub const FOLLOW_DEG_PER_S: f64 = 180.0;

/// A six-axis input polled once per tick without waiting (a SpaceMouse through hidapi).
pub trait SixAxisSource: Send {
    /// The current deflection (device frame, counts) and buttons; an error when the device is
    /// gone or sent something unreadable (the loop keeps the last pose and counts it).
    fn poll(&mut self) -> Result<(Motion6, u32), SourceError>;
}

/// A device that senses where the tool is (a haptic arm) and may display a force, polled once per
/// tick without waiting (a raw-HID device described by a profile: `hid::HidProfileDevice`).
pub trait PoseSource: Send {
    /// The tool's position in the device's frame (mm), its orientation if the device senses one,
    /// and the buttons.
    fn poll(&mut self) -> Result<(DVec3, Option<DQuat>, u32), SourceError>;
    /// Displays `force_n` (device frame); a device without force output does nothing.
    fn display(&mut self, force_n: DVec3) -> Result<(), SourceError>;

    /// What the device did besides moving the tool since the last call, for the session's notes.
    fn notes(&mut self) -> Vec<String> {
        Vec::new()
    }

    /// The force the device last sent and what its guard did (force-feedback devices).
    fn device_force(&self) -> Option<crate::haptic::Guarded> {
        None
    }
}

/// A six-axis source that failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct SourceError(pub String);

/// What the window asks for.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveInput {
    /// The pose the tool should move to.
    pub position_mm: DVec3,
    pub orientation: DQuat,
    pub buttons: u32,
    /// Events for the next tick, in order.
    pub events: Vec<Event>,
    /// Commands for the next tick, in order (resolved after the events).
    pub commands: Vec<Command>,
    /// Set to end the session (the loop's device then ends, after what is queued).
    pub finished: bool,
    /// The device frame's orientation in the world (the camera), for rate control.
    pub view: DQuat,
}

/// What the loop reports back.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LiveFeedback {
    pub tick: u64,
    pub force_n: DVec3,
    pub torque_nmm: DVec3,
}

/// The window's end of a live device.
#[derive(Debug, Clone)]
pub struct LiveHandle {
    input: Arc<Mutex<LiveInput>>,
    feedback: Arc<Mutex<LiveFeedback>>,
}

/// The loop's end: a [`Device`].
pub struct LiveDevice {
    input: Arc<Mutex<LiveInput>>,
    feedback: Arc<Mutex<LiveFeedback>>,
    /// The pose given to the last tick.
    last: TickInput,
    /// The window's target as last seen.
    target: (DVec3, DQuat),
    view: DQuat,
    dt_s: f64,
    rate: Option<RateControl>,
    absolute: Option<AbsoluteControl>,
    /// Tick at which a single shot's X-ray goes off.
    shot_off_at: Option<u64>,
    /// A dilator has been on the wire (the exchange's next step is then the catheter).
    dilated: bool,
}

/// A pose source moving the tool: the device's origin is where the tool was when the source was
/// first read, its axes the view's.
struct AbsoluteControl {
    source: Box<dyn PoseSource>,
    /// World position of the device's origin (set at the first reading).
    anchor: Option<DVec3>,
    errors: u64,
}

/// A six-axis source moving the pose.
struct RateControl {
    source: Box<dyn SixAxisSource>,
    settings: RateSettings,
    errors: u64,
}

/// A live device starting at a pose, ticking at `rate_hz`, and the window's handle to it.
pub fn live_device(position_mm: DVec3, orientation: DQuat, rate_hz: u32) -> (LiveDevice, LiveHandle) {
    let input = Arc::new(Mutex::new(LiveInput {
        position_mm,
        orientation,
        buttons: 0,
        events: Vec::new(),
        commands: Vec::new(),
        finished: false,
        view: DQuat::IDENTITY,
    }));
    let feedback = Arc::new(Mutex::new(LiveFeedback::default()));
    (
        LiveDevice {
            input: Arc::clone(&input),
            feedback: Arc::clone(&feedback),
            last: TickInput::pose(position_mm, orientation),
            target: (position_mm, orientation),
            view: DQuat::IDENTITY,
            dt_s: 1.0 / f64::from(rate_hz.max(1)),
            rate: None,
            absolute: None,
            shot_off_at: None,
            dilated: false,
        },
        LiveHandle { input, feedback },
    )
}

impl LiveDevice {
    /// Lets `source` move the pose by rate control.
    pub fn with_source(mut self, source: Box<dyn SixAxisSource>, settings: RateSettings) -> Self {
        self.rate = Some(RateControl {
            source,
            settings,
            errors: 0,
        });
        self
    }

    /// Lets a device that senses the tool's pose move it, and displays the force on it.
    pub fn with_pose_source(mut self, source: Box<dyn PoseSource>) -> Self {
        self.absolute = Some(AbsoluteControl {
            source,
            anchor: None,
            errors: 0,
        });
        self
    }

    /// Polls that failed so far (a SpaceMouse unplugged, unreadable reports).
    pub fn source_errors(&self) -> u64 {
        self.rate.as_ref().map_or(0, |r| r.errors) + self.absolute.as_ref().map_or(0, |a| a.errors)
    }

    /// One tick's move toward the window's target, at most the follow speeds.
    fn follow(&self) -> (DVec3, DQuat) {
        let (p0, q0) = (self.last.position_mm, self.last.orientation);
        let (p1, q1) = self.target;
        let p = p0 + (p1 - p0).clamp_length_max(FOLLOW_MM_PER_S * self.dt_s);
        let angle = q0.angle_between(q1);
        let max = FOLLOW_DEG_PER_S.to_radians() * self.dt_s;
        let q = if angle <= max || !angle.is_finite() {
            q1
        } else {
            q0.slerp(q1, max / angle).normalize()
        };
        (p, q)
    }
}

impl LiveHandle {
    /// Sets the pose the tool should move to.
    pub fn set_pose(&self, position_mm: DVec3, orientation: DQuat) {
        if let Ok(mut i) = self.input.lock() {
            i.position_mm = position_mm;
            i.orientation = orientation;
        }
    }

    /// Sets the view (camera orientation) that rate control moves the tool in.
    pub fn set_view(&self, view: DQuat) {
        if let Ok(mut i) = self.input.lock() {
            i.view = view;
        }
    }

    pub fn set_buttons(&self, buttons: u32) {
        if let Ok(mut i) = self.input.lock() {
            i.buttons = buttons;
        }
    }

    /// Queues an event for the next tick the loop takes.
    pub fn send(&self, event: Event) {
        if let Ok(mut i) = self.input.lock() {
            i.events.push(event);
        }
    }

    /// Queues a command, resolved into events in the loop against the latest tick.
    pub fn command(&self, command: Command) {
        if let Ok(mut i) = self.input.lock() {
            i.commands.push(command);
        }
    }

    /// Ends the session after what is queued so far.
    pub fn finish(&self) {
        if let Ok(mut i) = self.input.lock() {
            i.finished = true;
        }
    }

    /// The pose asked for last (with a six-axis source: the pose the loop reached).
    pub fn pose(&self) -> Option<(DVec3, DQuat)> {
        self.input.lock().ok().map(|i| (i.position_mm, i.orientation))
    }

    /// The latest force the loop computed.
    pub fn feedback(&self) -> LiveFeedback {
        self.feedback.lock().map(|f| *f).unwrap_or_default()
    }
}

impl Device for LiveDevice {
    fn notes(&mut self) -> Vec<String> {
        self.absolute.as_mut().map_or_else(Vec::new, |a| a.source.notes())
    }

    fn device_force(&self) -> Option<crate::haptic::Guarded> {
        self.absolute.as_ref().and_then(|a| a.source.device_force())
    }

    fn next(&mut self, tick: u64, last: Option<&TickOutput>) -> Option<TickInput> {
        if let (Some(out), Ok(mut f)) = (last, self.feedback.try_lock()) {
            *f = LiveFeedback {
                tick: out.tick,
                force_n: out.force_n,
                torque_nmm: out.torque_nmm,
            };
        }
        let mut events = Vec::new();
        let mut commands = Vec::new();
        let mut buttons = self.last.buttons;
        let mut shared = self.input.try_lock().ok();
        if let Some(s) = shared.as_mut() {
            if s.finished && s.events.is_empty() && s.commands.is_empty() {
                return None;
            }
            self.target = (s.position_mm, s.orientation);
            self.view = s.view;
            buttons = s.buttons;
            events = std::mem::take(&mut s.events);
            commands = std::mem::take(&mut s.commands);
        }
        if let (Some(abs), Some(out)) = (self.absolute.as_mut(), last)
            && abs.source.display(self.view.inverse() * out.force_n).is_err()
        {
            abs.errors += 1;
        }
        let (position_mm, orientation) = match (self.rate.as_mut(), self.absolute.as_mut()) {
            (None, Some(abs)) => {
                let mut pose = (self.last.position_mm, self.last.orientation);
                match abs.source.poll() {
                    Ok((p, q, b)) => {
                        let anchor = *abs.anchor.get_or_insert(self.last.position_mm - self.view * p);
                        pose.0 = anchor + self.view * p;
                        if let Some(q) = q {
                            pose.1 = (self.view * q).normalize();
                        } else {
                            pose.1 = self.target.1;
                        }
                        buttons = b;
                    }
                    Err(_) => abs.errors += 1,
                }
                if let Some(s) = shared.as_mut() {
                    s.position_mm = pose.0;
                    s.orientation = pose.1;
                }
                pose
            }
            (Some(rate), _) => {
                let mut pose = RatePose {
                    position_mm: self.last.position_mm,
                    orientation: self.last.orientation,
                };
                match rate.source.poll() {
                    Ok((motion, b)) => {
                        pose.step(
                            &rate.settings,
                            self.view,
                            motion.translation,
                            motion.rotation,
                            self.dt_s,
                        );
                        buttons = b;
                    }
                    Err(_) => rate.errors += 1,
                }
                // The window shows where the source took the tool.
                if let Some(s) = shared.as_mut() {
                    s.position_mm = pose.position_mm;
                    s.orientation = pose.orientation;
                }
                (pose.position_mm, pose.orientation)
            }
            (None, None) => self.follow(),
        };
        drop(shared);
        // Commands against the latest tick's switches (before the first tick: the start state).
        self.dilated |= last.is_some_and(crate::command::dilator_on);
        let mut switches = match last {
            Some(out) => Switches::of(out, self.shot_off_at.is_some(), self.dilated),
            None => Switches {
                stylet_in: true,
                xray_on: false,
                breath_hold: false,
                shot: false,
                next_step: None,
            },
        };
        let was_shot = switches.shot;
        for c in commands {
            events.extend(resolve(c, &mut switches));
        }
        if switches.shot && !was_shot {
            self.shot_off_at = Some(tick + (XRAY_SHOT_S / self.dt_s).round().max(1.0) as u64);
        } else if !switches.shot {
            self.shot_off_at = None;
        }
        if self.shot_off_at.is_some_and(|t| tick >= t) {
            events.push(Event::XrayOff);
            self.shot_off_at = None;
        }
        let input = TickInput {
            position_mm,
            orientation,
            buttons,
            events,
            second_hand: None,
        };
        self.last = TickInput {
            events: Vec::new(),
            ..input.clone()
        };
        Some(input)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loop_follows_the_window_smoothly_and_takes_every_event_once() {
        let (mut dev, handle) = live_device(DVec3::ZERO, DQuat::IDENTITY, 1000);
        let a = dev.next(0, None).unwrap();
        assert_eq!(a.position_mm, DVec3::ZERO);
        // A 3 mm jump of the target is followed at 150 mm/s: 0.15 mm a tick, 20 ticks.
        handle.set_pose(DVec3::new(3.0, 0.0, 0.0), DQuat::IDENTITY);
        handle.send(Event::StyletRemove);
        handle.send(Event::XrayOn);
        let b = dev.next(1, None).unwrap();
        assert!((b.position_mm.x - 0.15).abs() < 1e-12, "{:?}", b.position_mm);
        assert_eq!(b.events, vec![Event::StyletRemove, Event::XrayOn]);
        let mut x = b.position_mm.x;
        for t in 2..=20 {
            let p = dev.next(t, None).unwrap();
            assert!(p.events.is_empty());
            assert!(p.position_mm.x - x <= 0.15 + 1e-12);
            x = p.position_mm.x;
        }
        assert!((x - 3.0).abs() < 1e-9);
        handle.finish();
        assert!(dev.next(21, None).is_none());
    }

    /// A haptic arm that moves 1 mm along its x per reading and records the forces shown to it.
    struct Arm {
        x: f64,
        shown: Arc<Mutex<Vec<DVec3>>>,
    }

    impl PoseSource for Arm {
        fn poll(&mut self) -> Result<(DVec3, Option<DQuat>, u32), SourceError> {
            self.x += 1.0;
            Ok((DVec3::new(self.x, 0.0, 0.0), None, 1))
        }
        fn display(&mut self, force_n: DVec3) -> Result<(), SourceError> {
            self.shown.lock().unwrap().push(force_n);
            Ok(())
        }
    }

    #[test]
    fn a_pose_sensing_device_moves_the_tool_in_the_view_and_feels_the_force_in_its_own_frame() {
        let shown = Arc::new(Mutex::new(Vec::new()));
        let (dev, handle) = live_device(DVec3::new(100.0, 0.0, 0.0), DQuat::IDENTITY, 1000);
        let mut dev = dev.with_pose_source(Box::new(Arm {
            x: 0.0,
            shown: Arc::clone(&shown),
        }));
        // The view turned 90° about z: the device's x is the world's y.
        let view = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2);
        handle.set_view(view);
        let a = dev.next(0, None).unwrap();
        // The first reading anchors the device's origin at the tool.
        assert!(
            (a.position_mm - DVec3::new(100.0, 0.0, 0.0)).length() < 1e-9,
            "{:?}",
            a.position_mm
        );
        assert_eq!(a.buttons, 1);
        let out = TickOutput {
            force_n: DVec3::new(0.0, 2.0, 0.0),
            ..zero_output()
        };
        let b = dev.next(1, Some(&out)).unwrap();
        assert!(
            (b.position_mm - DVec3::new(100.0, 1.0, 0.0)).length() < 1e-9,
            "{:?}",
            b.position_mm
        );
        // The world's +y force is the device's +x.
        let f = shown.lock().unwrap()[0];
        assert!((f - DVec3::new(2.0, 0.0, 0.0)).length() < 1e-9, "{f:?}");
        // The window sees where the device took the tool.
        assert!((handle.pose().unwrap().0 - b.position_mm).length() < 1e-12);
    }

    #[test]
    fn a_busy_window_never_blocks_the_loop() {
        let (mut dev, handle) = live_device(DVec3::X, DQuat::IDENTITY, 1000);
        handle.set_pose(DVec3::new(1.1, 0.0, 0.0), DQuat::IDENTITY);
        handle.send(Event::XrayOn);
        let held = handle.input.lock().unwrap();
        // The window holds the lock: the loop keeps its last target, events wait.
        let t = dev.next(0, None).unwrap();
        assert_eq!(t.position_mm, DVec3::X);
        assert!(t.events.is_empty());
        drop(held);
        let t = dev.next(1, None).unwrap();
        assert!((t.position_mm.x - 1.1).abs() < 1e-12);
        assert_eq!(t.events, vec![Event::XrayOn]);
    }

    #[test]
    fn commands_resolve_against_the_latest_tick_and_a_shot_lasts_its_ticks() {
        let (mut dev, handle) = live_device(DVec3::ZERO, DQuat::IDENTITY, 1000);
        let mut out = zero_output();
        handle.command(Command::ToggleStylet);
        handle.command(Command::ToggleStylet);
        assert_eq!(
            dev.next(0, Some(&out)).unwrap().events,
            vec![Event::StyletRemove, Event::StyletInsert]
        );
        handle.command(Command::XrayShot);
        assert_eq!(dev.next(1, Some(&out)).unwrap().events, vec![Event::XrayOn]);
        out.xray_on = true;
        for t in 2..101 {
            assert!(dev.next(t, Some(&out)).unwrap().events.is_empty(), "tick {t}");
        }
        assert_eq!(dev.next(101, Some(&out)).unwrap().events, vec![Event::XrayOff]);
        out.xray_on = false;
        // Fluoroscopy during a shot takes over: no automatic off.
        handle.command(Command::XrayShot);
        dev.next(200, Some(&out));
        out.xray_on = true;
        handle.command(Command::ToggleFluoroscopy);
        assert_eq!(dev.next(201, Some(&out)).unwrap().events, vec![Event::XrayOff]);
        out.xray_on = false;
        handle.command(Command::ToggleFluoroscopy);
        assert_eq!(dev.next(202, Some(&out)).unwrap().events, vec![Event::XrayOn]);
        out.xray_on = true;
        for t in 203..400 {
            assert!(dev.next(t, Some(&out)).unwrap().events.is_empty(), "tick {t}");
        }
    }

    #[test]
    fn the_force_comes_back_to_the_window() {
        let (mut dev, handle) = live_device(DVec3::ZERO, DQuat::IDENTITY, 1000);
        let out = TickOutput {
            tick: 7,
            force_n: DVec3::new(0.0, 0.0, 1.5),
            ..zero_output()
        };
        dev.next(8, Some(&out));
        assert_eq!(handle.feedback().tick, 7);
        assert_eq!(handle.feedback().force_n.z, 1.5);
    }

    /// Replays SpaceMouse reports, one per poll.
    struct Recorded {
        reports: Vec<Vec<u8>>,
        state: crate::spacemouse::SpaceMouseState,
    }

    impl SixAxisSource for Recorded {
        fn poll(&mut self) -> Result<(Motion6, u32), SourceError> {
            let model = crate::spacemouse::MODELS[0];
            if !self.reports.is_empty() {
                let r = self.reports.remove(0);
                self.state
                    .apply(model.family, &r)
                    .map_err(|e| SourceError(e.to_string()))?;
            }
            Ok((self.state.motion(&model), self.state.buttons))
        }
    }

    #[test]
    fn a_spacemouse_moves_the_pose_by_rate_control_and_the_window_sees_it() {
        // Full push to the right (+X 350), held (the state persists), then button 1.
        let source = Recorded {
            reports: vec![vec![0x01, 0x5e, 0x01, 0, 0, 0, 0], vec![0x03, 0x01, 0x00], vec![0x7f]],
            state: Default::default(),
        };
        let (dev, handle) = live_device(DVec3::ZERO, DQuat::IDENTITY, 1000);
        let mut dev = dev.with_source(Box::new(source), RateSettings::SPACEMOUSE);
        handle.send(Event::XrayOn);
        let first = dev.next(0, None).unwrap();
        assert!((first.position_mm.x - 0.04).abs() < 1e-12, "40 mm/s for 1 ms");
        assert_eq!(first.events, vec![Event::XrayOn]);
        let mut last = first;
        for t in 1..1000 {
            last = dev.next(t, None).unwrap();
        }
        assert!((last.position_mm.x - 40.0).abs() < 1e-9, "{:?}", last.position_mm);
        assert_eq!(last.buttons, 1);
        // The report 0x7f is ignored, not an error; the window sees the pose.
        assert_eq!(dev.source_errors(), 0);
        assert_eq!(handle.pose().unwrap().0, last.position_mm);
        // A view turned 90° about z: "right" is now the world's +y.
        handle.set_view(DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2));
        let before = last.position_mm;
        let after = dev.next(1000, None).unwrap().position_mm;
        assert!((after - before - DVec3::new(0.0, 0.04, 0.0)).length() < 1e-9);
    }

    fn zero_output() -> TickOutput {
        TickOutput {
            tick: 0,
            time_s: 0.0,
            force_n: DVec3::ZERO,
            torque_nmm: DVec3::ZERO,
            components: Default::default(),
            insertion_dir: DVec3::Z,
            tip_label: 0,
            inserted_mm: 0.0,
            tip_mm: DVec3::ZERO,
            tip_depth_mm: 0.0,
            contacts: 0,
            indentation_mm: 0.0,
            stylet_in: true,
            xray_on: false,
            breath_hold: false,
            contrast_ml: 0.0,
            contrast_in_ducts_ml: 0.0,
            extravasated_ml: 0.0,
            contrast_extent_mm: 0.0,
            tissue_displacement_mm: 0.0,
            risk_displacement_mm: 0.0,
            second_hand: None,
            consequences: Default::default(),
            wire: None,
            refused: None,
        }
    }
}
