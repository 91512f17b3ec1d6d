//! A double of the Force Dimension DHD API for tests (docs/devices.md "Device doubles"): the
//! symbols Stylet's backend calls, with the SDK's constants and rules (dhdc.h, SDK 3.x), over the
//! simulated arm of `stylet-device-double-arm`. It plays an omega.3: positions in metres, forces
//! in newtons, no force limit set when opened (`dhdGetMaxForce` −1).
//!
//! Rules enforced as the SDK and firmware do: calls name the device opened (id −1, the default
//! device, or its own id) or fail with `DHD_ERROR_INVALID_INDEX`; forces move the arm only once
//! enabled with `dhdEnableForce(DHD_ON)`; a force above the limit set with `dhdSetMaxForce` is
//! scaled down to it and `dhdSetForce` returns `DHD_MOTOR_SATURATED`; with the firmware watchdog
//! set (`dhdSetWatchdog`, units of 125 µs) a gap between force commands longer than it cuts the
//! force and disables force output until enabled again. Every force applied is recorded.
#![allow(clippy::missing_safety_doc)]

use std::ffi::{c_char, c_double, c_int, c_uchar, c_uint};
use std::sync::{Mutex, MutexGuard};
use std::time::Instant;

use stylet_device_double_arm::{Arm, copy_forces, read_keyframes};

// dhdc.h
const DHD_ERROR_NOT_ENABLED: c_int = 19;
const DHD_ERROR_INVALID_INDEX: c_int = 15;
const DHD_ERROR_NO_DEVICE_FOUND: c_int = 5;
const DHD_DEVICE_OMEGA3: c_int = 33;
const DHD_ON: c_uchar = 1;
const DHD_MOTOR_SATURATED: c_int = 2;

/// The omega.3's continuous force (N), from Force Dimension's data sheet.
pub const OMEGA3_FORCE_N: f64 = 12.0;

struct Double {
    arm: Arm,
    open: bool,
    force_enabled: bool,
    /// The limit `dhdSetMaxForce` set (N); negative: none.
    max_force_n: f64,
    /// The firmware watchdog (units of 125 µs; 0 off) and the last force command.
    watchdog_units: u8,
    last_command: Option<Instant>,
    watchdog_cuts: u64,
    last_error: c_int,
    /// Calls that named another device than the one open.
    bad_ids: u64,
}

static DOUBLE: Mutex<Option<Double>> = Mutex::new(None);
/// Milliseconds the next `dhdGetPosition` holds its caller up (a test's hiccup).
static HICCUP_MS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

fn double() -> MutexGuard<'static, Option<Double>> {
    DOUBLE.lock().unwrap_or_else(|e| e.into_inner())
}

impl Double {
    fn new(arm: Arm) -> Self {
        Double {
            arm,
            open: false,
            force_enabled: false,
            max_force_n: -1.0,
            watchdog_units: 0,
            last_command: None,
            watchdog_cuts: 0,
            last_error: 0,
            bad_ids: 0,
        }
    }

    /// The firmware's side of time passing: the arm moves, the watchdog checks the last command.
    fn advance(&mut self) {
        if self.force_enabled
            && self.watchdog_units > 0
            && let Some(last) = self.last_command
            && last.elapsed().as_secs_f64() > f64::from(self.watchdog_units) * 125e-6
        {
            self.force_enabled = false;
            self.arm.cut_force();
            self.watchdog_cuts += 1;
        }
        self.arm.step();
    }
}

/// Runs `f` on the open device `id` names, or sets the last error and returns `fail`.
fn on_device<R>(id: c_char, fail: R, f: impl FnOnce(&mut Double) -> R) -> R {
    let mut guard = double();
    let Some(d) = guard.as_mut().filter(|d| d.open) else {
        if let Some(d) = guard.as_mut() {
            d.last_error = DHD_ERROR_NO_DEVICE_FOUND;
        }
        return fail;
    };
    // The default device is −1 (255 where `char` is unsigned); the one open has id 0.
    if !matches!(i32::from(id), -1 | 0 | 255) {
        d.last_error = DHD_ERROR_INVALID_INDEX;
        d.bad_ids += 1;
        return fail;
    }
    d.advance();
    f(d)
}

