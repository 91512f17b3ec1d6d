//! Rounded outputs with an exact digest (codec `stylet-columns-v2`, docs/session-format.md
//! "Rounded outputs").
//!
//! The contact tools' stick–slip proxies change the low mantissa bits of every force and torque
//! every tick, and those bits cost more than everything else in a session file. Replay does not
//! need them: it recomputes every output from the recorded inputs. So a block stores its forces
//! and torques rounded to a fixed step (far below what a haptic device renders or a chart shows)
//! and pins the exact values with a digest of their bits. Replay checks each tick's rounded
//! output against the file and, at the block's end, the digest of its exact outputs: still a
//! bit-for-bit proof.

/// Force steps per newton: 2¹⁶ (a step of 15 µN; haptic devices render about 10 mN).
pub const FORCE_STEPS_PER_N: f64 = 65_536.0;
/// Torque steps per newton millimetre: 2¹² (a step of 0.24 mN·mm).
pub const TORQUE_STEPS_PER_NMM: f64 = 4_096.0;

/// Largest magnitude of a step count: below 2⁵³, so every count and every rounded value
/// (count ÷ a power of two) is an exact `f64`.
const MAX_STEPS: f64 = 9_007_199_254_740_991.0;

/// `value` in steps of 1/`steps_per_unit` (ties to even), or `None` when it is not finite or too
/// large to round exactly (the writer then stores the block exactly, codec v1).
#[inline]
pub fn steps(value: f64, steps_per_unit: f64) -> Option<i64> {
    let s = (value * steps_per_unit).round_ties_even();
    (s.abs() <= MAX_STEPS).then_some(s as i64)
}

/// The value a step count stands for (exact: the count is below 2⁵³ and the divisor a power of
/// two).
#[inline]
pub fn from_steps(steps: i64, steps_per_unit: f64) -> f64 {
    steps as f64 / steps_per_unit
}

/// `value` as a rounded block stores it (`None`: not storable rounded).
#[inline]
pub fn rounded(value: f64, steps_per_unit: f64) -> Option<f64> {
    steps(value, steps_per_unit).map(|s| from_steps(s, steps_per_unit))
}

/// A tick's force (N) and torque (N·mm) as a rounded block stores them.
pub fn rounded_outputs(force_n: [f64; 3], torque_nmm: [f64; 3]) -> Option<([f64; 3], [f64; 3])> {
    let f = |v: [f64; 3], per: f64| -> Option<[f64; 3]> {
        Some([rounded(v[0], per)?, rounded(v[1], per)?, rounded(v[2], per)?])
    };
    Some((f(force_n, FORCE_STEPS_PER_N)?, f(torque_nmm, TORQUE_STEPS_PER_NMM)?))
}

/// FNV-1a (64-bit) over the exact bits of a block's outputs, tick after tick: force x, y, z then
/// torque x, y, z, each as the 8 little-endian bytes of its IEEE-754 pattern. Not a secret: it
/// proves the replay reproduced every bit, as the state digests do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputDigest(u64);

impl Default for OutputDigest {
    fn default() -> Self {
        OutputDigest(0xcbf2_9ce4_8422_2325)
    }
}

impl OutputDigest {
    /// Adds one tick's exact outputs.
    pub fn add(&mut self, force_n: [f64; 3], torque_nmm: [f64; 3]) {
        for v in force_n.into_iter().chain(torque_nmm) {
            for b in v.to_bits().to_le_bytes() {
                self.0 = (self.0 ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }

    pub fn value(&self) -> u64 {
        self.0
    }
}

/// What a rounded block promises: the digest of the exact outputs of ticks
/// `first_tick` … `first_tick + count − 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputCheck {
    pub first_tick: u64,
    pub count: u32,
    pub digest: u64,
}

impl OutputCheck {
    /// The block's last tick.
    pub fn last_tick(&self) -> u64 {
        self.first_tick + u64::from(self.count).saturating_sub(1)
    }

    pub fn covers(&self, tick: u64) -> bool {
        tick >= self.first_tick && tick - self.first_tick < u64::from(self.count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_is_exact_and_bounded() {
        assert_eq!(rounded(1.0, FORCE_STEPS_PER_N), Some(1.0));
        assert_eq!(rounded(0.3, FORCE_STEPS_PER_N), Some(19_661.0 / 65_536.0));
        // Half a step rounds to even.
        assert_eq!(steps(1.5 / 65_536.0, FORCE_STEPS_PER_N), Some(2));
        assert_eq!(steps(2.5 / 65_536.0, FORCE_STEPS_PER_N), Some(2));
        // −0 is stored as +0 (replay rounds its outputs the same way before comparing).
        assert_eq!(
            rounded(-0.0, FORCE_STEPS_PER_N).map(f64::to_bits),
            Some(0.0f64.to_bits())
        );
        for v in [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e300, -1e15] {
            assert_eq!(steps(v, FORCE_STEPS_PER_N), None, "{v}");
        }
        // Within half a step of the value, and every rounded value rounds to itself.
        for i in 0..1000 {
            let v = (i as f64 * 0.731).sin() * 3.3;
            let r = rounded(v, FORCE_STEPS_PER_N).unwrap();
            assert!((r - v).abs() <= 0.5 / FORCE_STEPS_PER_N);
            assert_eq!(rounded(r, FORCE_STEPS_PER_N), Some(r));
        }
    }

    #[test]
    fn the_digest_sees_every_bit_and_the_order() {
        let (f, t) = ([0.1, -0.2, 0.3], [1.0, 2.0, 3.0]);
        let mut a = OutputDigest::default();
        a.add(f, t);
        let mut b = OutputDigest::default();
        b.add([0.1, -0.2, f64::from_bits(0.3f64.to_bits() ^ 1)], t);
        assert_ne!(a, b);
        let mut c = OutputDigest::default();
        c.add(t, f);
        assert_ne!(a, c);
        let mut d = OutputDigest::default();
        d.add(f, t);
        assert_eq!(a, d);
    }
}
