//! Force Dimension DHD (omega, sigma, delta, Novint Falcon), loaded at run time from `libdhd.so`
//! or `dhd64.dll`. Signatures and constants are those of the SDK's `dhdc.h` (3.x): every call
//! names the device explicitly with id −1 (the default device); positions are metres, forces
//! newtons. The SDK has no scheduler, so the servo loop is a thread of ours at 1 kHz. On opening:
//! the force limit is read with `dhdGetMaxForce` and, where none is set (−1), set to the model's
//! nominal force with `dhdSetMaxForce`; the firmware watchdog is set to cut forces after 10 ms
//! without a command (`dhdSetWatchdog`, units of 125 µs), beside the guard's own watchdog.

use std::ffi::{CStr, c_char, c_double, c_int, c_uchar, c_uint};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use stylet_physics::glam::DVec3;

use super::library::{self, LibrarySpec};
use super::safety::{Hold, SafetyLimits};
use super::servo::{ServoCore, Shared};
use super::servo_thread::{ServoIo, ServoThread};
use super::{Backend, DeviceInfo, HapticDevice, HapticError, ServoCounts, ServoReading};

/// The default device (`char ID = -1`; `c_char` is signed or unsigned by platform, the bits are
/// the same).
#[allow(clippy::unnecessary_cast)]
const DEFAULT_DEVICE: c_char = -1i8 as c_char;
const DHD_ON: c_uchar = 1;
const DHD_OFF: c_uchar = 0;
/// `dhdSetForce`'s return when the force was scaled down to the motors' limit: not an error.
const DHD_MOTOR_SATURATED: c_int = 2;
/// `dhdErrorGetLast` when a feature is missing on this model (no firmware watchdog).
const DHD_ERROR_NOT_AVAILABLE: c_int = 6;
/// The firmware watchdog: 80 × 125 µs = 10 ms.
const WATCHDOG_UNITS: c_uchar = 80;
/// The firmware watchdog's period.
const WATCHDOG_PERIOD: std::time::Duration = std::time::Duration::from_micros(WATCHDOG_UNITS as u64 * 125);

/// Where the Force Dimension SDK installs `libdhd`.
pub const LIBRARY: LibrarySpec = LibrarySpec {
    backend: Backend::Dhd,
    names: if cfg!(windows) { &["dhd64.dll"] } else { &["libdhd.so"] },
    dirs: &[
        "/usr/lib",
        "/usr/local/lib",
        "/usr/lib/x86_64-linux-gnu",
        "/opt/forcedimension/lib",
    ],
};

/// A model's nominal force (N), from Force Dimension's and Novint's data sheets (continuous
/// force; the DHD devices are rated for it), by `dhdGetSystemType`; `None` for a type Stylet does
/// not know, which is refused rather than guessed.
pub fn nominal_force_n(system_type: c_int) -> Option<f64> {
    match system_type {
        // omega.3, omega.6 (right, left), omega.7 (right, left)
        33..=37 => Some(12.0),
        // delta.3, delta.6
        63 | 64 => Some(20.0),
        // sigma.7 (right, left) and its 33P variant (right, left)
        104..=107 => Some(20.0),
        // Novint Falcon
        60 => Some(9.0),
        _ => None,
    }
}

/// The DHD functions Stylet calls, resolved from the loaded library (kept alive beside them).
struct Api {
    open: unsafe extern "C" fn() -> c_int,
    close: unsafe extern "C" fn(c_char) -> c_int,
    get_system_type: unsafe extern "C" fn(c_char) -> c_int,
    get_system_name: unsafe extern "C" fn(c_char) -> *const c_char,
    enable_force: unsafe extern "C" fn(c_uchar, c_char) -> c_int,
    get_max_force: unsafe extern "C" fn(c_char) -> c_double,
    set_max_force: unsafe extern "C" fn(c_double, c_char) -> c_int,
    set_watchdog: unsafe extern "C" fn(c_uchar, c_char) -> c_int,
    get_position: unsafe extern "C" fn(*mut c_double, *mut c_double, *mut c_double, c_char) -> c_int,
    get_button_mask: unsafe extern "C" fn(c_char) -> c_uint,
    set_force: unsafe extern "C" fn(c_double, c_double, c_double, c_char) -> c_int,
    error_get_last: unsafe extern "C" fn() -> c_int,
    error_get_last_str: unsafe extern "C" fn() -> *const c_char,
    _library: libloading::Library,
}

