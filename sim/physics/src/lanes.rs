//! Four `f64` lanes for batches of four nodes (contact nodes, their gathers): the operations
//! the batched physics needs, each IEEE-exact per lane, so a lane gives the bits a scalar
//! computation of the same operations in the same order gives.
//!
//! Written once over [`Lane`]: AVX registers where the CPU has AVX2 (callers choose at run time
//! with [`has_avx2`] and compile their batch inside a `#[target_feature(enable = "avx2")]`
//! function), plain arrays elsewhere. No operation is fused (no FMA). Code generic over `Lane`
//! calls its operations from `#[inline(always)]` functions and loops, never from closures: a
//! closure is compiled without the AVX feature, and an AVX operation in it would be a call.

use std::ops::{Add, Div, Mul, Neg, Sub};

use glam::DVec3;

/// Lanes per batch.
pub(crate) const LANES: usize = 4;

/// Whether this CPU has AVX2 (the check is cached by the standard library).
#[inline]
pub(crate) fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Four `f64`, one per node, with the operations the law needs (each IEEE-exact per lane).
pub(crate) trait Lane:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> + Neg<Output = Self>
{
    /// One condition per lane.
    type Mask: Copy;
    fn load(v: [f64; LANES]) -> Self;
    fn store(self) -> [f64; LANES];
    #[inline(always)]
    fn splat(v: f64) -> Self {
        Self::load([v; LANES])
    }
    fn mask(m: [bool; LANES]) -> Self::Mask;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    /// self > o (false where either is NaN, as Rust's `>`).
    fn gt(self, o: Self) -> Self::Mask;
    /// Lanes where the value is finite and > 0 (glam's test for a usable reciprocal length).
    fn finite_positive(self) -> Self::Mask;
    /// `a` where `m`, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    /// Rounded to `f32` and back (Rust's `as f32 as f64`: to nearest, ties to even).
    fn round_f32(self) -> Self;
    /// Four consecutive `f32` per lane, widened (exact) and transposed: result `i` holds every
    /// lane's element `i` (the gathers read a row of four voxels along x per node at once).
    #[inline(always)]
    fn runs4(r: [&[f32; 4]; LANES]) -> [Self; 4] {
        std::array::from_fn(|i| Self::load([r[0][i] as f64, r[1][i] as f64, r[2][i] as f64, r[3][i] as f64]))
    }
    /// [`Self::runs4`] for two consecutive `f32` per lane.
    #[inline(always)]
    fn runs2(r: [&[f32; 2]; LANES]) -> [Self; 2] {
        std::array::from_fn(|i| Self::load([r[0][i] as f64, r[1][i] as f64, r[2][i] as f64, r[3][i] as f64]))
    }
}

/// The portable lanes: plain arrays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct F4([f64; LANES]);

macro_rules! lanewise {
    ($ty:ident, $trait:ident, $method:ident, $op:tt) => {
        impl $trait for $ty {
            type Output = $ty;
            #[inline(always)]
            fn $method(self, o: $ty) -> $ty {
                let (a, b) = (self.0, o.0);
                $ty([a[0] $op b[0], a[1] $op b[1], a[2] $op b[2], a[3] $op b[3]])
            }
        }
    };
}
lanewise!(F4, Add, add, +);
lanewise!(F4, Sub, sub, -);
lanewise!(F4, Mul, mul, *);
lanewise!(F4, Div, div, /);

impl Neg for F4 {
    type Output = F4;
    #[inline(always)]
    fn neg(self) -> F4 {
        F4(self.0.map(|a| -a))
    }
}

impl Lane for F4 {
    type Mask = [bool; LANES];
    #[inline(always)]
    fn load(v: [f64; LANES]) -> Self {
        F4(v)
    }

