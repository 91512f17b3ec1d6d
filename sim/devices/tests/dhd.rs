//! The Force Dimension backend against its device double (`doubles/dhd`, loaded at run time like
//! `libdhd.so`, playing an omega.3 with no force limit set): the wall scenario of
//! `common::wall_scenario`, plus what is DHD's own — the limit set from the model, the firmware
//! watchdog set, the device always named by id −1, forces off and the device closed at the end.

mod common;

use std::sync::Mutex;
use std::time::{Duration, Instant};

use common::{Probe, WALL_HAND, double_library, wall_scenario};
use stylet_devices::haptic::dhd::{Dhd, nominal_force_n};
use stylet_devices::haptic::{Backend, HapticDevice, HapticError};
use stylet_physics::glam::DVec3;

/// The double is one device per process: its tests take turns.
static DOUBLE: Mutex<()> = Mutex::new(());

#[test]
fn a_virtual_wall_through_the_dhd_double_is_safe_from_first_tick_to_last() {
    let _turn = DOUBLE.lock().unwrap_or_else(|e| e.into_inner());
    let library = double_library("stylet_dhd_double");
    let probe = Probe::open(&library);
    probe.set_hand(&WALL_HAND);
    let device = Dhd::open(Some(&library)).unwrap();
    assert_eq!(device.info().backend, Backend::Dhd);
    assert_eq!(device.info().model, "omega.3 (Stylet device double)");
    // No limit was set on the device (dhdGetMaxForce −1): the omega.3's nominal force, set.
    assert_eq!(device.info().max_force_n, 12.0);
    assert_eq!(nominal_force_n(33), Some(12.0));
    assert!(device.firmware_watchdog);
    assert_eq!(probe.state() & 0b101, 0b101, "open, with the firmware watchdog set");
    // A wall ten times stiffer than the check's: the omega's 12 N are reached through the
    // simulated hand's grip.
    let closed = wall_scenario(Box::new(device), &probe, 10.0);
    assert_eq!(closed.recoverable_errors, 0);
    // The firmware watchdog cuts in only if the servo thread itself was held up for more than
    // 10 ms (a loaded machine); forces were then enabled again and the checks above held.
    eprintln!("firmware watchdog cuts: {}", probe.state() >> 8);
}

/// The servo thread held up past the firmware watchdog (a loaded machine): the device cuts its
/// forces; Stylet's guard zeroes the force and ramps it in again, and forces are enabled again,
/// so the hand feels the wall again.
#[test]
fn a_servo_thread_held_up_past_the_firmware_watchdog_recovers_safely() {
    let _turn = DOUBLE.lock().unwrap_or_else(|e| e.into_inner());
    let library = double_library("stylet_dhd_double");
    let probe = Probe::open(&library);
    // The hand rests 4 mm inside a wall that pushes 0.5 N/mm: 2 N.
    probe.set_hand(&[[0.0, 0.0, 0.0, -4.0]]);
    let device = Dhd::open(Some(&library)).unwrap();
    let wall = |p: DVec3| DVec3::new(0.0, 0.0, 0.5 * (-p.z).max(0.0));
    // Each phase starts with 150 ms of no force (the hand out of the wall: the guard engages only
    // after 20 ticks of a small force), then the wall.
    let push_for = |d: Duration| {
        let start = Instant::now();
        while start.elapsed() < d {
            let f = if start.elapsed() < Duration::from_millis(150) {
                DVec3::ZERO
            } else {
                wall(device.reading().unwrap().position_mm)
            };
            device.set_force(f);
            std::thread::sleep(Duration::from_millis(1));
        }
    };
    push_for(Duration::from_millis(1500));
    let before = probe.forces().last().unwrap().1;
    assert!(before.z > 0.5, "the wall is felt: {before}");
    let trips = device.counts().guard.watchdog_trips;
    let hiccup_at_s = probe.forces().last().unwrap().0;
    probe.set_u32("stylet_double_hiccup", 30);
    push_for(Duration::from_millis(1500));
    assert!(probe.state() >> 8 >= 1, "the firmware watchdog cut the forces");
    assert!(
        device.counts().guard.watchdog_trips > trips,
        "the guard saw the late servo loop"
    );
    // The double accepts forces only while enabled: a second after the hiccup it takes the wall's
    // force again.
    let felt_again = probe
        .forces()
        .iter()
        .filter(|(t, _)| *t > hiccup_at_s + 1.2)
        .map(|(_, f)| f.z)
        .fold(0.0, f64::max);
    assert!(felt_again > 0.5, "forces enabled again and ramped in: {felt_again} N");
    Box::new(device).close().unwrap();
    assert_eq!(probe.violations(), 0);
}

#[test]
fn a_missing_or_foreign_library_is_a_message_naming_the_path() {
    let e = Dhd::open(Some(std::path::Path::new("/nowhere/libdhd.so")))
        .err()
        .unwrap();
    assert!(matches!(e, HapticError::LibraryNotFound { .. }), "{e}");
    assert!(e.to_string().contains("/nowhere/libdhd.so"), "{e}");
    // The OpenHaptics double is no DHD library: the first missing symbol is named.
    let e = Dhd::open(Some(&double_library("stylet_openhaptics_double")))
        .err()
        .unwrap()
        .to_string();
    assert!(e.starts_with("dhd: ") && e.contains("no symbol dhdOpen"), "{e}");
}
