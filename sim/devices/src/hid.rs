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

/// A SpaceMouse opened through hidapi.
pub struct HidSpaceMouse {
    device: HidDevice,
    pub model: Model,
    state: SpaceMouseState,
}

/// The connected SpaceMice Stylet knows (model and hidapi path).
pub fn connected_spacemice(api: &HidApi) -> Vec<(Model, std::ffi::CString)> {
    api.device_list()
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
                    self.state
                        .apply(self.model.family, &buf[..n])
                        .map_err(|e| SourceError(format!("{}: {e}", self.model.name)))?;
                }
                Err(e) => return Err(SourceError(format!("{}: {e}", self.model.name))),
            }
        }
        Ok((self.state.motion(&self.model), self.state.buttons))
    }
}
