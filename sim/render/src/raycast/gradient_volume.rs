//! The CT with its gradient beside every voxel (docs/rendering.md "Sampling", "Gradient"): the
//! record of voxel i is (I(i + e_x) − I(i − e_x), I(i + e_y) − I(i − e_y), I(i + e_z) − I(i − e_z),
//! I(i)), neighbours outside the grid reading air. A lattice sample reads its
//! eight records once and interpolates all four components together, so the value and the
//! central-difference gradient of thesis eq. 3.2.3 cost one trilinear read instead of seven
//! (Levoy's precomputed gradients, as VTK's ray casters use).
//!
//! Records are four 16-bit integers when the CT holds only integers and every difference fits
//! (real CT: 8 bytes a voxel), else four `f32` (16 bytes). Either way the interpolated value is
//! bit-identical to [`super::sampler::Grid3::interpolate`]: the same products and sums of the
//! same values in the same order, four lanes at a time.

use rayon::prelude::*;
use stylet_physics::atlas::AIR_HU;
use stylet_physics::glam::Vec4;

use super::sampler::Cell;

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
            r.par_chunks_mut(slab.max(1)).enumerate().for_each(|(k, s)| {
                fill(k, &mut |o, v| s[o] = v.map(|x| x as i16));
            });
            Records::Int16(r)
        } else {
            let mut r = vec![[0f32; 4]; len];
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
    /// the same dimensions): `Grid3::interpolate`'s order on all four lanes.
    #[inline(always)]
    pub fn interpolate(&self, cell: &Cell) -> Vec4 {
        match &self.records {
            Records::Int16(r) => self.lerp8(cell, |o| {
                debug_assert!(o < r.len());
                // SAFETY: see `lerp8`.
                widen(unsafe { r.get_unchecked(o) })
            }),
            Records::Float32(r) => self.lerp8(cell, |o| {
                debug_assert!(o < r.len());
                // SAFETY: see `lerp8`.
                Vec4::from_array(unsafe { *r.get_unchecked(o) })
            }),
        }
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

    #[test]
    fn the_interpolated_value_is_the_ct_trilinear_bit_for_bit() {
        let dims = [7usize, 6, 5];
        for (name, data) in [
            (
                "integers",
                ct(dims, |i, j, k| ((i * 37 + j * 11 + k * 5) % 23) as f32 * 10.0 - 100.0),
            ),
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
            assert_eq!(g.is_int16(), name == "integers", "{name}");
            let grid = Grid3::new(&data, d);
            for n in 0..500 {
                let f = n as f32;
                let c = Vec3::new(
                    (f * 0.37).sin() * 3.6 + 3.0,
                    (f * 0.11).cos() * 3.1 + 2.5,
                    (f * 0.23).sin() * 2.6 + 2.0,
                );
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
