//! 3D Systems OpenHaptics HD API (Touch, Touch X, Phantom Premium), loaded at run time from
//! `libHD.so` (often only as `libHD.so.3.x.y`) or `hd.dll`. Constants and signatures are those of
//! OpenHaptics 3 `hdDefines.h`, `hdDevice.h` and `hdScheduler.h`: the device opens with
//! `hdInitDevice(HD_DEFAULT_DEVICE)`, forces are enabled with `hdEnable(HD_FORCE_OUTPUT)`, and the
//! servo loop is a callback the HD scheduler runs at 1 kHz at the highest priority, reading the
//! pose and writing the force between `hdBeginFrame` and `hdEndFrame`.

use std::ffi::{CStr, c_char, c_int, c_uint, c_ulong, c_ushort, c_void};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use stylet_physics::glam::{DMat3, DVec3};

use super::library::{self, LibrarySpec};
use super::safety::{Hold, SafetyLimits};
use super::servo::{ServoCore, Shared};
use super::{Backend, DeviceInfo, HapticDevice, HapticError, ServoCounts, ServoReading};

/// `HHD`: a device handle.
type Hhd = c_uint;
/// `HD_INVALID_HANDLE`.
const HD_INVALID_HANDLE: Hhd = 0xFFFF_FFFF;

// Get parameters (hdDefines.h).
const HD_CURRENT_BUTTONS: c_uint = 0x2000;
const HD_CURRENT_POSITION: c_uint = 0x2050;
const HD_CURRENT_TRANSFORM: c_uint = 0x2052;
const HD_DEVICE_MODEL_TYPE: c_uint = 0x2501;
const HD_NOMINAL_MAX_FORCE: c_uint = 0x2603;
const HD_NOMINAL_MAX_CONTINUOUS_FORCE: c_uint = 0x2604;
// Set parameter and capability.
const HD_CALIBRATION_STYLE: c_uint = 0x2555;
const HD_CURRENT_FORCE: c_uint = 0x2700;
const HD_CALIBRATION_OK: c_uint = 0x5000;
const HD_CALIBRATION_NEEDS_UPDATE: c_uint = 0x5001;
const HD_CALIBRATION_NEEDS_MANUAL_INPUT: c_uint = 0x5002;
const HD_CALIBRATION_ENCODER_RESET: c_int = 1 << 0;
const HD_CALIBRATION_AUTO: c_int = 1 << 1;
const HD_CALIBRATION_INKWELL: c_int = 1 << 2;
/// How often the servo loop asks the device whether it is calibrated (ticks: half a second).
const CALIBRATION_CHECK_TICKS: u64 = 500;
const HD_FORCE_OUTPUT: c_uint = 0x4000;
// Errors that leave the device usable: counted and shown.
const HD_WARM_MOTORS: c_uint = 0x0200;
const HD_EXCEEDED_MAX_FORCE: c_uint = 0x0201;
const HD_EXCEEDED_MAX_FORCE_IMPULSE: c_uint = 0x0202;
const HD_EXCEEDED_MAX_VELOCITY: c_uint = 0x0203;
// Scheduler.
const HD_CALLBACK_DONE: c_uint = 0;
const HD_CALLBACK_CONTINUE: c_uint = 1;
const HD_MAX_SCHEDULER_PRIORITY: c_ushort = c_ushort::MAX;

/// `HDErrorInfo`, returned by value from `hdGetError`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
struct HdErrorInfo {
    error_code: c_uint,
    internal_error_code: c_int,
    hhd: Hhd,
}

/// `HDSchedulerCallback`.
type SchedulerCallback = unsafe extern "system" fn(*mut c_void) -> c_uint;

/// Where OpenHaptics installs `libHD`.
pub const LIBRARY: LibrarySpec = LibrarySpec {
    backend: Backend::OpenHaptics,
    names: if cfg!(windows) { &["hd.dll"] } else { &["libHD.so"] },
    dirs: &[
        "/usr/lib",
        "/usr/lib64",
        "/usr/local/lib",
        "/usr/lib/x86_64-linux-gnu",
        "/opt/OpenHaptics/lib",
    ],
};

