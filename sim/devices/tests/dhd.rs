//! The Force Dimension backend against its device double (`doubles/dhd`, loaded at run time like
//! `libdhd.so`, playing an omega.3 with no force limit set): the wall scenario of
//! `common::wall_scenario`, plus what is DHD's own — the limit set from the model, the firmware
//! watchdog set, the device always named by id −1, forces off and the device closed at the end.

mod common;

use common::{Probe, WALL_HAND, double_library, wall_scenario};
use stylet_devices::haptic::dhd::{Dhd, nominal_force_n};
use stylet_devices::haptic::{Backend, HapticDevice, HapticError};

#[test]
fn a_virtual_wall_through_the_dhd_double_is_safe_from_first_tick_to_last() {
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
    // The servo thread never let the firmware watchdog cut in (a command every millisecond, zero
    // through the guard's stall).
    assert_eq!(probe.state() >> 8, 0, "firmware watchdog cuts");
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
