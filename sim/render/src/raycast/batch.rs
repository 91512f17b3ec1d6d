//! Eight visible samples of one ray evaluated together (docs/rendering.md "Sample lanes"): the
//! march finds the visible lattice points one after the other, as before, but reads, classifies
//! and lights them eight at a time, then composites them in order. Every number is that of the
//! one-at-a-time loop bit for bit — the same products and sums of the same values in the same
//! order, several per instruction (AVX2 where the CPU has it) — so the picture does not change.
//!
//! Compositing stays one sample at a time and in order (front-to-back accumulation is a chain),
//! so early termination stops at the very sample the one-at-a-time loop stops at; the samples of
//! the last batch beyond it were read for nothing (at most seven per ray).

use stylet_physics::glam::Vec3;

use super::gradient_volume::GradientVolume;
use super::sampler::{Cell, world_gradient};
use super::shading::{MIN_GRADIENT, PhongTerms};
use super::window::Window;
use crate::transfer_table::TransferTable;

/// Samples evaluated together.
pub const LANES: usize = 8;

/// Entries a batch can hold: fewer than [`LANES`] waiting, plus a whole window's visible points
/// appended at once ([`Batch::append_window`]).
const CAPACITY: usize = 2 * LANES;

/// Visible samples of one ray, in the order the ray meets them, one array per component (the
/// lanes append and read eight at a time). Samples are evaluated [`LANES`] at a time from the
/// front ([`Batch::drop_front`]).
#[derive(Debug, Clone)]
pub(crate) struct Batch {
    len: usize,
    /// Base voxel per axis (entries past `len` are stale and never read).
    b: [[u32; CAPACITY]; 3],
    /// Fractions per axis.
    f: [[f32; CAPACITY]; 3],
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