/// The HD functions Stylet calls, resolved from the loaded library (kept alive beside them).
struct Api {
    init_device: unsafe extern "system" fn(*const c_char) -> Hhd,
    disable_device: unsafe extern "system" fn(Hhd),
    enable: unsafe extern "system" fn(c_uint),
    begin_frame: unsafe extern "system" fn(Hhd),
    end_frame: unsafe extern "system" fn(Hhd),
    get_doublev: unsafe extern "system" fn(c_uint, *mut f64),
    get_integerv: unsafe extern "system" fn(c_uint, *mut c_int),
    set_doublev: unsafe extern "system" fn(c_uint, *const f64),
    get_string: unsafe extern "system" fn(c_uint) -> *const c_char,
    get_error: unsafe extern "system" fn() -> HdErrorInfo,
    get_error_string: unsafe extern "system" fn(c_uint) -> *const c_char,
    schedule_asynchronous: unsafe extern "system" fn(SchedulerCallback, *mut c_void, c_ushort) -> c_ulong,
    start_scheduler: unsafe extern "system" fn(),
    stop_scheduler: unsafe extern "system" fn(),
    unschedule: unsafe extern "system" fn(c_ulong),
    check_calibration: unsafe extern "system" fn() -> c_uint,
    update_calibration: unsafe extern "system" fn(c_uint),
    _library: libloading::Library,
}

impl Api {
    fn load(explicit: Option<&Path>) -> Result<(Api, PathBuf), HapticError> {
        let (lib, path) = library::load(&LIBRARY, explicit)?;
        let missing = |name: &str, e: libloading::Error| HapticError::Library {
            backend: Backend::OpenHaptics,
            path: path.clone(),
            reason: format!("no symbol {name}: {e} (not the OpenHaptics HD library?)"),
        };
        macro_rules! sym {
            ($name:literal) => {
                // SAFETY: the symbol is looked up by its HD API name and given that function's
                // signature from the OpenHaptics headers; the library outlives the pointer
                // (it is kept in the same struct).
                *unsafe { lib.get(concat!($name, "\0").as_bytes()) }.map_err(|e| missing($name, e))?
            };
        }
        let api = Api {
            init_device: sym!("hdInitDevice"),
            disable_device: sym!("hdDisableDevice"),
            enable: sym!("hdEnable"),
            begin_frame: sym!("hdBeginFrame"),
            end_frame: sym!("hdEndFrame"),
            get_doublev: sym!("hdGetDoublev"),
            get_integerv: sym!("hdGetIntegerv"),
            set_doublev: sym!("hdSetDoublev"),
            get_string: sym!("hdGetString"),
            get_error: sym!("hdGetError"),
            get_error_string: sym!("hdGetErrorString"),
            schedule_asynchronous: sym!("hdScheduleAsynchronous"),
            start_scheduler: sym!("hdStartScheduler"),
            stop_scheduler: sym!("hdStopScheduler"),
            unschedule: sym!("hdUnschedule"),
            check_calibration: sym!("hdCheckCalibration"),
            update_calibration: sym!("hdUpdateCalibration"),
            _library: lib,
        };
        Ok((api, path))
    }

    /// The oldest pending error, if any.
    fn error(&self) -> Option<(c_uint, String)> {
        // SAFETY: HD API calls with their declared signatures; the string is the library's own
        // static text, copied at once.
        unsafe {
            let e = (self.get_error)();
            if e.error_code == 0 {
                return None;
            }
            let s = (self.get_error_string)(e.error_code);
            let text = if s.is_null() {
                String::new()
            } else {
                CStr::from_ptr(s).to_string_lossy().into_owned()
            };
            Some((e.error_code, format!("{text} (device error {})", e.internal_error_code)))
        }
    }

