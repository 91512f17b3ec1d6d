//! Every AVX2 kernel of the ray caster, in one file behind a safe interface (docs/rendering.md
//! "Sample lanes"). Each kernel computes, eight at a time, exactly the numbers its one-at-a-time
//! reference computes — the same operations on the same values in the same order, never fused —
//! so the picture is the same bit for bit; the references' tests compare them.
//!
//! Safety rests on two things, both checked here rather than left to callers: an `Avx2` value
//! exists only on a CPU with AVX2 (`Avx2::detect`), and every memory access of a kernel is
//! either a load or store of eight lanes from or into an array of eight (or more) entries, or a
//! record read whose index is asserted to lie in the slice.

use super::Lanes;
use super::appearance::Appearance;
use super::batch::{Batch, Evaluated};
use super::cube_mask::{CubeMask, WindowClasses};
use super::sampler::Grid3;
use super::window::{Lattice, Window};
use stylet_physics::glam::Vec3;

/// Proof that this CPU has AVX2 and the lanes were asked for: only [`Avx2::detect`] makes one
/// (on other architectures the type has no value), so the kernels' safety rests on it rather
/// than on a flag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Avx2(Present);

#[cfg(target_arch = "x86_64")]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Present;

#[cfg(not(target_arch = "x86_64"))]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Present {}

/// Whether this CPU has AVX2 (false off x86-64).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// For the lane tests: whether this CPU has AVX2, so the lanes have something to be compared
/// with. Without it a lane test compares the reference with itself; when `STYLET_REQUIRE_AVX2`
/// is set (scripts/test sets it on x86-64) that is a failure instead, so CI never passes the
/// lane tests by comparing nothing.
#[cfg(test)]
pub(crate) fn available_for_lane_tests() -> bool {
    let present = available();
    if !present {
        assert!(
            std::env::var_os("STYLET_REQUIRE_AVX2").is_none(),
            "STYLET_REQUIRE_AVX2 is set and this CPU has no AVX2: the lane tests would compare nothing"
        );
        eprintln!("this CPU has no AVX2: the lanes are not used here, nothing to compare");
    }
    present
}

// Off x86-64 no `Avx2` exists: every method is `match self.0 {}`, and its arguments go unused.
#[cfg_attr(not(target_arch = "x86_64"), allow(unused_variables))]
impl Avx2 {
    /// `Some` when `lanes` is [`Lanes::Auto`] and the CPU has AVX2.
    pub fn detect(lanes: Lanes) -> Option<Avx2> {
        #[cfg(target_arch = "x86_64")]
        {
            (lanes == Lanes::Auto && available()).then_some(Avx2(Present))
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = lanes;
            None
        }
    }

