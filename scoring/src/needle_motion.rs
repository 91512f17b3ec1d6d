//! Motion metrics of the hand-held needle as the field defines them: PerkTutor's metric scripts
//! (github.com/PerkTutor/PythonMetrics, branch `Core` at 14da78c for path length, tissue path,
//! tissue time and tissue damage; `master` at a94e288 for motion smoothness, depth perception and
//! rotational actions). docs/metrics.md "Needle motion (PerkTutor)" gives each formula and where
//! Stylet's inputs differ from a tracker's.
//!
//! The needle here is the *rigid* needle of the device pose, as a tracker sees it: its tip is the
//! device position p, its axis n = q·(0, 0, 1) points into the patient. "In tissue" is the
//! physics' own state: the needle in hand with `inserted_mm > 0` (PerkTutor tests the tracked tip
//! against a closed tissue surface; a simulation knows the puncture). Each sample i adds the step
//! from sample i − 1 (Δtᵢ = (tickᵢ − tickᵢ₋₁) / rate) and counts as in tissue by its own state,
//! as PerkTutor's backward rule does. Samples come only from ticks with the needle in hand; a tool
//! change ends the stream (the pose then belongs to another tool) and the next needle starts a new
//! one.

use serde::{Deserialize, Serialize};
use stylet_physics::glam::{DQuat, DVec3};

/// A rotation faster than this is a rotational action (PerkTutor `RotationalActions`, deg/s).
pub const ROTATION_SPEED_DEG_PER_S: f64 = 50.0;
/// … once the new state has lasted longer than this (s).
pub const ACTION_MIN_S: f64 = 0.2;

/// The needle-motion metrics of one session.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct NeedleMotionMetrics {
    /// Σ ‖pᵢ − pᵢ₋₁‖ (mm; PerkTutor `PathLength`).
    pub path_length_mm: f64,
    /// Σ [in tissueᵢ] ‖pᵢ − pᵢ₋₁‖ (mm; PerkTutor `TissuePath`).
    pub path_in_tissue_mm: f64,
    /// Σ [not in tissueᵢ] ‖pᵢ − pᵢ₋₁‖ (mm): the rest of the path.
    pub path_outside_tissue_mm: f64,
    /// Σ [in tissueᵢ] Δtᵢ (s; PerkTutor `TissueTime`).
    pub time_in_tissue_s: f64,
    /// Area swept by the rigid needle line inside tissue (mm²; PerkTutor `TissueDamage`): for two
    /// samples both in tissue, the quadrilateral pᵢ₋₁, pᵢ, Eᵢ, Eᵢ₋₁, E = p − inserted·n where the
    /// line crosses the skin, as two triangles (½‖(b − a) × (c − a)‖ each).
    pub tissue_damage_mm2: f64,
    /// √(Σ ‖jᵢ‖² Δtᵢ) (mm·s^-2.5; PerkTutor `MotionSmoothness`, labelled mm/s³ there): j from
    /// backward differences over four samples, each order divided by the latest Δt.
    pub jerk_mm_per_s2_5: f64,
    /// Σ |(pᵢ − pᵢ₋₁)·nᵢ| (mm; PerkTutor `DepthPerception`): motion along the needle's own axis,
    /// in and out alike.
    pub depth_perception_mm: f64,
    /// Rotational actions while in tissue (PerkTutor `RotationalActions`): starts of rotation
    /// faster than [`ROTATION_SPEED_DEG_PER_S`], a change of state counting once it has lasted
    /// longer than [`ACTION_MIN_S`].
    pub reorientations: u32,
}

/// One tick of the needle in hand.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeedleSample {
    pub tick: u64,
    /// The device position: the rigid needle's tip (mm).
    pub tip_mm: DVec3,
    /// The device orientation: the needle's axis is `orientation · (0, 0, 1)`.
    pub orientation: DQuat,
    /// Needle length inside the body (mm; > 0: in tissue).
    pub inserted_mm: f64,
}

impl NeedleSample {
    fn axis(&self) -> DVec3 {
        self.orientation * DVec3::Z
    }
    fn in_tissue(&self) -> bool {
        self.inserted_mm > 0.0
    }
    /// Where the rigid line crosses the skin: the inserted length back from the tip.
    fn skin_point_mm(&self) -> DVec3 {
        self.tip_mm - self.axis() * self.inserted_mm
    }
}

