//! Which input device moves which hand's tool (docs/simulator.md "Hands and devices"): the first
//! hand holds the needle (and the tools the keypad selects), the second hand, if any, a probe or
//! a finger. The choice is made in the start screen's devices dialog and remembered on this
//! machine, in the user's configuration folder beside the login (`devices.json`).
//!
//! What a machine offers is found when the window opens: the keys and mouse always; a SpaceMouse
//! or a gamepad when one is connected; the force-feedback device and the raw-HID device the
//! command line names (`--device`, `--hid-profile`). Each device moves one hand at most.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use stylet_physics::{HandTool, ProbeKind};

/// File name of the remembered assignment in the configuration directory.
pub const FILE_NAME: &str = "devices.json";

/// Largest assignment file read (bytes): a few lines of JSON.
pub const MAX_FILE_BYTES: u64 = 4096;

/// An input device that can move a tool.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum InputDevice {
    /// The window's keys and mouse (and the tablet page's commands).
    KeysAndMouse,
    /// The first connected SpaceMouse, by rate control.
    SpaceMouse,
    /// The first connected gamepad, by rate control.
    Gamepad,
    /// The force-feedback device named on the command line (`--device`).
    ForceFeedback,
    /// The raw-HID haptic device of the command line's profile (`--hid-profile`).
    HidProfile,
}

impl InputDevice {
    pub const ALL: [InputDevice; 5] = [
        InputDevice::KeysAndMouse,
        InputDevice::SpaceMouse,
        InputDevice::Gamepad,
        InputDevice::ForceFeedback,
        InputDevice::HidProfile,
    ];

    /// The device in words, for the dialog and the session's status line.
    pub fn title(self) -> &'static str {
        match self {
            InputDevice::KeysAndMouse => "keys and mouse",
            InputDevice::SpaceMouse => "SpaceMouse",
            InputDevice::Gamepad => "gamepad",
            InputDevice::ForceFeedback => "force-feedback device",
            InputDevice::HidProfile => "HID haptic device",
        }
    }
}

/// What the second hand holds when the session starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SecondHandTool {
    LinearProbe,
    /// The probe of abdominal ultrasound, the usual one for PTCD.
    #[default]
    ConvexProbe,
    Finger,
}

impl SecondHandTool {
    pub const ALL: [SecondHandTool; 3] = [
        SecondHandTool::ConvexProbe,
        SecondHandTool::LinearProbe,
        SecondHandTool::Finger,
    ];

    pub fn hand_tool(self) -> HandTool {
        match self {
            SecondHandTool::LinearProbe => HandTool::Probe(ProbeKind::Linear),
            SecondHandTool::ConvexProbe => HandTool::Probe(ProbeKind::Convex),
            SecondHandTool::Finger => HandTool::Finger,
        }
    }

    pub fn title(self) -> &'static str {
        match self {
            SecondHandTool::LinearProbe => "linear probe",
            SecondHandTool::ConvexProbe => "convex probe",
            SecondHandTool::Finger => "finger",
        }
    }
}

/// Which device moves which hand.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandAssignment {
    /// The device of the first hand: the needle, and the tools the keypad selects.
    pub needle_hand: InputDevice,
    /// The device of the second hand; `None`: one hand, tools switched in turn.
    pub probe_hand: Option<InputDevice>,
    /// What the second hand holds at the start (it can change during the session).
    #[serde(default)]
    pub probe_hand_tool: SecondHandTool,
}

/// What this machine offers besides the keys and mouse: each device's name when it is there.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Available {
    pub space_mouse: Option<String>,
    pub gamepad: Option<String>,
    pub force_feedback: Option<String>,
    pub hid_profile: Option<String>,
}

impl Available {
    /// The device's name on this machine, or why it cannot be used.
    pub fn name(&self, device: InputDevice) -> Result<String, AssignmentError> {
        let (found, why) = match device {
            InputDevice::KeysAndMouse => return Ok("keys and mouse".into()),
            InputDevice::SpaceMouse => (&self.space_mouse, "no SpaceMouse is connected"),
            InputDevice::Gamepad => (&self.gamepad, "no gamepad is connected"),
            InputDevice::ForceFeedback => (
                &self.force_feedback,
                "no force-feedback device was named (start with --device BACKEND)",
            ),
            InputDevice::HidProfile => (
                &self.hid_profile,
                "no HID device profile was given (start with --hid-profile FILE)",
            ),
        };
        found.clone().ok_or(AssignmentError::Unavailable {
            device,
            reason: why.into(),
        })
    }

