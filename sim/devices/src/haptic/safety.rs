//! The force guard: every force on its way to a person's hand passes through it, once per servo
//! tick (docs/devices.md "Safety"). In order:
//!
//! 1. **Hold.** Paused, out of focus or stopping: zero, and the force must engage afresh.
//!    A computed force that is not finite (NaN, infinite) is zero the same way.
//! 2. **Watchdog.** The newest force the simulation published is older than
//!    [`SafetyLimits::watchdog_s`]: zero (a stalled simulation must not leave its last force on
//!    the hand), engage afresh. Its age counts from when it was published, not from when the servo
//!    loop first saw it, so a servo loop held up for a while cannot stretch the limit.
//! 3. **Engage.** Forces start only once the computed force has stayed below
//!    [`SafetyLimits::engage_below_n`] for [`SafetyLimits::engage_ticks`] ticks (a hand that opens
//!    the device already inside the skin is not kicked out), then
//! 4. **ramp** in linearly over [`SafetyLimits::ramp_s`];
//! 5. **clamp** to the device's nominal maximum (the direction kept), and
//! 6. **continuous limit**: the mean magnitude over the last
//!    [`SafetyLimits::continuous_window_ticks`] servo ticks (a second at 1 kHz; ticks before the
//!    device opened count as zero) stays at or below the nominal continuous force (the motors'
//!    thermal limit), the newest force scaled down to keep it there.
//!
//! Time is passed in (seconds on the servo loop's monotonic clock), so the guard is a pure
//! function of its inputs and tested without a clock.

use std::collections::VecDeque;

use stylet_physics::glam::DVec3;

/// The limits a guard enforces; the forces from the device's own nominal figures, read when it
/// opens.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafetyLimits {
    /// Largest force magnitude sent (N): the device's nominal maximum.
    pub max_force_n: f64,
    /// Largest mean magnitude over the window (N): the device's nominal continuous force.
    pub max_continuous_force_n: f64,
    /// The window the continuous force is averaged over (servo ticks).
    pub continuous_window_ticks: usize,
    /// The computed force must stay below this (N) …
    pub engage_below_n: f64,
    /// … for this many consecutive ticks before forces engage.
    pub engage_ticks: u32,
    /// Forces ramp from zero to full over this time once engaged (s).
    pub ramp_s: f64,
    /// Zero force when the simulation has produced no new force for this long (s).
    pub watchdog_s: f64,
}

impl SafetyLimits {
    /// The guard's defaults around a device's nominal forces (N).
    pub fn for_device(max_force_n: f64, max_continuous_force_n: f64) -> Self {
        SafetyLimits {
            max_force_n,
            max_continuous_force_n: max_continuous_force_n.min(max_force_n),
            continuous_window_ticks: 1000,
            engage_below_n: 0.2,
            engage_ticks: 20,
            ramp_s: 1.0,
            watchdog_s: 0.010,
        }
    }
}

/// Why the guard holds forces at zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hold {
    /// Nothing holds: forces flow.
    None,
    /// The session is paused.
    Paused,
    /// The simulator's window lost the focus.
    FocusLost,
    /// The clutch is held: the hand repositions the stylus while the tool stays.
    Clutched,
    /// The device reports itself uncalibrated: positions cannot be trusted.
    Calibrating,
    /// The device is being closed, or an error stopped force output.
    Stopping,
}

/// The simulation's newest force and when it was published (s, on the servo loop's clock).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Computed {
    pub force_n: DVec3,
    pub published_s: f64,
}

/// What the guard did to one tick's force.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Limits {
    /// Zero: held (paused, no focus, stopping).
    pub held: bool,
    /// Zero: the watchdog fired (no new force in time).
    pub watchdog: bool,
    /// Zero: waiting for a small force to engage.
    pub waiting: bool,
    /// Zero: the computed force was not finite (NaN or infinite), so forces engage afresh.
    pub not_finite: bool,
    /// Scaled by the ramp.
    pub ramping: bool,
    /// Clamped to the nominal maximum.
    pub clamped: bool,
    /// Scaled down to the continuous limit.
    pub continuous: bool,
}