/// Collects [`NeedleMotionMetrics`] tick by tick.
#[derive(Debug, Clone)]
pub struct NeedleMotion {
    rate_hz: f64,
    metrics: NeedleMotionMetrics,
    /// The last samples of the current stream, newest first (for the backward differences).
    history: Vec<NeedleSample>,
    squared_jerk: f64,
    /// Rotational actions: moving or still, since when (tick); `None` out of tissue.
    rotation: Option<(bool, u64)>,
}

impl NeedleMotion {
    pub fn new(rate_hz: u32) -> NeedleMotion {
        NeedleMotion {
            rate_hz: f64::from(rate_hz),
            metrics: NeedleMotionMetrics::default(),
            history: Vec::with_capacity(4),
            squared_jerk: 0.0,
            rotation: None,
        }
    }

    /// One tick: the needle's sample, or `None` when another tool is in hand.
    pub fn observe(&mut self, sample: Option<NeedleSample>) {
        let Some(s) = sample else {
            self.history.clear();
            self.rotation = None;
            return;
        };
        if let Some(prev) = self.history.first().copied()
            && s.tick > prev.tick
        {
            let dt_s = (s.tick - prev.tick) as f64 / self.rate_hz;
            let step = s.tip_mm - prev.tip_mm;
            let m = &mut self.metrics;
            m.path_length_mm += step.length();
            if s.in_tissue() {
                m.path_in_tissue_mm += step.length();
                m.time_in_tissue_s += dt_s;
            } else {
                m.path_outside_tissue_mm += step.length();
            }
            m.depth_perception_mm += step.dot(s.axis()).abs();
            if s.in_tissue() && prev.in_tissue() {
                m.tissue_damage_mm2 += swept_area_mm2(&prev, &s);
            }
            if let [p1, p2, p3] = self.history[..] {
                self.squared_jerk += jerk(&s, &p1, &p2, &p3, self.rate_hz).length_squared() * dt_s;
            }
            self.rotate(&prev, &s, dt_s);
        } else if !self.history.is_empty() {
            // The same tick twice (not in a replay): PerkTutor drops repeated timestamps.
            return;
        }
        self.history.insert(0, s);
        self.history.truncate(3);
    }

    /// PerkTutor's action state machine on the rotation speed, run while in tissue.
    fn rotate(&mut self, prev: &NeedleSample, s: &NeedleSample, dt_s: f64) {
        if !s.in_tissue() {
            self.rotation = None;
            return;
        }
        let Some((moving, since)) = self.rotation else {
            self.rotation = Some((false, s.tick));
            return;
        };
        let speed = rotation_deg(prev.orientation, s.orientation) / dt_s;
        let now_moving = speed > ROTATION_SPEED_DEG_PER_S;
        if now_moving == moving {
            self.rotation = Some((moving, s.tick));
        } else if (s.tick - since) as f64 / self.rate_hz > ACTION_MIN_S {
            self.rotation = Some((now_moving, s.tick));
            if now_moving {
                self.metrics.reorientations += 1;
            }
        }
    }

    pub fn finish(&self) -> NeedleMotionMetrics {
        NeedleMotionMetrics {
            jerk_mm_per_s2_5: self.squared_jerk.sqrt(),
            ..self.metrics
        }
    }
}

/// The quadrilateral the rigid line sweeps between two samples, as two triangles: (p₁, p₀, E₁)
/// and (E₁, p₀, E₀) (PerkTutor splits along the same diagonal).
fn swept_area_mm2(a: &NeedleSample, b: &NeedleSample) -> f64 {
    let (p0, p1, e0, e1) = (a.tip_mm, b.tip_mm, a.skin_point_mm(), b.skin_point_mm());
    triangle_area_mm2(p1, p0, e1) + triangle_area_mm2(e1, p0, e0)
}

fn triangle_area_mm2(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    0.5 * (b - a).cross(c - a).length()
}

