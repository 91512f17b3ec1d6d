//! The OpenHaptics backend against its device double (`doubles/openhaptics`, loaded at run time
//! like `libHD.so`, playing a Touch: 3.3 N peak, 0.88 N continuous): the wall scenario of
//! `common::wall_scenario`, plus what is OpenHaptics' own — frames paired, the continuous limit
//! acting, the scheduler stopped at the end, and the calibration: an uncalibrated device holds
//! forces at zero until it is calibrated.

mod common;

use std::sync::Mutex;
use std::time::{Duration, Instant};

use common::{Probe, WALL_HAND, double_library, wall_scenario};
use stylet_devices::haptic::openhaptics::OpenHaptics;
use stylet_devices::haptic::{Calibration, HapticDevice, HapticError};
use stylet_physics::glam::DVec3;

/// The double is one device per process: its tests take turns.
static DOUBLE: Mutex<()> = Mutex::new(());

#[test]
fn a_virtual_wall_through_the_openhaptics_double_is_safe_from_first_tick_to_last() {
    let _turn = DOUBLE.lock().unwrap_or_else(|e| e.into_inner());
    let library = double_library("stylet_openhaptics_double");
    let probe = Probe::open(&library);
    probe.set_hand(&WALL_HAND);
    let device = OpenHaptics::open(Some(&library)).unwrap();
    assert_eq!(device.info().model, "Touch (Stylet device double)");
    assert_eq!(device.info().max_force_n, 3.3);
    assert_eq!(device.info().max_continuous_force_n, 0.88);
    let closed = wall_scenario(Box::new(device), &probe, 1.0);
    // The wall asks for more than 0.88 N for over a second: the continuous limit acted.
    assert!(closed.guard.continuous > 0, "{closed:?}");
    assert_eq!(probe.state(), 0, "closed and the scheduler stopped");
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

/// A Touch that needs its stylus in the inkwell gets no force (the guard holds it) until the
/// driver can calibrate; then Stylet asks for the inkwell calibration (the style the Touch
/// supports) and forces engage and ramp in.
#[test]
fn an_uncalibrated_touch_holds_forces_until_it_is_calibrated_in_its_inkwell() {
    let _turn = DOUBLE.lock().unwrap_or_else(|e| e.into_inner());
    let library = double_library("stylet_openhaptics_double");
    let probe = Probe::open(&library);
    probe.set_hand(&[[0.0, 0.0, 0.0, 10.0]]);
    probe.set_u32("stylet_double_set_calibration", 0x5002);
    let device = OpenHaptics::open(Some(&library)).unwrap();
    let small = DVec3::new(0.0, 0.0, 0.1);
    let push_for = |device: &OpenHaptics, d: Duration| {
        let start = Instant::now();
        while start.elapsed() < d {
            device.set_force(small);
            std::thread::sleep(Duration::from_millis(1));
        }
    };
    push_for(&device, Duration::from_millis(400));
    assert_eq!(
        device.calibration(),
        Calibration {
            needs_manual_input: true,
            updates: 0
        }
    );
    assert!(device.reading().unwrap().force.limits.held);
    assert!(
        probe.forces().iter().all(|(_, f)| *f == DVec3::ZERO),
        "a force while uncalibrated"
    );
    // The stylus rests in its inkwell: the driver can now update the calibration, and the force
    // ramps in over a second from then. Pushed until it is whole (on a loaded machine the servo
    // thread may take longer to get there; 15 s is a deadline, not a measurement).
    probe.set_u32("stylet_double_set_calibration", 0x5001);
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(15)
        && probe.forces().last().is_none_or(|(_, f)| (*f - small).length() >= 1e-9)
    {
        push_for(&device, Duration::from_millis(100));
    }
    assert_eq!(
        device.calibration(),
        Calibration {
            needs_manual_input: false,
            updates: 1
        }
    );
    assert_eq!(probe.count("stylet_double_calibration_updates"), 1);
    let last = probe.forces().last().unwrap().1;
    assert!((last - small).length() < 1e-9, "ramped in after calibrating: {last}");
    Box::new(device).close().unwrap();
    assert_eq!(probe.violations(), 0);
}