// ---- The DHD API ----

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdOpen() -> c_int {
    let mut guard = double();
    let arm = guard
        .take()
        .map(|d| d.arm.restarted())
        .unwrap_or_else(|| Arm::new(vec![[0.0; 4]]));
    let mut fresh = Double::new(arm);
    fresh.open = true;
    *guard = Some(fresh);
    0
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdClose(id: c_char) -> c_int {
    on_device(id, -1, |d| {
        d.open = false;
        d.force_enabled = false;
        d.arm.cut_force();
        0
    })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdGetSystemType(id: c_char) -> c_int {
    on_device(id, -1, |_| DHD_DEVICE_OMEGA3)
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdGetSystemName(id: c_char) -> *const c_char {
    on_device(id, std::ptr::null(), |_| c"omega.3 (Stylet device double)".as_ptr())
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdEnableForce(val: c_uchar, id: c_char) -> c_int {
    on_device(id, -1, |d| {
        d.force_enabled = val == DHD_ON;
        if !d.force_enabled {
            d.arm.cut_force();
        }
        d.last_command = Some(Instant::now());
        0
    })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdGetMaxForce(id: c_char) -> c_double {
    on_device(id, -1.0, |d| d.max_force_n)
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdSetMaxForce(limit: c_double, id: c_char) -> c_int {
    on_device(id, -1, |d| {
        d.max_force_n = limit;
        0
    })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdSetWatchdog(units: c_uchar, id: c_char) -> c_int {
    on_device(id, -1, |d| {
        d.watchdog_units = units;
        0
    })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdGetPosition(px: *mut c_double, py: *mut c_double, pz: *mut c_double, id: c_char) -> c_int {
    // A test's hiccup: the caller's thread held up once, as a loaded machine would.
    let delay_ms = HICCUP_MS.swap(0, std::sync::atomic::Ordering::Relaxed);
    if delay_ms > 0 {
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
    }
    on_device(id, -1, |d| {
        let p = d.arm.position_mm();
        // SAFETY: three doubles the caller owns, as the SDK requires.
        unsafe {
            *px = p[0] / 1000.0;
            *py = p[1] / 1000.0;
            *pz = p[2] / 1000.0;
        }
        0
    })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdGetButtonMask(id: c_char) -> c_uint {
    on_device(id, 0, |d| d.arm.buttons)
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdSetForce(fx: c_double, fy: c_double, fz: c_double, id: c_char) -> c_int {
    on_device(id, -1, |d| {
        d.last_command = Some(Instant::now());
        if !d.force_enabled {
            d.last_error = DHD_ERROR_NOT_ENABLED;
            return 0;
        }
        let mut f = [fx, fy, fz];
        let magnitude = (fx * fx + fy * fy + fz * fz).sqrt();
        let limit = if d.max_force_n >= 0.0 {
            d.max_force_n
        } else {
            OMEGA3_FORCE_N
        };
        let saturated = magnitude > limit;
        if saturated {
            f = f.map(|c| c * limit / magnitude);
        }
        d.arm.accept_force(f);
        if saturated { DHD_MOTOR_SATURATED } else { 0 }
    })
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdErrorGetLast() -> c_int {
    double().as_ref().map_or(0, |d| d.last_error)
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn dhdErrorGetLastStr() -> *const c_char {
    match double().as_ref().map_or(0, |d| d.last_error) {
        0 => c"no error".as_ptr(),
        DHD_ERROR_NO_DEVICE_FOUND => c"no device found".as_ptr(),
        DHD_ERROR_INVALID_INDEX => c"invalid index".as_ptr(),
        DHD_ERROR_NOT_ENABLED => c"feature not enabled".as_ptr(),
        _ => c"error".as_ptr(),
    }
}

// ---- For the tests ----

/// Sets the scripted hand before `dhdOpen`: `n` keyframes of (t s, x, y, z mm).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_set_hand(keyframes: *const f64, n: usize) {
    // SAFETY: the caller passes 4·n doubles.
    let hand = unsafe { read_keyframes(keyframes, n) };
    *double() = Some(Double::new(Arm::new(hand)));
}

/// Holds up the thread of the next `dhdGetPosition` for `ms` milliseconds (the backend's servo
/// thread, as a loaded machine would).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_hiccup(ms: u32) {
    HICCUP_MS.store(u64::from(ms), std::sync::atomic::Ordering::Relaxed);
}

/// Copies up to `capacity` recorded forces, 4 doubles each (t s, fx, fy, fz N); returns how many
/// were recorded in all.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_forces(out: *mut f64, capacity: usize) -> usize {
    // SAFETY: the caller passes room for 4·capacity doubles.
    double()
        .as_ref()
        .map_or(0, |d| unsafe { copy_forces(&d.arm, out, capacity) })
}

/// Seconds on the clock of the recorded forces now (it starts again when the device opens), so a
/// test can put its own instants on that clock; a negative number before the hand is set.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_time_s() -> f64 {
    double().as_ref().map_or(-1.0, |d| d.arm.time_s())
}

/// Calls that named another device than the one open (the backend must pass −1).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_frame_violations() -> u64 {
    double().as_ref().map_or(0, |d| d.bad_ids)
}

/// Bit 0: the device is open; bit 2: the firmware watchdog is set; bits 8…: how often it cut the
/// force.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_state() -> u32 {
    double().as_ref().map_or(0, |d| {
        d.open as u32 | (((d.watchdog_units > 0) as u32) << 2) | ((d.watchdog_cuts.min(0xFF_FFFF) as u32) << 8)
    })
}
