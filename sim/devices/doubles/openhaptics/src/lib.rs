//! A double of the OpenHaptics HD API for tests (docs/devices.md "Device doubles"): the symbols
//! Stylet's backend calls, with the real API's constants and rules, over the simulated arm of
//! `stylet-device-double-arm`.
//!
//! Rules enforced as the real API does: a frame must be begun before it is ended and not begun
//! twice; forces are accepted only inside a frame and only once `HD_FORCE_OUTPUT` is enabled;
//! violations queue an error for `hdGetError`. Every force accepted is recorded with its time,
//! for the tests to read back (`stylet_double_*`). Nominal forces are the Touch's: 3.3 N peak,
//! 0.88 N continuous.
#![allow(clippy::missing_safety_doc)]

use std::ffi::{c_char, c_int, c_uint, c_ulong, c_ushort, c_void};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use stylet_device_double_arm::{Arm, copy_forces, read_keyframes};

const HD_INVALID_ENUM: c_uint = 0x0100;
const HD_INVALID_VALUE: c_uint = 0x0101;
const HD_INVALID_OPERATION: c_uint = 0x0102;
const HD_ILLEGAL_BEGIN: c_uint = 0x0400;
const HD_ILLEGAL_END: c_uint = 0x0401;
const HD_CURRENT_BUTTONS: c_uint = 0x2000;
const HD_CURRENT_POSITION: c_uint = 0x2050;
const HD_CURRENT_TRANSFORM: c_uint = 0x2052;
const HD_DEVICE_MODEL_TYPE: c_uint = 0x2501;
const HD_NOMINAL_MAX_FORCE: c_uint = 0x2603;
const HD_NOMINAL_MAX_CONTINUOUS_FORCE: c_uint = 0x2604;
const HD_CALIBRATION_STYLE: c_uint = 0x2555;
const HD_CALIBRATION_OK: c_uint = 0x5000;
const HD_CALIBRATION_NEEDS_UPDATE: c_uint = 0x5001;
/// The Touch calibrates in its inkwell.
const HD_CALIBRATION_INKWELL: c_int = 1 << 2;
const HD_CURRENT_FORCE: c_uint = 0x2700;
const HD_FORCE_OUTPUT: c_uint = 0x4000;
const HD_CALLBACK_CONTINUE: c_uint = 1;

/// The Touch's nominal forces (N).
pub const MAX_FORCE_N: f64 = 3.3;
pub const MAX_CONTINUOUS_FORCE_N: f64 = 0.88;

#[repr(C)]
#[derive(Clone, Copy)]
pub struct HdErrorInfo {
    error_code: c_uint,
    internal_error_code: c_int,
    hhd: c_uint,
}

type Callback = unsafe extern "system" fn(*mut c_void) -> c_uint;

struct Double {
    arm: Arm,
    open: bool,
    force_output: bool,
    in_frame: bool,
    errors: Vec<c_uint>,
    frame_violations: u64,
    callback: Option<(usize, usize)>,
    /// What `hdCheckCalibration` answers, and the calibrations asked for.
    calibration: c_uint,
    calibration_updates: u64,
}

static DOUBLE: Mutex<Option<Double>> = Mutex::new(None);
static RUN: AtomicBool = AtomicBool::new(false);
static SCHEDULER: Mutex<Option<JoinHandle<()>>> = Mutex::new(None);

fn double() -> MutexGuard<'static, Option<Double>> {
    DOUBLE.lock().unwrap_or_else(|e| e.into_inner())
}

fn with<R>(f: impl FnOnce(&mut Double) -> R) -> Option<R> {
    double().as_mut().map(f)
}

impl Double {
    fn new(arm: Arm) -> Self {
        Double {
            arm,
            open: false,
            force_output: false,
            in_frame: false,
            errors: Vec::new(),
            frame_violations: 0,
            callback: None,
            calibration: HD_CALIBRATION_OK,
            calibration_updates: 0,
        }
    }
}