    fn check(&self, operation: &'static str) -> Result<(), HapticError> {
        match self.error() {
            None => Ok(()),
            Some((code, message)) => Err(HapticError::Device {
                backend: Backend::OpenHaptics,
                operation,
                code,
                message,
            }),
        }
    }
}

/// Whether an HD error leaves the device usable (forces continue, the error is counted).
fn recoverable(code: c_uint) -> bool {
    matches!(
        code,
        HD_WARM_MOTORS | HD_EXCEEDED_MAX_FORCE | HD_EXCEEDED_MAX_FORCE_IMPULSE | HD_EXCEEDED_MAX_VELOCITY
    )
}

/// The calibration style to ask for among those the device supports (`HD_CALIBRATION_STYLE`):
/// automatic, else the inkwell, else an encoder reset, as OpenHaptics' calibration example
/// prefers them; `None` for a device that names none.
fn calibration_style(supported: c_int) -> Option<c_uint> {
    [
        HD_CALIBRATION_AUTO,
        HD_CALIBRATION_INKWELL,
        HD_CALIBRATION_ENCODER_RESET,
    ]
    .into_iter()
    .find(|s| supported & s != 0)
    .map(|s| s as c_uint)
}

/// The device's calibration as the servo loop last found it, for the other threads.
#[derive(Default)]
struct CalibrationState {
    needs_manual_input: AtomicBool,
    updates: AtomicU64,
}

/// What the HD scheduler's callback owns.
struct Callback {
    api: Arc<Api>,
    hhd: Hhd,
    core: ServoCore,
    shared: Arc<Shared>,
    /// The style `hdUpdateCalibration` is asked for.
    calibration_style: Option<c_uint>,
    calibration: Arc<CalibrationState>,
    /// `hdCheckCalibration`'s last answer, and ticks since the callback started.
    calibration_status: c_uint,
    ticks: u64,
}

impl Callback {
    /// One servo tick inside an HD frame.
    fn tick(&mut self) -> c_uint {
        let api = &self.api;
        let (mut position, mut transform, mut buttons) = ([0.0f64; 3], [0.0f64; 16], 0 as c_int);
        // SAFETY: HD API calls with their declared signatures, each buffer as long as the
        // parameter it receives (3 doubles, 16 doubles, one int).
        unsafe {
            (api.begin_frame)(self.hhd);
            if self.ticks.is_multiple_of(CALIBRATION_CHECK_TICKS) {
                self.calibration_status = (api.check_calibration)();
            }
            (api.get_doublev)(HD_CURRENT_POSITION, position.as_mut_ptr());
            (api.get_doublev)(HD_CURRENT_TRANSFORM, transform.as_mut_ptr());
            (api.get_integerv)(HD_CURRENT_BUTTONS, &mut buttons);
        }
        // The transform is column-major: its first three columns' first three rows are the
        // stylus' rotation.
        let col = |c: usize| DVec3::new(transform[4 * c], transform[4 * c + 1], transform[4 * c + 2]);
        let rotation = DMat3::from_cols(col(0), col(1), col(2));
        // Positions of an uncalibrated device cannot be trusted: no force until it is.
        let device_hold = (self.calibration_status != HD_CALIBRATION_OK).then_some(Hold::Calibrating);
        let sent = self
            .core
            .tick_held(DVec3::from_array(position), Some(rotation), buttons as u32, device_hold);
        let force = sent.to_array();
        // SAFETY: as above; `force` holds the 3 doubles HD_CURRENT_FORCE takes.
        unsafe {
            (api.set_doublev)(HD_CURRENT_FORCE, force.as_ptr());
            (api.end_frame)(self.hhd);
        }
        self.ticks += 1;
        while let Some((code, message)) = api.error() {
            if recoverable(code) {
                self.shared.count_recoverable();
            } else {
                let _ = self.shared.fault.set(HapticError::Device {
                    backend: Backend::OpenHaptics,
                    operation: "servo loop",
                    code,
                    message,
                });
                self.zero();
                return HD_CALLBACK_DONE;
            }
        }
        // (An error from the update shows on the next tick's draining.)
        self.calibrate();
        HD_CALLBACK_CONTINUE
    }

