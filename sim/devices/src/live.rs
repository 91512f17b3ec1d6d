//! A device driven from the user interface: the window (keyboard, mouse, SpaceMouse, tablet page)
//! sets the pose it wants and queues events; the haptic loop takes them each tick.
//!
//! The loop never waits for the window: it reads the shared state with `try_lock`, and when the
//! window holds the lock it repeats the previous pose (events stay queued for the next tick). The
//! force of each tick goes back the same way, for the on-screen force display of devices that
//! cannot display force themselves.
//!
//! With a six-axis source (a SpaceMouse, [`SixAxisSource`]) the loop moves the pose itself by
//! rate control, tick by tick in the window's view, and hands the pose back for display; the
//! window then only sends events and the view.

use std::sync::{Arc, Mutex};

use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::{Event, TickInput, TickOutput};

use crate::Device;
use crate::rate::{RatePose, RateSettings};
use crate::spacemouse::Motion6;

/// A six-axis input polled once per tick without waiting (a SpaceMouse through hidapi).
pub trait SixAxisSource: Send {
    /// The current deflection (device frame, counts) and buttons; an error when the device is
    /// gone or sent something unreadable (the loop keeps the last pose and counts it).
    fn poll(&mut self) -> Result<(Motion6, u32), SourceError>;
}

/// A six-axis source that failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct SourceError(pub String);

/// What the window asks for.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveInput {
    pub position_mm: DVec3,
    pub orientation: DQuat,
    pub buttons: u32,
    /// Events for the next tick, in order.
    pub events: Vec<Event>,
    /// Set to end the session (the loop's device then ends).
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
    last: TickInput,
    rate: Option<RateControl>,
}

/// A six-axis source moving the pose.
struct RateControl {
    source: Box<dyn SixAxisSource>,
    settings: RateSettings,
    dt_s: f64,
    view: DQuat,
    errors: u64,
}

/// A live device starting at a pose, and the window's handle to it.
pub fn live_device(position_mm: DVec3, orientation: DQuat) -> (LiveDevice, LiveHandle) {
    let input = Arc::new(Mutex::new(LiveInput {
        position_mm,
        orientation,
        buttons: 0,
        events: Vec::new(),
        finished: false,
        view: DQuat::IDENTITY,
    }));
    let feedback = Arc::new(Mutex::new(LiveFeedback::default()));
    (
        LiveDevice {
            input: Arc::clone(&input),
            feedback: Arc::clone(&feedback),
            last: TickInput::pose(position_mm, orientation),
            rate: None,
        },
        LiveHandle { input, feedback },
    )
}

impl LiveDevice {
    /// Lets `source` move the pose by rate control, ticking at `rate_hz`.
    pub fn with_source(mut self, source: Box<dyn SixAxisSource>, settings: RateSettings, rate_hz: u32) -> Self {
        self.rate = Some(RateControl {
            source,
            settings,
            dt_s: 1.0 / f64::from(rate_hz.max(1)),
            view: DQuat::IDENTITY,
            errors: 0,
        });
        self
    }

    /// Polls that failed so far (a SpaceMouse unplugged, unreadable reports).
    pub fn source_errors(&self) -> u64 {
        self.rate.as_ref().map_or(0, |r| r.errors)
    }
}

impl LiveHandle {
    /// Sets the view (camera orientation) that rate control moves the tool in.
    pub fn set_view(&self, view: DQuat) {
        if let Ok(mut i) = self.input.lock() {
            i.view = view;
        }
    }