    /// The SpaceMouse and gamepad connected now, with the devices the command line names.
    pub fn probe(force_feedback: Option<String>, hid_profile: Option<String>) -> Available {
        let space_mouse = stylet_devices::hid::first_spacemouse_name();
        #[cfg(feature = "gamepad")]
        let gamepad = stylet_devices::gilrs_pad::GilrsGamepad::open_first()
            .ok()
            .map(|p| p.name);
        #[cfg(not(feature = "gamepad"))]
        let gamepad = None;
        Available {
            space_mouse,
            gamepad,
            force_feedback,
            hid_profile,
        }
    }
}

/// Why an assignment cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AssignmentError {
    #[error("the {} cannot be used: {reason}", device.title())]
    Unavailable { device: InputDevice, reason: String },
    #[error("the {} cannot move both hands: choose another device for the probe hand", device.title())]
    BothHands { device: InputDevice },
}

impl HandAssignment {
    /// One hand: the first force-feedback device, HID device, SpaceMouse or gamepad there is,
    /// else the keys and mouse (what a session by hand used before devices could be assigned).
    pub fn default_for(available: &Available) -> HandAssignment {
        let needle_hand = [
            InputDevice::ForceFeedback,
            InputDevice::HidProfile,
            InputDevice::SpaceMouse,
            InputDevice::Gamepad,
        ]
        .into_iter()
        .find(|d| available.name(*d).is_ok())
        .unwrap_or(InputDevice::KeysAndMouse);
        HandAssignment {
            needle_hand,
            probe_hand: None,
            probe_hand_tool: SecondHandTool::default(),
        }
    }

    /// Checks that every device is there and each moves one hand.
    pub fn check(&self, available: &Available) -> Result<(), AssignmentError> {
        available.name(self.needle_hand)?;
        if let Some(probe) = self.probe_hand {
            if probe == self.needle_hand {
                return Err(AssignmentError::BothHands { device: probe });
            }
            available.name(probe)?;
        }
        Ok(())
    }

    /// The hand the window's keys and mouse steer, if either.
    pub fn keys_steer(&self) -> Option<Hand> {
        if self.needle_hand == InputDevice::KeysAndMouse {
            Some(Hand::Needle)
        } else if self.probe_hand == Some(InputDevice::KeysAndMouse) {
            Some(Hand::Probe)
        } else {
            None
        }
    }

    /// The assignment in words: "needle: SpaceMouse; probe: keys and mouse (convex probe)".
    pub fn describe(&self) -> String {
        match self.probe_hand {
            None => format!("one hand: {}", self.needle_hand.title()),
            Some(p) => format!(
                "needle hand: {}; probe hand: {} ({})",
                self.needle_hand.title(),
                p.title(),
                self.probe_hand_tool.title()
            ),
        }
    }
}

/// One of the two hands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hand {
    Needle,
    Probe,
}

/// Why the remembered assignment cannot be read or kept.
#[derive(Debug, thiserror::Error)]
pub enum AssignmentFileError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a Stylet device assignment: {reason}")]
    Invalid { path: PathBuf, reason: String },
}