    /// Outside the frame, as OpenHaptics' calibration example does: a device that needs an update
    /// gets one in the supported style; one that needs the hand (the inkwell) is flagged.
    fn calibrate(&mut self) {
        let c = &self.calibration;
        if self.calibration_status == HD_CALIBRATION_NEEDS_UPDATE
            && let Some(style) = self.calibration_style
        {
            // SAFETY: HD API calls with their declared signatures.
            self.calibration_status = unsafe {
                (self.api.update_calibration)(style);
                (self.api.check_calibration)()
            };
            c.updates.fetch_add(1, Ordering::Relaxed);
        }
        let manual = matches!(
            self.calibration_status,
            HD_CALIBRATION_NEEDS_MANUAL_INPUT | HD_CALIBRATION_NEEDS_UPDATE
        );
        c.needs_manual_input.store(manual, Ordering::Relaxed);
    }

    /// One frame that commands zero force.
    fn zero(&self) {
        let zero = [0.0f64; 3];
        // SAFETY: HD API calls with their declared signatures.
        unsafe {
            (self.api.begin_frame)(self.hhd);
            (self.api.set_doublev)(HD_CURRENT_FORCE, zero.as_ptr());
            (self.api.end_frame)(self.hhd);
        }
    }
}

/// The HD scheduler's entry: one tick; a panic stops force output (zero force) instead of
/// unwinding into the vendor's scheduler.
unsafe extern "system" fn servo_callback(user: *mut c_void) -> c_uint {
    // SAFETY: `user` is the `Callback` boxed in `OpenHaptics::open`, alive until the callback is
    // unscheduled and the scheduler stopped (`OpenHaptics::stop`), and only this callback uses
    // it while scheduled.
    let callback = unsafe { &mut *(user as *mut Callback) };
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| callback.tick())) {
        Ok(code) => code,
        Err(_) => {
            let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| callback.zero()));
            HD_CALLBACK_DONE
        }
    }
}

/// An open OpenHaptics device with its servo loop running.
pub struct OpenHaptics {
    api: Arc<Api>,
    hhd: Hhd,
    info: DeviceInfo,
    shared: Arc<Shared>,
    callback: *mut Callback,
    handle: c_ulong,
    stopped: bool,
    calibration: Arc<CalibrationState>,
    pub library_path: PathBuf,
}

// SAFETY: the raw callback pointer is only dereferenced by the HD scheduler's thread while
// scheduled, and freed by `stop` after the scheduler stopped; everything else is Send.
unsafe impl Send for OpenHaptics {}