    /// Sets the pose the tool should take from the next tick on.
    pub fn set_pose(&self, position_mm: DVec3, orientation: DQuat) {
        if let Ok(mut i) = self.input.lock() {
            i.position_mm = position_mm;
            i.orientation = orientation;
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

    /// Ends the session after the events queued so far.
    pub fn finish(&self) {
        if let Ok(mut i) = self.input.lock() {
            i.finished = true;
        }
    }

    /// The pose asked for last.
    pub fn pose(&self) -> Option<(DVec3, DQuat)> {
        self.input.lock().ok().map(|i| (i.position_mm, i.orientation))
    }

    /// The latest force the loop computed.
    pub fn feedback(&self) -> LiveFeedback {
        self.feedback.lock().map(|f| *f).unwrap_or_default()
    }
}

impl Device for LiveDevice {
    fn next(&mut self, tick: u64, last: Option<&TickOutput>) -> Option<TickInput> {
        if let (Some(out), Ok(mut f)) = (last, self.feedback.try_lock()) {
            *f = LiveFeedback {
                tick: out.tick,
                force_n: out.force_n,
                torque_nmm: out.torque_nmm,
            };
        }
        let _ = tick;
        let mut input = TickInput::pose(self.last.position_mm, self.last.orientation);
        input.buttons = self.last.buttons;
        let shared = self.input.try_lock();
        if let Ok(shared) = &shared
            && shared.finished
            && shared.events.is_empty()
        {
            return None;
        }
        match (&mut self.rate, shared) {
            (Some(rate), shared) => {
                // The source moves the pose; the window gets it back for display.
                if let Ok(s) = &shared {
                    rate.view = s.view;
                }
                match rate.source.poll() {
                    Ok((motion, buttons)) => {
                        let mut pose = RatePose {
                            position_mm: input.position_mm,
                            orientation: input.orientation,
                        };
                        pose.step(
                            &rate.settings,
                            rate.view,
                            motion.translation,
                            motion.rotation,
                            rate.dt_s,
                        );
                        input.position_mm = pose.position_mm;
                        input.orientation = pose.orientation;
                        input.buttons = buttons;
                    }
                    Err(_) => rate.errors += 1,
                }
                if let Ok(mut s) = shared {
                    s.position_mm = input.position_mm;
                    s.orientation = input.orientation;
                    input.events = std::mem::take(&mut s.events);
                }
            }
            (None, Ok(mut s)) => {
                input.position_mm = s.position_mm;
                input.orientation = s.orientation;
                input.buttons = s.buttons;
                input.events = std::mem::take(&mut s.events);
            }
            (None, Err(_)) => {}
        }
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
    fn the_loop_takes_the_latest_pose_and_every_event_once() {
        let (mut dev, handle) = live_device(DVec3::ZERO, DQuat::IDENTITY);
        let a = dev.next(0, None).unwrap();
        assert_eq!(a.position_mm, DVec3::ZERO);
        handle.set_pose(DVec3::new(1.0, 2.0, 3.0), DQuat::IDENTITY);
        handle.send(Event::StyletRemove);
        handle.send(Event::XrayOn);
        let b = dev.next(1, None).unwrap();
        assert_eq!(b.position_mm, DVec3::new(1.0, 2.0, 3.0));
        assert_eq!(b.events, vec![Event::StyletRemove, Event::XrayOn]);
        let c = dev.next(2, None).unwrap();
        assert!(c.events.is_empty());
        handle.finish();
        assert!(dev.next(3, None).is_none());
    }

    #[test]
    fn a_busy_window_never_blocks_the_loop() {
        let (mut dev, handle) = live_device(DVec3::X, DQuat::IDENTITY);
        handle.set_pose(DVec3::Y, DQuat::IDENTITY);
        handle.send(Event::XrayOn);
        let held = handle.input.lock().unwrap();
        // The window holds the lock: the loop repeats the last pose it took, events wait.
        let t = dev.next(0, None).unwrap();
        assert_eq!(t.position_mm, DVec3::X);
        assert!(t.events.is_empty());
        drop(held);
        let t = dev.next(1, None).unwrap();
        assert_eq!(t.position_mm, DVec3::Y);
        assert_eq!(t.events, vec![Event::XrayOn]);
    }

    #[test]
    fn the_force_comes_back_to_the_window() {
        let (mut dev, handle) = live_device(DVec3::ZERO, DQuat::IDENTITY);
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
        // Full push to the right (+X 350) for one tick's report, then held (the state persists).
        let source = Recorded {
            reports: vec![vec![0x01, 0x5e, 0x01, 0, 0, 0, 0], vec![0x03, 0x01, 0x00], vec![0x7f]],
            state: Default::default(),
        };
        let (dev, handle) = live_device(DVec3::ZERO, DQuat::IDENTITY);
        let mut dev = dev.with_source(Box::new(source), RateSettings::SPACEMOUSE, 1000);
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
        }
    }
}
