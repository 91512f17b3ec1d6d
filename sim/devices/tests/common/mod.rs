//! What the device-double tests share: loading a double's test entry points, and the scenario
//! every backend is put through — a scripted hand opens the device inside a virtual wall, leaves
//! it and pushes back in, the simulation stalls, the device closes — checked from the double's
//! own record of every force it was sent.
#![allow(
    dead_code,
    reason = "each test binary uses a part: the Haply test has no shared library"
)]

use std::path::PathBuf;
use std::time::{Duration, Instant};

use stylet_devices::haptic::{HapticDevice, ServoCounts};
use stylet_physics::glam::DVec3;

/// A double's shared library, built beside the test binary (it is a dev-dependency).
pub fn double_library(crate_name: &str) -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().unwrap();
    let name = format!(
        "{}{crate_name}{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    );
    let p = dir.join(&name);
    assert!(
        p.is_file(),
        "{} missing: the double is built as a dev-dependency",
        p.display()
    );
    p
}

/// A double's test entry points, through the same library the backend loaded.
pub struct Probe(libloading::Library);

impl Probe {
    pub fn open(library: &std::path::Path) -> Probe {
        // SAFETY: the test's own double, a library without initialisers.
        Probe(unsafe { libloading::Library::new(library) }.unwrap())
    }

    pub fn set_hand(&self, keyframes: &[[f64; 4]]) {
        // SAFETY: the double's function with its declared signature; 4 doubles per keyframe.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn(*const f64, usize)> =
                self.0.get(b"stylet_double_set_hand\0").unwrap();
            f(keyframes.as_ptr().cast(), keyframes.len());
        }
    }

    /// Every force the double accepted: (t s, force N).
    pub fn forces(&self) -> Vec<(f64, DVec3)> {
        // SAFETY: the double's function with its declared signature; room for 4·n doubles.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn(*mut f64, usize) -> usize> =
                self.0.get(b"stylet_double_forces\0").unwrap();
            let n = f(std::ptr::null_mut(), 0);
            let mut buf = vec![0.0f64; 4 * (n + 64)];
            let n = f(buf.as_mut_ptr(), n + 64).min(n + 64);
            buf.chunks(4)
                .take(n)
                .map(|c| (c[0], DVec3::new(c[1], c[2], c[3])))
                .collect()
        }
    }

    /// Calls that broke the API's rules (frames for OpenHaptics, device ids for DHD).
    pub fn violations(&self) -> u64 {
        // SAFETY: the double's function with its declared signature.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn() -> u64> =
                self.0.get(b"stylet_double_frame_violations\0").unwrap();
            f()
        }
    }

    /// Calls a test entry point taking one `u32` (a status to set).
    pub fn set_u32(&self, name: &str, value: u32) {
        let symbol = format!("{name}\0");
        // SAFETY: the double's function with its declared signature.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn(u32)> = self.0.get(symbol.as_bytes()).unwrap();
            f(value);
        }
    }

    /// Calls a test entry point returning a count.
    pub fn count(&self, name: &str) -> u64 {
        let symbol = format!("{name}\0");
        // SAFETY: the double's function with its declared signature.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn() -> u64> = self.0.get(symbol.as_bytes()).unwrap();
            f()
        }
    }

    /// The double's state bits (bit 0: the device open; the rest per double).
    pub fn state(&self) -> u32 {
        // SAFETY: the double's function with its declared signature.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn() -> u32> = self.0.get(b"stylet_double_state\0").unwrap();
            f()
        }
    }
}

/// What a double recorded, as the wall scenario reads it.
pub trait Record {
    /// Every force the double accepted: (t s, force N).
    fn forces(&self) -> Vec<(f64, DVec3)>;
    /// Calls or messages that broke the vendor API's rules.
    fn violations(&self) -> u64;
    /// Whether the device is open (connected) now.
    fn is_open(&self) -> bool;
}

impl Record for Probe {
    fn forces(&self) -> Vec<(f64, DVec3)> {
        Probe::forces(self)
    }
    fn violations(&self) -> u64 {
        Probe::violations(self)
    }
    fn is_open(&self) -> bool {
        self.state() & 1 == 1
    }
}

/// The hand of the wall scenario (device frame, mm): it starts 5 mm inside the wall, leaves it,
/// waits out the ramp, then pushes 30 mm in within 0.1 s and stays.
pub const WALL_HAND: [[f64; 4]; 6] = [
    [0.0, 0.0, 0.0, -5.0],
    [0.3, 0.0, 0.0, -5.0],
    [0.5, 0.0, 0.0, 10.0],
    [1.6, 0.0, 0.0, 10.0],
    [1.7, 0.0, 0.0, -30.0],
    [3.2, 0.0, 0.0, -30.0],
];