/// One tick's force: as computed and as sent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Guarded {
    pub computed_n: DVec3,
    pub sent_n: DVec3,
    pub limits: Limits,
}

/// How often each limit acted since the guard was made.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GuardCounts {
    pub clamped: u64,
    pub continuous: u64,
    pub watchdog_trips: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    /// Forces off until the computed force has been small for `small_ticks`.
    Waiting { small_ticks: u32 },
    /// Forces on, scaled by the ramp that started at `since_s`.
    Engaged { since_s: f64 },
}

/// The guard of one device (see the module's doc).
#[derive(Debug, Clone)]
pub struct ForceGuard {
    limits: SafetyLimits,
    state: State,
    /// Whether the watchdog is tripped (counted once per stall).
    tripped: bool,
    /// The last sent magnitudes (N), one per tick, at most a window less one, and their sum.
    window: VecDeque<f64>,
    window_sum_n: f64,
    /// Ticks recorded.
    recorded: u64,
    counts: GuardCounts,
    /// When the servo loop last asked (s, its clock).
    last_tick_s: Option<f64>,
}

impl ForceGuard {
    pub fn new(limits: SafetyLimits) -> Self {
        ForceGuard {
            limits,
            state: State::Waiting { small_ticks: 0 },
            tripped: false,
            window: VecDeque::new(),
            window_sum_n: 0.0,
            recorded: 0,
            counts: GuardCounts::default(),
            last_tick_s: None,
        }
    }

    pub fn limits(&self) -> &SafetyLimits {
        &self.limits
    }

    pub fn counts(&self) -> GuardCounts {
        self.counts
    }

    /// The force to send this servo tick at `now_s`, from the simulation's newest `computed`
    /// force (`None` before the first).
    pub fn filter(&mut self, computed: Option<Computed>, now_s: f64, hold: Hold) -> Guarded {
        let computed_n = computed.map_or(DVec3::ZERO, |c| c.force_n);
        let mut limits = Limits::default();
        let zero = |guard: &mut Self, limits: Limits| {
            guard.state = State::Waiting { small_ticks: 0 };
            guard.record(0.0);
            Guarded {
                computed_n,
                sent_n: DVec3::ZERO,
                limits,
            }
        };
        // The servo loop itself late by more than the watchdog (the machine stalled it): the hand
        // may have moved meanwhile, and a device's own watchdog may have cut its forces.
        let servo_gap = self
            .last_tick_s
            .replace(now_s)
            .is_some_and(|t| now_s - t > self.limits.watchdog_s);
        if hold != Hold::None {
            limits.held = true;
            return zero(self, limits);
        }
        if servo_gap {
            // Zero this tick, then the force ramps in again from zero (no jump to whatever the
            // simulation computes now); a guard still waiting to engage keeps waiting.
            self.counts.watchdog_trips += 1;
            limits.watchdog = true;
            return self.zero_then_ramp(computed_n, now_s, limits);
        }
        if !computed_n.is_finite() {
            limits.not_finite = true;
            return zero(self, limits);
        }
        // Watchdog: how old the newest force is.
        let fresh = computed.is_some_and(|c| now_s - c.published_s <= self.limits.watchdog_s);
        if !fresh {
            if !self.tripped && computed.is_some() {
                self.counts.watchdog_trips += 1;
            }
            self.tripped = computed.is_some();
            limits.watchdog = true;
            // Zero while stalled; once the simulation resumes the force ramps in again from zero
            // (the needle may be held in tissue, so waiting for a small force could last the rest
            // of the session). A guard not yet engaged keeps waiting.
            return self.zero_then_ramp(computed_n, now_s, limits);
        }
        self.tripped = false;
        let magnitude = computed_n.length();
        let since_s = match self.state {
            State::Waiting { small_ticks } => {
                let small_ticks = if magnitude < self.limits.engage_below_n {
                    small_ticks + 1
                } else {
                    0
                };
                if small_ticks < self.limits.engage_ticks {
                    self.state = State::Waiting { small_ticks };
                    limits.waiting = true;
                    self.record(0.0);
                    return Guarded {
                        computed_n,
                        sent_n: DVec3::ZERO,
                        limits,
                    };
                }
                self.state = State::Engaged { since_s: now_s };
                now_s
            }
            State::Engaged { since_s } => since_s,
        };
        let ramp = ((now_s - since_s) / self.limits.ramp_s).clamp(0.0, 1.0);
        let mut sent = computed_n;
        if ramp < 1.0 {
            sent *= ramp;
            limits.ramping = true;
        }
        if sent.length() > self.limits.max_force_n {
            sent = sent.normalize_or_zero() * self.limits.max_force_n;
            limits.clamped = true;
            self.counts.clamped += 1;
        }
        // Continuous limit: the window's mean with this force in it at most the limit.
        let n = self.limits.continuous_window_ticks.max(1) as f64;
        let allowed_n = (self.limits.max_continuous_force_n * n - self.window_sum_n).max(0.0);
        if sent.length() > allowed_n {
            sent = sent.normalize_or_zero() * allowed_n;
            limits.continuous = true;
            self.counts.continuous += 1;
        }
        self.record(sent.length());
        Guarded {
            computed_n,
            sent_n: sent,
            limits,
        }
    }

