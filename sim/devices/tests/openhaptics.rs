//! The OpenHaptics backend against its device double (`doubles/openhaptics`, loaded at run time
//! like `libHD.so`): a scripted hand opens the device inside a virtual wall, leaves it and pushes
//! back in; the double records every force it was sent. Checked from the double's own record:
//! nothing before the force was small, a ramp, the nominal maximum and the continuous limit never
//! exceeded, zero within 10 ms of a stalled simulation, zero at the end, frames paired.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use stylet_devices::haptic::openhaptics::OpenHaptics;
use stylet_devices::haptic::{HapticDevice, HapticError};
use stylet_physics::glam::DVec3;

/// The double's shared library, built beside the test binary (it is a dev-dependency).
fn double_library() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().unwrap();
    let name = format!(
        "{}stylet_openhaptics_double{}",
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

/// The double's test entry points, through the same library the backend loaded.
struct Probe(libloading::Library);

impl Probe {
    fn open() -> Probe {
        // SAFETY: the test's own double, a library without initialisers.
        Probe(unsafe { libloading::Library::new(double_library()) }.unwrap())
    }

    fn set_hand(&self, keyframes: &[[f64; 4]]) {
        // SAFETY: the double's function with its declared signature; 4 doubles per keyframe.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn(*const f64, usize)> =
                self.0.get(b"stylet_double_set_hand\0").unwrap();
            f(keyframes.as_ptr().cast(), keyframes.len());
        }
    }

    /// Every force the double accepted: (t s, force N).
    fn forces(&self) -> Vec<(f64, DVec3)> {
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

    fn frame_violations(&self) -> u64 {
        // SAFETY: the double's function with its declared signature.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn() -> u64> =
                self.0.get(b"stylet_double_frame_violations\0").unwrap();
            f()
        }
    }

    fn state(&self) -> u32 {
        // SAFETY: the double's function with its declared signature.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn() -> u32> = self.0.get(b"stylet_double_state\0").unwrap();
            f()
        }
    }
}

/// The wall of `stylet device check`: the plane z = 0, 0.5 N/mm into +z below it.
fn wall_force(p: DVec3) -> DVec3 {
    DVec3::new(0.0, 0.0, 0.5 * (-p.z).max(0.0))
}

#[test]
fn a_virtual_wall_through_the_openhaptics_double_is_safe_from_first_tick_to_last() {
    let probe = Probe::open();
    // The hand starts 5 mm inside the wall, leaves it, waits out the ramp, then pushes 30 mm in
    // within 0.1 s and stays.
    probe.set_hand(&[
        [0.0, 0.0, 0.0, -5.0],
        [0.3, 0.0, 0.0, -5.0],
        [0.5, 0.0, 0.0, 10.0],
        [1.6, 0.0, 0.0, 10.0],
        [1.7, 0.0, 0.0, -30.0],
        [3.2, 0.0, 0.0, -30.0],
    ]);
    let device = Box::new(OpenHaptics::open(Some(&double_library())).unwrap());
    assert_eq!(device.info().model, "Touch (Stylet device double)");
    assert_eq!(device.info().max_force_n, 3.3);
    assert_eq!(device.info().max_continuous_force_n, 0.88);
    // The simulation's side at 1 kHz for 3 s, computing the wall's force from each reading.
    let start = Instant::now();
    let mut seq = 0;
    let mut intervals = Vec::new();
    let mut last_tick = None;
    while start.elapsed() < Duration::from_secs(3) {
        if let Some(r) = device.reading() {
            device.set_force(wall_force(r.position_mm), seq);
            seq += 1;
            if last_tick != Some(r.tick) {
                last_tick = Some(r.tick);
            }
        }
        std::thread::sleep(Duration::from_micros(900));
    }
    let stalled_at = start.elapsed().as_secs_f64();
    // The simulation stalls for 50 ms: the watchdog must zero the force.
    std::thread::sleep(Duration::from_millis(50));
    let counts = device.counts();
    let closed = device.close().unwrap();
    assert!(closed.ticks >= counts.ticks);
    assert_eq!(probe.state(), 0, "closed and the scheduler stopped");
    assert_eq!(probe.frame_violations(), 0);

    let forces = probe.forces();
    assert!(forces.len() > 2500, "{} servo ticks in 3 s", forces.len());
    for w in forces.windows(2) {
        intervals.push(w[1].0 - w[0].0);
    }
    intervals.sort_by(f64::total_cmp);
    let p99_ms = intervals[intervals.len() * 99 / 100] * 1000.0;
    let rate_hz = (forces.len() - 1) as f64 / (forces.last().unwrap().0 - forces[0].0);
    eprintln!("servo rate {rate_hz:.0} Hz, p99 interval {p99_ms:.2} ms, {counts:?}");
    // Inside the wall at the start: nothing is sent until the hand has left it.
    let first_force = forces.iter().find(|(_, f)| f.length() > 0.0).unwrap();
    assert!(
        first_force.0 > 1.6,
        "a force at {:.3} s, before the hand pushed in",
        first_force.0
    );
    // Never above the nominal maximum; the clamp acted (the wall asks for 5 N and more).
    let peak = forces.iter().map(|(_, f)| f.length()).fold(0.0, f64::max);
    assert!(peak <= 3.3 + 1e-9 && peak > 3.0, "peak {peak} N");
    assert!(closed.guard.clamped > 0 && closed.guard.continuous > 0, "{closed:?}");
    // The mean over any 1000 consecutive servo ticks (a second of the device's 1 kHz scheduler) at
    // most the continuous force. Counted in ticks, as the guard counts: on a loaded machine the
    // scheduler catches up late ticks in a burst, so a second of wall clock may hold a few more.
    let window = 1000;
    let mut worst_mean_n: f64 = 0.0;
    let mut sum: f64 = forces.iter().take(window).map(|(_, f)| f.length()).sum();
    for i in window..=forces.len() {
        let mean = sum / window as f64;
        worst_mean_n = worst_mean_n.max(mean);
        assert!(
            mean <= 0.88 + 1e-9,
            "mean {mean} N over the 1000 ticks to {:.3} s",
            forces[i - 1].0
        );
        if i < forces.len() {
            sum += forces[i].1.length() - forces[i - window].1.length();
        }
    }
    eprintln!("peak {peak:.3} N, largest mean over a second {worst_mean_n:.4} N");
    // Zero within 10 ms (+ a few servo ticks) of the stall, and the last force of all zero.
    let after_stall: Vec<&(f64, DVec3)> = forces.iter().filter(|(t, _)| *t > stalled_at + 0.015).collect();
    assert!(!after_stall.is_empty());
    assert!(
        after_stall.iter().all(|(_, f)| *f == DVec3::ZERO),
        "force after the stall"
    );
    assert!(closed.guard.watchdog_trips >= 1);
    assert_eq!(forces.last().unwrap().1, DVec3::ZERO);
}

#[test]
fn a_missing_library_is_a_message_naming_the_paths_tried() {
    let e = OpenHaptics::open(Some(std::path::Path::new("/nowhere/libHD.so")))
        .err()
        .unwrap();
    assert!(matches!(e, HapticError::LibraryNotFound { .. }), "{e}");
    assert!(e.to_string().contains("/nowhere/libHD.so"), "{e}");
    // A library without the HD API's symbols: named, with the first one missing.
    let not_hd = std::env::current_exe().unwrap();
    let e = OpenHaptics::open(Some(&not_hd)).err().unwrap().to_string();
    assert!(e.starts_with("openhaptics: "), "{e}");
}
