//! The CT with its gradient beside every voxel (docs/rendering.md "Sampling", "Gradient"): the
//! record of voxel i is (I(i + e_x) − I(i − e_x), I(i + e_y) − I(i − e_y), I(i + e_z) − I(i − e_z),
//! I(i)), neighbours outside the grid reading air. A lattice sample reads its
//! eight records once and interpolates all four components together, so the value and the
//! central-difference gradient of thesis eq. 3.2.3 cost one trilinear read instead of seven
//! (Levoy's precomputed gradients, as VTK's ray casters use).
//!
//! Records are four 16-bit integers when the CT holds only integers and every difference fits
//! (real CT: 8 bytes a voxel), else four `f32` (16 bytes). 16-bit records are blended within a
//! slice in fixed point ([`XY_WEIGHT_ONE`]: an exact integer, which the SIMD lanes compute with
//! one multiply-add per two rows before any conversion) and along z in `f32`; `f32` records in
//! `f32` throughout, bit-identical to `sampler::Grid3::interpolate`.

use rayon::prelude::*;
use stylet_physics::atlas::AIR_HU;
use stylet_physics::glam::Vec4;

use super::cell::Cell;

/// The records, x fastest.
#[derive(Debug, Clone, PartialEq)]
enum Records {
    Int16(Vec<[i16; 4]>),
    Float32(Vec<[f32; 4]>),
}

/// The records as stored, for uploading them unchanged (the GPU ray caster reads the same ones).
#[derive(Debug, Clone, Copy)]
pub enum RecordSlice<'a> {
    Int16(&'a [[i16; 4]]),
    Float32(&'a [[f32; 4]]),
}

/// 2⁷: the fixed-point unit of the weights along x and y of 16-bit records. A located
/// fraction f becomes q = round(f·2⁷) ([`xy_fraction`]) and the pair (2⁷ − q, q); a corner's
/// weight w_x·w_y ≤ 2¹⁴ fits the lanes' signed 16-bit multiplier, and a slice's blend of four
/// records, ≤ 2¹⁵·2¹⁴ in size, is an exact `i32`. A sample moves by at most 1/256 voxel across
/// the slice (0.003 mm on the chest CT; a GPU's texture filter: 1/512); along z, the axis a CT
/// spaces widest, the blend stays `f32`.
pub const XY_WEIGHT_ONE: i32 = 1 << 7;

/// 2⁻¹⁴: scales a blend of [`XY_WEIGHT_ONE`]²-weighted records back to HU (exact: a power of
/// two).
pub const XY_WEIGHT_UNIT: f32 = 1.0 / (XY_WEIGHT_ONE * XY_WEIGHT_ONE) as f32;

/// The fixed-point fraction along x or y: round(f·2⁷), ties to even (the product is exact).
/// f ∈ [0, 1] gives 0 … 2⁷. On x86-64 one `cvtss2si` (SSE2), which rounds to nearest-even in
/// the default rounding mode as the lanes' `_mm256_cvtps_epi32` does; `round_ties_even` there is
/// a libm call (`rintf`) that took 4 % of a frame on the general path.
#[inline(always)]
pub fn xy_fraction(f: f32) -> i32 {
    let x = f * XY_WEIGHT_ONE as f32;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_cvtss_si32, _mm_set_ss};
        // SAFETY: SSE2 is part of x86-64.
        unsafe { _mm_cvtss_si32(_mm_set_ss(x)) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        x.round_ties_even() as i32
    }
}

/// Value and index-space central differences of every CT voxel.
#[derive(Debug, Clone, PartialEq)]
pub struct GradientVolume {
    dims: [u32; 3],
    records: Records,
    sy: usize,
    sz: usize,
    /// Every axis has ≥ 2 voxels: [`Self::interpolate`] applies (the ray loop's fast path).
    fast: bool,
}

