//! Drift-free pacing of the 1 kHz haptic loop (docs/simulator.md "The haptic loop").
//!
//! Tick k is due at `start + k·period` and must be done by `start + (k + 1)·period`: deadlines
//! are absolute, so one late tick does not push every later one back (no drift). The pacer sleeps
//! until shortly before a tick is due and spins the rest, since `thread::sleep` overshoots by
//! tens of microseconds. Pacing decides only *when* a tick runs, never what it computes: the
//! simulation is a function of the recorded inputs alone.

use std::time::{Duration, Instant};

/// Sleeping stops this long before a deadline; the rest is spun (sleep overshoot on Linux is
/// typically 50–100 µs).
const SPIN: Duration = Duration::from_micros(150);

/// A loop more than this many periods behind (a stalled machine) starts a new schedule at the
/// current time instead of running the backlog back to back; the skipped periods count as missed.
pub const MAX_BACKLOG_PERIODS: u32 = 10;

/// When ticks are due.
#[derive(Debug)]
pub struct Pacer {
    start: Instant,
    period: Duration,
    /// Ticks of the current schedule are counted from this tick.
    first_tick: u64,
}

/// How one tick kept its deadline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// Time past the tick's deadline when it was done (zero when on time).
    pub late: Duration,
    /// Periods given up because the loop was too far behind (the schedule restarted).
    pub skipped_periods: u64,
}

impl Pacer {
    /// A schedule of `rate_hz` ticks per second starting now with tick `first_tick`.
    pub fn new(rate_hz: u32, first_tick: u64) -> Pacer {
        Pacer {
            start: Instant::now(),
            period: Duration::from_secs(1) / rate_hz.max(1),
            first_tick,
        }
    }

    pub fn period(&self) -> Duration {
        self.period
    }

    /// When `tick` is due (it may start then).
    pub fn due(&self, tick: u64) -> Instant {
        let n = tick.saturating_sub(self.first_tick);
        // u64 nanoseconds: no wrap for 584 years of ticks.
        self.start + Duration::from_nanos((self.period.as_nanos() as u64).saturating_mul(n))
    }

    /// Waits until `tick` is due (returns at once when it is already due).
    pub fn wait_until_due(&self, tick: u64) {
        let due = self.due(tick);
        loop {
            let now = Instant::now();
            let Some(left) = due.checked_duration_since(now) else {
                return;
            };
            if left > SPIN {
                std::thread::sleep(left - SPIN);
            } else {
                std::hint::spin_loop();
            }
        }
    }

    /// Call when `tick` is done: how late it was. When the loop has fallen more than
    /// [`MAX_BACKLOG_PERIODS`] behind, the schedule restarts at the next tick.
    pub fn done(&mut self, tick: u64) -> Timing {
        self.done_at(tick, Instant::now())
    }

    /// [`Pacer::done`] with the time the tick was done given, so the arithmetic is testable
    /// without a real clock.
    fn done_at(&mut self, tick: u64, now: Instant) -> Timing {
        let deadline = self.due(tick + 1);
        let late = now.saturating_duration_since(deadline);
        let mut skipped_periods = 0;
        if late > self.period * MAX_BACKLOG_PERIODS {
            skipped_periods = (late.as_nanos() / self.period.as_nanos().max(1)) as u64;
            self.start = now;
            self.first_tick = tick + 1;
        }
        Timing { late, skipped_periods }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deadlines_are_absolute() {
        let p = Pacer::new(1000, 5);
        assert_eq!(p.period(), Duration::from_millis(1));
        assert_eq!(p.due(5), p.start);
        assert_eq!(p.due(1005) - p.due(5), Duration::from_secs(1));
        // Ticks before the schedule's first are due at once.
        assert_eq!(p.due(0), p.start);
    }

    #[test]
    fn waiting_never_returns_before_a_tick_is_due() {
        let p = Pacer::new(1000, 0);
        for k in 0..20 {
            p.wait_until_due(k);
            assert!(Instant::now() >= p.due(k), "tick {k} started early");
        }
    }

    #[test]
    fn a_late_tick_does_not_move_the_later_deadlines() {
        let mut p = Pacer::new(1000, 0);
        let start = p.start;
        let ms = Duration::from_millis;
        // Tick 3 is done 4 ms after its deadline (start + 4 ms): late, but within the backlog.
        let t = p.done_at(3, start + ms(8));
        assert_eq!(
            t,
            Timing {
                late: ms(4),
                skipped_periods: 0
            }
        );
        // No drift: tick 4 is still due 4 ms after the start, and tick 1 000 a second after it.
        assert_eq!(p.due(4), start + ms(4));
        assert_eq!(p.due(1000), start + ms(1000));
        // A tick done before its deadline is not late.
        assert_eq!(p.done_at(4, start + ms(5)).late, Duration::ZERO);
    }

    #[test]
    fn a_stalled_loop_restarts_its_schedule_and_counts_the_gap() {
        let mut p = Pacer::new(1000, 0);
        let start = p.start;
        let ms = Duration::from_millis;
        // Tick 0 (deadline start + 1 ms) done 30 ms late: more than the backlog of 10 periods.
        let stalled = start + ms(31);
        let t = p.done_at(0, stalled);
        assert_eq!(
            t,
            Timing {
                late: ms(30),
                skipped_periods: 30
            }
        );
        // The next tick is due at the stall, not 30 ms before it, and on time within its period.
        assert_eq!(p.due(1), stalled);
        assert_eq!(p.due(2), stalled + ms(1));
        let on_time = p.done_at(1, stalled + Duration::from_micros(500));
        assert_eq!(
            on_time,
            Timing {
                late: Duration::ZERO,
                skipped_periods: 0
            }
        );
        // Exactly at the backlog limit the schedule is kept.
        let mut q = Pacer::new(1000, 0);
        let kept = q.done_at(0, q.start + ms(1) + ms(10));
        assert_eq!(kept.skipped_periods, 0);
        assert_eq!(q.due(1), q.start + ms(1));
    }
}
