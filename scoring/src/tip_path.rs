//! The needle tip's path through one attempt (skin puncture to withdrawal), for the attempt's
//! path inefficiency: the tip's path length from its skin entry until it reached the target (else
//! until its deepest point), over the straight distance between the two points.
//!
//! Each step is added before the point it ends at is marked as reached, so the step that enters
//! the target counts: by the triangle inequality the ratio is then never below 1.

use stylet_physics::glam::DVec3;

/// The tip's path through one attempt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TipPath {
    entry_mm: DVec3,
    last_mm: DVec3,
    length_mm: f64,
    /// Where the tip first reached the target, and the path length up to there.
    reached: Option<(DVec3, f64)>,
    /// The deepest point: inserted length, tip, path length up to there.
    deepest: (f64, DVec3, f64),
}

impl TipPath {
    /// The attempt starts at the skin entry: the first tick with the needle in the body.
    pub fn enter(tip_mm: DVec3, inserted_mm: f64, in_target: bool) -> TipPath {
        TipPath {
            entry_mm: tip_mm,
            last_mm: tip_mm,
            length_mm: 0.0,
            reached: in_target.then_some((tip_mm, 0.0)),
            deepest: (inserted_mm, tip_mm, 0.0),
        }
    }

    /// The next tick in the body.
    pub fn step(&mut self, tip_mm: DVec3, inserted_mm: f64, in_target: bool) {
        self.length_mm += tip_mm.distance(self.last_mm);
        self.last_mm = tip_mm;
        if in_target && self.reached.is_none() {
            self.reached = Some((tip_mm, self.length_mm));
        }
        if inserted_mm > self.deepest.0 {
            self.deepest = (inserted_mm, tip_mm, self.length_mm);
        }
    }

    pub fn entry_mm(&self) -> DVec3 {
        self.entry_mm
    }

    /// The tip at the attempt's last tick in the body.
    pub fn last_mm(&self) -> DVec3 {
        self.last_mm
    }

    /// Where the tip first reached the target.
    pub fn reached_target_mm(&self) -> Option<DVec3> {
        self.reached.map(|(p, _)| p)
    }

    /// The deepest point of the attempt (largest inserted length).
    pub fn deepest_mm(&self) -> DVec3 {
        self.deepest.1
    }

    /// Path length to the target (else to the deepest point) / straight distance from the entry;
    /// `None` when the two points are within 1 mm (no meaningful ratio).
    pub fn inefficiency(&self) -> Option<f64> {
        let (end, path) = match self.reached {
            Some(reached) => reached,
            None => (self.deepest.1, self.deepest.2),
        };
        let straight = end.distance(self.entry_mm);
        // ≥ 1 by the triangle inequality; the rounding of a long sum of steps can put a straight
        // push a few ulps below, which is no inefficiency.
        (straight > 1.0).then(|| (path / straight).max(1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A tip path from its points; the last point is in the target when `ends_in_target`.
    fn walk(points: &[DVec3], ends_in_target: bool) -> TipPath {
        let mut path = TipPath::enter(points[0], 0.0, false);
        for (i, p) in points.iter().enumerate().skip(1) {
            let in_target = ends_in_target && i == points.len() - 1;
            path.step(*p, i as f64, in_target);
        }
        path
    }

    fn point() -> impl Strategy<Value = DVec3> {
        (-100.0..100.0f64, -100.0..100.0f64, -100.0..100.0f64).prop_map(|(x, y, z)| DVec3::new(x, y, z))
    }

    proptest! {
        /// A path's length is never shorter than the straight line between its ends.
        #[test]
        fn inefficiency_is_never_below_one(points in prop::collection::vec(point(), 2..60), reached: bool) {
            let path = walk(&points, reached);
            if let Some(ratio) = path.inefficiency() {
                prop_assert!(ratio >= 1.0, "ratio {ratio}");
            }
        }

        /// One straight push in ticks of any length: exactly 1 (up to rounding of the sum).
        #[test]
        fn a_straight_push_is_one(
            start in point(),
            direction in point(),
            steps in prop::collection::vec(0.001..2.0f64, 2..400),
        ) {
            prop_assume!(direction.length() > 1e-3);
            let dir = direction.normalize();
            let mut depth = 0.0;
            let mut points = vec![start];
            for s in &steps {
                depth += s;
                points.push(start + dir * depth);
            }
            prop_assume!(depth > 1.0);
            let ratio = walk(&points, true).inefficiency().expect("longer than 1 mm");
            prop_assert!((ratio - 1.0).abs() < 1e-9, "ratio {ratio}");
        }
    }

    /// The step that enters the target counts: two ticks, entry then target, give exactly 1.
    #[test]
    fn the_step_into_the_target_counts() {
        let path = walk(&[DVec3::ZERO, DVec3::new(0.0, 0.0, 10.0)], true);
        assert_eq!(path.inefficiency(), Some(1.0));
        assert_eq!(path.reached_target_mm(), Some(DVec3::new(0.0, 0.0, 10.0)));
    }

    /// Hand-computed: 10 mm in, 5 mm back, 15 mm in to the target at 20 mm → 30 / 20 = 1.5.
    #[test]
    fn a_redirection_costs_its_detour() {
        let z = |d: f64| DVec3::new(0.0, 0.0, d);
        let path = walk(&[z(0.0), z(10.0), z(5.0), z(20.0)], true);
        assert_eq!(path.inefficiency(), Some(1.5));
    }

    /// Without the target, the path to the deepest point: in to 10, back to 4, in to 8 → the
    /// deepest point is at 10 mm after 10 mm of path → 1.
    #[test]
    fn without_the_target_the_deepest_point_ends_the_path() {
        let z = |d: f64| DVec3::new(0.0, 0.0, d);
        let mut path = TipPath::enter(z(0.0), 0.0, false);
        for d in [10.0, 4.0, 8.0] {
            path.step(z(d), d, false);
        }
        assert_eq!(path.deepest_mm(), z(10.0));
        assert_eq!(path.inefficiency(), Some(1.0));
    }
}
