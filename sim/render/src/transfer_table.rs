//! The transfer function as the ray loop reads it (docs/rendering.md "Transfer table"): c(v) of
//! eq. 3.2.2 sampled once per frame at equidistant CT values, with the opacity correction for the
//! step length and the premultiplication already applied, read with linear interpolation. Both
//! renderers read the same table, so they agree on every lattice sample's colour; a lookup is two
//! loads and one lerp instead of a sum over trapezoids, a division and a `powf` per sample.

use crate::raycast::shading::corrected_alpha;
use crate::transfer::TransferFunction;
use stylet_physics::glam::Vec4;

/// Most entries a table holds (128 KiB of `f32` RGBA): CT ranges wider than this many HU get
/// entries further apart than 1 HU.
pub const MAX_ENTRIES: usize = 8192;

/// (α·r, α·g, α·b, α) at CT values `lo_hu + i·step_hu`, α = 1 − (1 − a)^Δ (eq. 3.2.2 with the
/// opacity correction of docs/rendering.md "One ray", step 5).
#[derive(Debug, Clone, PartialEq)]
pub struct TransferTable {
    pub lo_hu: f32,
    pub step_hu: f32,
    /// 1 / `step_hu`.
    pub inv_step: f32,
    /// Premultiplied, step-corrected RGBA per entry; at least two entries. Private, like the
    /// clamps derived from its length below.
    entries: Vec<[f32; 4]>,
    /// visible_before[i]: how many of entries 0 … i − 1 have α > 0 (len = entries + 1), so
    /// [`Self::visible_in`] is two loads.
    visible_before: Vec<u32>,
    /// len − 1 as `f32` and len − 2: the clamps of [`Self::position`], worked out once rather
    /// than per sample.
    last_position: f32,
    last_base: usize,
}

impl TransferTable {
    /// Samples `tf` over [`lo_hu`, `hi_hu`] (the values the frame can read: the CT's range and
    /// air) for rays stepping `step_mm`. Entries lie 1 HU apart from ⌊lo⌋ when the range allows
    /// (integral CTs then read exact table points), else the range is split into
    /// [`MAX_ENTRIES`] − 1 steps.
    pub fn new(tf: &TransferFunction, lo_hu: f32, hi_hu: f32, step_mm: f32) -> TransferTable {
        let (lo, hi) = if lo_hu.is_finite() && hi_hu.is_finite() && lo_hu <= hi_hu {
            (lo_hu.floor(), hi_hu.ceil().max(lo_hu.floor() + 1.0))
        } else {
            (-1024.0, 3071.0)
        };
        let span = (hi - lo) as f64;
        let (count, step_hu) = if span < MAX_ENTRIES as f64 {
            (span as usize + 1, 1.0f32)
        } else {
            (MAX_ENTRIES, (span / (MAX_ENTRIES - 1) as f64) as f32)
        };
        let entries: Vec<[f32; 4]> = (0..count)
            .map(|i| {
                let c = tf.eval(lo + i as f32 * step_hu);
                let alpha = if c[3] > 0.0 {
                    corrected_alpha(c[3], step_mm)
                } else {
                    0.0
                };
                [c[0] * alpha, c[1] * alpha, c[2] * alpha, alpha]
            })
            .collect();
        let mut visible_before = Vec::with_capacity(count + 1);
        let mut n = 0u32;
        visible_before.push(0);
        for e in &entries {
            n += u32::from(e[3] > 0.0);
            visible_before.push(n);
        }
        TransferTable {
            lo_hu: lo,
            step_hu,
            inv_step: 1.0 / step_hu,
            last_position: (entries.len() - 1) as f32,
            last_base: entries.len() - 2,
            entries,
            visible_before,
        }
    }