    /// Appends the window's points whose bits are set in `take`, in order (the first after
    /// `counted` samples, the rest after none), on the lanes: each component left-packed by one
    /// permutation. The batch must hold fewer than [`LANES`] entries.
    #[inline(always)]
    pub fn append_window(&mut self, avx2: Avx2, window: &Window, take: u8, counted: u32) {
        let n = self.len;
        assert!(n < LANES, "a batch holds {LANES} samples");
        debug_assert!(take != 0, "an empty append would give counted_before to no sample");
        #[cfg(target_arch = "x86_64")]
        {
            let _ = avx2;
            // SAFETY: an `Avx2` exists only when the CPU has AVX2; n + 8 ≤ CAPACITY.
            unsafe { avx2::append_window(self, window, take) };
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = avx2;
            let mut m = n;
            for i in 0..LANES {
                if take & (1 << i) != 0 {
                    for a in 0..3 {
                        self.b[a][m] = window.b[a][i];
                        self.f[a][m] = window.f[a][i];
                    }
                    self.t[m] = window.t[i];
                    m += 1;
                }
            }
        }
        let added = take.count_ones() as usize;
        self.counted_before[n..n + added].fill(0);
        self.counted_before[n] = counted;
        self.len = n + added;
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
    /// Bit i: sample i's gradient is shorter than [`MIN_GRADIENT`] (unshaded, f = 1).
    pub unshaded: u8,
    /// Samples held (evaluated, not yet composited; see [`Self::take_front`]).
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
    /// The batch's first min(len, [`LANES`]) samples, evaluated by `kernel`, moved out of the
    /// batch into `self` (which must hold none).
    #[inline(always)]
    pub fn take_front(&mut self, kernel: &Kernel, batch: &mut Batch, half: Vec3) {
        debug_assert_eq!(self.len, 0, "evaluated samples not composited");
        kernel.evaluate(batch, half, self);
        let n = batch.len().min(LANES);
        self.t.copy_from_slice(&batch.t[..LANES]);
        self.counted_before.copy_from_slice(&batch.counted_before[..LANES]);
        self.len = n;
        batch.drop_front(n);
    }

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

/// What a batch is evaluated against: the records, the table and the frame's shading terms.
#[derive(Clone, Copy)]
pub(crate) struct Kernel<'a> {
    pub grads: &'a GradientVolume,
    pub table: &'a TransferTable,
    pub phong: &'a PhongTerms,
    /// ½ M⁻¹'s rows: ∇s = Σ_a Δ_a·rows[a] ([`world_gradient`]).
    pub half_rows: [Vec3; 3],
    /// Evaluate on AVX2 lanes (16-bit records on a CPU with AVX2), else one sample at a time.
    avx2: Option<Avx2>,
    /// With the lanes: the 16-bit records and their strides along y and z, taken out of
    /// `grads` once for [`Self::prefetch`] (called for every visible sample).
    lane_records: Option<(&'a [[i16; 4]], usize, usize)>,
}

impl<'a> Kernel<'a> {
    /// The kernel for `grads`: AVX2 lanes when `avx2` is given and the records are 16-bit
    /// integers; else one sample at a time (the reference).
    pub fn new(
        grads: &'a GradientVolume,
        table: &'a TransferTable,
        phong: &'a PhongTerms,
        half_rows: [Vec3; 3],
        avx2: Option<Avx2>,
    ) -> Self {
        let avx2 = avx2.filter(|_| grads.is_int16());
        let lane_records = match (avx2, grads.records()) {
            (Some(_), super::gradient_volume::RecordSlice::Int16(records)) => {
                let (sy, sz) = grads.strides();
                Some((records, sy, sz))
            }
            _ => None,
        };
        Kernel {
            grads,
            table,
            phong,
            half_rows,
            avx2,
            lane_records,
        }
    }

    /// Asks the CPU to start loading the four record rows a located sample will read (the batch
    /// reads them only once it is full, up to seven samples later).
    #[inline(always)]
    pub fn prefetch(&self, cell: &Cell) {
        #[cfg(target_arch = "x86_64")]
        if let Some((records, sy, sz)) = self.lane_records {
            let o = cell.b[0] as usize + sy * cell.b[1] as usize + sz * cell.b[2] as usize;
            prefetch_rows(records, sy, sz, o);
        }
    }

    /// [`Self::prefetch`] of all eight points of a window, visible or not: their records'
    /// offsets worked out on the lanes, then four prefetches per point. Prefetching the points
    /// the batch will not read costs less than a branch per point (measured on the chest CT).
    #[inline(always)]
    pub fn prefetch_window(&self, window: &Window) {
        #[cfg(target_arch = "x86_64")]
        if let (Some(_), Some((records, sy, sz))) = (self.avx2, self.lane_records) {
            // SAFETY: an `Avx2` exists only when the CPU has AVX2.
            unsafe { avx2::prefetch_window(records, sy, sz, window) };
        }
        let _ = window;
    }

    /// Whether batches go through the AVX2 lanes.
    #[cfg(test)]
    pub fn uses_avx2(&self) -> bool {
        self.avx2.is_some()
    }

    /// Reads, classifies and lights the batch's samples for a ray with Phong half vector
    /// `half`: the first min(`batch.len()`, [`LANES`]) entries. Later entries of `out` are
    /// unspecified.
    #[inline(always)]
    pub fn evaluate(&self, batch: &Batch, half: Vec3, out: &mut Evaluated) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2.is_some()
            && let super::gradient_volume::RecordSlice::Int16(records) = self.grads.records()
        {
            // SAFETY: an `Avx2` exists only when the CPU has AVX2 (`Avx2::detect`); the cells come
            // from `Grid3::locate` on the records' grid, as `GradientVolume::interpolate` needs.
            unsafe { avx2::evaluate(self, records, batch, half, out) };
            return;
        }
        self.evaluate_one_at_a_time(batch, half, out);
    }

    /// The reference: each sample as the one-at-a-time loop computes it.
    pub fn evaluate_one_at_a_time(&self, batch: &Batch, half: Vec3, out: &mut Evaluated) {
        out.unshaded = 0;
        for i in 0..batch.len.min(LANES) {
            let r = self.grads.interpolate(&batch.cell(i));
            out.colour[i] = self.table.lookup(r.w);
            let g = world_gradient(&self.half_rows, r.truncate());
            let len = g.length();
            if len < MIN_GRADIENT {
                out.unshaded |= 1 << i;
                out.lit[i] = 0.0;
            } else {
                out.lit[i] = self.phong.lit(g, len, half);
            }
        }
    }
}

/// Asks the CPU to start loading the four record rows of the cell whose base record is `o`
/// (rows o, o + s_y, o + s_z, o + s_y + s_z: those `interpolate` reads). A prefetch never faults,
/// so any `o` is harmless.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn prefetch_rows(records: &[[i16; 4]], sy: usize, sz: usize, o: usize) {
    use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
    let p = records.as_ptr().cast::<i8>();
    for i in [o, o + sy, o + sz, o + sy + sz] {
        // SAFETY: `_mm_prefetch` is a hint (SSE, part of x86-64) and reads nothing;
        // `wrapping_add` keeps the address computation defined.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(i * 8)) };
    }
}

/// Which evaluation the ray caster may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lanes {
    /// SIMD lanes where the CPU and the records allow, and the rays of three (or two) pixels
    /// marched in turn (the same pixels, faster).
    Auto,
    /// One sample at a time, one ray after the other: the reference the lanes are tested
    /// against.
    OneAtATime,
    /// The rays of two pixels marched in turn, one sample at a time: what [`Lanes::Auto`] runs
    /// on a CPU without AVX2, here on any CPU, so that path is tested where AVX2 is present.
    PairsWithoutSimd,
}

impl Lanes {
    /// Whether pixels' rays are marched in turn (three or two, [`Lanes::Auto`]; two,
    /// [`Lanes::PairsWithoutSimd`]).
    pub fn pairs(self) -> bool {
        self != Lanes::OneAtATime
    }
}

/// Proof that this CPU has AVX2 and the lanes were asked for: only [`Avx2::detect`] makes one,
/// once per frame, so the lane kernels' safety rests on it rather than on a flag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Avx2(());

