//! The OpenHaptics backend against its device double (`doubles/openhaptics`, loaded at run time
//! like `libHD.so`, playing a Touch: 3.3 N peak, 0.88 N continuous): the wall scenario of
//! `common::wall_scenario`, plus what is OpenHaptics' own — frames paired, the continuous limit
//! acting, the scheduler stopped at the end.

mod common;

use common::{Probe, WALL_HAND, double_library, wall_scenario};
use stylet_devices::haptic::openhaptics::OpenHaptics;
use stylet_devices::haptic::{HapticDevice, HapticError};

#[test]
fn a_virtual_wall_through_the_openhaptics_double_is_safe_from_first_tick_to_last() {
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