/// Voxel `(i, j, k)` of `data` shifted by `d` along `axis`, air outside the grid.
#[inline(always)]
fn neighbour(data: &[f32], dims: [usize; 3], ijk: [usize; 3], axis: usize, d: isize) -> f32 {
    let mut p = ijk;
    let q = p[axis] as isize + d;
    if q < 0 || q >= dims[axis] as isize {
        return AIR_HU;
    }
    p[axis] = q as usize;
    data[p[0] + dims[0] * (p[1] + dims[1] * p[2])]
}

/// The record of voxel `ijk`: (Δx, Δy, Δz, I) with Δa = I(i + e_a) − I(i − e_a), air outside.
#[inline]
pub fn record(data: &[f32], dims: [usize; 3], ijk: [usize; 3]) -> [f32; 4] {
    let v = data[ijk[0] + dims[0] * (ijk[1] + dims[1] * ijk[2])];
    let d = |a: usize| neighbour(data, dims, ijk, a, 1) - neighbour(data, dims, ijk, a, -1);
    [d(0), d(1), d(2), v]
}

impl GradientVolume {
    /// The records of a CT (`data`, x fastest, `dims` voxels); rayon over z-slices.
    pub fn new(data: &[f32], dims: [u32; 3]) -> GradientVolume {
        let d = dims.map(|n| n as usize);
        let slab = d[0] * d[1];
        let len = slab * d[2];
        assert!(data.len() >= len, "{} values for {dims:?} voxels", data.len());
        let data = &data[..len];
        // Every difference lies within max − min of the values and air.
        let integral = data.iter().all(|&v| v.fract() == 0.0);
        let (lo, hi) = data
            .iter()
            .fold((AIR_HU, AIR_HU), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        let int16 = integral && lo >= i16::MIN as f32 && hi <= i16::MAX as f32 && hi - lo <= i16::MAX as f32;
        let fill = |k: usize, out: &mut dyn FnMut(usize, [f32; 4])| {
            for j in 0..d[1] {
                for i in 0..d[0] {
                    out(i + d[0] * j, record(data, d, [i, j, k]));
                }
            }
        };
        let records = if int16 {
            let mut r = vec![[0i16; 4]; len];
            crate::huge_pages::advise(&mut r);
            r.par_chunks_mut(slab.max(1)).enumerate().for_each(|(k, s)| {
                fill(k, &mut |o, v| s[o] = v.map(|x| x as i16));
            });
            Records::Int16(r)
        } else {
            let mut r = vec![[0f32; 4]; len];
            crate::huge_pages::advise(&mut r);
            r.par_chunks_mut(slab.max(1)).enumerate().for_each(|(k, s)| {
                fill(k, &mut |o, v| s[o] = v);
            });
            Records::Float32(r)
        };
        GradientVolume {
            dims,
            records,
            sy: d[0],
            sz: slab,
            fast: dims.iter().all(|&n| n >= 2),
        }
    }

    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Whether the records are 16-bit integers (8 bytes a voxel) rather than `f32` (16).
    pub fn is_int16(&self) -> bool {
        matches!(self.records, Records::Int16(_))
    }

    /// The records, x fastest.
    pub fn records(&self) -> RecordSlice<'_> {
        match &self.records {
            Records::Int16(r) => RecordSlice::Int16(r),
            Records::Float32(r) => RecordSlice::Float32(r),
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        match &self.records {
            Records::Int16(r) => r.len() * 8,
            Records::Float32(r) => r.len() * 16,
        }
    }

    /// The records' strides along y and z.
    pub fn strides(&self) -> (usize, usize) {
        (self.sy, self.sz)
    }

    /// Whether every axis has ≥ 2 voxels ([`Self::interpolate`] applies).
    pub fn is_fast(&self) -> bool {
        self.fast
    }

    /// The record of voxel (`i`, `j`, `k`) as `f32` (tests, and one-voxel axes).
    pub fn get(&self, i: u32, j: u32, k: u32) -> Vec4 {
        let o = i as usize + self.sy * j as usize + self.sz * k as usize;
        match &self.records {
            Records::Int16(r) => widen(&r[o]),
            Records::Float32(r) => Vec4::from_array(r[o]),
        }
    }

    /// (Δx, Δy, Δz, s) trilinearly interpolated at a located read (`Grid3::locate` on a grid of
    /// the same dimensions): in fixed point for 16-bit records (`Self::fixed_point`), else
    /// `Grid3::interpolate`'s order on all four lanes.
    #[inline(always)]
    pub fn interpolate(&self, cell: &Cell) -> Vec4 {
        match &self.records {
            Records::Int16(r) => self.fixed_point(r, cell),
            Records::Float32(r) => self.lerp8(cell, |o| {
                debug_assert!(o < r.len());
                // SAFETY: see `lerp8`.
                Vec4::from_array(unsafe { *r.get_unchecked(o) })
            }),
        }
    }

    /// The trilinear blend of the eight 16-bit records around `cell`: within each of the two
    /// slices (z and z + 1) in fixed point, c = Σ record·w_x·w_y over the slice's four records
    /// ([`XY_WEIGHT_ONE`]), an exact `i32` converted to `f32`; then c₀·(1 − f_z) + c₁·f_z in
    /// `f32`; then times 2⁻¹⁴. The SIMD lanes compute the same (a slice's blend is one
    /// `vpmaddwd` per two rows and an add).
    #[inline(always)]
    fn fixed_point(&self, records: &[[i16; 4]], cell: &Cell) -> Vec4 {
        debug_assert!(self.fast && (0..3).all(|a| cell.b[a] + 1 < self.dims[a]));
        let [bx, by, bz] = cell.b;
        let o = bx as usize + self.sy * by as usize + self.sz * bz as usize;
        debug_assert!(o + self.sy + self.sz + 1 < records.len());
        let (qx, qy) = (xy_fraction(cell.f[0]), xy_fraction(cell.f[1]));
        let weights = ([XY_WEIGHT_ONE - qx, qx], [XY_WEIGHT_ONE - qy, qy]);
        let fz = cell.f[2];
        let (c0, c1) = (
            self.slice_sums(records, o, weights),
            self.slice_sums(records, o + self.sz, weights),
        );
        (c0 * (1.0 - fz) + c1 * fz) * XY_WEIGHT_UNIT
    }

    /// Σ record·w_x·w_y over the four records of the slice whose first is `o` (records o, o + 1,
    /// o + s_y, o + s_y + 1), exact in `i32`, converted to `f32`.
    #[inline(always)]
    fn slice_sums(&self, records: &[[i16; 4]], o: usize, (wx, wy): ([i32; 2], [i32; 2])) -> Vec4 {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_mm_add_epi32, _mm_cvtepi32_ps, _mm_loadl_epi64, _mm_madd_epi16};
            use std::arch::x86_64::{_mm_set1_epi32, _mm_unpacklo_epi16};
            // SSE2 (part of x86-64): a row's two records interleaved channel by channel
            // (a₀ b₀ a₁ b₁ …) and weighted by (w_x,0·w_y, w_x,1·w_y) in one multiply-add: the
            // same exact integers as the loop below.
            let row = |at: usize, wy: i32| {
                let pair = (wx[0] * wy) | ((wx[1] * wy) << 16);
                // SAFETY: records at and at + 1 are in bounds (the caller's cell: as `lerp8`'s,
                // the largest index read is o + 1 + s_y + s_z).
                unsafe {
                    let a = _mm_loadl_epi64(records.as_ptr().add(at).cast());
                    let b = _mm_loadl_epi64(records.as_ptr().add(at + 1).cast());
                    _mm_madd_epi16(_mm_unpacklo_epi16(a, b), _mm_set1_epi32(pair))
                }
            };
            // SAFETY: SSE2 is part of x86-64.
            Vec4::from(unsafe { _mm_cvtepi32_ps(_mm_add_epi32(row(o, wy[0]), row(o + self.sy, wy[1]))) })
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.slice_sums_portable(records, o, (wx, wy))
    }

