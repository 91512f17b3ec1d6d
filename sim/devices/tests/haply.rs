//! The Haply backend against its device double (`doubles/haply`, a loopback WebSocket server
//! speaking the Inverse Service's protocol over a simulated Inverse3): the wall scenario of
//! `common::wall_scenario`, plus what is Haply's own — the device found in the inventory, every
//! message in the 3.5 wire format for that device, the connection closed at the end, and a
//! service that stops answering stopping force output with a message.

mod common;

use std::time::{Duration, Instant};

use common::{Record, WALL_HAND, wall_scenario};
use stylet_devices::haptic::haply::{Haply, MAX_CONTINUOUS_FORCE_N, MAX_FORCE_N};
use stylet_devices::haptic::{Backend, HapticDevice};
use stylet_haply_double::{DEVICE_ID, HaplyDouble};
use stylet_physics::glam::DVec3;

impl Record for HaplyDouble {
    fn forces(&self) -> Vec<(f64, DVec3)> {
        HaplyDouble::forces(self)
            .iter()
            .map(|f| (f[0], DVec3::new(f[1], f[2], f[3])))
            .collect()
    }
    fn violations(&self) -> u64 {
        HaplyDouble::violations(self)
    }
    /// Connected; the server notices a close within its next read, so this waits for it a little.
    fn is_open(&self) -> bool {
        let start = Instant::now();
        while self.connected() && start.elapsed() < Duration::from_millis(500) {
            std::thread::sleep(Duration::from_millis(5));
        }
        self.connected()
    }
}

#[test]
fn a_virtual_wall_through_the_haply_double_is_safe_from_first_tick_to_last() {
    let double = HaplyDouble::start(WALL_HAND.to_vec()).unwrap();
    let device = Haply::open(Some(&double.url)).unwrap();
    assert_eq!(device.info().backend, Backend::Haply);
    assert_eq!(device.info().model, format!("Inverse3 {DEVICE_ID}"));
    assert_eq!(device.device_id, DEVICE_ID);
    assert_eq!(device.info().max_force_n, MAX_FORCE_N);
    assert_eq!(device.info().max_continuous_force_n, MAX_CONTINUOUS_FORCE_N);
    assert!(double.connected());
    let closed = wall_scenario(Box::new(device), &double, 1.0);
    assert_eq!(closed.recoverable_errors, 0);
    assert_eq!(double.connections(), 1);
}

#[test]
fn the_grip_buttons_reach_the_reading() {
    let double = HaplyDouble::start(vec![[0.0, 10.0, 20.0, 30.0]]).unwrap();
    double.set_buttons(0b10);
    let device = Haply::open(Some(&double.url)).unwrap();
    let start = Instant::now();
    let reading = loop {
        if let Some(r) = device.reading()
            && r.buttons == 0b10
        {
            break r;
        }
        assert!(start.elapsed() < Duration::from_secs(2), "no reading with the b button");
        std::thread::sleep(Duration::from_millis(2));
    };
    assert!(
        (reading.position_mm - DVec3::new(10.0, 20.0, 30.0)).length() < 0.5,
        "{reading:?}"
    );
    Box::new(device).close().unwrap();
}

#[test]
fn a_service_that_goes_away_stops_force_output_with_a_message() {
    let double = HaplyDouble::start(vec![[0.0, 0.0, 0.0, 10.0]]).unwrap();
    let device = Haply::open(Some(&double.url)).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    assert!(device.fault().is_none());
    drop(double);
    let start = Instant::now();
    while device.fault().is_none() {
        assert!(
            start.elapsed() < Duration::from_secs(2),
            "no fault after the service went away"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let e = Box::new(device).close().unwrap_err().to_string();
    assert!(e.starts_with("haply: ws://127.0.0.1:"), "{e}");
}