    /// Adds this tick's magnitude, keeping a window less one of them.
    /// Zero this tick; an engaged guard ramps the force in again from zero (rule 4) when forces
    /// flow, a waiting one keeps waiting.
    fn zero_then_ramp(&mut self, computed_n: DVec3, now_s: f64, limits: Limits) -> Guarded {
        if let State::Engaged { .. } = self.state {
            self.state = State::Engaged { since_s: now_s };
        }
        self.record(0.0);
        Guarded {
            computed_n,
            sent_n: DVec3::ZERO,
            limits,
        }
    }

    fn record(&mut self, magnitude_n: f64) {
        self.window.push_back(magnitude_n);
        self.window_sum_n += magnitude_n;
        while self.window.len() >= self.limits.continuous_window_ticks.max(1) {
            let old = self.window.pop_front().unwrap_or(0.0);
            self.window_sum_n -= old;
        }
        // Re-summed once a window, so rounding cannot accumulate over a long session.
        self.recorded += 1;
        if self
            .recorded
            .is_multiple_of(self.limits.continuous_window_ticks.max(1) as u64)
        {
            self.window_sum_n = self.window.iter().sum();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 0.001;

    fn limits() -> SafetyLimits {
        SafetyLimits::for_device(3.3, 0.88)
    }

    /// Runs `ticks` servo ticks with a fresh force each, from tick `from`.
    fn run(g: &mut ForceGuard, from: u64, ticks: u64, force: DVec3) -> Vec<Guarded> {
        (from..from + ticks)
            .map(|k| {
                let now_s = k as f64 * DT;
                g.filter(
                    Some(Computed {
                        force_n: force,
                        published_s: now_s,
                    }),
                    now_s,
                    Hold::None,
                )
            })
            .collect()
    }

    #[test]
    fn forces_wait_for_a_small_force_then_ramp_in_over_a_second() {
        let mut g = ForceGuard::new(limits());
        // The hand opens the device inside the skin: 2 N computed, nothing sent.
        let inside = run(&mut g, 0, 500, DVec3::new(0.0, 0.0, 2.0));
        assert!(inside.iter().all(|o| o.sent_n == DVec3::ZERO && o.limits.waiting));
        // Small for 19 ticks: still waiting; the 20th engages.
        let small = run(&mut g, 500, 20, DVec3::new(0.0, 0.0, 0.1));
        assert!(small[..19].iter().all(|o| o.limits.waiting));
        assert!(
            !small[19].limits.waiting && small[19].sent_n == DVec3::ZERO,
            "ramp at 0"
        );
        // Then 0.5 N ramps in: half after 0.5 s, full after 1 s.
        let f = DVec3::new(0.5, 0.0, 0.0);
        let ramp = run(&mut g, 520, 1100, f);
        assert!(
            (ramp[499].sent_n.x - 0.5 * 500.0 / 1000.0).abs() < 1e-12,
            "{:?}",
            ramp[499]
        );
        assert!(ramp[499].limits.ramping);
        assert_eq!(ramp[1099].sent_n, f);
        assert!(!ramp[1099].limits.ramping);
    }

    fn engaged() -> ForceGuard {
        let mut g = ForceGuard::new(limits());
        run(&mut g, 0, 1100, DVec3::ZERO);
        g
    }

    #[test]
    fn forces_are_clamped_to_the_nominal_maximum_keeping_their_direction() {
        let mut g = engaged();
        let o = run(&mut g, 1100, 1, DVec3::new(0.0, 30.0, 40.0))[0];
        assert!((o.sent_n.length() - 3.3).abs() < 1e-12, "{o:?}");
        assert!((o.sent_n.normalize() - DVec3::new(0.0, 0.6, 0.8)).length() < 1e-12);
        assert!(o.limits.clamped);
        assert_eq!(g.counts().clamped, 1);
    }

    #[test]
    fn the_mean_over_a_second_stays_at_the_continuous_force() {
        let mut g = engaged();
        // 3 N held for two seconds: the first second's zeros (engaging) let it through for a
        // while, then the mean over any second stays at 0.88 N.
        let out = run(&mut g, 1100, 2000, DVec3::new(3.0, 0.0, 0.0));
        assert!(out[0].sent_n.x == 3.0);
        assert!(out.iter().any(|o| o.limits.continuous));
        for end in 1000..2000 {
            let mean: f64 = out[end - 999..=end].iter().map(|o| o.sent_n.length()).sum::<f64>() / 1000.0;
            assert!(mean <= 0.88 + 1e-9, "mean {mean} at {end}");
        }
        assert!(g.counts().continuous > 0);
    }

    #[test]
    fn a_stalled_simulation_zeroes_the_force_within_10_ms_and_ramps_it_back() {
        let mut g = engaged();
        let f = DVec3::new(1.0, 0.0, 0.0);
        run(&mut g, 1100, 10, f);
        // The simulation stalls: the same force, published at tick 1109, tick after tick.
        let last = Computed {
            force_n: f,
            published_s: 1109.0 * DT,
        };
        let stalled: Vec<Guarded> = (1110..1130)
            .map(|k| g.filter(Some(last), k as f64 * DT, Hold::None))
            .collect();
        let first_zero = stalled.iter().position(|o| o.sent_n == DVec3::ZERO).unwrap();
        assert!(first_zero <= 10, "zero {first_zero} ms after the last force");
        assert!(stalled[first_zero..].iter().all(|o| o.limits.watchdog));
        assert_eq!(g.counts().watchdog_trips, 1, "one stall, one trip");
        // It resumes with the same 1 N: the force ramps in again from zero, with no jump.
        let resumed = run(&mut g, 1130, 50, f);
        assert!(resumed.iter().all(|o| !o.limits.waiting && o.limits.ramping));
        assert!(resumed[0].sent_n.length() < 0.01);
        assert!(resumed.windows(2).all(|w| w[1].sent_n.length() >= w[0].sent_n.length()));
    }

    #[test]
    fn a_force_the_servo_loop_first_sees_late_is_as_old_as_when_it_was_published() {
        let mut g = engaged();
        let f = DVec3::new(1.0, 0.0, 0.0);
        run(&mut g, 1100, 10, f);
        // The last force before a stall was published 0.4 ms into tick 1109; the servo loop, held
        // up by 8 ms (less than its own gap check), first sees it 7.6 ms old at tick 1117.
        let last = Computed {
            force_n: f,
            published_s: 1109.4 * DT,
        };
        let seen: Vec<Guarded> = (1117..1125)
            .map(|k| g.filter(Some(last), k as f64 * DT, Hold::None))
            .collect();
        assert!(seen[..3].iter().all(|o| o.sent_n == f), "{seen:?}");
        assert!(
            seen[3..].iter().all(|o| o.sent_n == DVec3::ZERO && o.limits.watchdog),
            "zero 10 ms after it was published, not after it was seen: {seen:?}"
        );
        assert_eq!(g.counts().watchdog_trips, 1);
    }

    #[test]
    fn a_late_servo_loop_zeroes_the_force_and_ramps_it_in_again() {
        let mut g = engaged();
        let f = DVec3::new(1.0, 0.0, 0.0);
        let before = run(&mut g, 1100, 10, f);
        assert!(before.last().unwrap().sent_n.length() > 0.5);
        let trips = g.counts().watchdog_trips;
        // The servo loop is 25 ms late, while the simulation kept producing forces.
        let newest = Computed {
            force_n: f,
            published_s: 1135.0 * DT,
        };
        let late = g.filter(Some(newest), 1135.0 * DT, Hold::None);
        assert_eq!(late.sent_n, DVec3::ZERO);
        assert!(late.limits.watchdog);
        assert_eq!(g.counts().watchdog_trips, trips + 1);
        // It ramps in again from zero, without waiting for a small force (the needle may well be
        // in tissue).
        let resumed = run(&mut g, 1136, 500, f);
        assert!(resumed.iter().all(|o| !o.limits.waiting && o.limits.ramping));
        assert!(resumed[0].sent_n.length() < 0.01);
        assert!(resumed.windows(2).all(|w| w[1].sent_n.length() >= w[0].sent_n.length()));
        assert!(
            (resumed[499].sent_n.length() - 0.5).abs() < 0.01,
            "half way after half a second"
        );
    }

    #[test]
    fn pausing_losing_focus_and_stopping_send_zero() {
        for hold in [
            Hold::Paused,
            Hold::FocusLost,
            Hold::Clutched,
            Hold::Calibrating,
            Hold::Stopping,
        ] {
            let mut g = engaged();
            let o = g.filter(
                Some(Computed {
                    force_n: DVec3::X,
                    published_s: 1.2,
                }),
                1.2,
                hold,
            );
            assert_eq!(o.sent_n, DVec3::ZERO, "{hold:?}");
            assert!(o.limits.held);
            let again = g.filter(
                Some(Computed {
                    force_n: DVec3::X,
                    published_s: 1.201,
                }),
                1.201,
                Hold::None,
            );
            assert!(again.limits.waiting, "{hold:?}: engages afresh");
        }
    }

    #[test]
    fn a_force_that_is_not_finite_sends_zero_and_engages_afresh() {
        for bad in [f64::NAN, f64::INFINITY] {
            let mut g = engaged();
            let o = run(&mut g, 1100, 1, DVec3::new(0.0, bad, 1.0))[0];
            assert_eq!(o.sent_n, DVec3::ZERO);
            assert!(o.limits.not_finite);
            assert!(run(&mut g, 1101, 1, DVec3::X)[0].limits.waiting);
        }
    }

    #[test]
    fn no_force_before_the_first_computed_one() {
        let mut g = ForceGuard::new(limits());
        let o = g.filter(None, 0.0, Hold::None);
        assert_eq!(o.sent_n, DVec3::ZERO);
        assert_eq!(g.counts().watchdog_trips, 0);
    }
}