impl Api {
    fn load(explicit: Option<&Path>) -> Result<(Api, PathBuf), HapticError> {
        let (lib, path) = library::load(&LIBRARY, explicit)?;
        let missing = |name: &str, e: libloading::Error| HapticError::Library {
            backend: Backend::Dhd,
            path: path.clone(),
            reason: format!("no symbol {name}: {e} (not Force Dimension's DHD library?)"),
        };
        macro_rules! sym {
            ($name:literal) => {
                // SAFETY: the symbol is looked up by its DHD name and given that function's
                // signature from dhdc.h; the library outlives the pointer (kept in this struct).
                *unsafe { lib.get(concat!($name, "\0").as_bytes()) }.map_err(|e| missing($name, e))?
            };
        }
        let api = Api {
            open: sym!("dhdOpen"),
            close: sym!("dhdClose"),
            get_system_type: sym!("dhdGetSystemType"),
            get_system_name: sym!("dhdGetSystemName"),
            enable_force: sym!("dhdEnableForce"),
            get_max_force: sym!("dhdGetMaxForce"),
            set_max_force: sym!("dhdSetMaxForce"),
            set_watchdog: sym!("dhdSetWatchdog"),
            get_position: sym!("dhdGetPosition"),
            get_button_mask: sym!("dhdGetButtonMask"),
            set_force: sym!("dhdSetForce"),
            error_get_last: sym!("dhdErrorGetLast"),
            error_get_last_str: sym!("dhdErrorGetLastStr"),
            _library: lib,
        };
        Ok((api, path))
    }

    /// The SDK's last error as a typed error of `operation`.
    fn error(&self, operation: &'static str) -> HapticError {
        // SAFETY: DHD calls with their declared signatures; the string is the library's own
        // text, copied at once.
        let (code, message) = unsafe {
            let code = (self.error_get_last)();
            let s = (self.error_get_last_str)();
            let text = if s.is_null() {
                String::new()
            } else {
                CStr::from_ptr(s).to_string_lossy().into_owned()
            };
            (code, text)
        };
        HapticError::Device {
            backend: Backend::Dhd,
            operation,
            code: code.max(0) as u32,
            message,
        }
    }

    /// `Ok` for a DHD return of 0 or more, else the SDK's error.
    fn check(&self, rc: c_int, operation: &'static str) -> Result<c_int, HapticError> {
        if rc < 0 { Err(self.error(operation)) } else { Ok(rc) }
    }
}

/// The servo thread's reads and writes.
struct DhdIo {
    api: Arc<Api>,
    /// When the last force was commanded: a longer gap than the firmware watchdog's means the
    /// device cut its forces, so they are enabled again (the guard engages afresh meanwhile).
    last_write: Option<std::time::Instant>,
}

impl ServoIo for DhdIo {
    fn read(&mut self) -> Result<(DVec3, Option<stylet_physics::glam::DMat3>, u32), HapticError> {
        let (mut x, mut y, mut z) = (0.0, 0.0, 0.0);
        // SAFETY: DHD calls with their declared signatures; three doubles we own.
        let rc = unsafe { (self.api.get_position)(&mut x, &mut y, &mut z, DEFAULT_DEVICE) };
        self.api.check(rc, "dhdGetPosition")?;
        // SAFETY: as above.
        let buttons = unsafe { (self.api.get_button_mask)(DEFAULT_DEVICE) };
        Ok((DVec3::new(x, y, z) * 1000.0, None, buttons))
    }

    fn write(&mut self, force_n: DVec3) -> Result<(), HapticError> {
        let now = std::time::Instant::now();
        if self.last_write.replace(now).is_some_and(|t| now - t > WATCHDOG_PERIOD) {
            // SAFETY: a DHD call with its declared signature.
            let rc = unsafe { (self.api.enable_force)(DHD_ON, DEFAULT_DEVICE) };
            self.api.check(rc, "dhdEnableForce")?;
        }
        // SAFETY: a DHD call with its declared signature.
        let rc = unsafe { (self.api.set_force)(force_n.x, force_n.y, force_n.z, DEFAULT_DEVICE) };
        match rc {
            DHD_MOTOR_SATURATED => Ok(()),
            rc => self.api.check(rc, "dhdSetForce").map(|_| ()),
        }
    }

    fn zero(&mut self) {
        // SAFETY: DHD calls with their declared signatures; failures here leave nothing to do
        // but disable forces, which is the next call.
        unsafe {
            (self.api.set_force)(0.0, 0.0, 0.0, DEFAULT_DEVICE);
        }
    }
}

/// An open Force Dimension device with its servo thread running.
pub struct Dhd {
    api: Arc<Api>,
    info: DeviceInfo,
    shared: Arc<Shared>,
    servo: ServoThread<DhdIo>,
    stopped: bool,
    /// Whether the firmware watchdog is on (a model without one leaves the guard's alone).
    pub firmware_watchdog: bool,
    pub library_path: PathBuf,
}