    /// Points k … k + 7 of `lattice` located in `grid`: `Placer::place` (whose test compares
    /// them with the march's own formulas, one point at a time).
    #[inline(always)]
    pub fn place(self, grid: &Grid3, lattice: &Lattice, k: u32, out: &mut Window) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `self` exists only on a CPU with AVX2.
        unsafe {
            kernels::place(grid, lattice, k, out)
        }
        #[cfg(not(target_arch = "x86_64"))]
        match self.0 {}
    }

    /// The march's two questions for a window at once (`Window::inside` points only; the
    /// others read 0): bit i of `visible` when point i's cube is visible
    /// (`CubeMask::visible`), and the last bit of `far` when the last point's brick is at
    /// distance ≥ `leap_from` ≥ 1 (`BrickDistance::at`, [`WindowClasses::far`]). The mask's
    /// indices must fit `i32` lanes (`CubeMask::lanes_fit`).
    #[inline(always)]
    pub fn classify(self, mask: &CubeMask, window: &Window, leap_from: u8) -> WindowClasses {
        debug_assert!(leap_from >= 1 && mask.lanes_fit());
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `self` exists only on a CPU with AVX2.
        unsafe {
            kernels::classify(mask, window, leap_from)
        }
        #[cfg(not(target_arch = "x86_64"))]
        match self.0 {}
    }

    /// Appends the window's points whose bits are set in `take` to `batch`, in order (the
    /// first after `counted` samples, the rest after none): each component left-packed by one
    /// permutation. The batch must hold fewer than [`super::batch::LANES`] entries; the
    /// result is that of pushing the points one by one (`Batch::push`).
    #[inline(always)]
    pub fn append_window(self, batch: &mut Batch, window: &Window, take: u8, counted: u32) {
        let n = batch.len();
        assert!(n < super::batch::LANES, "a batch holds {} samples", super::batch::LANES);
        debug_assert!(take != 0, "an empty append would give counted_before to no sample");
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `self` exists only on a CPU with AVX2.
        unsafe {
            kernels::append_window(batch, window, take)
        }
        #[cfg(not(target_arch = "x86_64"))]
        match self.0 {}
        let added = take.count_ones() as usize;
        batch.counted_before[n..n + added].fill(0);
        batch.counted_before[n] = counted;
        batch.len = n + added;
    }

    /// `Kernel::prefetch`: asks the CPU to start loading the four record rows of the cell whose
    /// base record is `o`.
    #[inline(always)]
    pub fn prefetch(self, records: &[[i16; 4]], sy: usize, sz: usize, o: usize) {
        #[cfg(target_arch = "x86_64")]
        kernels::prefetch_rows(records, sy, sz, o);
        #[cfg(not(target_arch = "x86_64"))]
        match self.0 {}
    }

    /// `Kernel::prefetch_window`: the four record rows of each of the window's points.
    #[inline(always)]
    pub fn prefetch_window(self, records: &[[i16; 4]], sy: usize, sz: usize, window: &Window) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `self` exists only on a CPU with AVX2.
        unsafe {
            kernels::prefetch_window(records, sy, sz, window)
        }
        #[cfg(not(target_arch = "x86_64"))]
        match self.0 {}
    }

    /// `Kernel::evaluate_one_at_a_time` of a batch of cells on 16-bit `records` with strides
    /// `strides` along y and z.
    #[inline(always)]
    pub fn evaluate(
        self,
        look: &Appearance,
        records: &[[i16; 4]],
        strides: (usize, usize),
        batch: &Batch,
        half: Vec3,
        out: &mut Evaluated,
    ) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `self` exists only on a CPU with AVX2.
        unsafe {
            kernels::evaluate(look, records, strides, batch, half, out)
        }
        #[cfg(not(target_arch = "x86_64"))]
        match self.0 {}
    }
}

#[cfg(target_arch = "x86_64")]
mod kernels {
    use std::arch::x86_64::*;

    use stylet_physics::glam::Vec3;

    use super::super::appearance::Appearance;
    use super::super::batch::{Batch, CAPACITY, Evaluated, LANES};
    use super::super::cube_mask::{CubeMask, WindowClasses};
    use super::super::gradient_volume::{XY_WEIGHT_ONE, XY_WEIGHT_UNIT};
    use super::super::sampler::Grid3;
    use super::super::shading::{Exponent, MIN_GRADIENT};
    use super::super::window::{Lattice, POINTS, Window};
    use crate::transfer_table::TransferTable;