/// Jerk by backward differences over s and the three samples before it (newest first), each
/// order divided by the latest interval, as PerkTutor does.
fn jerk(s: &NeedleSample, p1: &NeedleSample, p2: &NeedleSample, p3: &NeedleSample, rate_hz: f64) -> DVec3 {
    let dt = |a: &NeedleSample, b: &NeedleSample| (a.tick - b.tick) as f64 / rate_hz;
    let (d01, d12, d23) = (dt(s, p1), dt(p1, p2), dt(p2, p3));
    let v0 = (s.tip_mm - p1.tip_mm) / d01;
    let v1 = (p1.tip_mm - p2.tip_mm) / d12;
    let v2 = (p2.tip_mm - p3.tip_mm) / d23;
    let a0 = (v0 - v1) / d01;
    let a1 = (v1 - v2) / d12;
    (a0 - a1) / d01
}

/// The angle of the rotation from `a` to `b` (degrees, 0…180): 2·atan2(‖v‖, |w|) of b·a⁻¹ (libm:
/// the same bits on every platform; atan2 keeps small angles exact where acos would not).
pub fn rotation_deg(a: DQuat, b: DQuat) -> f64 {
    let d = b * a.conjugate();
    let v = DVec3::new(d.x, d.y, d.z).length();
    (2.0 * libm::atan2(v, d.w.abs())).to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    const RATE: u32 = 1000;

    fn sample(tick: u64, tip: [f64; 3], q: DQuat, inserted_mm: f64) -> Option<NeedleSample> {
        Some(NeedleSample {
            tick,
            tip_mm: DVec3::from_array(tip),
            orientation: q,
            inserted_mm,
        })
    }

    fn run(samples: impl IntoIterator<Item = Option<NeedleSample>>) -> NeedleMotionMetrics {
        let mut m = NeedleMotion::new(RATE);
        for s in samples {
            m.observe(s);
        }
        m.finish()
    }

    #[test]
    fn a_straight_push_is_path_depth_and_time_without_damage() {
        // Along +z (the needle's axis) 0.1 mm per tick: 10 ticks outside, then 20 in tissue.
        let m = run((0..=30).map(|i| {
            let z = 0.1 * i as f64;
            sample(i, [0.0, 0.0, z], DQuat::IDENTITY, (z - 1.0).max(0.0))
        }));
        assert!((m.path_length_mm - 3.0).abs() < 1e-12);
        assert!((m.path_in_tissue_mm - 2.0).abs() < 1e-12, "{m:?}");
        assert!((m.path_outside_tissue_mm - 1.0).abs() < 1e-12);
        assert!((m.time_in_tissue_s - 0.020).abs() < 1e-12);
        assert!((m.depth_perception_mm - 3.0).abs() < 1e-12);
        assert_eq!(m.tissue_damage_mm2, 0.0);
        assert!(
            m.jerk_mm_per_s2_5 < 1e-6,
            "constant velocity: rounding only, {}",
            m.jerk_mm_per_s2_5
        );
        assert_eq!(m.reorientations, 0);
    }

    #[test]
    fn a_lateral_shift_in_tissue_sweeps_shift_times_depth() {
        // 40 mm in, the hand moves 5 mm sideways (x) in 50 ticks: a 5 × 40 mm parallelogram.
        let m = run((0..=50).map(|i| sample(i, [0.1 * i as f64, 0.0, 40.0], DQuat::IDENTITY, 40.0)));
        assert!((m.tissue_damage_mm2 - 200.0).abs() < 1e-9, "{}", m.tissue_damage_mm2);
        assert_eq!(m.depth_perception_mm, 0.0, "no motion along the axis");
        assert!((m.path_in_tissue_mm - 5.0).abs() < 1e-12);
    }

    #[test]
    fn a_pivot_about_the_skin_sweeps_a_fan() {
        // 40 mm in, pivoting about the skin point by 0.1° a tick for 90 ticks: a 9° sector of
        // radius 40 mm is π·40²·9/360 = 125.66 mm²; the chords' triangles give 40²·sin(0.1°)/2
        // each, 90 of them.
        let step = 0.1f64.to_radians();
        let m = run((0..=90).map(|i| {
            let q = DQuat::from_rotation_y(step * i as f64);
            let tip = DVec3::new(0.0, 0.0, -40.0) + q * DVec3::new(0.0, 0.0, 40.0);
            sample(i, tip.to_array(), q, 40.0)
        }));
        let want = 90.0 * 0.5 * 40.0 * 40.0 * libm::sin(step);
        assert!(
            (m.tissue_damage_mm2 - want).abs() < 1e-9,
            "{} vs {want}",
            m.tissue_damage_mm2
        );
        assert!((m.tissue_damage_mm2 - 125.66).abs() < 0.01);
        // 0.1° per ms is 100°/s: one rotational action, once it has lasted more than 0.2 s.
        assert_eq!(m.reorientations, 0, "90 ms of rotation is not an action yet");
    }

    #[test]
    fn a_rotation_longer_than_the_debounce_is_one_action() {
        // In tissue: 300 ms still, 400 ms turning at 100°/s, 400 ms still, 400 ms turning again.
        let speed = 0.1f64.to_radians();
        let mut angle = 0.0;
        let m = run((0..1500u64).map(|i| {
            if (300..700).contains(&i) || (1100..1500).contains(&i) {
                angle += speed;
            }
            sample(i, [0.0, 0.0, 30.0], DQuat::from_rotation_x(angle), 30.0)
        }));
        assert_eq!(m.reorientations, 2);
        // The same turns out of tissue do not count.
        let m = run((0..1500u64).map(|i| {
            let a = if (300..700).contains(&i) {
                speed * (i - 300) as f64
            } else {
                0.0
            };
            sample(i, [0.0, 0.0, 0.0], DQuat::from_rotation_x(a), 0.0)
        }));
        assert_eq!(m.reorientations, 0);
    }

    #[test]
    fn jerk_of_a_start_and_a_stop_is_hand_computed() {
        // At rest, then 100 mm/s along x for 100 ticks, then at rest: each corner changes the
        // velocity by v; its jerk is +v/Δt² then −v/Δt² on two samples, so
        // Σ‖j‖²Δt = 2 corners · 2 · v²/Δt⁴ · Δt = 4 v²/Δt³.
        let (v, dt) = (100.0, 1e-3);
        let x = |i: u64| v * dt * (i.clamp(10, 110) - 10) as f64;
        let m = run((0..200u64).map(|i| sample(i, [x(i), 0.0, 0.0], DQuat::IDENTITY, 0.0)));
        let want = (4.0 * v * v / (dt * dt * dt)).sqrt();
        assert!(
            (m.jerk_mm_per_s2_5 / want - 1.0).abs() < 1e-9,
            "{} vs {want}",
            m.jerk_mm_per_s2_5
        );
    }

    #[test]
    fn another_tool_ends_the_stream() {
        // 1 mm steps, then a tick with the probe in hand, then the needle again 50 mm away: the
        // jump is no step of the needle.
        let mut samples: Vec<_> = (0..5)
            .map(|i| sample(i, [i as f64, 0.0, 0.0], DQuat::IDENTITY, 0.0))
            .collect();
        samples.push(None);
        samples.extend((6..10).map(|i| sample(i, [50.0 + i as f64, 0.0, 0.0], DQuat::IDENTITY, 0.0)));
        let m = run(samples);
        assert!((m.path_length_mm - 7.0).abs() < 1e-12, "{}", m.path_length_mm);
        assert_eq!(m.jerk_mm_per_s2_5, 0.0);
    }

    #[test]
    fn rotation_angles_are_exact_for_small_and_half_turns() {
        let a = DQuat::from_rotation_z(0.3);
        // 10⁻⁷ rad from two quaternions of ~10⁻¹⁶ rounding each: within 10⁻¹² ° (acos would lose
        // half the digits here).
        assert!((rotation_deg(a, DQuat::from_rotation_z(0.3 + 1e-7)) - 1e-7f64.to_degrees()).abs() < 1e-12);
        assert!((rotation_deg(DQuat::IDENTITY, DQuat::from_rotation_x(std::f64::consts::PI)) - 180.0).abs() < 1e-9);
        // q and −q are the same rotation.
        assert!(rotation_deg(a, -a) < 1e-12);
    }
}