impl OpenHaptics {
    /// Opens the default device through the library at `explicit` or on the usual paths, reads
    /// its nominal forces, enables force output and starts the servo loop (zero force until the
    /// guard engages).
    pub fn open(explicit: Option<&Path>) -> Result<OpenHaptics, HapticError> {
        let (api, library_path) = Api::load(explicit)?;
        let api = Arc::new(api);
        // SAFETY: HD API calls with their declared signatures; a null name is HD_DEFAULT_DEVICE.
        let hhd = unsafe { (api.init_device)(std::ptr::null()) };
        api.check("hdInitDevice")?;
        if hhd == HD_INVALID_HANDLE {
            return Err(HapticError::Device {
                backend: Backend::OpenHaptics,
                operation: "hdInitDevice",
                code: 0,
                message: "no device".into(),
            });
        }
        let disable = |e: HapticError| {
            // SAFETY: as above.
            unsafe { (api.disable_device)(hhd) };
            e
        };
        let (mut max, mut continuous) = (0.0f64, 0.0f64);
        // SAFETY: as above, one double each.
        let model = unsafe {
            (api.get_doublev)(HD_NOMINAL_MAX_FORCE, &mut max);
            (api.get_doublev)(HD_NOMINAL_MAX_CONTINUOUS_FORCE, &mut continuous);
            let s = (api.get_string)(HD_DEVICE_MODEL_TYPE);
            if s.is_null() {
                "OpenHaptics device".to_string()
            } else {
                CStr::from_ptr(s).to_string_lossy().into_owned()
            }
        };
        api.check("reading the nominal forces").map_err(disable)?;
        let plausible = |f: f64| f.is_finite() && f > 0.0 && f <= 50.0;
        if !plausible(max) {
            return Err(disable(HapticError::BadLimits {
                backend: Backend::OpenHaptics,
                max_force_n: max,
            }));
        }
        if !plausible(continuous) {
            continuous = max;
        }
        let info = DeviceInfo {
            backend: Backend::OpenHaptics,
            model,
            max_force_n: max,
            max_continuous_force_n: continuous.min(max),
            senses_orientation: true,
        };
        let mut styles: c_int = 0;
        // SAFETY: as above, one int.
        unsafe { (api.get_integerv)(HD_CALIBRATION_STYLE, &mut styles) };
        api.check("reading the calibration styles").map_err(disable)?;
        let shared = Shared::new();
        let calibration = Arc::new(CalibrationState::default());
        let callback = Box::into_raw(Box::new(Callback {
            api: api.clone(),
            hhd,
            core: ServoCore::new(
                SafetyLimits::for_device(info.max_force_n, info.max_continuous_force_n),
                shared.clone(),
            ),
            shared: shared.clone(),
            calibration_style: calibration_style(styles),
            calibration: calibration.clone(),
            calibration_status: HD_CALIBRATION_OK,
            ticks: 0,
        }));
        // SAFETY: HD API calls with their declared signatures; the callback's state lives until
        // `stop` unschedules it.
        let handle = unsafe {
            (api.enable)(HD_FORCE_OUTPUT);
            let h = (api.schedule_asynchronous)(servo_callback, callback as *mut c_void, HD_MAX_SCHEDULER_PRIORITY);
            (api.start_scheduler)();
            h
        };
        let mut device = OpenHaptics {
            api,
            hhd,
            info,
            shared,
            callback,
            handle,
            stopped: false,
            calibration,
            library_path,
        };
        if let Err(e) = device.api.check("starting the scheduler") {
            device.stop();
            return Err(e);
        }
        Ok(device)
    }

    /// Zero force for a few ticks, then the scheduler stopped, the callback unscheduled and freed,
    /// the device released. Safe to call twice.
    fn stop(&mut self) {
        if self.stopped {
            return;
        }
        self.stopped = true;
        self.shared.set_hold(Hold::Stopping);
        // Two ticks under the hold: the last force the servo loop sent is zero.
        let zeroed = self.shared.wait_ticks(2, Duration::from_millis(50));
        // SAFETY: HD API calls with their declared signatures; after the scheduler stopped and the
        // callback is unscheduled nothing uses its state, so it is freed here, once.
        unsafe {
            (self.api.stop_scheduler)();
            (self.api.unschedule)(self.handle);
            if !zeroed {
                // The servo loop had stopped (a device error) or stalled: one frame of zero force
                // from here before the device is released.
                let zero = [0.0f64; 3];
                (self.api.begin_frame)(self.hhd);
                (self.api.set_doublev)(HD_CURRENT_FORCE, zero.as_ptr());
                (self.api.end_frame)(self.hhd);
            }
            (self.api.disable_device)(self.hhd);
            drop(Box::from_raw(self.callback));
        }
    }
}

impl HapticDevice for OpenHaptics {
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

    fn calibration(&self) -> super::Calibration {
        super::Calibration {
            needs_manual_input: self.calibration.needs_manual_input.load(Ordering::Relaxed),
            updates: self.calibration.updates.load(Ordering::Relaxed),
        }
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

impl Drop for OpenHaptics {
    /// Zero force and the servo loop stopped however the device goes: closed, dropped on an error
    /// path, or unwound by a panic.
    fn drop(&mut self) {
        self.stop();
    }
}