    /// Continuous table position of `hu`, clamped to the table: (entry i, fraction f) with
    /// i ≤ len − 2, so entries i and i + 1 exist.
    #[inline(always)]
    fn position(&self, hu: f32) -> (usize, f32) {
        // NaN clamps to 0 (`max` returns the other operand).
        let x = ((hu - self.lo_hu) * self.inv_step).max(0.0).min(self.last_position);
        // SAFETY: 0 ≤ x ≤ len − 1 (NaN became 0 above), so the conversion is exact truncation.
        let i = (unsafe { x.to_int_unchecked::<u32>() } as usize).min(self.last_base);
        (i, x - i as f32)
    }

    /// Premultiplied, step-corrected (α·r, α·g, α·b, α) per entry (at least two), at CT values
    /// `lo_hu + i·step_hu`.
    pub fn entries(&self) -> &[[f32; 4]] {
        &self.entries
    }

    /// The clamps of a table position: len − 1 (as `f32`) and the last entry an interpolation
    /// may start from, len − 2 (for the AVX2 lanes of `raycast::avx2`, which repeat `position`).
    pub(crate) fn clamps(&self) -> (f32, usize) {
        (self.last_position, self.last_base)
    }

    /// (α·r, α·g, α·b, α) at `hu`: linear interpolation between the two nearest entries.
    #[inline(always)]
    pub fn lookup(&self, hu: f32) -> [f32; 4] {
        let (i, f) = self.position(hu);
        self.blend(i, 1.0 - f, f)
    }

    /// Entries i and i + 1 weighted by (1 − f, f), given as (`one_minus_f`, `f`): the last step
    /// of [`Self::lookup`], shared with the AVX2 lanes of `raycast::avx2`, which compute the position
    /// eight at a time. i must be ≤ len − 2, as [`Self::position`] keeps it.
    #[inline(always)]
    pub(crate) fn blend(&self, i: usize, one_minus_f: f32, f: f32) -> [f32; 4] {
        let (a, b) = (self.entries[i], self.entries[i + 1]);
        // Four lanes at once (SSE on x86-64): the same products and sums as lane by lane.
        (Vec4::from_array(a) * one_minus_f + Vec4::from_array(b) * f).to_array()
    }

    /// What [`Self::visible_in`] depends on: equal keys give equal answers for every range (the
    /// cache key of the cube masks).
    pub fn visibility_key(&self) -> VisibilityKey {
        VisibilityKey {
            lo_hu: self.lo_hu.to_bits(),
            step_hu: self.step_hu.to_bits(),
            visible_before: self.visible_before.clone(),
        }
    }

    /// Whether any value in [`lo_hu`, `hi_hu`] looks up α > 0: cells of the occupancy grid whose
    /// range fails this are skipped by empty-space leaping without changing the image.
    pub fn visible_in(&self, lo_hu: f32, hi_hu: f32) -> bool {
        if !(lo_hu <= hi_hu) {
            return false;
        }
        let (i0, _) = self.position(lo_hu);
        let (i1, _) = self.position(hi_hu);
        // Values in [lo, hi] interpolate entries i0 … i1 + 1.
        self.visible_before[i1 + 2] > self.visible_before[i0]
    }
}

