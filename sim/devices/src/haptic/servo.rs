//! What every backend's servo loop does each tick, whatever calls it (a vendor's scheduler or a
//! thread of ours): take the simulation's newest force without waiting, pass it through the guard,
//! and publish the reading and the force sent.

use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Instant;

use stylet_physics::glam::{DMat3, DVec3};

use super::mailbox::Mailbox;
use super::safety::{Computed, ForceGuard, Hold, SafetyLimits};
use super::{HapticError, ServoCounts, ServoReading};

/// Width of a tick-interval bin (ms) and how many there are (to 10 ms).
const INTERVAL_BIN_MS: f64 = 0.025;
const INTERVAL_BINS: usize = 400;

/// The state the simulation's thread and the servo loop share.
#[derive(Debug)]
pub(crate) struct Shared {
    forces: Mailbox<Computed>,
    pub readings: Mailbox<ServoReading>,
    hold: AtomicU8,
    ticks: AtomicU64,
    recoverable: AtomicU64,
    clamped: AtomicU64,
    continuous: AtomicU64,
    watchdog_trips: AtomicU64,
    /// Tick intervals, counted in bins of [`INTERVAL_BIN_MS`] (the last holds the longer ones).
    intervals: [AtomicU64; INTERVAL_BINS],
    /// Set once, by the servo loop, when a device error stops force output.
    pub fault: OnceLock<HapticError>,
    started: Instant,
}

impl Shared {
    pub fn new() -> Arc<Self> {
        Arc::new(Shared {
            forces: Mailbox::new(),
            readings: Mailbox::new(),
            hold: AtomicU8::new(0),
            ticks: AtomicU64::new(0),
            recoverable: AtomicU64::new(0),
            clamped: AtomicU64::new(0),
            continuous: AtomicU64::new(0),
            watchdog_trips: AtomicU64::new(0),
            intervals: std::array::from_fn(|_| AtomicU64::new(0)),
            fault: OnceLock::new(),
            started: Instant::now(),
        })
    }

    /// Publishes the simulation's newest force (N, device frame), stamped now on the servo loop's
    /// clock for its watchdog.
    pub fn put_force(&self, force_n: DVec3) {
        self.forces.put(Computed {
            force_n,
            published_s: self.started.elapsed().as_secs_f64(),
        });
    }

    pub fn set_hold(&self, hold: Hold) {
        let v = match hold {
            Hold::None => 0,
            Hold::Paused => 1,
            Hold::FocusLost => 2,
            Hold::Stopping => 3,
            Hold::Clutched => 4,
            Hold::Calibrating => 5,
        };
        self.hold.store(v, Ordering::Release);
    }

    pub fn hold(&self) -> Hold {
        match self.hold.load(Ordering::Acquire) {
            0 => Hold::None,
            1 => Hold::Paused,
            2 => Hold::FocusLost,
            4 => Hold::Clutched,
            5 => Hold::Calibrating,
            _ => Hold::Stopping,
        }
    }

    pub fn count_recoverable(&self) {
        self.recoverable.fetch_add(1, Ordering::Relaxed);
    }

    pub fn counts(&self) -> ServoCounts {
        ServoCounts {
            ticks: self.ticks.load(Ordering::Acquire),
            recoverable_errors: self.recoverable.load(Ordering::Relaxed),
            guard: super::GuardCounts {
                clamped: self.clamped.load(Ordering::Relaxed),
                continuous: self.continuous.load(Ordering::Relaxed),
                watchdog_trips: self.watchdog_trips.load(Ordering::Relaxed),
            },
        }
    }

    /// The `q` quantile of the tick intervals so far (ms, to a bin's width; the last bin reads as
    /// its lower edge).
    pub fn interval_percentile_ms(&self, q: f64) -> f64 {
        let counts: Vec<u64> = self.intervals.iter().map(|c| c.load(Ordering::Relaxed)).collect();
        let total: u64 = counts.iter().sum();
        if total == 0 {
            return f64::NAN;
        }
        let want = (q * total as f64).ceil() as u64;
        let mut seen = 0;
        for (i, c) in counts.iter().enumerate() {
            seen += c;
            if seen >= want {
                return ((i + 1) as f64 * INTERVAL_BIN_MS).min(INTERVAL_BINS as f64 * INTERVAL_BIN_MS);
            }
        }
        INTERVAL_BINS as f64 * INTERVAL_BIN_MS
    }

    /// Waits (up to `timeout`) until the servo loop has run `ticks` more ticks; `false` if it
    /// did not (stopped or stalled).
    pub fn wait_ticks(&self, ticks: u64, timeout: std::time::Duration) -> bool {
        let start = self.ticks.load(Ordering::Acquire);
        let deadline = Instant::now() + timeout;
        while self.ticks.load(Ordering::Acquire) < start + ticks {
            if Instant::now() > deadline {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_micros(200));
        }
        true
    }
}

/// The servo loop's own state: the guard and the last force it took.
pub(crate) struct ServoCore {
    guard: ForceGuard,
    last: Option<Computed>,
    last_time_s: Option<f64>,
    shared: Arc<Shared>,
}

impl ServoCore {
    pub fn new(limits: SafetyLimits, shared: Arc<Shared>) -> Self {
        ServoCore {
            guard: ForceGuard::new(limits),
            last: None,
            last_time_s: None,
            shared,
        }
    }

    /// One servo tick: the force (N, device frame) to send for this reading.
    pub fn tick(&mut self, position_mm: DVec3, rotation: Option<DMat3>, buttons: u32) -> DVec3 {
        self.tick_held(position_mm, rotation, buttons, None)
    }

    /// One servo tick, held at zero by the device itself when `device_hold` says why (an
    /// uncalibrated device), whatever the simulation's side holds.
    pub fn tick_held(
        &mut self,
        position_mm: DVec3,
        rotation: Option<DMat3>,
        buttons: u32,
        device_hold: Option<Hold>,
    ) -> DVec3 {
        let s = &self.shared;
        self.last = s.forces.try_latest(self.last);
        let time_s = s.started.elapsed().as_secs_f64();
        if let Some(previous) = self.last_time_s.replace(time_s) {
            let bin = (((time_s - previous) * 1000.0) / INTERVAL_BIN_MS) as usize;
            s.intervals[bin.min(INTERVAL_BINS - 1)].fetch_add(1, Ordering::Relaxed);
        }
        let force = self
            .guard
            .filter(self.last, time_s, device_hold.unwrap_or_else(|| s.hold()));
        let c = self.guard.counts();
        s.clamped.store(c.clamped, Ordering::Relaxed);
        s.continuous.store(c.continuous, Ordering::Relaxed);
        s.watchdog_trips.store(c.watchdog_trips, Ordering::Relaxed);
        let tick = s.ticks.load(Ordering::Relaxed);
        s.readings.try_put(ServoReading {
            tick,
            time_s,
            position_mm,
            rotation,
            buttons,
            force,
        });
        s.ticks.store(tick + 1, Ordering::Release);
        force.sent_n
    }
}