    /// [`Self::slice_sums`] without SIMD (other architectures; tested against it on x86-64).
    #[cfg_attr(target_arch = "x86_64", allow(dead_code))]
    fn slice_sums_portable(&self, records: &[[i16; 4]], o: usize, (wx, wy): ([i32; 2], [i32; 2])) -> Vec4 {
        let mut sum = [0i32; 4];
        for (j, wy) in wy.into_iter().enumerate() {
            for (i, wx) in wx.into_iter().enumerate() {
                for (s, &v) in sum.iter_mut().zip(&records[o + i + self.sy * j]) {
                    *s += i32::from(v) * (wx * wy);
                }
            }
        }
        Vec4::from_array(sum.map(|s| s as f32))
    }

    /// The trilinear blend of the eight records around `cell` read by `at`.
    ///
    /// Callers pass cells from `Grid3::locate` on these dimensions with every axis ≥ 2 voxels
    /// (`fast`), which keeps b_a ≤ n_a − 2: the largest index read, o + 1 + sy + sz, is at most
    /// nx·ny·nz − 1 < the records' length.
    #[inline(always)]
    fn lerp8(&self, cell: &Cell, at: impl Fn(usize) -> Vec4) -> Vec4 {
        debug_assert!(self.fast && (0..3).all(|a| cell.b[a] + 1 < self.dims[a]));
        let [bx, by, bz] = cell.b;
        let [fx, fy, fz] = cell.f;
        let (sy, sz) = (self.sy, self.sz);
        let o = bx as usize + sy * by as usize + sz * bz as usize;
        let (gx, gy, gz) = (1.0 - fx, 1.0 - fy, 1.0 - fz);
        let c00 = at(o) * gx + at(o + 1) * fx;
        let c10 = at(o + sy) * gx + at(o + sy + 1) * fx;
        let c01 = at(o + sz) * gx + at(o + sz + 1) * fx;
        let c11 = at(o + sz + sy) * gx + at(o + sz + sy + 1) * fx;
        let c0 = c00 * gy + c10 * fy;
        let c1 = c01 * gy + c11 * fy;
        c0 * gz + c1 * fz
    }
}