impl Dhd {
    /// Opens the default device through the library at `explicit` or on the usual paths, sets
    /// its force limit and firmware watchdog, enables forces and starts the servo loop (zero
    /// force until the guard engages).
    pub fn open(explicit: Option<&Path>) -> Result<Dhd, HapticError> {
        let (api, library_path) = Api::load(explicit)?;
        let api = Arc::new(api);
        // SAFETY: DHD calls with their declared signatures.
        let rc = unsafe { (api.open)() };
        api.check(rc, "dhdOpen")?;
        let close = |e: HapticError| {
            // SAFETY: as above.
            unsafe { (api.close)(DEFAULT_DEVICE) };
            e
        };
        // SAFETY: as above; the name is the library's own text, copied at once.
        let (system_type, model) = unsafe {
            let t = (api.get_system_type)(DEFAULT_DEVICE);
            let s = (api.get_system_name)(DEFAULT_DEVICE);
            let name = if s.is_null() {
                format!("Force Dimension device type {t}")
            } else {
                CStr::from_ptr(s).to_string_lossy().into_owned()
            };
            (t, name)
        };
        api.check(system_type, "dhdGetSystemType").map_err(close)?;
        let Some(nominal_n) = nominal_force_n(system_type) else {
            return Err(close(HapticError::Device {
                backend: Backend::Dhd,
                operation: "dhdGetSystemType",
                code: system_type as u32,
                message: format!("{model}: a model whose nominal force Stylet does not know"),
            }));
        };
        // The limit the SDK enforces: the one set (by a lab's configuration) if lower than the
        // model's nominal force, else the nominal force, set now.
        // SAFETY: as above.
        let set_limit = unsafe { (api.get_max_force)(DEFAULT_DEVICE) };
        let max_force_n = if set_limit.is_finite() && set_limit > 0.0 {
            set_limit.min(nominal_n)
        } else {
            nominal_n
        };
        // SAFETY: as above.
        let rc = unsafe { (api.set_max_force)(max_force_n, DEFAULT_DEVICE) };
        api.check(rc, "dhdSetMaxForce").map_err(close)?;
        // SAFETY: as above.
        let rc = unsafe { (api.set_watchdog)(WATCHDOG_UNITS, DEFAULT_DEVICE) };
        let firmware_watchdog = if rc < 0 {
            // SAFETY: as above.
            if unsafe { (api.error_get_last)() } == DHD_ERROR_NOT_AVAILABLE {
                false
            } else {
                return Err(close(api.error("dhdSetWatchdog")));
            }
        } else {
            true
        };
        let info = DeviceInfo {
            backend: Backend::Dhd,
            model,
            max_force_n,
            max_continuous_force_n: max_force_n,
            senses_orientation: false,
        };
        // SAFETY: as above; zero force first, then forces enabled.
        let rc = unsafe {
            (api.set_force)(0.0, 0.0, 0.0, DEFAULT_DEVICE);
            (api.enable_force)(DHD_ON, DEFAULT_DEVICE)
        };
        api.check(rc, "dhdEnableForce").map_err(close)?;
        let shared = Shared::new();
        let core = ServoCore::new(
            SafetyLimits::for_device(info.max_force_n, info.max_continuous_force_n),
            shared.clone(),
        );
        let servo = ServoThread::spawn(
            DhdIo {
                api: api.clone(),
                last_write: None,
            },
            core,
            shared.clone(),
            "dhd servo",
        )
        .map_err(|e| {
            close(HapticError::Device {
                backend: Backend::Dhd,
                operation: "starting the servo thread",
                code: 0,
                message: e.to_string(),
            })
        })?;
        Ok(Dhd {
            api,
            info,
            shared,
            servo,
            stopped: false,
            firmware_watchdog,
            library_path,
        })
    }

    /// Zero force for a few ticks, the servo thread stopped, forces disabled and the device
    /// closed. Safe to call twice.
    fn stop(&mut self) {
        if self.stopped {
            return;
        }
        self.stopped = true;
        self.shared.set_hold(Hold::Stopping);
        self.shared.wait_ticks(2, Duration::from_millis(50));
        if let Some(mut io) = self.servo.stop() {
            io.zero();
        }
        // SAFETY: DHD calls with their declared signatures.
        unsafe {
            (self.api.set_force)(0.0, 0.0, 0.0, DEFAULT_DEVICE);
            (self.api.enable_force)(DHD_OFF, DEFAULT_DEVICE);
            (self.api.close)(DEFAULT_DEVICE);
        }
    }
}

impl HapticDevice for Dhd {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn reading(&self) -> Option<ServoReading> {
        self.shared.readings.latest()
    }

    fn set_force(&self, force_n: DVec3) {
        self.shared.put_force(force_n);
    }

    fn set_hold(&self, hold: Hold) {
        self.shared.set_hold(hold);
    }

    fn counts(&self) -> ServoCounts {
        self.shared.counts()
    }

    fn interval_p99_ms(&self) -> f64 {
        self.shared.interval_percentile_ms(0.99)
    }

    fn fault(&self) -> Option<HapticError> {
        self.shared.fault.get().cloned()
    }

    fn close(mut self: Box<Self>) -> Result<ServoCounts, HapticError> {
        self.stop();
        let counts = self.shared.counts();
        match self.shared.fault.get() {
            Some(e) => Err(e.clone()),
            None => Ok(counts),
        }
    }
}

impl Drop for Dhd {
    /// Zero force, the thread stopped and the device closed however the device goes.
    fn drop(&mut self) {
        self.stop();
    }
}