/// See [`TransferTable::visibility_key`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VisibilityKey {
    lo_hu: u32,
    step_hu: u32,
    visible_before: Vec<u32>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transfer::Trapezoid;

    fn soft() -> TransferFunction {
        TransferFunction::Trapezoids(vec![
            Trapezoid {
                tissue: "soft".into(),
                hu: [-60.0, 0.0, 50.0, 70.0],
                rgb: [0.8, 0.7, 0.6],
                opacity: 1.0,
                weight: 0.01,
            },
            Trapezoid {
                tissue: "bone".into(),
                hu: [300.0, 550.0, 3000.0, 3100.0],
                rgb: [0.95, 0.93, 0.85],
                opacity: 1.0,
                weight: 1.0,
            },
        ])
    }

    #[test]
    fn entries_are_the_corrected_premultiplied_transfer_function() {
        let tf = soft();
        let t = TransferTable::new(&tf, -1024.0, 3071.0, 0.5);
        assert_eq!((t.lo_hu, t.step_hu, t.entries.len()), (-1024.0, 1.0, 4096));
        for hu in [-1024.0f32, -30.0, 25.0, 400.0, 1000.0, 3071.0] {
            let c = tf.eval(hu);
            let alpha = corrected_alpha(c[3], 0.5);
            let want = [c[0] * alpha, c[1] * alpha, c[2] * alpha, alpha];
            assert_eq!(t.lookup(hu), want, "{hu}");
        }
        // Between integer points the trapezoids are linear; the opacity correction is not: over
        // 1 HU it bends the lerp by < 10⁻³ (a quarter of an 8-bit step) while a < 0.99, and by up
        // to 0.016 in the last HU before a reaches 1 (1 − √(1 − a) is steepest there; such a
        // sample is all but opaque either way).
        for i in 0..2000 {
            let hu = -100.0 + i as f32 * 0.37;
            let c = tf.eval(hu);
            let alpha = corrected_alpha(c[3], 0.5);
            let got = t.lookup(hu);
            let tol = if c[3] < 0.99 { 1e-3 } else { 0.02 };
            assert!((got[3] - alpha).abs() < tol, "{hu}: {} vs {alpha}", got[3]);
            assert!((got[0] - c[0] * alpha).abs() < tol, "{hu}");
        }
    }

    #[test]
    fn values_outside_the_range_clamp_and_nan_reads_the_first_entry() {
        let t = TransferTable::new(&soft(), -1000.0, 3000.0, 1.0);
        assert_eq!(t.lookup(-5000.0), t.entries[0]);
        assert_eq!(t.lookup(9000.0), *t.entries.last().unwrap());
        assert_eq!(t.lookup(f32::NAN), t.entries[0]);
    }

    #[test]
    fn wide_ranges_are_split_into_the_maximum_entries() {
        let t = TransferTable::new(&soft(), -3024.0, 30000.0, 0.5);
        assert_eq!(t.entries.len(), MAX_ENTRIES);
        assert!((t.lo_hu + (MAX_ENTRIES - 1) as f32 * t.step_hu - 30000.0).abs() < 1.0);
        // Bad ranges fall back to the usual CT range instead of panicking.
        assert_eq!(TransferTable::new(&soft(), f32::NAN, 0.0, 0.5).entries.len(), 4096);
        assert_eq!(TransferTable::new(&soft(), 5.0, 5.0, 0.5).entries.len(), 2);
    }

    #[test]
    fn visibility_covers_every_value_that_reads_a_visible_entry() {
        let t = TransferTable::new(&soft(), -1024.0, 3071.0, 0.5);
        // −60.5 interpolates entries −61 and −60 (both zero): invisible; −59.5 reads entry −59
        // (α > 0). The test is conservative by one entry (a range ending on −60 counts as
        // visible), which costs a sample, never a pixel.
        assert!(!t.visible_in(-1024.0, -61.0));
        assert!(!t.visible_in(-1024.0, -60.5));
        assert!(t.visible_in(-1024.0, -59.5));
        assert!(t.visible_in(60.0, 65.0));
        assert!(!t.visible_in(71.0, 299.0));
        assert!(t.visible_in(2000.0, 2000.0));
        assert!(!t.visible_in(5.0, 1.0));
        // Exhaustively against lookups: a range is visible iff some value in it looks up α > 0.
        for lo in (-100..120).step_by(7) {
            for w in [0, 1, 3, 20] {
                let (lo, hi) = (lo as f32 + 0.25, (lo + w) as f32 + 0.75);
                let mut any = false;
                let mut v = lo;
                while v <= hi {
                    any |= t.lookup(v)[3] > 0.0;
                    v += 0.125;
                }
                any |= t.lookup(hi)[3] > 0.0;
                if any {
                    assert!(t.visible_in(lo, hi), "{lo}..{hi}");
                }
            }
        }
    }
}