/// The wall of `stylet device check`: the plane z = 0, 0.5 N/mm into +z below it, at `scale`
/// (a device whose limits are far above the wall's forces gets a stiffer wall, so it clamps).
fn wall_force(p: DVec3, scale: f64) -> DVec3 {
    DVec3::new(0.0, 0.0, scale * 0.5 * (-p.z).max(0.0))
}

/// Runs the wall scenario on `device` (opened with [`WALL_HAND`] set) and checks the double's
/// record: nothing before the hand has left the wall, the peak at the nominal maximum and never
/// above, the mean over 1000 ticks at most the continuous force, zero within 10 ms of the stall
/// and zero at the end. Returns the counts at close.
pub fn wall_scenario(device: Box<dyn HapticDevice>, probe: &dyn Record, wall_scale: f64) -> ServoCounts {
    let max_n = device.info().max_force_n;
    let continuous_n = device.info().max_continuous_force_n;
    // The simulation's side at 1 kHz for 3 s, computing the wall's force from each reading.
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(3) {
        if let Some(r) = device.reading() {
            device.set_force(wall_force(r.position_mm, wall_scale));
        }
        std::thread::sleep(Duration::from_micros(900));
    }
    let stalled_at = start.elapsed().as_secs_f64();
    // The simulation stalls for 50 ms: the watchdog must zero the force.
    std::thread::sleep(Duration::from_millis(50));
    let counts = device.counts();
    let p99_ms = device.interval_p99_ms();
    let closed = device.close().unwrap();
    assert!(closed.ticks >= counts.ticks);
    assert!(!probe.is_open(), "closed");
    assert_eq!(probe.violations(), 0);

    let forces = probe.forces();
    assert!(forces.len() > 2500, "{} servo ticks in 3 s", forces.len());
    let rate_hz = (forces.len() - 1) as f64 / (forces.last().unwrap().0 - forces[0].0);
    eprintln!("servo rate {rate_hz:.0} Hz, p99 interval {p99_ms:.2} ms, {counts:?}");
    // Inside the wall at the start: nothing is sent until the hand has left it.
    let first_force = forces.iter().find(|(_, f)| f.length() > 0.0).unwrap();
    assert!(
        first_force.0 > 1.6,
        "a force at {:.3} s, before the hand pushed in",
        first_force.0
    );
    // Never above the nominal maximum; the clamp acted (the wall asks for more).
    let peak = forces.iter().map(|(_, f)| f.length()).fold(0.0, f64::max);
    assert!(peak <= max_n + 1e-9 && peak > 0.9 * max_n, "peak {peak} N of {max_n} N");
    assert!(closed.guard.clamped > 0, "{closed:?}");
    // The mean over any 1000 consecutive servo ticks (a second of a 1 kHz servo loop) at most the
    // continuous force. Counted in ticks, as the guard counts: on a loaded machine a late servo
    // loop catches up in a burst, so a second of wall clock may hold a few more.
    let window = 1000;
    let mut worst_mean_n: f64 = 0.0;
    let mut sum: f64 = forces.iter().take(window).map(|(_, f)| f.length()).sum();
    for i in window..=forces.len() {
        let mean = sum / window as f64;
        worst_mean_n = worst_mean_n.max(mean);
        assert!(
            mean <= continuous_n + 1e-9,
            "mean {mean} N over the 1000 ticks to {:.3} s",
            forces[i - 1].0
        );
        if i < forces.len() {
            sum += forces[i].1.length() - forces[i - window].1.length();
        }
    }
    eprintln!("peak {peak:.3} N, largest mean over 1000 ticks {worst_mean_n:.4} N");
    // Zero within 10 ms (+ a few servo ticks) of the stall, and the last force of all zero.
    let after_stall: Vec<&(f64, DVec3)> = forces.iter().filter(|(t, _)| *t > stalled_at + 0.015).collect();
    assert!(!after_stall.is_empty());
    assert!(
        after_stall.iter().all(|(_, f)| *f == DVec3::ZERO),
        "force after the stall"
    );
    assert!(closed.guard.watchdog_trips >= 1);
    assert_eq!(forces.last().unwrap().1, DVec3::ZERO);
    closed
}