/// Four 16-bit integers as `f32` (exact).
#[inline(always)]
fn widen(r: &[i16; 4]) -> Vec4 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_cvtepi32_ps, _mm_loadl_epi64, _mm_srai_epi32, _mm_unpacklo_epi16};
        // SAFETY: SSE2 is part of x86-64; the load reads the 8 bytes of `r` (no alignment needed).
        unsafe {
            let x = _mm_loadl_epi64(r.as_ptr().cast());
            Vec4::from(_mm_cvtepi32_ps(_mm_srai_epi32(_mm_unpacklo_epi16(x, x), 16)))
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Vec4::new(r[0] as f32, r[1] as f32, r[2] as f32, r[3] as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::super::sampler::{Edge, Grid3};
    use super::*;
    use stylet_physics::glam::Vec3;

    fn ct(dims: [usize; 3], f: impl Fn(usize, usize, usize) -> f32) -> Vec<f32> {
        let mut v = Vec::with_capacity(dims.iter().product());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    v.push(f(i, j, k));
                }
            }
        }
        v
    }

    #[test]
    fn records_hold_the_value_and_central_differences_with_air_outside() {
        let dims = [4, 3, 2];
        let data = ct(dims, |i, j, k| (i * 10 + j * 100 + k * 1000) as f32);
        let g = GradientVolume::new(&data, [4, 3, 2]);
        assert!(g.is_int16());
        // Interior along x: I(2) − I(0) = 20; y at j = 1: 200; z at k = 0: I(1) − air.
        assert_eq!(g.get(1, 1, 0), Vec4::new(20.0, 200.0, 1110.0 + 1000.0, 110.0));
        // x at i = 0: I(1) − air; y at j = 2: air − I(1); z at k = 1: air − I(0).
        assert_eq!(
            g.get(0, 2, 1),
            Vec4::new(1210.0 + 1000.0, -1000.0 - 1100.0, -1000.0 - 200.0, 1200.0)
        );
    }

    /// Points spread over the 7 × 6 × 5 test grids, some past its edges.
    fn points() -> impl Iterator<Item = Vec3> {
        (0..500).map(|n| {
            let f = n as f32;
            Vec3::new(
                (f * 0.37).sin() * 3.6 + 3.0,
                (f * 0.11).cos() * 3.1 + 2.5,
                (f * 0.23).sin() * 2.6 + 2.0,
            )
        })
    }

    #[test]
    fn fixed_point_fractions_round_to_nearest_even() {
        for n in 0..=(128 * 64) {
            // Every 1/64 of a weight step, ties (n odd multiples of 32) included.
            let f = n as f32 / (128.0 * 64.0);
            assert_eq!(xy_fraction(f), (f * 128.0).round_ties_even() as i32, "f = {f}");
        }
        assert_eq!([xy_fraction(0.5 / 128.0), xy_fraction(1.5 / 128.0)], [0, 2]);
    }

    #[test]
    fn sixteen_bit_records_blend_each_slice_in_fixed_point() {
        let dims = [7usize, 6, 5];
        let data = ct(dims, |i, j, k| ((i * 37 + j * 11 + k * 5) % 23) as f32 * 10.0 - 100.0);
        let d = dims.map(|n| n as u32);
        let g = GradientVolume::new(&data, d);
        assert!(g.is_int16());
        let grid = Grid3::new(&data, d);
        let mut checked = 0;
        for c in points() {
            let Some(cell) = grid.locate(c) else { continue };
            let r = g.interpolate(&cell);
            let [bx, by, bz] = cell.b.map(|b| b as usize);
            let [fx, fy, fz] = cell.f;
            // In f64, with the fractions across the slice moved to the nearest 1/128.
            let q = |f: f32| (f64::from(f) * 128.0).round_ties_even() / 128.0;
            let (qx, qy, fz) = (q(fx), q(fy), f64::from(fz));
            for lane in 0..4 {
                let v = |i, j, k| f64::from(record(&data, dims, [bx + i, by + j, bz + k])[lane]);
                let slice = |k| {
                    (v(0, 0, k) * (1.0 - qx) + v(1, 0, k) * qx) * (1.0 - qy)
                        + (v(0, 1, k) * (1.0 - qx) + v(1, 1, k) * qx) * qy
                };
                let want = slice(0) * (1.0 - fz) + slice(1) * fz;
                let got = f64::from(r[lane]);
                // f32 rounding of the slices' blends and of the blend along z, relative to the
                // largest record blended.
                let mut largest = 1.0f64;
                for (i, j, k) in (0..8).map(|n| (n & 1, (n >> 1) & 1, n >> 2)) {
                    largest = largest.max(v(i, j, k).abs());
                }
                assert!(
                    (got - want).abs() <= 1e-6 * largest,
                    "lane {lane} at {c}: {got} vs {want}"
                );
                // Within what 1/256 voxel across the slice can change from the f32 trilinear.
                let steep = |step: [usize; 2]| {
                    let mut most = 0.0f64;
                    for (j, k) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (a, b) = if step[0] == 1 {
                            ((0, j, k), (1, j, k))
                        } else {
                            ((j, 0, k), (j, 1, k))
                        };
                        most = most.max((v(b.0, b.1, b.2) - v(a.0, a.1, a.2)).abs());
                    }
                    most
                };
                let float = if lane == 3 {
                    f64::from(grid.interpolate(&cell))
                } else {
                    f64::from(grid.differences(c, Edge::Air).unwrap()[lane])
                };
                let bound = (steep([1, 0]) + steep([0, 1])) / 256.0 + 1e-3;
                assert!(
                    (got - float).abs() <= bound,
                    "lane {lane} at {c}: {got} vs {float} (±{bound})"
                );
            }
            checked += 1;
        }
        assert!(checked > 250, "{checked} points inside");
        // The SIMD slice sums are the portable loop's integers.
        let Records::Int16(records) = &g.records else {
            unreachable!()
        };
        for c in points() {
            let Some(cell) = grid.locate(c) else { continue };
            let [bx, by, bz] = cell.b.map(|b| b as usize);
            let (qx, qy) = (xy_fraction(cell.f[0]), xy_fraction(cell.f[1]));
            let w = ([XY_WEIGHT_ONE - qx, qx], [XY_WEIGHT_ONE - qy, qy]);
            for o in [bx + g.sy * by + g.sz * bz, bx + g.sy * by + g.sz * (bz + 1)] {
                assert_eq!(
                    g.slice_sums(records, o, w),
                    g.slice_sums_portable(records, o, w),
                    "at {c}"
                );
            }
        }
        // At a voxel every weight but one is zero: the record exactly.
        for (i, j, k) in [(0, 0, 0), (3, 2, 1), (5, 4, 3), (6, 5, 4)] {
            let cell = grid.locate(Vec3::new(i as f32, j as f32, k as f32)).unwrap();
            assert_eq!(g.interpolate(&cell), g.get(i, j, k), "voxel ({i}, {j}, {k})");
        }
    }

    #[test]
    fn float_records_interpolate_as_the_ct_trilinear_bit_for_bit() {
        let dims = [7usize, 6, 5];
        for (name, data) in [
            (
                "fractions",
                ct(dims, |i, j, k| ((i * 37 + j * 11 + k * 5) % 23) as f32 * 3.7 - 50.25),
            ),
            (
                "wide range",
                ct(dims, |i, j, k| if (i + j + k) % 2 == 0 { -32000.0 } else { 32000.0 }),
            ),
        ] {
            let d = dims.map(|n| n as u32);
            let g = GradientVolume::new(&data, d);
            assert!(!g.is_int16(), "{name}");
            let grid = Grid3::new(&data, d);
            for c in points() {
                let Some(cell) = grid.locate(c) else { continue };
                let r = g.interpolate(&cell);
                assert_eq!(r.w.to_bits(), grid.interpolate(&cell).to_bits(), "{name} at {c}");
                // The gradient lanes: the same blend of the records' differences.
                let want = |lane: usize| {
                    let [bx, by, bz] = cell.b;
                    let [fx, fy, fz] = cell.f;
                    let v = |i, j, k| record(&data, dims, [i as usize, j as usize, k as usize])[lane];
                    let c00 = v(bx, by, bz) * (1.0 - fx) + v(bx + 1, by, bz) * fx;
                    let c10 = v(bx, by + 1, bz) * (1.0 - fx) + v(bx + 1, by + 1, bz) * fx;
                    let c01 = v(bx, by, bz + 1) * (1.0 - fx) + v(bx + 1, by, bz + 1) * fx;
                    let c11 = v(bx, by + 1, bz + 1) * (1.0 - fx) + v(bx + 1, by + 1, bz + 1) * fx;
                    let c0 = c00 * (1.0 - fy) + c10 * fy;
                    let c1 = c01 * (1.0 - fy) + c11 * fy;
                    c0 * (1.0 - fz) + c1 * fz
                };
                for lane in 0..3 {
                    assert_eq!(r[lane].to_bits(), want(lane).to_bits(), "{name} lane {lane} at {c}");
                }
                // The on-the-fly differences (J, one-voxel axes, the GPU's formula) agree.
                let d = grid.differences(c, Edge::Air).unwrap();
                assert_eq!(
                    d.to_array().map(f32::to_bits),
                    [r.x, r.y, r.z].map(f32::to_bits),
                    "{name} at {c}"
                );
            }
        }
    }
}
