//! A force-feedback device as the simulator's pose source (docs/devices.md "Workspace mapping"):
//! the vendor's frame turned into Stylet's device frame (x right, y away from the user, z up; the
//! live device then turns that into the view), the stylus' orientation into the tool's (its axis
//! pointing where the stylus tip points), a scale from the device's workspace to the tool's, and a
//! clutch: while its button is held the tool stays where it is and the hand may reposition the
//! stylus ("indexing"); forces are held at zero meanwhile and ramp in again after.

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

use stylet_physics::glam::{DMat3, DQuat, DVec3};

use super::safety::Hold;
use super::{Backend, HapticDevice};
use crate::live::{PoseSource, SourceError};

/// The vendor's axes in Stylet's device frame (x right, y away from the user, z up): the columns
/// are where the vendor's x, y and z point.
pub fn vendor_axes(backend: Backend) -> DMat3 {
    match backend {
        // OpenHaptics: x right, y up, z toward the user.
        Backend::OpenHaptics => DMat3::from_cols(DVec3::X, DVec3::Z, DVec3::NEG_Y),
        // Force Dimension: x toward the user, y right, z up.
        Backend::Dhd => DMat3::from_cols(DVec3::NEG_Y, DVec3::X, DVec3::Z),
        // Haply Inverse3 (its device frame as the Inverse Service reports it): x right, y away
        // from the user, z up.
        Backend::Haply => DMat3::IDENTITY,
    }
}

/// How the device's workspace maps to the tool's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mapping {
    /// Tool millimetres per device millimetre (1: the hand moves the needle as far as it moves).
    pub scale: f64,
    /// The button bit that clutches (bit 1: the stylus' second button).
    pub clutch_button: u32,
}

impl Default for Mapping {
    fn default() -> Self {
        Mapping {
            scale: 1.0,
            clutch_button: 1 << 1,
        }
    }
}

/// The window's reason to hold forces at zero (paused, out of focus), shared with the loop that
/// owns the device: the window sets it, the device's pose source applies it on its next poll
/// (within a haptic tick; if that loop stalls, the servo loop's watchdog zeroes the force).
#[derive(Debug, Clone, Default)]
pub struct WindowHold(Arc<AtomicU8>);

impl WindowHold {
    pub fn set(&self, hold: Hold) {
        let v = match hold {
            Hold::Paused => 1,
            Hold::FocusLost => 2,
            // The window has no other reasons: the clutch and stopping belong to the device.
            Hold::None | Hold::Clutched | Hold::Calibrating | Hold::Stopping => 0,
        };
        self.0.store(v, Ordering::Release);
    }

    pub fn get(&self) -> Hold {
        match self.0.load(Ordering::Acquire) {
            1 => Hold::Paused,
            2 => Hold::FocusLost,
            _ => Hold::None,
        }
    }
}

/// An open force-feedback device moving the tool.
pub struct HapticPose {
    device: Box<dyn HapticDevice>,
    axes: DMat3,
    mapping: Mapping,
    /// Added to the scaled device position, and turned before the stylus' orientation: what
    /// clutching has shifted.
    offset_mm: DVec3,
    turn: DQuat,
    /// The pose reported while the clutch is held.
    clutched_at: Option<(DVec3, Option<DQuat>)>,
    last: Option<(DVec3, Option<DQuat>)>,
    window_hold: WindowHold,
    /// The hold last given to the device.
    applied: Hold,
    /// Lines for the session's notes, taken by [`PoseSource::notes`].
    notes: Vec<String>,
    /// The guard's counts as last noted, and polls since.
    noted_counts: super::ServoCounts,
    polls_since_counts: u32,
    fault_noted: bool,
    /// The device's calibration as last noted.
    noted_calibration: super::Calibration,
    /// The force of the latest reading, turned into Stylet's device frame.
    last_force: Option<super::Guarded>,
}

/// How often the force guard's counts are compared for a note (polls: a second at 1 kHz).
const COUNTS_EVERY_POLLS: u32 = 1000;

impl HapticPose {
    pub fn new(device: Box<dyn HapticDevice>, mapping: Mapping) -> Self {
        let axes = vendor_axes(device.info().backend);
        let mapped = format!(
            "device mapping: {} tool mm per device mm; clutch: button bit {}",
            mapping.scale,
            mapping.clutch_button.trailing_zeros()
        );
        HapticPose {
            device,
            axes,
            mapping,
            offset_mm: DVec3::ZERO,
            turn: DQuat::IDENTITY,
            clutched_at: None,
            last: None,
            window_hold: WindowHold::default(),
            applied: Hold::None,
            notes: vec![mapped],
            noted_counts: super::ServoCounts::default(),
            polls_since_counts: 0,
            fault_noted: false,
            noted_calibration: super::Calibration::default(),
            last_force: None,
        }
    }

