//! The arm every device double simulates (docs/devices.md "Device doubles"): the stylus a mass
//! on a spring, pulled along by a scripted hand and pushed by the forces the backend sends, so a
//! wall the backend renders pushes the stylus back out. Each double wraps it in its vendor's API
//! and records every force it accepted, for the tests to read back.
#![allow(clippy::missing_safety_doc)]

use std::time::Instant;

/// Stylus mass (kg), the hand's grip as a spring (N/mm) and its damping (N·s/mm).
const MASS_KG: f64 = 0.05;
const GRIP_N_PER_MM: f64 = 0.5;
const GRIP_DAMPING_N_S_PER_MM: f64 = 0.008;
/// Integration step (s) and the longest gap integrated at once (s).
const STEP_S: f64 = 1e-4;
const LONGEST_GAP_S: f64 = 0.05;

/// A scripted hand moving a stylus that feels the forces sent.
#[derive(Debug, Clone)]
pub struct Arm {
    /// The scripted hand: (t s, x, y, z mm) keyframes, linear between, held after the last.
    hand: Vec<[f64; 4]>,
    /// Button bits the device reports.
    pub buttons: u32,
    /// The stylus (mm, mm/s) and the force last accepted (N).
    position_mm: [f64; 3],
    velocity_mm_s: [f64; 3],
    force_n: [f64; 3],
    last_step: Option<Instant>,
    started: Instant,
    /// Every force accepted: (t s, fx, fy, fz N).
    forces: Vec<[f64; 4]>,
}

impl Arm {
    /// An arm whose stylus starts where the hand does.
    pub fn new(hand: Vec<[f64; 4]>) -> Self {
        let start = hand.first().map_or([0.0; 3], |k| [k[1], k[2], k[3]]);
        Arm {
            hand,
            buttons: 0,
            position_mm: start,
            velocity_mm_s: [0.0; 3],
            force_n: [0.0; 3],
            last_step: None,
            started: Instant::now(),
            forces: Vec::new(),
        }
    }

    /// The same hand script from the start, clock reset (a device opened again).
    pub fn restarted(&self) -> Self {
        Arm::new(self.hand.clone())
    }

    /// When the arm started: the zero of its clock.
    pub fn started_at(&self) -> Instant {
        self.started
    }

    /// Seconds since the arm started.
    pub fn time_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    fn hand_at(&self, t: f64) -> [f64; 3] {
        let k = &self.hand;
        match k.iter().position(|p| p[0] > t) {
            None => k.last().map_or([0.0; 3], |p| [p[1], p[2], p[3]]),
            Some(0) => [k[0][1], k[0][2], k[0][3]],
            Some(i) => {
                let (a, b) = (k[i - 1], k[i]);
                let s = (t - a[0]) / (b[0] - a[0]);
                [0, 1, 2].map(|c| a[c + 1] + s * (b[c + 1] - a[c + 1]))
            }
        }
    }

    /// Advances the stylus to now (semi-implicit Euler in 0.1 ms steps).
    pub fn step(&mut self) {
        let now = Instant::now();
        let last = self.last_step.replace(now).unwrap_or(now);
        let mut left = now.duration_since(last).as_secs_f64().min(LONGEST_GAP_S);
        let hand = self.hand_at(now.duration_since(self.started).as_secs_f64());
        while left > 0.0 {
            let dt = left.min(STEP_S);
            left -= dt;
            for c in 0..3 {
                let pull_n =
                    GRIP_N_PER_MM * (hand[c] - self.position_mm[c]) - GRIP_DAMPING_N_S_PER_MM * self.velocity_mm_s[c];
                // N / kg = m/s² = 1000 mm/s².
                let accel_mm_s2 = (pull_n + self.force_n[c]) / MASS_KG * 1000.0;
                self.velocity_mm_s[c] += accel_mm_s2 * dt;
                self.position_mm[c] += self.velocity_mm_s[c] * dt;
            }
        }
    }

    /// The stylus tip (mm).
    pub fn position_mm(&self) -> [f64; 3] {
        self.position_mm
    }

    /// Applies and records a force (N) from now on.
    pub fn accept_force(&mut self, force_n: [f64; 3]) {
        self.force_n = force_n;
        let t = self.time_s();
        self.forces.push([t, force_n[0], force_n[1], force_n[2]]);
    }

    /// Stops pushing without recording (the device's own cut-off, not a command).
    pub fn cut_force(&mut self) {
        self.force_n = [0.0; 3];
    }

    /// Every force accepted: (t s, fx, fy, fz N).
    pub fn forces(&self) -> &[[f64; 4]] {
        &self.forces
    }
}

/// Reads `n` keyframes of (t s, x, y, z mm) a test passed across the C boundary.
///
/// # Safety
/// `keyframes` points to 4·n doubles.
pub unsafe fn read_keyframes(keyframes: *const f64, n: usize) -> Vec<[f64; 4]> {
    // SAFETY: the caller passes 4·n doubles.
    (0..n)
        .map(|i| unsafe { [0, 1, 2, 3].map(|c| *keyframes.add(4 * i + c)) })
        .collect()
}

/// Copies up to `capacity` recorded forces into `out`, 4 doubles each; returns how many were
/// recorded in all.
///
/// # Safety
/// `out` has room for 4·capacity doubles (it may be null when `capacity` is 0).
pub unsafe fn copy_forces(arm: &Arm, out: *mut f64, capacity: usize) -> usize {
    for (i, f) in arm.forces.iter().take(capacity).enumerate() {
        // SAFETY: the caller passes room for 4·capacity doubles.
        unsafe { std::ptr::copy_nonoverlapping(f.as_ptr(), out.add(4 * i), 4) };
    }
    arm.forces.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hand_script_is_linear_between_keyframes_and_held_after() {
        let arm = Arm::new(vec![[0.0, 0.0, 0.0, 0.0], [1.0, 10.0, 0.0, -10.0]]);
        assert_eq!(arm.hand_at(0.5), [5.0, 0.0, -5.0]);
        assert_eq!(arm.hand_at(3.0), [10.0, 0.0, -10.0]);
        assert_eq!(arm.hand_at(-1.0), [0.0, 0.0, 0.0]);
    }

    #[test]
    fn a_steady_force_displaces_the_stylus_against_the_grip() {
        let mut arm = Arm::new(vec![[0.0, 0.0, 0.0, 0.0]]);
        arm.accept_force([0.0, 0.0, 1.0]);
        let until = Instant::now() + std::time::Duration::from_millis(400);
        while Instant::now() < until {
            arm.step();
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        // 1 N against a 0.5 N/mm grip settles near 2 mm.
        let z = arm.position_mm()[2];
        assert!((z - 2.0).abs() < 0.2, "z {z} mm");
        assert_eq!(arm.forces().len(), 1);
    }
}
