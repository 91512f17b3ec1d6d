//! A double of the OpenHaptics HD API for tests (docs/devices.md "Device doubles"): the symbols
//! Stylet's backend calls, with the real API's constants and rules, over a simulated arm — the
//! stylus a mass on a spring pulled along by a scripted hand and pushed by the forces sent.
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

const HD_INVALID_ENUM: c_uint = 0x0100;
const HD_INVALID_OPERATION: c_uint = 0x0102;
const HD_ILLEGAL_BEGIN: c_uint = 0x0400;
const HD_ILLEGAL_END: c_uint = 0x0401;
const HD_CURRENT_BUTTONS: c_uint = 0x2000;
const HD_CURRENT_POSITION: c_uint = 0x2050;
const HD_CURRENT_TRANSFORM: c_uint = 0x2052;
const HD_DEVICE_MODEL_TYPE: c_uint = 0x2501;
const HD_NOMINAL_MAX_FORCE: c_uint = 0x2603;
const HD_NOMINAL_MAX_CONTINUOUS_FORCE: c_uint = 0x2604;
const HD_CURRENT_FORCE: c_uint = 0x2700;
const HD_FORCE_OUTPUT: c_uint = 0x4000;
const HD_CALLBACK_CONTINUE: c_uint = 1;

/// The Touch's nominal forces (N).
pub const MAX_FORCE_N: f64 = 3.3;
pub const MAX_CONTINUOUS_FORCE_N: f64 = 0.88;
/// The arm: stylus mass (kg), the hand's grip as a spring (N/mm) and its damping (N·s/mm).
const MASS_KG: f64 = 0.05;
const GRIP_N_PER_MM: f64 = 0.5;
const GRIP_DAMPING_N_S_PER_MM: f64 = 0.008;

#[repr(C)]
#[derive(Clone, Copy)]
pub struct HdErrorInfo {
    error_code: c_uint,
    internal_error_code: c_int,
    hhd: c_uint,
}

type Callback = unsafe extern "system" fn(*mut c_void) -> c_uint;

struct Double {
    open: bool,
    force_output: bool,
    in_frame: bool,
    errors: Vec<c_uint>,
    frame_violations: u64,
    /// The scripted hand: (t s, x, y, z mm) keyframes, linear between, held after the last.
    hand: Vec<[f64; 4]>,
    buttons: c_uint,
    /// The stylus (mm, mm/s) and the force last accepted (N).
    position: [f64; 3],
    velocity: [f64; 3],
    force: [f64; 3],
    last_step: Option<Instant>,
    started: Instant,
    /// Every force accepted: (t s, fx, fy, fz N).
    forces: Vec<[f64; 4]>,
    callback: Option<(usize, usize)>,
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
    fn new(hand: Vec<[f64; 4]>) -> Self {
        let start = hand.first().map_or([0.0; 3], |k| [k[1], k[2], k[3]]);
        Double {
            open: false,
            force_output: false,
            in_frame: false,
            errors: Vec::new(),
            frame_violations: 0,
            hand,
            buttons: 0,
            position: start,
            velocity: [0.0; 3],
            force: [0.0; 3],
            last_step: None,
            started: Instant::now(),
            forces: Vec::new(),
            callback: None,
        }
    }

    fn hand_at(&self, t: f64) -> [f64; 3] {
        let k = &self.hand;
        match k.iter().position(|p| p[0] > t) {
            None => k.last().map_or([0.0; 3], |p| [p[1], p[2], p[3]]),
            Some(0) => [k[0][1], k[0][2], k[0][3]],
            Some(i) => {
                let (a, b) = (k[i - 1], k[i]);
                let s = (t - a[0]) / (b[0] - a[0]);
                [0, 1, 2].map(|c| a[c + 1] + s * (b[c + 1] - a[c + 1]))
            }
        }
    }

    /// Advances the arm to now (semi-implicit Euler in 0.1 ms steps).
    fn step(&mut self) {
        let now = Instant::now();
        let last = self.last_step.replace(now).unwrap_or(now);
        let mut left = now.duration_since(last).as_secs_f64().min(0.05);
        let t = now.duration_since(self.started).as_secs_f64();
        let hand = self.hand_at(t);
        while left > 0.0 {
            let dt = left.min(1e-4);
            left -= dt;
            for c in 0..3 {
                let pull_n = GRIP_N_PER_MM * (hand[c] - self.position[c]) - GRIP_DAMPING_N_S_PER_MM * self.velocity[c];
                // N / kg = m/s² = 1000 mm/s².
                let accel_mm_s2 = (pull_n + self.force[c]) / MASS_KG * 1000.0;
                self.velocity[c] += accel_mm_s2 * dt;
                self.position[c] += self.velocity[c] * dt;
            }
        }
    }
}

// ---- The HD API ----

#[unsafe(no_mangle)]
pub unsafe extern "system" fn hdInitDevice(_name: *const c_char) -> c_uint {
    let mut d = double();
    let hand = d.take().map(|d| d.hand).unwrap_or_else(|| vec![[0.0, 0.0, 0.0, 0.0]]);
    let mut fresh = Double::new(hand);
    fresh.open = true;
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
        d.step();
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
        HD_CURRENT_POSITION => Some(d.position.to_vec()),
        HD_CURRENT_TRANSFORM => {
            let mut m = vec![0.0; 16];
            m[0] = 1.0;
            m[5] = 1.0;
            m[10] = 1.0;
            m[15] = 1.0;
            m[12..15].copy_from_slice(&d.position);
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
            Some(d.buttons as c_int)
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
            d.force = f;
            let t = d.started.elapsed().as_secs_f64();
            d.forces.push([t, f[0], f[1], f[2]]);
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
    let k: Vec<[f64; 4]> = (0..n)
        .map(|i| unsafe { [0, 1, 2, 3].map(|c| *keyframes.add(4 * i + c)) })
        .collect();
    *double() = Some(Double::new(k));
}

/// Copies up to `capacity` recorded forces, 4 doubles each (t s, fx, fy, fz N); returns how many
/// were recorded in all.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn stylet_double_forces(out: *mut f64, capacity: usize) -> usize {
    with(|d| {
        for (i, f) in d.forces.iter().take(capacity).enumerate() {
            // SAFETY: the caller passes room for 4·capacity doubles.
            unsafe { std::ptr::copy_nonoverlapping(f.as_ptr(), out.add(4 * i), 4) };
        }
        d.forces.len()
    })
    .unwrap_or(0)
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