    #[inline(always)]
    fn store(self) -> [f64; LANES] {
        self.0
    }
    #[inline(always)]
    fn mask(m: [bool; LANES]) -> Self::Mask {
        m
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        F4(self.0.map(f64::sqrt))
    }
    #[inline(always)]
    fn abs(self) -> Self {
        F4(self.0.map(f64::abs))
    }
    #[inline(always)]
    fn gt(self, o: Self) -> Self::Mask {
        let (a, b) = (self.0, o.0);
        [a[0] > b[0], a[1] > b[1], a[2] > b[2], a[3] > b[3]]
    }
    #[inline(always)]
    fn finite_positive(self) -> Self::Mask {
        self.0.map(|a| a.is_finite() && a > 0.0)
    }
    #[inline(always)]
    fn select(m: Self::Mask, a: Self, b: Self) -> Self {
        F4(std::array::from_fn(|i| if m[i] { a.0[i] } else { b.0[i] }))
    }
    #[inline(always)]
    fn round_f32(self) -> Self {
        F4(self.0.map(|a| a as f32 as f64))
    }
}

/// The AVX lanes: one 256-bit register.
///
/// Only code inside a `#[target_feature(enable = "avx2")]` function, called after [`has_avx2`],
/// may make values of this type; the operations are `#[inline(always)]` so that they compile
/// inside that function, where the AVX instructions are enabled.
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx {
    use super::{LANES, Lane};
    use std::arch::x86_64::*;
    use std::ops::{Add, Div, Mul, Neg, Sub};

    #[derive(Clone, Copy)]
    pub(crate) struct Avx(__m256d);

    macro_rules! op {
        ($trait:ident, $method:ident, $intrinsic:ident) => {
            impl $trait for Avx {
                type Output = Avx;
                #[inline(always)]
                fn $method(self, o: Avx) -> Avx {
                    // SAFETY: see the type's doc (AVX is present where this runs).
                    Avx(unsafe { $intrinsic(self.0, o.0) })
                }
            }
        };
    }
    op!(Add, add, _mm256_add_pd);
    op!(Sub, sub, _mm256_sub_pd);
    op!(Mul, mul, _mm256_mul_pd);
    op!(Div, div, _mm256_div_pd);

    impl Neg for Avx {
        type Output = Avx;
        #[inline(always)]
        fn neg(self) -> Avx {
            // Flips the sign bit, as Rust's unary minus.
            // SAFETY: see the type's doc.
            Avx(unsafe { _mm256_xor_pd(self.0, _mm256_set1_pd(-0.0)) })
        }
    }

    impl Lane for Avx {
        type Mask = __m256d;
        #[inline(always)]
        fn load(v: [f64; LANES]) -> Self {
            // SAFETY: see the type's doc; the load reads the four values of `v`.
            Avx(unsafe { _mm256_loadu_pd(v.as_ptr()) })
        }
        #[inline(always)]
        fn store(self) -> [f64; LANES] {
            let mut v = [0.0; LANES];
            // SAFETY: see the type's doc; the store writes the four values of `v`.
            unsafe { _mm256_storeu_pd(v.as_mut_ptr(), self.0) };
            v
        }
        #[inline(always)]
        fn mask(m: [bool; LANES]) -> Self::Mask {
            let on = |b: bool| if b { f64::from_bits(u64::MAX) } else { 0.0 };
            // SAFETY: see the type's doc.
            unsafe { _mm256_setr_pd(on(m[0]), on(m[1]), on(m[2]), on(m[3])) }
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            // SAFETY: see the type's doc.
            Avx(unsafe { _mm256_sqrt_pd(self.0) })
        }
        #[inline(always)]
        fn abs(self) -> Self {
            // Clears the sign bit, as f64::abs.
            // SAFETY: see the type's doc.
            Avx(unsafe { _mm256_andnot_pd(_mm256_set1_pd(-0.0), self.0) })
        }
        #[inline(always)]
        fn gt(self, o: Self) -> Self::Mask {
            // Ordered, quiet: false where either is NaN.
            // SAFETY: see the type's doc.
            unsafe { _mm256_cmp_pd::<_CMP_GT_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn finite_positive(self) -> Self::Mask {
            // 0 < v < +∞ (false for NaN): finite and positive.
            // SAFETY: see the type's doc.
            unsafe {
                _mm256_and_pd(
                    _mm256_cmp_pd::<_CMP_GT_OQ>(self.0, _mm256_setzero_pd()),
                    _mm256_cmp_pd::<_CMP_LT_OQ>(self.0, _mm256_set1_pd(f64::INFINITY)),
                )
            }
        }
        #[inline(always)]
        fn select(m: Self::Mask, a: Self, b: Self) -> Self {
            // SAFETY: see the type's doc.
            Avx(unsafe { _mm256_blendv_pd(b.0, a.0, m) })
        }
        #[inline(always)]
        fn round_f32(self) -> Self {
            // The conversion rounds by MXCSR's mode, to nearest (ties to even) as Rust assumes.
            // SAFETY: see the type's doc.
            Avx(unsafe { _mm256_cvtps_pd(_mm256_cvtpd_ps(self.0)) })
        }
        #[inline(always)]
        fn runs4(r: [&[f32; 4]; LANES]) -> [Self; 4] {
            // One 128-bit load per lane, a 4 × 4 transpose (_MM_TRANSPOSE4_PS), then the exact
            // widening of each column: 4 loads and 8 shuffles instead of 16 loads and 12 inserts.
            // SAFETY: see the type's doc; each load reads the four values of one `&[f32; 4]`.
            unsafe {
                let (a, b) = (_mm_loadu_ps(r[0].as_ptr()), _mm_loadu_ps(r[1].as_ptr()));
                let (c, d) = (_mm_loadu_ps(r[2].as_ptr()), _mm_loadu_ps(r[3].as_ptr()));
                let (ab_lo, cd_lo) = (_mm_unpacklo_ps(a, b), _mm_unpacklo_ps(c, d));
                let (ab_hi, cd_hi) = (_mm_unpackhi_ps(a, b), _mm_unpackhi_ps(c, d));
                [
                    Avx(_mm256_cvtps_pd(_mm_movelh_ps(ab_lo, cd_lo))),
                    Avx(_mm256_cvtps_pd(_mm_movehl_ps(cd_lo, ab_lo))),
                    Avx(_mm256_cvtps_pd(_mm_movelh_ps(ab_hi, cd_hi))),
                    Avx(_mm256_cvtps_pd(_mm_movehl_ps(cd_hi, ab_hi))),
                ]
            }
        }
        #[inline(always)]
        fn runs2(r: [&[f32; 2]; LANES]) -> [Self; 2] {
            // One 64-bit load per lane, pairs of lanes side by side, then the even and odd
            // elements picked out and widened.
            // SAFETY: see the type's doc; each load reads the two values of one `&[f32; 2]`
            // (`_mm_loadu_si64` has no alignment requirement).
            unsafe {
                let (a, b) = (
                    _mm_loadu_si64(r[0].as_ptr().cast()),
                    _mm_loadu_si64(r[1].as_ptr().cast()),
                );
                let (c, d) = (
                    _mm_loadu_si64(r[2].as_ptr().cast()),
                    _mm_loadu_si64(r[3].as_ptr().cast()),
                );
                let ab = _mm_movelh_ps(_mm_castsi128_ps(a), _mm_castsi128_ps(b));
                let cd = _mm_movelh_ps(_mm_castsi128_ps(c), _mm_castsi128_ps(d));
                [
                    Avx(_mm256_cvtps_pd(_mm_shuffle_ps::<0b10_00_10_00>(ab, cd))),
                    Avx(_mm256_cvtps_pd(_mm_shuffle_ps::<0b11_01_11_01>(ab, cd))),
                ]
            }
        }
    }
}

/// A vector per lane.
#[derive(Clone, Copy)]
pub(crate) struct V4<L> {
    pub x: L,
    pub y: L,
    pub z: L,
}

impl<L: Lane> V4<L> {
    #[inline(always)]
    pub(crate) fn load(v: &Vec4s) -> Self {
        V4 {
            x: L::load(v.x),
            y: L::load(v.y),
            z: L::load(v.z),
        }
    }
    #[inline(always)]
    pub(crate) fn store(self) -> Vec4s {
        Vec4s {
            x: self.x.store(),
            y: self.y.store(),
            z: self.z.store(),
        }
    }
    #[inline(always)]
    pub(crate) fn add(self, o: Self) -> Self {
        V4 {
            x: self.x + o.x,
            y: self.y + o.y,
            z: self.z + o.z,
        }
    }
    #[inline(always)]
    pub(crate) fn sub(self, o: Self) -> Self {
        V4 {
            x: self.x - o.x,
            y: self.y - o.y,
            z: self.z - o.z,
        }
    }
    #[inline(always)]
    pub(crate) fn neg(self) -> Self {
        V4 {
            x: -self.x,
            y: -self.y,
            z: -self.z,
        }
    }
    /// s·v, as glam's `f64 * DVec3` and `DVec3 * f64` (one product per component, and IEEE
    /// products commute).
    #[inline(always)]
    pub(crate) fn scaled(self, s: L) -> Self {
        V4 {
            x: s * self.x,
            y: s * self.y,
            z: s * self.z,
        }
    }
    /// v/s, as glam's `DVec3 / f64`.
    #[inline(always)]
    pub(crate) fn divided(self, s: L) -> Self {
        V4 {
            x: self.x / s,
            y: self.y / s,
            z: self.z / s,
        }
    }
    /// (x·x′ + y·y′) + z·z′, glam's order.
    #[inline(always)]
    pub(crate) fn dot(self, o: Self) -> L {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    #[inline(always)]
    pub(crate) fn length(self) -> L {
        self.dot(self).sqrt()
    }
    /// glam's `normalize_or_zero`: v·(1/‖v‖) where that reciprocal is finite and > 0, else 0.
    #[inline(always)]
    pub(crate) fn normalize_or_zero(self) -> Self {
        let zero = L::splat(0.0);
        self.normalize_or(V4 {
            x: zero,
            y: zero,
            z: zero,
        })
    }
    /// glam's `normalize_or`: v·(1/‖v‖) where that reciprocal is finite and > 0, else
    /// `fallback`.
    #[inline(always)]
    pub(crate) fn normalize_or(self, fallback: Self) -> Self {
        let rcp = L::splat(1.0) / self.length();
        let ok = rcp.finite_positive();
        V4 {
            x: L::select(ok, self.x * rcp, fallback.x),
            y: L::select(ok, self.y * rcp, fallback.y),
            z: L::select(ok, self.z * rcp, fallback.z),
        }
    }
    #[inline(always)]
    pub(crate) fn select(m: L::Mask, a: Self, b: Self) -> Self {
        V4 {
            x: L::select(m, a.x, b.x),
            y: L::select(m, a.y, b.y),
            z: L::select(m, a.z, b.z),
        }
    }
}

/// Four vectors, one per lane, as arrays of their components (what batches are built from).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Vec4s {
    pub x: [f64; LANES],
    pub y: [f64; LANES],
    pub z: [f64; LANES],
}

impl Vec4s {
    /// Lane i holding `v[i]` (built without zeroing first).
    #[inline(always)]
    pub(crate) fn from_lanes(v: [DVec3; LANES]) -> Self {
        Vec4s {
            x: v.map(|p| p.x),
            y: v.map(|p| p.y),
            z: v.map(|p| p.z),
        }
    }
    /// Lane `i` set to `v`.
    #[inline(always)]
    pub(crate) fn set(&mut self, i: usize, v: DVec3) {
        self.x[i] = v.x;
        self.y[i] = v.y;
        self.z[i] = v.z;
    }
    #[inline(always)]
    pub(crate) fn get(&self, i: usize) -> DVec3 {
        DVec3::new(self.x[i], self.y[i], self.z[i])
    }
}