    /// A note when the device's calibration changed: it asks for the hand, or was calibrated.
    fn note_calibration(&mut self) {
        let (now, then) = (self.device.calibration(), self.noted_calibration);
        if now == then {
            return;
        }
        if now.needs_manual_input && !then.needs_manual_input {
            self.notes
                .push("calibration: put the stylus in its inkwell (forces held until calibrated)".into());
        }
        if now.updates > then.updates {
            self.notes
                .push(format!("calibration: updated ({} so far)", now.updates));
        }
        self.noted_calibration = now;
    }

    /// A note when the force guard acted since the last one (at most one a second).
    fn note_counts(&mut self) {
        self.polls_since_counts += 1;
        if self.polls_since_counts < COUNTS_EVERY_POLLS {
            return;
        }
        self.polls_since_counts = 0;
        let (now, then) = (self.device.counts(), self.noted_counts);
        let (g, h) = (now.guard, then.guard);
        if g != h || now.recoverable_errors != then.recoverable_errors {
            self.notes.push(format!(
                "force guard since the last note: clamped to the maximum {} ticks, to the continuous limit {}; watchdog fired {} times; {} recoverable device errors",
                g.clamped - h.clamped,
                g.continuous - h.continuous,
                g.watchdog_trips - h.watchdog_trips,
                now.recoverable_errors - then.recoverable_errors
            ));
        }
        self.noted_counts = now;
    }

    /// The switch through which the window holds forces (pause, focus).
    pub fn window_hold(&self) -> WindowHold {
        self.window_hold.clone()
    }

    pub fn device(&self) -> &dyn HapticDevice {
        self.device.as_ref()
    }

    /// Whether the clutch is held now.
    pub fn clutched(&self) -> bool {
        self.clutched_at.is_some()
    }

    /// Closes the device (zero force, servo loop stopped).
    pub fn close(self) -> Result<super::ServoCounts, super::HapticError> {
        self.device.close()
    }

    /// The stylus' orientation as the tool's: the tool axis (+z) along the stylus tip, which
    /// points along the vendor's −z in the stylus frame.
    fn tool_orientation(&self, stylus: DMat3) -> Option<DQuat> {
        let m = self.axes * stylus * DMat3::from_rotation_x(std::f64::consts::PI);
        let q = DQuat::from_mat3(&m);
        (q.is_finite() && (q.length() - 1.0).abs() < 1e-3).then(|| q.normalize())
    }
}

impl PoseSource for HapticPose {
    fn poll(&mut self) -> Result<(DVec3, Option<DQuat>, u32), SourceError> {
        if let Some(e) = self.device.fault() {
            if !self.fault_noted {
                self.fault_noted = true;
                self.notes.push(format!("force output stopped: {e}"));
            }
            return Err(SourceError(e.to_string()));
        }
        self.note_counts();
        self.note_calibration();
        let Some(r) = self.device.reading() else {
            return Err(SourceError(format!(
                "{}: no servo tick yet",
                self.device.info().backend
            )));
        };
        self.last_force = Some(super::Guarded {
            computed_n: self.axes * r.force.computed_n,
            sent_n: self.axes * r.force.sent_n,
            limits: r.force.limits,
        });
        let raw_mm = self.axes * r.position_mm * self.mapping.scale;
        let raw_q = r.rotation.and_then(|m| self.tool_orientation(m));
        let held = r.buttons & self.mapping.clutch_button != 0;
        let pose = match (held, self.clutched_at) {
            (true, None) => {
                let at = self
                    .last
                    .unwrap_or((raw_mm + self.offset_mm, raw_q.map(|q| self.turn * q)));
                self.clutched_at = Some(at);
                at
            }
            (true, Some(at)) => at,
            (false, Some(at)) => {
                // Released: the tool continues from where it stayed.
                self.offset_mm = at.0 - raw_mm;
                if let (Some(stayed), Some(q)) = (at.1, raw_q) {
                    self.turn = (stayed * q.inverse()).normalize();
                }
                self.clutched_at = None;
                at
            }
            (false, None) => (raw_mm + self.offset_mm, raw_q.map(|q| (self.turn * q).normalize())),
        };
        self.last = Some(pose);
        let hold = match self.window_hold.get() {
            Hold::None if self.clutched_at.is_some() => Hold::Clutched,
            window => window,
        };
        if hold != self.applied {
            self.device.set_hold(hold);
            self.notes.push(
                match hold {
                    Hold::Clutched => "clutch held: the tool stays while the hand repositions; no force",
                    Hold::FocusLost => "forces held: the window lost the focus",
                    Hold::Paused => "forces held: paused",
                    Hold::Stopping => "forces held: the device is closing",
                    Hold::Calibrating => "forces held: the device is calibrating",
                    Hold::None => "forces flow again (they ramp in over a second)",
                }
                .to_string(),
            );
            self.applied = hold;
        }
        Ok((pose.0, pose.1, r.buttons))
    }

