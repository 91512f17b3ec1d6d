//! Eight visible samples of one ray evaluated together (docs/rendering.md "Sample lanes"): the
//! march finds the visible lattice points one after the other, as before, but reads, classifies
//! and lights them eight at a time, then composites them in order. Every number is that of the
//! one-at-a-time loop bit for bit — the same products and sums of the same values in the same
//! order, several per instruction (AVX2 where the CPU has it) — so the picture does not change.
//!
//! Compositing stays one sample at a time and in order (front-to-back accumulation is a chain),
//! so early termination stops at the very sample the one-at-a-time loop stops at; the samples of
//! the last batch beyond it were read for nothing (at most seven per ray).

use super::cell::Cell;
use super::shading::PhongTerms;

/// Samples evaluated together.
pub const LANES: usize = 8;

/// Entries a batch can hold: fewer than [`LANES`] waiting, plus a whole window's visible points
/// appended at once (`Avx2::append_window`).
pub(super) const CAPACITY: usize = 2 * LANES;

/// Visible samples of one ray, in the order the ray meets them, one array per component (the
/// lanes append and read eight at a time). Samples are evaluated [`LANES`] at a time from the
/// front ([`Batch::drop_front`]).
#[derive(Debug, Clone)]
pub(crate) struct Batch {
    pub(super) len: usize,
    /// Base voxel per axis (entries past `len` are stale and never read).
    pub(super) b: [[u32; CAPACITY]; 3],
    /// Fractions per axis.
    pub(super) f: [[f32; CAPACITY]; 3],
    /// The ray parameter of each sample (the shadow is tested at composite time).
    pub t: [f32; CAPACITY],
    /// Samples counted just before each entry (air outside the CT at the box's faces), so the
    /// count stops where the one-at-a-time loop's stops.
    pub counted_before: [u32; CAPACITY],
}

impl Default for Batch {
    fn default() -> Self {
        Batch {
            len: 0,
            b: [[0; CAPACITY]; 3],
            f: [[0.0; CAPACITY]; 3],
            t: [0.0; CAPACITY],
            counted_before: [0; CAPACITY],
        }
    }
}

impl Batch {
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether [`LANES`] samples (or more) wait: time to evaluate.
    pub fn is_full(&self) -> bool {
        self.len >= LANES
    }

    /// Entry `i`'s cell.
    #[inline(always)]
    pub fn cell(&self, i: usize) -> Cell {
        Cell {
            b: [self.b[0][i], self.b[1][i], self.b[2][i]],
            f: [self.f[0][i], self.f[1][i], self.f[2][i]],
        }
    }

    /// Adds a located sample (`Grid3::locate` on the records' grid) at ray parameter `t`; a
    /// batch is evaluated once [`LANES`] wait, so a push never finds it full.
    #[inline(always)]
    pub fn push(&mut self, cell: Cell, t: f32, counted_before: u32) {
        // The length read once: the stores below cannot change it (and it is not reloaded).
        let n = self.len;
        assert!(n < LANES, "a batch holds {LANES} samples");
        for a in 0..3 {
            self.b[a][n] = cell.b[a];
            self.f[a][n] = cell.f[a];
        }
        self.t[n] = t;
        self.counted_before[n] = counted_before;
        self.len = n + 1;
    }

    /// Removes the first `n` entries (those just evaluated, now held by `Evaluated`): `n` is
    /// [`LANES`] or the whole batch.
    #[inline(always)]
    pub fn drop_front(&mut self, n: usize) {
        debug_assert!(n == LANES || n == self.len);
        if n >= self.len {
            self.len = 0;
            return;
        }
        for a in 0..3 {
            self.b[a].copy_within(LANES..CAPACITY, 0);
            self.f[a].copy_within(LANES..CAPACITY, 0);
        }
        self.t.copy_within(LANES..CAPACITY, 0);
        self.counted_before.copy_within(LANES..CAPACITY, 0);
        self.len -= LANES;
    }
}

/// What compositing needs of each sample of a batch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Evaluated {
    /// The table's (α·r, α·g, α·b, α) at the sample's value.
    pub colour: [[f32; 4]; LANES],
    /// diffuse·|N·L| + specular·|N·H|^shininess of eq. 3.2.3 (the part the shadow scales);
    /// 0 for an unshaded sample.
    pub lit: [f32; LANES],
    /// Bit i: sample i's gradient is shorter than `shading::MIN_GRADIENT` (unshaded, f = 1).
    pub unshaded: u8,
    /// Samples held (evaluated, not yet composited; see `Kernel::take_front`).
    pub len: usize,
    /// Their ray parameters and the samples counted before each (the batch's, moved here).
    pub t: [f32; LANES],
    pub counted_before: [u32; LANES],
}

impl Default for Evaluated {
    fn default() -> Self {
        Evaluated {
            colour: [[0.0; 4]; LANES],
            lit: [0.0; LANES],
            unshaded: 0,
            len: 0,
            t: [0.0; LANES],
            counted_before: [0; LANES],
        }
    }
}

impl Evaluated {
    /// f of eq. 3.2.3 for sample `i` under shadow factor `f_shadow` (`PhongTerms::shade`'s last
    /// operation).
    #[inline(always)]
    pub fn shade(&self, i: usize, phong: &PhongTerms, f_shadow: f32) -> f32 {
        if self.unshaded & (1 << i) != 0 {
            1.0
        } else {
            phong.ambient + self.lit[i] * f_shadow
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[should_panic(expected = "a batch holds 8 samples")]
    fn a_ninth_sample_is_refused() {
        let mut batch = Batch::default();
        let cell = Cell { b: [0; 3], f: [0.0; 3] };
        for _ in 0..=LANES {
            batch.push(cell, 0.0, 0);
        }
    }
}