impl Avx2 {
    /// `Some` when `lanes` is [`Lanes::Auto`] and the CPU has AVX2.
    pub fn detect(lanes: Lanes) -> Option<Avx2> {
        (lanes == Lanes::Auto && avx2_available()).then_some(Avx2(()))
    }
}

/// For the lane tests: whether this CPU has AVX2, so the lanes have something to be compared
/// with. Without it a lane test compares the reference with itself; when `STYLET_REQUIRE_AVX2`
/// is set (scripts/test sets it on x86-64) that is a failure instead, so CI never passes the
/// lane tests by comparing nothing.
#[cfg(test)]
pub(crate) fn avx2_for_lane_tests() -> bool {
    let present = avx2_available();
    if !present {
        assert!(
            std::env::var_os("STYLET_REQUIRE_AVX2").is_none(),
            "STYLET_REQUIRE_AVX2 is set and this CPU has no AVX2: the lane tests would compare nothing"
        );
        eprintln!("this CPU has no AVX2: the lanes are not used here, nothing to compare");
    }
    present
}

/// Whether this CPU has AVX2 (false off x86-64).
pub fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use stylet_physics::glam::Vec3;

    use super::super::gradient_volume::{XY_WEIGHT_ONE, XY_WEIGHT_UNIT};
    use super::super::shading::{Exponent, MIN_GRADIENT};
    use super::{Batch, Evaluated, Kernel, LANES};
    use crate::raycast::window::Window;
    use crate::transfer_table::TransferTable;

    /// For each 8-bit mask, the lanes of its set bits in order, 3 bits each in a nibble (lane
    /// of the k-th set bit in bits 4k … 4k + 2): the left-packing permutation of the mask.
    const LEFT_PACK: [u32; 256] = {
        let mut table = [0u32; 256];
        let mut m = 0;
        while m < 256 {
            let (mut packed, mut k, mut lane) = (0u32, 0, 0);
            while lane < 8 {
                if m & (1 << lane) != 0 {
                    packed |= (lane as u32) << (4 * k);
                    k += 1;
                }
                lane += 1;
            }
            table[m] = packed;
            m += 1;
        }
        table
    };

    /// `Kernel::prefetch_window` on the lanes: o = b_x + s_y·b_y + s_z·b_z for the eight
    /// points, then the four rows of each.
    ///
    /// # Safety
    /// AVX2.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn prefetch_window(records: &[[i16; 4]], sy: usize, sz: usize, window: &Window) {
        // Offsets of located points are < the records' count ≤ 2²⁸ (`MAX_VOXELS`); the lanes
        // wrap for others, and a prefetch of any address is harmless.
        // SAFETY: loads: eight lanes from eight.
        let lane = |a: usize| unsafe { _mm256_loadu_si256(window.b[a].as_ptr().cast()) };
        let o = _mm256_add_epi32(
            lane(0),
            _mm256_add_epi32(
                _mm256_mullo_epi32(_mm256_set1_epi32(sy as i32), lane(1)),
                _mm256_mullo_epi32(_mm256_set1_epi32(sz as i32), lane(2)),
            ),
        );
        let mut offsets = [0u32; 8];
        // SAFETY: eight lanes into eight.
        unsafe { _mm256_storeu_si256(offsets.as_mut_ptr().cast(), o) };
        for o in offsets {
            super::prefetch_rows(records, sy, sz, o as usize);
        }
    }

    /// The window's points of `take` written from entry `batch.len` on, in order: every
    /// component (t, base voxels, fractions) permuted so the taken lanes come first, and stored
    /// whole (the lanes past them are overwritten later or never read).
    ///
    /// # Safety
    /// AVX2, and `batch.len + 8 ≤` the batch's capacity.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn append_window(batch: &mut Batch, window: &Window, take: u8) {
        let n = batch.len;
        debug_assert!(n + LANES <= batch.t.len());
        let nibbles = _mm256_srlv_epi32(
            _mm256_set1_epi32(LEFT_PACK[take as usize] as i32),
            _mm256_setr_epi32(0, 4, 8, 12, 16, 20, 24, 28),
        );
        let lanes = _mm256_and_si256(nibbles, _mm256_set1_epi32(7));
        // SAFETY: all: eight lanes read from eight, stored at n … n + 7 < capacity (the caller).
        unsafe {
            let t = _mm256_permutevar8x32_ps(_mm256_loadu_ps(window.t.as_ptr()), lanes);
            _mm256_storeu_ps(batch.t.as_mut_ptr().add(n), t);
            for a in 0..3 {
                let b = _mm256_permutevar8x32_epi32(_mm256_loadu_si256(window.b[a].as_ptr().cast()), lanes);
                _mm256_storeu_si256(batch.b[a].as_mut_ptr().add(n).cast(), b);
                let f = _mm256_permutevar8x32_ps(_mm256_loadu_ps(window.f[a].as_ptr()), lanes);
                _mm256_storeu_ps(batch.f[a].as_mut_ptr().add(n), f);
            }
        }
    }

    /// Step 1 of [`evaluate`]: each sample's (Δx, Δy, Δz, s) as `GradientVolume::interpolate`
    /// reads 16-bit records, times 2¹⁴ (unused lanes repeat sample 0). Per sample two registers
    /// hold the rows at y and at y + 1 (16 bytes a row: records x and x + 1), each at z and
    /// z + 1; a byte shuffle pairs each channel of a row's two records, so one multiply-add
    /// (`vpmaddwd`) per register weights them along x and y in fixed point, and one integer add
    /// gives the exact blends c₀ (at z) and c₁ (at z + 1). Then z in `f32`, as the reference.
    /// The eight samples' offsets and weights are worked out together on the lanes.
    ///
    /// # Safety
    /// AVX2; entry 0 and every entry below `count` of `batch` a located cell of `records` with
    /// strides `sy`, `sz` (`o + sy + sz + 1` < `records.len()`, as `GradientVolume::lerp8`).
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn read_records(records: &[[i16; 4]], sy: usize, sz: usize, batch: &Batch, count: usize) -> [__m128; LANES] {
        let mut offsets = [0u32; LANES];
        // Per sample: the weight pairs of the rows at y and at y + 1, then (1 − f_z, f_z).
        let mut weights = [[0i32; 2]; LANES];
        let mut z_weights = [[0f32; 2]; LANES];
        // Lanes from `count` on take sample 0's cell (a batch at the ray's end holds fewer).
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let from = _mm256_and_si256(lane, _mm256_cmpgt_epi32(_mm256_set1_epi32(count as i32), lane));
        // SAFETY: loads and stores of eight lanes: each array holds ≥ 8 entries.
        unsafe {
            let base = |a: usize| _mm256_permutevar8x32_epi32(_mm256_loadu_si256(batch.b[a].as_ptr().cast()), from);
            let o = _mm256_add_epi32(
                base(0),
                _mm256_add_epi32(
                    _mm256_mullo_epi32(_mm256_set1_epi32(sy as i32), base(1)),
                    _mm256_mullo_epi32(_mm256_set1_epi32(sz as i32), base(2)),
                ),
            );
            _mm256_storeu_si256(offsets.as_mut_ptr().cast(), o);
            // q = round(f·2⁷), ties to even (`xy_fraction`; the product is exact).
            let fraction = |a: usize| _mm256_permutevar8x32_ps(_mm256_loadu_ps(batch.f[a].as_ptr()), from);
            let q = |a: usize| {
                let f = fraction(a);
                _mm256_cvtps_epi32(_mm256_mul_ps(f, splat(XY_WEIGHT_ONE as f32)))
            };
            let (qx, qy) = (q(0), q(1));
            let one = _mm256_set1_epi32(XY_WEIGHT_ONE);
            let (gx, gy) = (_mm256_sub_epi32(one, qx), _mm256_sub_epi32(one, qy));
            // A row's two 16-bit weights in one 32-bit lane: w_x,0·w_y low, w_x,1·w_y high.
            let pair = |wy: __m256i| {
                _mm256_or_si256(
                    _mm256_mullo_epi32(gx, wy),
                    _mm256_slli_epi32::<16>(_mm256_mullo_epi32(qx, wy)),
                )
            };
            let (near, far) = (pair(gy), pair(qy));
            let w = weights.as_mut_ptr().cast::<i32>();
            _mm256_storeu_si256(w.cast(), _mm256_unpacklo_epi32(near, far)); // 0 1 | 4 5
            _mm256_storeu_si256(w.add(8).cast(), _mm256_unpackhi_epi32(near, far)); // 2 3 | 6 7
            let fz = fraction(2);
            let gz = _mm256_sub_ps(splat(1.0), fz);
            let z = z_weights.as_mut_ptr().cast::<f32>();
            _mm256_storeu_ps(z, _mm256_unpacklo_ps(gz, fz));
            _mm256_storeu_ps(z.add(8), _mm256_unpackhi_ps(gz, fz));
        }
        // The stores above hold samples 0 1 4 5 2 3 6 7 in turn.
        const SLOT: [usize; LANES] = [0, 1, 4, 5, 2, 3, 6, 7];
        // (a₀ b₀ a₁ b₁ a₂ b₂ a₃ b₃) from (a₀ a₁ a₂ a₃ b₀ b₁ b₂ b₃), in each 128-bit half.
        let pairs = _mm256_setr_epi8(
            0, 1, 8, 9, 2, 3, 10, 11, 4, 5, 12, 13, 6, 7, 14, 15, //
            0, 1, 8, 9, 2, 3, 10, 11, 4, 5, 12, 13, 6, 7, 14, 15,
        );
        let at = records.as_ptr();
        std::array::from_fn(|i| {
            let o = offsets[i] as usize;
            debug_assert!(o + sy + sz + 1 < records.len(), "lane {i} of {count}: offset {o}");
            let [w_near, w_far] = weights[SLOT[i]];
            let [gz, fz] = z_weights[SLOT[i]];
            // SAFETY: the caller's bound; each load reads records i and i + 1 of a row.
            let rows = |z0: usize, z1: usize| unsafe {
                let lo = _mm256_castsi128_si256(_mm_loadu_si128(at.add(z0).cast()));
                _mm256_shuffle_epi8(
                    _mm256_inserti128_si256::<1>(lo, _mm_loadu_si128(at.add(z1).cast())),
                    pairs,
                )
            };
            // (c₀ | c₁): the rows at y weighted by w_y,0, those at y + 1 by w_y,1, added.
            let c = _mm256_add_epi32(
                _mm256_madd_epi16(rows(o, o + sz), _mm256_set1_epi32(w_near)),
                _mm256_madd_epi16(rows(o + sy, o + sy + sz), _mm256_set1_epi32(w_far)),
            );
            let p = _mm256_mul_ps(_mm256_cvtepi32_ps(c), _mm256_set_m128(_mm_set1_ps(fz), _mm_set1_ps(gz)));
            // c₀·(1 − f_z) + c₁·f_z.
            _mm_add_ps(_mm256_castps256_ps128(p), _mm256_extractf128_ps::<1>(p))
        })
    }

    /// (a·x + b·y) + c·z per lane: glam's `Vec3::dot` order and the world gradient's.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn dot(a: __m256, b: __m256, c: __m256, x: __m256, y: __m256, z: __m256) -> __m256 {
        _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(a, x), _mm256_mul_ps(b, y)),
            _mm256_mul_ps(c, z),
        )
    }

    /// `power_whole(x, e)` on every lane for an `e` of `BITS` bits (≤ 9: e ≤ 256): the same
    /// products in the same order, r ← r·x^(2^k) for each set bit k from the lowest, written out
    /// without a branch (a bit's product kept or not by a blend; the loop with a test per bit
    /// cost about 2.5 % of the soft frame). No squaring past the top bit, as few as the loop.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn power_bits<const BITS: u32>(x: __m256, e: u32) -> __m256 {
        debug_assert!(BITS <= 9 && u32::BITS - e.leading_zeros() == BITS);
        let (mut base, mut r) = (x, _mm256_set1_ps(1.0));
        for bit in 0..BITS {
            let keep = _mm256_castsi256_ps(_mm256_set1_epi32(-(((e >> bit) & 1) as i32)));
            r = _mm256_blendv_ps(r, _mm256_mul_ps(r, base), keep);
            if bit + 1 < BITS {
                base = _mm256_mul_ps(base, base);
            }
        }
        r
    }

    /// `power_whole(x, e)` on every lane, for any whole e ≤ 256.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn power_whole(x: __m256, e: u32) -> __m256 {
        match u32::BITS - e.leading_zeros() {
            0 => _mm256_set1_ps(1.0),
            1 => power_bits::<1>(x, e),
            2 => power_bits::<2>(x, e),
            3 => power_bits::<3>(x, e),
            4 => power_bits::<4>(x, e),
            5 => power_bits::<5>(x, e),
            6 => power_bits::<6>(x, e),
            7 => power_bits::<7>(x, e),
            8 => power_bits::<8>(x, e),
            _ => power_bits::<9>(x, e),
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    fn splat(v: f32) -> __m256 {
        _mm256_set1_ps(v)
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    fn abs(v: __m256) -> __m256 {
        _mm256_andnot_ps(_mm256_set1_ps(-0.0), v)
    }

    /// `TransferTable::lookup` of the first `len` lanes of `values` into `colours`: the clamped
    /// table position x = clamp((v − lo)/step, 0, len − 1), its entry i = min(⌊x⌋, len − 2) and
    /// fraction x − i on the lanes, then entries i and i + 1 blended by (1 − f, f) per sample.
    /// `max` gives 0 for NaN, as the scalar clamp; for x = ±0 either zero blends to entry 0.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn colours(table: &TransferTable, values: __m256, len: usize, colours: &mut [[f32; 4]; LANES]) {
        let (last_position, last_base) = table.clamps();
        let x = _mm256_mul_ps(_mm256_sub_ps(values, splat(table.lo_hu)), splat(table.inv_step));
        let x = _mm256_min_ps(_mm256_max_ps(x, _mm256_setzero_ps()), splat(last_position));
        // Truncation of 0 ≤ x ≤ len − 1 < 2³¹.
        let i = _mm256_min_epi32(_mm256_cvttps_epi32(x), _mm256_set1_epi32(last_base as i32));
        let f = _mm256_sub_ps(x, _mm256_cvtepi32_ps(i));
        let g = _mm256_sub_ps(splat(1.0), f);
        let (mut is, mut fs, mut gs) = ([0i32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
        // SAFETY: eight lanes into eight.
        unsafe {
            _mm256_storeu_si256(is.as_mut_ptr().cast(), i);
            _mm256_storeu_ps(fs.as_mut_ptr(), f);
            _mm256_storeu_ps(gs.as_mut_ptr(), g);
        }
        for k in 0..len.min(LANES) {
            colours[k] = table.blend(is[k] as usize, gs[k], fs[k]);
        }
    }

    /// `Kernel::evaluate_one_at_a_time` on eight lanes.
    ///
    /// # Safety
    /// AVX2, and `records` are `kernel.grads`' records with every batch cell located on them.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn evaluate(
        kernel: &Kernel,
        records: &[[i16; 4]],
        batch: &Batch,
        half: Vec3,
        out: &mut Evaluated,
    ) {
        let (sy, sz) = kernel.grads.strides();
        let count = batch.len.min(LANES);
        // 1. Each sample's (Δx, Δy, Δz, s)·2¹⁴; unused lanes repeat sample 0.
        // SAFETY: the caller's contract.
        let r = unsafe { read_records(records, sy, sz, batch, count) };
        // 2. Transposed: Δx, Δy, Δz and s of the eight samples, one register each, scaled by
        // 2⁻¹⁴ as `GradientVolume::interpolate` does (exact either way: a power of two).
        let a = _mm256_set_m128(r[4], r[0]);
        let b = _mm256_set_m128(r[5], r[1]);
        let c = _mm256_set_m128(r[6], r[2]);
        let d = _mm256_set_m128(r[7], r[3]);
        let ab_lo = _mm256_unpacklo_ps(a, b); // x0 x1 y0 y1 | x4 x5 y4 y5
        let cd_lo = _mm256_unpacklo_ps(c, d); // x2 x3 y2 y3 | x6 x7 y6 y7
        let ab_hi = _mm256_unpackhi_ps(a, b); // z0 z1 w0 w1 | …
        let cd_hi = _mm256_unpackhi_ps(c, d);
        let real = |v: __m256| _mm256_mul_ps(v, splat(XY_WEIGHT_UNIT));
        let dx = real(_mm256_shuffle_ps::<0x44>(ab_lo, cd_lo));
        let dy = real(_mm256_shuffle_ps::<0xEE>(ab_lo, cd_lo));
        let dz = real(_mm256_shuffle_ps::<0x44>(ab_hi, cd_hi));
        // 3. The colours: the table's position of the eight values at once, then two entries and
        // a lerp per sample (`TransferTable::lookup`'s operations).
        let values = real(_mm256_shuffle_ps::<0xEE>(ab_hi, cd_hi));
        colours(kernel.table, values, count, &mut out.colour);
        // 4. ∇s = rows[0]·Δx + rows[1]·Δy + rows[2]·Δz, per component.
        let [r0, r1, r2] = kernel.half_rows;
        let gx = dot(splat(r0.x), splat(r1.x), splat(r2.x), dx, dy, dz);
        let gy = dot(splat(r0.y), splat(r1.y), splat(r2.y), dx, dy, dz);
        let gz = dot(splat(r0.z), splat(r1.z), splat(r2.z), dx, dy, dz);
        // 5. |∇s|, and N = ∇s·(−1/|∇s|) (`PhongTerms::lit`).
        let len = _mm256_sqrt_ps(dot(gx, gy, gz, gx, gy, gz));
        let unshaded = _mm256_cmp_ps::<_CMP_LT_OQ>(len, splat(MIN_GRADIENT));
        let inv = _mm256_div_ps(splat(-1.0), len);
        let (nx, ny, nz) = (_mm256_mul_ps(gx, inv), _mm256_mul_ps(gy, inv), _mm256_mul_ps(gz, inv));
        let p = kernel.phong;
        let specular = if p.specular > 0.0 {
            let x = abs(dot(nx, ny, nz, splat(half.x), splat(half.y), splat(half.z)));
            let power = match p.exponent {
                Exponent::Whole(e) => power_whole(x, e),
                Exponent::Real(e) => {
                    let mut lanes = [0.0f32; LANES];
                    // SAFETY: 8 floats into 8 floats.
                    unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), x) };
                    let lanes = lanes.map(|v| v.powf(e));
                    // SAFETY: as above.
                    unsafe { _mm256_loadu_ps(lanes.as_ptr()) }
                }
            };
            _mm256_mul_ps(splat(p.specular), power)
        } else {
            _mm256_setzero_ps()
        };
        let l = p.toward_light;
        let diffuse = abs(dot(nx, ny, nz, splat(l.x), splat(l.y), splat(l.z)));
        let lit = _mm256_add_ps(_mm256_mul_ps(splat(p.diffuse), diffuse), specular);
        // Unshaded lanes hold 0, as the reference writes.
        let lit = _mm256_andnot_ps(unshaded, lit);
        // SAFETY: 8 floats into `lit`'s 8.
        unsafe { _mm256_storeu_ps(out.lit.as_mut_ptr(), lit) };
        let live = (1u32 << count) - 1;
        out.unshaded = (_mm256_movemask_ps(unshaded) as u32 & live) as u8;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Light;
    use crate::transfer::{TransferFunction, Trapezoid};
    use stylet_physics::glam::Vec3;

    fn ct(dims: [usize; 3]) -> Vec<f32> {
        let mut v = Vec::with_capacity(dims.iter().product());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    // Edges, a flat block whose inside has no gradient (unshaded), and values
                    // beyond both ends of the table (its clamps).
                    let x = ((i * 37 + j * 11 + k * 5) % 23) as f32;
                    v.push(if i < 5 && j < 5 && k < 5 {
                        40.0
                    } else if i == 8 && j % 3 == 0 {
                        4000.0
                    } else if j == 7 && k % 2 == 0 {
                        -3000.0
                    } else {
                        x * 90.0 - 1000.0
                    });
                }
            }
        }
        v
    }

    #[test]
    fn lanes_give_the_bits_of_one_sample_at_a_time() {
        let lanes_here = avx2_for_lane_tests();
        let dims = [9usize, 8, 7];
        let data = ct(dims);
        let d = dims.map(|n| n as u32);
        let grads = GradientVolume::new(&data, d);
        let grid = super::super::sampler::Grid3::new(&data, d);
        // Soft tissue, and bone visible up to the table's top end (where the clamp matters).
        let tf = TransferFunction::Trapezoids(vec![
            Trapezoid {
                tissue: "soft".into(),
                hu: [-400.0, -100.0, 300.0, 900.0],
                rgb: [0.9, 0.6, 0.5],
                opacity: 0.7,
                weight: 1.0,
            },
            Trapezoid {
                tissue: "bone".into(),
                hu: [700.0, 1000.0, 3000.0, 3100.0],
                rgb: [1.0, 0.95, 0.9],
                opacity: 0.9,
                weight: 1.0,
            },
        ]);
        let table = TransferTable::new(&tf, -1024.0, 1200.0, 0.5);
        let rows = [
            Vec3::new(0.7, 0.1, 0.0),
            Vec3::new(-0.1, 0.8, 0.05),
            Vec3::new(0.0, 0.02, 0.3),
        ];
        for shininess in [0.0, 1.0, 20.0, 7.5] {
            for specular in [0.0, 0.4] {
                let light = Light {
                    toward_light: Vec3::new(0.3, -0.5, 0.8).normalize(),
                    ambient: 0.25,
                    diffuse: 0.6,
                    specular,
                    shininess,
                    shadow_in: 0.3,
                };
                let phong = PhongTerms::new(&light);
                let lanes = Kernel::new(&grads, &table, &phong, rows, Avx2::detect(Lanes::Auto));
                let one = Kernel::new(&grads, &table, &phong, rows, Avx2::detect(Lanes::OneAtATime));
                assert_eq!(lanes.uses_avx2(), lanes_here);
                assert!(!one.uses_avx2());
                let mut batch = Batch::default();
                let (mut n, mut unshaded) = (0, 0);
                // Samples whose value lies below or above the table (clamped to its ends).
                let (mut below, mut above) = (0, 0);
                for s in 0..600 {
                    let f = s as f32;
                    let c = Vec3::new(
                        (f * 0.37).sin() * 4.6 + 4.0,
                        (f * 0.11).cos() * 4.1 + 3.5,
                        (f * 0.23).sin() * 3.6 + 3.0,
                    ) * if s % 3 == 0 { 0.45 } else { 1.0 };
                    let Some(cell) = grid.locate(c) else { continue };
                    batch.push(cell, f, 0);
                    // Full batches and, every so often, a short one.
                    if batch.is_full() || s % 97 == 0 {
                        let half = Vec3::new(f.sin(), 0.4, f.cos()).normalize();
                        // A short batch's entries past its length are never read: poisoned with
                        // cells far outside the records (the lanes repeat sample 0 there).
                        for e in batch.len()..CAPACITY {
                            for a in 0..3 {
                                batch.b[a][e] = 1 << 30;
                                batch.f[a][e] = f32::NAN;
                            }
                        }
                        let (mut a, mut b) = (Evaluated::default(), Evaluated::default());
                        lanes.evaluate(&batch, half, &mut a);
                        one.evaluate(&batch, half, &mut b);
                        for i in 0..batch.len() {
                            let v = grads.interpolate(&batch.cell(i)).w;
                            below += usize::from(v < -1024.0);
                            above += usize::from(v > 1200.0);
                            assert_eq!(a.colour[i].map(f32::to_bits), b.colour[i].map(f32::to_bits), "{s}/{i}");
                            assert_eq!(a.lit[i].to_bits(), b.lit[i].to_bits(), "sample {s}, lane {i}");
                            for f_shadow in [1.0, 0.3] {
                                let want = if b.unshaded & (1 << i) != 0 {
                                    1.0
                                } else {
                                    let g = {
                                        let r = grads.interpolate(&batch.cell(i));
                                        rows[0] * r.x + rows[1] * r.y + rows[2] * r.z
                                    };
                                    phong.shade(g, g.length(), half, f_shadow)
                                };
                                assert_eq!(a.shade(i, &phong, f_shadow).to_bits(), want.to_bits());
                            }
                        }
                        assert_eq!(a.unshaded, b.unshaded, "sample {s}");
                        unshaded += b.unshaded.count_ones() as usize;
                        n += batch.len();
                        batch.drop_front(batch.len());
                    }
                }
                assert!(n > 400, "{n} samples compared");
                assert!(below > 10 && above > 10, "{below} below and {above} above the table");
                assert!(unshaded > 0 && unshaded < n, "{unshaded} of {n} samples unshaded");
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_lanes_raise_to_every_whole_power_as_one_sample_does() {
        use std::arch::x86_64::*;
        if !avx2_for_lane_tests() {
            return;
        }
        // |N·H| ranges over [0, 1]; include 0, 1, values whose powers underflow, and a few > 1.
        let xs: Vec<f32> = (0..=64)
            .map(|i| i as f32 / 64.0)
            .chain([1e-3, 0.013, 0.031, 0.5 + f32::EPSILON, 0.999_999, 1.000_001, 1.5])
            .collect();
        for e in 0..=256u32 {
            for chunk in xs.chunks(LANES) {
                let mut lanes = [0.0f32; LANES];
                lanes[..chunk.len()].copy_from_slice(chunk);
                let mut out = [0.0f32; LANES];
                // SAFETY: AVX2 was detected above; 8 floats from and into 8.
                unsafe {
                    #[target_feature(enable = "avx2")]
                    unsafe fn run(x: &[f32; LANES], e: u32, out: &mut [f32; LANES]) {
                        // SAFETY: 8 floats from and into 8.
                        unsafe {
                            let r = avx2::power_whole(_mm256_loadu_ps(x.as_ptr()), e);
                            _mm256_storeu_ps(out.as_mut_ptr(), r);
                        }
                    }
                    run(&lanes, e, &mut out);
                }
                for (x, got) in lanes.iter().zip(out) {
                    let want = super::super::shading::power_whole(*x, e);
                    assert_eq!(got.to_bits(), want.to_bits(), "{x}^{e}: lanes {got}, one sample {want}");
                }
            }
        }
    }

    #[test]
    #[should_panic(expected = "a batch holds 8 samples")]
    fn a_ninth_sample_is_refused() {
        let mut batch = Batch::default();
        let cell = Cell { b: [0; 3], f: [0.0; 3] };
        for _ in 0..=LANES {
            batch.push(cell, 0.0, 0);
        }
    }

    #[test]
    fn a_window_appended_on_the_lanes_is_its_points_pushed_in_order() {
        let (true, Some(avx2)) = (avx2_for_lane_tests(), Avx2::detect(Lanes::Auto)) else {
            return;
        };
        let mut window = Window::default();
        for i in 0..8 {
            window.t[i] = 10.0 + i as f32 * 0.5;
            for a in 0..3 {
                window.b[a][i] = (100 * a + i) as u32;
                window.f[a][i] = (a * 8 + i) as f32 / 32.0;
            }
        }
        // Every mask, after every number of waiting samples.
        for take in 1..=u8::MAX {
            for waiting in 0..LANES {
                let (mut lanes, mut pushed) = (Batch::default(), Batch::default());
                for w in 0..waiting {
                    let cell = Cell {
                        b: [w as u32; 3],
                        f: [0.25; 3],
                    };
                    lanes.push(cell, w as f32, 1);
                    pushed.push(cell, w as f32, 1);
                }
                lanes.append_window(avx2, &window, take, 3);
                let mut first = true;
                for i in (0..8).filter(|i| take & (1 << i) != 0) {
                    let cell = window.cell_at(i);
                    if pushed.is_full() {
                        // Past eight: compare the front, then the rest after dropping it.
                        break;
                    }
                    pushed.push(cell, window.t[i], if first { 3 } else { 0 });
                    first = false;
                }
                let n = pushed.len();
                assert_eq!(lanes.len(), waiting + take.count_ones() as usize, "mask {take:#010b}");
                for i in 0..n {
                    assert_eq!(
                        lanes.cell(i),
                        pushed.cell(i),
                        "mask {take:#010b}, waiting {waiting}, entry {i}"
                    );
                    assert_eq!(lanes.t[i].to_bits(), pushed.t[i].to_bits());
                    assert_eq!(lanes.counted_before[i], pushed.counted_before[i]);
                }
                // What lies past the first eight moves to the front.
                let taken: Vec<usize> = (0..8).filter(|i| take & (1 << i) != 0).collect();
                if lanes.is_full() {
                    lanes.drop_front(LANES);
                    let rest = &taken[LANES - waiting..];
                    assert_eq!(lanes.len(), rest.len());
                    for (e, &i) in rest.iter().enumerate() {
                        assert_eq!(lanes.cell(e), window.cell_at(i), "mask {take:#010b}, entry {e}");
                        assert_eq!(lanes.t[e].to_bits(), window.t[i].to_bits());
                        assert_eq!(lanes.counted_before[e], 0);
                    }
                }
            }
        }
    }
}