impl HandAssignment {
    /// Reads `dir/devices.json`; `None` when there is none (never chosen on this machine).
    pub fn load(dir: &Path) -> Result<Option<HandAssignment>, AssignmentFileError> {
        let path = dir.join(FILE_NAME);
        let meta = match fs::metadata(&path) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(AssignmentFileError::Io { path, source }),
        };
        if meta.len() > MAX_FILE_BYTES {
            return Err(AssignmentFileError::Invalid {
                path,
                reason: format!("larger than {MAX_FILE_BYTES} bytes"),
            });
        }
        let text = fs::read(&path).map_err(|source| AssignmentFileError::Io {
            path: path.clone(),
            source,
        })?;
        serde_json::from_slice(&text)
            .map(Some)
            .map_err(|e| AssignmentFileError::Invalid {
                path,
                reason: e.to_string(),
            })
    }

    /// Writes `dir/devices.json`, replacing an older one atomically (a crash leaves the old one).
    pub fn save(&self, dir: &Path) -> Result<PathBuf, AssignmentFileError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| AssignmentFileError::Io { path, source }
        };
        fs::create_dir_all(dir).map_err(io(dir))?;
        let path = dir.join(FILE_NAME);
        let tmp = dir.join(format!(".{FILE_NAME}.tmp"));
        let mut f = fs::File::create(&tmp).map_err(io(&tmp))?;
        let json = serde_json::to_vec_pretty(self).expect("enums serialise");
        f.write_all(&json).map_err(io(&tmp))?;
        f.sync_all().map_err(io(&tmp))?;
        fs::rename(&tmp, &path).map_err(io(&path))?;
        Ok(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with(space_mouse: bool, force_feedback: bool) -> Available {
        Available {
            space_mouse: space_mouse.then(|| "SpaceMouse Compact".into()),
            force_feedback: force_feedback.then(|| "Touch (openhaptics)".into()),
            ..Available::default()
        }
    }

    /// Without a choice, one hand on the best device there is: what sessions by hand used.
    #[test]
    fn the_default_is_one_hand_on_the_best_device_there_is() {
        let d = |a: &Available| HandAssignment::default_for(a).needle_hand;
        assert_eq!(d(&Available::default()), InputDevice::KeysAndMouse);
        assert_eq!(d(&with(true, false)), InputDevice::SpaceMouse);
        assert_eq!(d(&with(true, true)), InputDevice::ForceFeedback);
        assert_eq!(HandAssignment::default_for(&with(true, true)).probe_hand, None);
    }

    /// A device moves one hand; a device that is not there is refused by name and reason.
    #[test]
    fn each_device_moves_one_hand_and_must_be_there() {
        let a = |needle, probe| HandAssignment {
            needle_hand: needle,
            probe_hand: probe,
            probe_hand_tool: SecondHandTool::ConvexProbe,
        };
        let both = a(InputDevice::SpaceMouse, Some(InputDevice::SpaceMouse));
        assert_eq!(
            both.check(&with(true, false)),
            Err(AssignmentError::BothHands {
                device: InputDevice::SpaceMouse
            })
        );
        let e = a(InputDevice::ForceFeedback, Some(InputDevice::KeysAndMouse))
            .check(&with(true, false))
            .unwrap_err();
        assert!(e.to_string().contains("start with --device"), "{e}");
        let e = a(InputDevice::KeysAndMouse, Some(InputDevice::SpaceMouse))
            .check(&Available::default())
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "the SpaceMouse cannot be used: no SpaceMouse is connected"
        );
        let ok = a(InputDevice::ForceFeedback, Some(InputDevice::KeysAndMouse));
        assert_eq!(ok.check(&with(false, true)), Ok(()));
        assert_eq!(ok.keys_steer(), Some(Hand::Probe));
        assert_eq!(a(InputDevice::KeysAndMouse, None).keys_steer(), Some(Hand::Needle));
        assert_eq!(
            a(InputDevice::SpaceMouse, Some(InputDevice::ForceFeedback)).keys_steer(),
            None
        );
    }

    /// The choice is kept on this machine and read back; a damaged or oversized file is refused
    /// with its path and what is wrong, and the old file survives a failed save.
    #[test]
    fn the_assignment_is_remembered_and_a_damaged_file_is_named() {
        let dir = tempfile::tempdir().unwrap();
        assert!(HandAssignment::load(dir.path()).unwrap().is_none());
        let a = HandAssignment {
            needle_hand: InputDevice::ForceFeedback,
            probe_hand: Some(InputDevice::SpaceMouse),
            probe_hand_tool: SecondHandTool::LinearProbe,
        };
        let path = a.save(dir.path()).unwrap();
        assert_eq!(HandAssignment::load(dir.path()).unwrap(), Some(a));
        let text = fs::read_to_string(&path).unwrap();
        assert!(text.contains("\"needle_hand\": \"force-feedback\""), "{text}");
        assert!(text.contains("\"probe_hand_tool\": \"linear-probe\""), "{text}");
        fs::write(&path, r#"{"needle_hand": "telepathy", "probe_hand": null}"#).unwrap();
        let e = HandAssignment::load(dir.path()).unwrap_err();
        assert!(
            e.to_string().contains("devices.json is not a Stylet device assignment"),
            "{e}"
        );
        assert!(e.to_string().contains("telepathy"), "{e}");
        fs::write(&path, vec![b' '; MAX_FILE_BYTES as usize + 1]).unwrap();
        let e = HandAssignment::load(dir.path()).unwrap_err();
        assert!(e.to_string().contains("larger than 4096 bytes"), "{e}");
    }
}