// ---- The HD API ----

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdInitDevice(_name: *const c_char) -> c_uint {
    let mut d = double();
    let (arm, calibration) = d
        .take()
        .map(|d| (d.arm.restarted(), d.calibration))
        .unwrap_or_else(|| (Arm::new(vec![[0.0; 4]]), HD_CALIBRATION_OK));
    let mut fresh = Double::new(arm);
    fresh.open = true;
    fresh.calibration = calibration;
    *d = Some(fresh);
    0
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdDisableDevice(_hhd: c_uint) {
    with(|d| {
        d.open = false;
        d.force_output = false;
    });
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdEnable(cap: c_uint) {
    with(|d| {
        if cap == HD_FORCE_OUTPUT {
            d.force_output = true;
        } else {
            d.errors.push(HD_INVALID_ENUM);
        }
    });
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdBeginFrame(_hhd: c_uint) {
    with(|d| {
        if d.in_frame {
            d.errors.push(HD_ILLEGAL_BEGIN);
            d.frame_violations += 1;
        }
        d.in_frame = true;
        d.arm.step();
    });
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdEndFrame(_hhd: c_uint) {
    with(|d| {
        if !d.in_frame {
            d.errors.push(HD_ILLEGAL_END);
            d.frame_violations += 1;
        }
        d.in_frame = false;
    });
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdGetDoublev(param: c_uint, out: *mut f64) {
    let values: Option<Vec<f64>> = with(|d| match param {
        HD_CURRENT_POSITION => Some(d.arm.position_mm().to_vec()),
        HD_CURRENT_TRANSFORM => {
            let mut m = vec![0.0; 16];
            m[0] = 1.0;
            m[5] = 1.0;
            m[10] = 1.0;
            m[15] = 1.0;
            m[12..15].copy_from_slice(&d.arm.position_mm());
            Some(m)
        }
        HD_NOMINAL_MAX_FORCE => Some(vec![MAX_FORCE_N]),
        HD_NOMINAL_MAX_CONTINUOUS_FORCE => Some(vec![MAX_CONTINUOUS_FORCE_N]),
        _ => {
            d.errors.push(HD_INVALID_ENUM);
            None
        }
    })
    .flatten();
    if let Some(v) = values {
        // SAFETY: the caller passes a buffer as long as the parameter, as the HD API requires.
        unsafe { std::ptr::copy_nonoverlapping(v.as_ptr(), out, v.len()) };
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdGetIntegerv(param: c_uint, out: *mut c_int) {
    if let Some(Some(b)) = with(|d| {
        if param == HD_CURRENT_BUTTONS {
            Some(d.arm.buttons as c_int)
        } else if param == HD_CALIBRATION_STYLE {
            Some(HD_CALIBRATION_INKWELL)
        } else {
            d.errors.push(HD_INVALID_ENUM);
            None
        }
    }) {
        // SAFETY: one int, as the HD API requires.
        unsafe { *out = b };
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdSetDoublev(param: c_uint, value: *const f64) {
    // SAFETY: three doubles for HD_CURRENT_FORCE, as the HD API requires.
    let f = unsafe { [*value, *value.add(1), *value.add(2)] };
    with(|d| {
        if param != HD_CURRENT_FORCE {
            d.errors.push(HD_INVALID_ENUM);
        } else if !d.in_frame {
            d.errors.push(HD_INVALID_OPERATION);
            d.frame_violations += 1;
        } else if d.force_output {
            d.arm.accept_force(f);
        }
    });
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdGetString(param: c_uint) -> *const c_char {
    if param == HD_DEVICE_MODEL_TYPE {
        c"Touch (Stylet device double)".as_ptr()
    } else {
        with(|d| d.errors.push(HD_INVALID_ENUM));
        std::ptr::null()
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdCheckCalibration() -> c_uint {
    with(|d| d.calibration).unwrap_or(HD_CALIBRATION_OK)
}

/// Calibrates in a supported style once the device can (it needs an update, as after the stylus
/// rested in its inkwell); a style the Touch lacks is an invalid value.
#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdUpdateCalibration(style: c_uint) {
    with(|d| {
        if style as c_int != HD_CALIBRATION_INKWELL {
            d.errors.push(HD_INVALID_VALUE);
        } else if d.calibration == HD_CALIBRATION_NEEDS_UPDATE {
            d.calibration = HD_CALIBRATION_OK;
            d.calibration_updates += 1;
        }
    });
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdGetError() -> HdErrorInfo {
    let code = with(|d| if d.errors.is_empty() { 0 } else { d.errors.remove(0) }).unwrap_or(0);
    HdErrorInfo {
        error_code: code,
        internal_error_code: 0,
        hhd: 0,
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdGetErrorString(code: c_uint) -> *const c_char {
    match code {
        HD_INVALID_ENUM => c"Invalid enumeration".as_ptr(),
        HD_INVALID_VALUE => c"Invalid value".as_ptr(),
        HD_INVALID_OPERATION => c"Invalid operation".as_ptr(),
        HD_ILLEGAL_BEGIN => c"Illegal begin".as_ptr(),
        HD_ILLEGAL_END => c"Illegal end".as_ptr(),
        _ => c"Unknown error".as_ptr(),
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdScheduleAsynchronous(
    callback: Callback,
    user: *mut c_void,
    _priority: c_ushort,
) -> c_ulong {
    with(|d| d.callback = Some((callback as usize, user as usize)));
    1
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdStartScheduler() {
    let Some(Some((callback, user))) = with(|d| d.callback) else {
        return;
    };
    RUN.store(true, Ordering::Release);
    let handle = std::thread::spawn(move || {
        // SAFETY: the pointer was a `Callback` when it was scheduled.
        let callback: Callback = unsafe { std::mem::transmute::<usize, Callback>(callback) };
        let period = Duration::from_millis(1);
        let mut next = Instant::now() + period;
        while RUN.load(Ordering::Acquire) {
            // SAFETY: the user pointer the caller scheduled with its callback.
            if unsafe { callback(user as *mut c_void) } != HD_CALLBACK_CONTINUE {
                break;
            }
            let now = Instant::now();
            if next > now {
                std::thread::sleep(next - now);
            }
            next += period;
        }
    });
    *SCHEDULER.lock().unwrap_or_else(|e| e.into_inner()) = Some(handle);
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdStopScheduler() {
    RUN.store(false, Ordering::Release);
    if let Some(h) = SCHEDULER.lock().unwrap_or_else(|e| e.into_inner()).take() {
        let _ = h.join();
    }
}

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdUnschedule(_handle: c_ulong) {
    with(|d| d.callback = None);
}

// ---- For the tests ----

/// Sets the scripted hand before `hdInitDevice`: `n` keyframes of (t s, x, y, z mm).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_set_hand(keyframes: *const f64, n: usize) {
    // SAFETY: the caller passes 4·n doubles.
    let hand = unsafe { read_keyframes(keyframes, n) };
    *double() = Some(Double::new(Arm::new(hand)));
}

/// Copies up to `capacity` recorded forces, 4 doubles each (t s, fx, fy, fz N); returns how many
/// were recorded in all.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_forces(out: *mut f64, capacity: usize) -> usize {
    // SAFETY: the caller passes room for 4·capacity doubles.
    with(|d| unsafe { copy_forces(&d.arm, out, capacity) }).unwrap_or(0)
}

/// Sets what `hdCheckCalibration` answers (0x5000 OK, 0x5001 needs an update, 0x5002 needs the
/// stylus in its inkwell); kept when the device is opened again.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_set_calibration(status: c_uint) {
    with(|d| d.calibration = status);
}

/// How many calibrations the backend asked for (`hdUpdateCalibration` that calibrated).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_calibration_updates() -> u64 {
    with(|d| d.calibration_updates).unwrap_or(0)
}

/// Seconds on the clock of the recorded forces now (it starts again when the device opens), so a
/// test can put its own instants on that clock; a negative number before the hand is set.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_time_s() -> f64 {
    with(|d| d.arm.time_s()).unwrap_or(-1.0)
}

/// How many frame rules were broken (begin twice, end without begin, force outside a frame).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_frame_violations() -> u64 {
    with(|d| d.frame_violations).unwrap_or(0)
}

/// Whether the device is open (between `hdInitDevice` and `hdDisableDevice`) and the scheduler
/// runs: bit 0 open, bit 1 scheduler running.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_state() -> u32 {
    let open = with(|d| d.open).unwrap_or(false) as u32;
    let running = SCHEDULER.lock().unwrap_or_else(|e| e.into_inner()).is_some() as u32;
    open | (running << 1)
}
