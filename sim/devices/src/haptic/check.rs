//! The headless device check (`stylet device check`): a virtual wall — the plane z = 0 of the
//! device's frame, pushing 0.5 N/mm into +z below it — rendered for a while, with what a person
//! setting up a skills lab needs to know: the servo rate and its jitter, where the stylus went, the
//! largest force sent and how often the guard clamped or its watchdog fired.

use std::time::{Duration, Instant};

use stylet_physics::glam::DVec3;

use super::{Calibration, HapticDevice, HapticError, ServoCounts};

/// The wall's stiffness (N/mm).
pub const WALL_N_PER_MM: f64 = 0.5;

/// The wall's force on a stylus at `position_mm` (device frame).
pub fn wall_force(position_mm: DVec3) -> DVec3 {
    DVec3::new(0.0, 0.0, WALL_N_PER_MM * (-position_mm.z).max(0.0))
}

/// What a check measured.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckReport {
    pub model: String,
    pub seconds: f64,
    pub counts: ServoCounts,
    /// Servo ticks per second over the check.
    pub servo_rate_hz: f64,
    /// The 99th percentile of the servo loop's tick intervals (ms).
    pub interval_p99_ms: f64,
    /// The stylus' range in the device frame (mm).
    pub position_min_mm: DVec3,
    pub position_max_mm: DVec3,
    /// The largest force magnitude sent (N).
    pub largest_sent_n: f64,
    /// The device's calibration at the end of the check.
    pub calibration: Calibration,
}

impl CheckReport {
    pub fn lines(&self) -> Vec<String> {
        let c = &self.counts;
        let (lo, hi) = (self.position_min_mm, self.position_max_mm);
        vec![
            format!("device: {}", self.model),
            format!(
                "servo loop: {:.0} Hz over {:.1} s ({} ticks), 99 % of ticks within {:.2} ms",
                self.servo_rate_hz, self.seconds, c.ticks, self.interval_p99_ms
            ),
            format!(
                "stylus range: x {:.1} … {:.1}, y {:.1} … {:.1}, z {:.1} … {:.1} mm",
                lo.x, hi.x, lo.y, hi.y, lo.z, hi.z
            ),
            format!("largest force sent: {:.2} N", self.largest_sent_n),
            format!(
                "guard: clamped to the nominal maximum {} times, to the continuous limit {} times; watchdog fired {} times; {} recoverable device errors",
                c.guard.clamped, c.guard.continuous, c.guard.watchdog_trips, c.recoverable_errors
            ),
            match (self.calibration.needs_manual_input, self.calibration.updates) {
                (true, _) => "calibration: needed — put the stylus in its inkwell (forces were held)".into(),
                (false, 0) => "calibration: nothing to do".into(),
                (false, n) => format!("calibration: updated {n} times"),
            },
            "force at the end: zero (device closed)".into(),
        ]
    }
}

/// Renders the wall on `device` for `seconds` from this thread at about 1 kHz, then closes it
/// (zero force). The servo loop runs from the moment the device opened; the hand may start
/// inside the wall (forces engage once it has left).
pub fn run_wall(device: Box<dyn HapticDevice>, seconds: f64) -> Result<CheckReport, HapticError> {
    let model = device.info().model.clone();
    let start = Instant::now();
    let first = device.counts().ticks;
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    let mut largest: f64 = 0.0;
    while start.elapsed().as_secs_f64() < seconds {
        if let Some(r) = device.reading() {
            device.set_force(wall_force(r.position_mm));
            lo = lo.min(r.position_mm);
            hi = hi.max(r.position_mm);
            largest = largest.max(r.force.sent_n.length());
        }
        if let Some(e) = device.fault() {
            let _ = device.close();
            return Err(e);
        }
        std::thread::sleep(Duration::from_micros(900));
    }
    let elapsed = start.elapsed().as_secs_f64();
    let interval_p99_ms = device.interval_p99_ms();
    let calibration = device.calibration();
    let counts = device.close()?;
    Ok(CheckReport {
        model,
        seconds: elapsed,
        servo_rate_hz: (counts.ticks - first) as f64 / elapsed,
        interval_p99_ms,
        counts,
        position_min_mm: lo,
        position_max_mm: hi,
        largest_sent_n: largest,
        calibration,
    })
}
