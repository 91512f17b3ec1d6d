//! HID devices through hidapi (feature `hid`; hidraw on Linux, no system library needed):
//! SpaceMice as six-axis sources for the live device.
//!
//! Only the opening and reading live here; the report layouts are in [`crate::spacemouse`] and
//! tested from recorded report bytes. No SpaceMouse was at hand when this was written: it is
//! built and type-checked in CI but not yet tried with hardware.

use hidapi::{HidApi, HidDevice};

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
