//! HID devices through hidapi (feature `hid`; hidraw on Linux, no system library needed):
//! SpaceMice as six-axis sources for the live device, and raw-HID haptic devices described by a
//! profile as its pose sources (with force output).
//!
//! Only the opening and reading live here; the report layouts are in [`crate::spacemouse`] and
//! tested from recorded report bytes. No SpaceMouse was at hand when this was written: it is
//! built and type-checked in CI but not yet tried with hardware.

use hidapi::{HidApi, HidDevice};

use stylet_physics::glam::{DQuat, DVec3};

use crate::live::{SixAxisSource, SourceError};
use crate::spacemouse::{Model, Motion6, SpaceMouseState, find_model};

/// Most reports taken from the device in one poll (a tick); the rest wait for the next.
const MAX_REPORTS_PER_POLL: usize = 32;
/// A deflected SpaceMouse repeats its reports every ≈ 16 ms; with none for this long (a wireless
/// link lost) the deflection counts as zero, so the tool does not run on by itself.
const STALE_AFTER: std::time::Duration = std::time::Duration::from_millis(250);
/// HID usage of six-axis controllers (Generic Desktop page, Multi-axis Controller); a receiver
/// exposes other interfaces too (keyboard, vendor) that must not be opened instead.
const USAGE_PAGE_GENERIC_DESKTOP: u16 = 0x01;
const USAGE_MULTI_AXIS: u16 = 0x08;

/// A SpaceMouse opened through hidapi.
pub struct HidSpaceMouse {
    device: HidDevice,
    pub model: Model,
    state: SpaceMouseState,
    last_report: std::time::Instant,
}

/// The connected SpaceMice Stylet knows (model and hidapi path).
pub fn connected_spacemice(api: &HidApi) -> Vec<(Model, std::ffi::CString)> {
    api.device_list()
        .filter(|d| d.usage_page() == USAGE_PAGE_GENERIC_DESKTOP && d.usage() == USAGE_MULTI_AXIS)
        .filter_map(|d| find_model(d.vendor_id(), d.product_id()).map(|m| (m, d.path().to_owned())))
        .collect()
}

/// The model of the first connected SpaceMouse Stylet knows, if any (nothing is opened).
pub fn first_spacemouse_name() -> Option<String> {
    let api = HidApi::new().ok()?;
    connected_spacemice(&api).first().map(|(m, _)| m.name.to_string())
}

impl HidSpaceMouse {
    /// Opens the first connected SpaceMouse Stylet knows.
    pub fn open_first() -> Result<HidSpaceMouse, SourceError> {
        let api = HidApi::new().map_err(|e| SourceError(format!("cannot use HID devices: {e}")))?;
        let Some((model, path)) = connected_spacemice(&api).into_iter().next() else {
            return Err(SourceError(
                "no SpaceMouse found (on Linux, check read access to /dev/hidraw*: a udev rule for vendor 046d or 256f)"
                    .into(),
            ));
        };
        let device = api
            .open_path(&path)
            .map_err(|e| SourceError(format!("cannot open the {}: {e}", model.name)))?;
        device
            .set_blocking_mode(false)
            .map_err(|e| SourceError(format!("{}: {e}", model.name)))?;
        Ok(HidSpaceMouse {
            device,
            model,
            state: SpaceMouseState::default(),
            last_report: std::time::Instant::now(),
        })
    }
}

impl SixAxisSource for HidSpaceMouse {
    fn poll(&mut self) -> Result<(Motion6, u32), SourceError> {
        let mut buf = [0u8; 64];
        for _ in 0..MAX_REPORTS_PER_POLL {
            match self.device.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    self.last_report = std::time::Instant::now();
                    self.state
                        .apply(self.model.family, &buf[..n])
                        .map_err(|e| SourceError(format!("{}: {e}", self.model.name)))?;
                }
                Err(e) => return Err(SourceError(format!("{}: {e}", self.model.name))),
            }
        }
        if self.last_report.elapsed() > STALE_AFTER {
            self.state.translation = [0; 3];
            self.state.rotation = [0; 3];
        }
        Ok((self.state.motion(&self.model), self.state.buttons))
    }
}

/// A raw-HID device described by a profile (`hid_profile`): its input reports move the tool,
/// its output report displays the force. Reads never wait; the latest report of a tick wins.
pub struct HidProfileDevice {
    device: HidDevice,
    pub profile: crate::hid_profile::HidProfile,
    last: Option<crate::hid_profile::HidSample>,
    last_report: std::time::Instant,
}

impl HidProfileDevice {
    /// Opens the first connected device with the profile's vendor and product ids.
    pub fn open(profile: crate::hid_profile::HidProfile) -> Result<HidProfileDevice, SourceError> {
        let api = HidApi::new().map_err(|e| SourceError(format!("cannot use HID devices: {e}")))?;
        let device = api.open(profile.vendor_id, profile.product_id).map_err(|e| {
            SourceError(format!(
                "cannot open '{}' ({:04x}:{:04x}): {e} (is it connected, and may this user read /dev/hidraw*?)",
                profile.name, profile.vendor_id, profile.product_id
            ))
        })?;
        device
            .set_blocking_mode(false)
            .map_err(|e| SourceError(format!("{}: {e}", profile.name)))?;
        Ok(HidProfileDevice {
            device,
            profile,
            last: None,
            last_report: std::time::Instant::now(),
        })
    }
}

impl crate::live::PoseSource for HidProfileDevice {
    fn poll(&mut self) -> Result<(DVec3, Option<DQuat>, u32), SourceError> {
        let mut buf = [0u8; crate::hid_profile::MAX_REPORT_BYTES as usize];
        for _ in 0..MAX_REPORTS_PER_POLL {
            match self.device.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    // Other reports (not the profile's input report) are skipped.
                    if let Ok(sample) = self.profile.decode(&buf[..n]) {
                        self.last = Some(sample);
                        self.last_report = std::time::Instant::now();
                    }
                }
                Err(e) => return Err(SourceError(format!("{}: {e}", self.profile.name))),
            }
        }
        match &self.last {
            Some(s) if self.last_report.elapsed() <= STALE_AFTER * 4 => Ok((s.position_mm, s.orientation, s.buttons)),
            Some(_) => Err(SourceError(format!("{}: no report for a second", self.profile.name))),
            None => Err(SourceError(format!("{}: no report yet", self.profile.name))),
        }
    }

    fn display(&mut self, force_n: DVec3) -> Result<(), SourceError> {
        match self.profile.encode_force(force_n) {
            Some(report) => self
                .device
                .write(&report)
                .map(|_| ())
                .map_err(|e| SourceError(format!("{}: {e}", self.profile.name))),
            None => Ok(()),
        }
    }
}