    /// `place_one_at_a_time` on eight lanes (`k` + 7 ≤ `i32::MAX`, which `Placer::place`
    /// asserts: the lattice indices are `i32` lanes).
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn place(grid: &Grid3, lattice: &Lattice, k: u32, out: &mut Window) {
        let Lattice { ce, dc, j, step } = *lattice;
        let (hi, top, last_base) = grid.locate_bounds();
        let ks = _mm256_add_epi32(_mm256_set1_epi32(k as i32), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
        // (k as f32 + j)·Δ: k < 2³¹ converts as the `u32` cast does (round to nearest).
        let t = _mm256_mul_ps(
            _mm256_add_ps(_mm256_cvtepi32_ps(ks), _mm256_set1_ps(j)),
            _mm256_set1_ps(step),
        );
        // SAFETY: 8 floats into 8.
        unsafe { _mm256_storeu_ps(out.t.as_mut_ptr(), t) };
        let mut inside = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
        for a in 0..3 {
            // c_a = ce_a + dc_a·t (glam's `Vec3` order).
            let x = _mm256_add_ps(_mm256_set1_ps(ce[a]), _mm256_mul_ps(_mm256_set1_ps(dc[a]), t));
            // −½ ≤ c_a < n_a − ½, false for NaN, as the scalar test.
            let ge = _mm256_cmp_ps::<_CMP_GE_OQ>(x, _mm256_set1_ps(-0.5));
            let lt = _mm256_cmp_ps::<_CMP_LT_OQ>(x, _mm256_set1_ps(hi[a]));
            inside = _mm256_and_ps(inside, _mm256_and_ps(ge, lt));
            // `f32::clamp(0, top)`: max/min return their second operand on ties (±0) and NaN,
            // as clamp keeps x unless x < 0 or x > top.
            let x = _mm256_min_ps(_mm256_set1_ps(top[a]), _mm256_max_ps(_mm256_setzero_ps(), x));
            // Truncation (x ≥ 0 where inside), then ≤ n_a − 2.
            let b = _mm256_min_epi32(_mm256_cvttps_epi32(x), _mm256_set1_epi32(last_base[a] as i32));
            let f = _mm256_sub_ps(x, _mm256_cvtepi32_ps(b));
            // SAFETY: 8 lanes into 8.
            unsafe {
                _mm256_storeu_si256(out.b[a].as_mut_ptr().cast(), b);
                _mm256_storeu_ps(out.f[a].as_mut_ptr(), f);
            }
        }
        out.inside = _mm256_movemask_ps(inside) as u8;
        debug_assert_eq!(POINTS, 8);
    }

    /// `CubeMask::classify` on eight lanes: each point's cube bit from the 32-bit half-word that
    /// holds it (x86-64 is little-endian: bit r of a `u64` word is bit r mod 32 of half-word
    /// 2w + r / 32; indices and bits on the lanes, the eight words by scalar loads), the last
    /// point's brick distance by one scalar load.
    /// Indices are `i32` lanes: the mask's must fit (`CubeMask::classify` checks). Each index is
    /// clamped to the mask's last half-word, so a window of points that are not the mask's cells
    /// reads wrong bits but nothing outside the mask (one instruction per window; a bounds check
    /// per lane cost the soft frame about 10 %).
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn classify(mask: &CubeMask, window: &Window, leap_from: u8) -> WindowClasses {
        // SAFETY: loads: eight lanes from eight.
        let b = [0, 1, 2].map(|a| unsafe { _mm256_loadu_si256(window.b[a].as_ptr().cast()) });
        let bit_of_lane = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let live = _mm256_cmpeq_epi32(
            _mm256_and_si256(_mm256_set1_epi32(window.inside as i32), bit_of_lane),
            bit_of_lane,
        );
        // The last point's brick, by one scalar load (`BrickDistance::at`).
        let last = POINTS - 1;
        let far_distance = if window.inside >> last & 1 == 1 {
            Some(mask.bricks.at([0, 1, 2].map(|a| window.b[a][last]))).filter(|&d| d >= leap_from)
        } else {
            None
        };
        // r = b_x + n_x·b_y; half-word 2·w_slab·b_z + r / 32, bit r mod 32.
        let r = _mm256_add_epi32(b[0], _mm256_mullo_epi32(_mm256_set1_epi32(mask.dims[0] as i32), b[1]));
        let half_word = _mm256_add_epi32(
            _mm256_mullo_epi32(_mm256_set1_epi32(2 * mask.words_per_slab as i32), b[2]),
            _mm256_srli_epi32::<5>(r),
        );
        // Eight scalar loads, not a gather: the window's points mostly share a half-word or two,
        // and the loads' answers arrive sooner (every preset 2–3 % faster than the gather).
        // Lanes that are not live read half-word 0 and are masked out below.
        let last_half_word = (2 * mask.bits.len()).checked_sub(1).expect("a cube mask holds a word");
        let clamped = _mm256_min_epu32(
            _mm256_and_si256(half_word, live),
            _mm256_set1_epi32(last_half_word as i32),
        );
        let mut at = [0u32; POINTS];
        // SAFETY: eight lanes into eight.
        unsafe { _mm256_storeu_si256(at.as_mut_ptr().cast(), clamped) };
        let half_words = mask.bits.as_ptr().cast::<u32>();
        // SAFETY: every index is at most the last half-word of `bits` (clamped above).
        let word = |i: usize| unsafe { *half_words.add(at[i] as usize) } as i32;
        let words = _mm256_setr_epi32(word(0), word(1), word(2), word(3), word(4), word(5), word(6), word(7));
        let bit = _mm256_and_si256(
            _mm256_srlv_epi32(words, _mm256_and_si256(r, _mm256_set1_epi32(31))),
            _mm256_set1_epi32(1),
        );
        let visible = _mm256_cmpeq_epi32(bit, _mm256_set1_epi32(1));
        let lanes = |v: __m256i| _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_and_si256(v, live))) as u8;
        WindowClasses {
            far: u8::from(far_distance.is_some()) << last,
            far_distance: far_distance.unwrap_or(0),
            visible: lanes(visible),
        }
    }

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

    /// The largest of eight unsigned 32-bit lanes (three max steps across the halves).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn lane_max(v: __m256i) -> u32 {
        let m = _mm_max_epu32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
        let m = _mm_max_epu32(m, _mm_shuffle_epi32::<0b01_00_11_10>(m));
        let m = _mm_max_epu32(m, _mm_shuffle_epi32::<0b10_11_00_01>(m));
        _mm_cvtsi128_si32(m) as u32
    }

    /// Asks the CPU to start loading the four record rows of the cell whose base record is `o`
    /// (rows o, o + s_y, o + s_z, o + s_y + s_z: those `interpolate` reads). A prefetch never
    /// faults, so any `o` is harmless.
    #[inline(always)]
    pub(super) fn prefetch_rows(records: &[[i16; 4]], sy: usize, sz: usize, o: usize) {
        let p = records.as_ptr().cast::<i8>();
        for i in [o, o + sy, o + sz, o + sy + sz] {
            // SAFETY: `_mm_prefetch` is a hint (SSE, part of x86-64) and reads nothing;
            // `wrapping_add` keeps the address computation defined.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(i * 8)) };
        }
    }

    /// `Kernel::prefetch_window` on the lanes: o = b_x + s_y·b_y + s_z·b_z for the eight
    /// points, then the four rows of each.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn prefetch_window(records: &[[i16; 4]], sy: usize, sz: usize, window: &Window) {
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
            prefetch_rows(records, sy, sz, o as usize);
        }
    }

    /// The window's points of `take` written from entry `batch.len` on, in order: every
    /// component (t, base voxels, fractions) permuted so the taken lanes come first, and stored
    /// whole (the lanes past them are overwritten later or never read).
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn append_window(batch: &mut Batch, window: &Window, take: u8) {
        let n = batch.len();
        assert!(n + LANES <= CAPACITY, "a batch holds {LANES} samples");
        let nibbles = _mm256_srlv_epi32(
            _mm256_set1_epi32(LEFT_PACK[take as usize] as i32),
            _mm256_setr_epi32(0, 4, 8, 12, 16, 20, 24, 28),
        );
        let lanes = _mm256_and_si256(nibbles, _mm256_set1_epi32(7));
        // SAFETY: all: eight lanes read from eight, stored at n … n + 7 < capacity (asserted).
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
    /// Every record read lies in `records`: the highest of the eight offsets is asserted to
    /// (as `GradientVolume::lerp8`'s bound: o + s_y + s_z + 1 < the records' count), once per
    /// batch, so a cell not located on them is refused.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn read_records(records: &[[i16; 4]], sy: usize, sz: usize, batch: &Batch, count: usize) -> [__m128; LANES] {
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
            let highest = lane_max(o) as usize;
            assert!(
                highest + sy + sz + 1 < records.len(),
                "{count} samples: offset {highest}"
            );
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
            let [w_near, w_far] = weights[SLOT[i]];
            let [gz, fz] = z_weights[SLOT[i]];
            // SAFETY: o ≤ the highest offset, whose farthest record was asserted to lie in
            // `records`; each load reads records i and i + 1 of a row.
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
    #[target_feature(enable = "avx2")]
    pub(super) fn evaluate(
        look: &Appearance,
        records: &[[i16; 4]],
        (sy, sz): (usize, usize),
        batch: &Batch,
        half: Vec3,
        out: &mut Evaluated,
    ) {
        let count = batch.len().min(LANES);
        // 1. Each sample's (Δx, Δy, Δz, s)·2¹⁴; unused lanes repeat sample 0.
        let r = read_records(records, sy, sz, batch, count);
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
        colours(look.table, values, count, &mut out.colour);
        // 4. ∇s = rows[0]·Δx + rows[1]·Δy + rows[2]·Δz, per component.
        let [r0, r1, r2] = look.half_rows;
        let gx = dot(splat(r0.x), splat(r1.x), splat(r2.x), dx, dy, dz);
        let gy = dot(splat(r0.y), splat(r1.y), splat(r2.y), dx, dy, dz);
        let gz = dot(splat(r0.z), splat(r1.z), splat(r2.z), dx, dy, dz);
        // 5. |∇s|, and N = ∇s·(−1/|∇s|) (`PhongTerms::lit`).
        let len = _mm256_sqrt_ps(dot(gx, gy, gz, gx, gy, gz));
        let unshaded = _mm256_cmp_ps::<_CMP_LT_OQ>(len, splat(MIN_GRADIENT));
        let inv = _mm256_div_ps(splat(-1.0), len);
        let (nx, ny, nz) = (_mm256_mul_ps(gx, inv), _mm256_mul_ps(gy, inv), _mm256_mul_ps(gz, inv));
        let p = look.phong;
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
    use crate::raycast::batch::LANES;
    use crate::raycast::cell::Cell;

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_lanes_raise_to_every_whole_power_as_one_sample_does() {
        use std::arch::x86_64::*;
        if !available_for_lane_tests() {
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
                #[target_feature(enable = "avx2")]
                fn run(x: &[f32; LANES], e: u32, out: &mut [f32; LANES]) {
                    // SAFETY: 8 floats from and into 8.
                    unsafe {
                        let r = kernels::power_whole(_mm256_loadu_ps(x.as_ptr()), e);
                        _mm256_storeu_ps(out.as_mut_ptr(), r);
                    }
                }
                // SAFETY: AVX2 was detected above.
                unsafe { run(&lanes, e, &mut out) };
                for (x, got) in lanes.iter().zip(out) {
                    let want = super::super::shading::power_whole(*x, e);
                    assert_eq!(got.to_bits(), want.to_bits(), "{x}^{e}: lanes {got}, one sample {want}");
                }
            }
        }
    }

    #[test]
    fn a_cell_outside_the_records_is_refused() {
        let (true, Some(avx2)) = (available_for_lane_tests(), Avx2::detect(Lanes::Auto)) else {
            return;
        };
        use crate::raycast::gradient_volume::{GradientVolume, RecordSlice};
        use crate::raycast::sampler::Cell;
        use crate::raycast::shading::PhongTerms;
        use crate::transfer::TransferFunction;
        use crate::transfer_table::TransferTable;
        let data = vec![0.0f32; 4 * 4 * 4];
        let grads = GradientVolume::new(&data, [4, 4, 4]);
        let RecordSlice::Int16(records) = grads.records() else {
            panic!("the records of a small CT are 16-bit")
        };
        let table = TransferTable::new(&TransferFunction::Trapezoids(vec![]), -1024.0, 1200.0, 1.0);
        let phong = PhongTerms::new(&crate::scene::Light {
            toward_light: stylet_physics::glam::Vec3::Z,
            ambient: 0.25,
            diffuse: 0.6,
            specular: 0.0,
            shininess: 1.0,
            shadow_in: 0.3,
        });
        let look = Appearance {
            table: &table,
            phong: &phong,
            half_rows: [Vec3::X; 3],
        };
        let mut batch = Batch::default();
        // Base voxel (3, 3, 3): its cell would read records past the last.
        batch.push(
            Cell {
                b: [3, 3, 3],
                f: [0.5; 3],
            },
            0.0,
            0,
        );
        let refused = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let mut out = Evaluated::default();
            avx2.evaluate(&look, records, grads.strides(), &batch, Vec3::Z, &mut out)
        }));
        let message = *refused
            .expect_err("a read past the records must be refused")
            .downcast::<String>()
            .expect("an assertion's message");
        assert!(message.contains("offset"), "{message}");
    }

    #[test]
    fn a_window_appended_on_the_lanes_is_its_points_pushed_in_order() {
        let (true, Some(avx2)) = (available_for_lane_tests(), Avx2::detect(Lanes::Auto)) else {
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
                avx2.append_window(&mut lanes, &window, take, 3);
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