    fn display(&mut self, force_n: DVec3) -> Result<(), SourceError> {
        if let Some(e) = self.device.fault() {
            return Err(SourceError(e.to_string()));
        }
        // Stylet's device frame back to the vendor's (the axes are orthonormal: the transpose
        // inverts them).
        self.device.set_force(self.axes.transpose() * force_n);
        Ok(())
    }

    fn notes(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notes)
    }

    fn device_force(&self) -> Option<super::Guarded> {
        self.last_force
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use super::*;
    use crate::haptic::safety::{Guarded, Limits};
    use crate::haptic::{DeviceInfo, HapticError, ServoCounts, ServoReading};

    /// What the fake device was told, and the reading it gives.
    #[derive(Default)]
    struct Seen {
        position_mm: DVec3,
        rotation: Option<DMat3>,
        buttons: u32,
        force_n: DVec3,
        holds: Vec<Hold>,
        calibration: crate::haptic::Calibration,
    }

    struct Fake {
        info: DeviceInfo,
        seen: Arc<Mutex<Seen>>,
    }

    impl HapticDevice for Fake {
        fn info(&self) -> &DeviceInfo {
            &self.info
        }
        fn reading(&self) -> Option<ServoReading> {
            let s = self.seen.lock().unwrap();
            Some(ServoReading {
                tick: 0,
                time_s: 0.0,
                position_mm: s.position_mm,
                rotation: s.rotation,
                buttons: s.buttons,
                force: Guarded {
                    computed_n: DVec3::ZERO,
                    sent_n: DVec3::ZERO,
                    limits: Limits::default(),
                },
            })
        }
        fn set_force(&self, force_n: DVec3) {
            self.seen.lock().unwrap().force_n = force_n;
        }
        fn set_hold(&self, hold: Hold) {
            self.seen.lock().unwrap().holds.push(hold);
        }
        fn counts(&self) -> ServoCounts {
            ServoCounts::default()
        }
        fn interval_p99_ms(&self) -> f64 {
            1.0
        }
        fn fault(&self) -> Option<HapticError> {
            None
        }
        fn calibration(&self) -> crate::haptic::Calibration {
            self.seen.lock().unwrap().calibration
        }
        fn close(self: Box<Self>) -> Result<ServoCounts, HapticError> {
            Ok(ServoCounts::default())
        }
    }

    fn fake(backend: Backend) -> (HapticPose, Arc<Mutex<Seen>>) {
        let seen = Arc::new(Mutex::new(Seen::default()));
        let info = DeviceInfo {
            backend,
            model: "fake".into(),
            max_force_n: 3.3,
            max_continuous_force_n: 0.9,
            senses_orientation: true,
        };
        let device = Fake {
            info,
            seen: Arc::clone(&seen),
        };
        (HapticPose::new(Box::new(device), Mapping::default()), seen)
    }

    fn close(a: DVec3, b: DVec3) -> bool {
        (a - b).length() < 1e-9
    }

    #[test]
    fn each_vendor_frame_turns_into_right_away_up_and_forces_turn_back() {
        // (backend, the vendor's "up", the vendor's "toward the user")
        for (backend, up, toward) in [
            (Backend::OpenHaptics, DVec3::Y, DVec3::Z),
            (Backend::Dhd, DVec3::Z, DVec3::X),
        ] {
            let (mut pose, seen) = fake(backend);
            seen.lock().unwrap().position_mm = up * 10.0 + toward * 4.0;
            let (p, _, _) = pose.poll().unwrap();
            assert!(close(p, DVec3::new(0.0, -4.0, 10.0)), "{backend}: {p}");
            pose.display(DVec3::new(0.0, 0.0, 2.0)).unwrap();
            let f = seen.lock().unwrap().force_n;
            assert!(
                close(f, up * 2.0),
                "{backend}: an upward force is the vendor's up, not {f}"
            );
        }
    }

    #[test]
    fn the_tool_points_where_the_stylus_tip_points() {
        let (mut pose, seen) = fake(Backend::OpenHaptics);
        // The stylus at rest: its tip along the vendor's −z, away from the user.
        seen.lock().unwrap().rotation = Some(DMat3::IDENTITY);
        let (_, q, _) = pose.poll().unwrap();
        let axis = q.unwrap() * DVec3::Z;
        assert!(close(axis, DVec3::Y), "{axis}");
        // Tipped down by 90° about the vendor's x: the tip points down.
        seen.lock().unwrap().rotation = Some(DMat3::from_rotation_x(-std::f64::consts::FRAC_PI_2));
        let (_, q, _) = pose.poll().unwrap();
        let axis = q.unwrap() * DVec3::Z;
        assert!(close(axis, DVec3::NEG_Z), "{axis}");
    }

    #[test]
    fn the_clutch_keeps_the_tool_still_while_the_hand_moves_and_holds_the_force() {
        let (mut pose, seen) = fake(Backend::Haply);
        let clutch = Mapping::default().clutch_button;
        seen.lock().unwrap().position_mm = DVec3::new(5.0, 0.0, 0.0);
        assert!(close(pose.poll().unwrap().0, DVec3::new(5.0, 0.0, 0.0)));
        // Clutch held, hand moves 40 mm back: the tool stays, forces are held at zero.
        {
            let mut s = seen.lock().unwrap();
            s.buttons = clutch;
            s.position_mm = DVec3::new(5.0, -40.0, 0.0);
        }
        assert!(close(pose.poll().unwrap().0, DVec3::new(5.0, 0.0, 0.0)));
        assert!(pose.clutched());
        assert_eq!(seen.lock().unwrap().holds, [Hold::Clutched]);
        // Released and moved 3 mm forward: the tool moves 3 mm on from where it stayed.
        seen.lock().unwrap().buttons = 0;
        assert!(close(pose.poll().unwrap().0, DVec3::new(5.0, 0.0, 0.0)));
        seen.lock().unwrap().position_mm = DVec3::new(5.0, -37.0, 0.0);
        assert!(close(pose.poll().unwrap().0, DVec3::new(5.0, 3.0, 0.0)));
        assert_eq!(seen.lock().unwrap().holds, [Hold::Clutched, Hold::None]);
        let notes = pose.notes();
        assert_eq!(notes.len(), 3, "{notes:?}");
        assert!(notes[0].starts_with("device mapping: 1 tool mm per device mm; clutch: button bit 1"));
        assert!(notes[1].starts_with("clutch held") && notes[2].starts_with("forces flow again"));
        assert!(pose.notes().is_empty(), "taken once");
    }

    #[test]
    fn the_window_hold_wins_over_the_clutch_and_is_applied_once() {
        let (mut pose, seen) = fake(Backend::Haply);
        let window = pose.window_hold();
        window.set(Hold::FocusLost);
        pose.poll().unwrap();
        pose.poll().unwrap();
        seen.lock().unwrap().buttons = Mapping::default().clutch_button;
        pose.poll().unwrap();
        window.set(Hold::None);
        pose.poll().unwrap();
        seen.lock().unwrap().buttons = 0;
        pose.poll().unwrap();
        assert_eq!(
            seen.lock().unwrap().holds,
            [Hold::FocusLost, Hold::Clutched, Hold::None]
        );
    }

    #[test]
    fn calibration_asking_for_the_hand_and_updates_are_noted_once() {
        let (mut pose, seen) = fake(Backend::OpenHaptics);
        pose.poll().unwrap();
        assert_eq!(pose.notes().len(), 1, "the mapping");
        seen.lock().unwrap().calibration.needs_manual_input = true;
        pose.poll().unwrap();
        pose.poll().unwrap();
        let notes = pose.notes();
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(notes[0].contains("inkwell"));
        seen.lock().unwrap().calibration = crate::haptic::Calibration {
            needs_manual_input: false,
            updates: 1,
        };
        pose.poll().unwrap();
        assert_eq!(pose.notes(), ["calibration: updated (1 so far)"]);
    }
}
