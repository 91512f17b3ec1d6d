//! The finest level of empty-space leaping (docs/rendering.md "One ray", step 8): one bit per
//! voxel cube, the eight voxels a trilinear sample with that base voxel reads. A cube is visible
//! when the transfer table has α > 0 anywhere between the least and the greatest of its eight
//! values; a sample whose cube is not visible interpolates only values the table maps to α = 0,
//! so the CPU ray loop skips it after computing its base voxel, without reading the CT or the
//! table. The picture is the same with and without the mask.
//!
//! Built per transfer-table visibility (not per frame) and cached by the render volume:
//! a few hundred milliseconds for a 512 × 512 × 133 CT, 1 bit per voxel.

use rayon::prelude::*;

use super::brick_distance::BrickDistance;
use crate::transfer_table::TransferTable;

/// What the AVX2 classification of a window (`Avx2::classify`) tells of its points, one bit
/// per point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct WindowClasses {
    /// The window's last point (bit 7) when it is inside and its brick is at distance
    /// ≥ `leap_from` from a visible one: a leap starts there. Earlier points are not asked: a
    /// window passes their invisible cubes on the lanes anyway, and one scalar load costs less
    /// than a gather of eight distances whose answer the window waits for (soft, skin and bone
    /// frames 2–3 % faster; the same points sampled).
    pub far: u8,
    /// The last point's brick distance when `far` is set (the leap's box), else 0.
    pub far_distance: u8,
    /// Inside points whose cube is visible.
    pub visible: u8,
}

/// Visibility bits of every voxel cube, one z-slab of cubes after another.
#[derive(Debug, Clone, PartialEq)]
pub struct CubeMask {
    /// CT dimensions.
    pub dims: [u32; 3],
    /// 64-bit words per slab: ⌈nx·ny / 64⌉ (slabs start on a word, so they are built in parallel).
    pub(super) words_per_slab: usize,
    pub(super) bits: Vec<u64>,
    /// Whether every cube and bit-word index fits an `i32` lane ([`Self::lanes_fit`]); always
    /// so for a grid of at most `MAX_VOXELS` (2²⁸).
    lanes_fit: bool,
    /// The cubes' bricks and their distances to visible ones (leaping over many cubes at once).
    pub(super) bricks: BrickDistance,
}

impl CubeMask {
    /// The mask of a CT (`data`, x fastest, every axis ≥ 2 voxels) under `table`.
    pub fn new(data: &[f32], dims: [u32; 3], table: &TransferTable) -> CubeMask {
        let [nx, ny, nz] = dims.map(|n| n as usize);
        let words_per_slab = (nx * ny).div_ceil(64);
        let mut bits = vec![0u64; words_per_slab * nz];
        crate::huge_pages::advise(&mut bits);
        let lanes_fit = nx * ny < i32::MAX as usize && bits.len() * 2 < i32::MAX as usize;
        if nx < 2 || ny < 2 || nz < 2 || data.len() < nx * ny * nz {
            return CubeMask {
                dims,
                words_per_slab,
                bits,
                lanes_fit: false,
                bricks: BrickDistance::new([0; 3], |_, _, _, _| true),
            };
        }
        let slab = nx * ny;
        bits.par_chunks_mut(words_per_slab)
            .enumerate()
            .take(nz - 1)
            .for_each(|(k, words)| {
                let (lo_slice, hi_slice) = (&data[k * slab..(k + 1) * slab], &data[(k + 1) * slab..(k + 2) * slab]);
                // Per row pair: the min and max over the four voxels (i, j), (i, j + 1) of both
                // slices, then over i and i + 1.
                let mut col_min = vec![0.0f32; nx];
                let mut col_max = vec![0.0f32; nx];
                for j in 0..ny - 1 {
                    let rows = [
                        &lo_slice[j * nx..(j + 1) * nx],
                        &lo_slice[(j + 1) * nx..(j + 2) * nx],
                        &hi_slice[j * nx..(j + 1) * nx],
                        &hi_slice[(j + 1) * nx..(j + 2) * nx],
                    ];
                    for i in 0..nx {
                        let (a, b, c, d) = (rows[0][i], rows[1][i], rows[2][i], rows[3][i]);
                        col_min[i] = a.min(b).min(c.min(d));
                        col_max[i] = a.max(b).max(c.max(d));
                    }
                    for i in 0..nx - 1 {
                        let lo = col_min[i].min(col_min[i + 1]);
                        let hi = col_max[i].max(col_max[i + 1]);
                        // NaN voxels: `min`/`max` pass the other operand; a cube of NaNs reads
                        // lo > hi and stays visible (never skipped).
                        if !(lo <= hi) || table.visible_in(lo, hi) {
                            let r = i + nx * j;
                            words[r >> 6] |= 1u64 << (r & 63);
                        }
                    }
                }
            });
        let mut mask = CubeMask {
            dims,
            words_per_slab,
            bits,
            lanes_fit,
            bricks: BrickDistance::new([0; 3], |_, _, _, _| true),
        };
        let bricks = BrickDistance::new(dims.map(|n| n - 1), |x0, x1, y, z| mask.any_visible(x0, x1, y, z));
        mask.bricks = bricks;
        mask
    }

    /// The bricks of cubes and their distances to the nearest visible cube's brick.
    pub fn bricks(&self) -> &BrickDistance {
        &self.bricks
    }

    /// Whether the cube with base voxel (`bx`, `by`, `bz`) (each ≤ n − 2) may be visible.
    #[inline(always)]
    pub fn visible(&self, bx: u32, by: u32, bz: u32) -> bool {
        let r = bx as usize + self.dims[0] as usize * by as usize;
        let w = bz as usize * self.words_per_slab + (r >> 6);
        // Out-of-range bases (not produced by the ray loop) count as visible.
        self.bits.get(w).is_none_or(|word| word >> (r & 63) & 1 == 1)
    }

    /// Whether every cube and bit-word index fits an `i32` lane, as the AVX2 classification of
    /// a window needs (`Avx2::classify`).
    pub fn lanes_fit(&self) -> bool {
        self.lanes_fit
    }

    /// Whether any cube with base voxel (x, `by`, `bz`), `x0` ≤ x < `x1`, is visible (a word's
    /// bits at a time).
    pub fn any_visible(&self, x0: u32, x1: u32, by: u32, bz: u32) -> bool {
        let row = self.dims[0] as usize * by as usize;
        let slab = bz as usize * self.words_per_slab;
        let (mut r, end) = (row + x0 as usize, row + x1 as usize);
        while r < end {
            let n = (64 - (r & 63)).min(end - r);
            let word = self.bits.get(slab + (r >> 6)).copied().unwrap_or(u64::MAX);
            let run = if n == 64 { u64::MAX } else { (1u64 << n) - 1 };
            if (word >> (r & 63)) & run != 0 {
                return true;
            }
            r += n;
        }
        false
    }

    /// Number of visible cubes (tests, statistics).
    pub fn count_visible(&self) -> u64 {
        self.bits.iter().map(|w| w.count_ones() as u64).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transfer::{TransferFunction, Trapezoid};

    fn table() -> TransferTable {
        let tf = TransferFunction::Trapezoids(vec![Trapezoid {
            tissue: "soft".into(),
            hu: [-60.0, 0.0, 50.0, 70.0],
            rgb: [0.8, 0.7, 0.6],
            opacity: 1.0,
            weight: 0.5,
        }]);
        TransferTable::new(&tf, -1024.0, 3071.0, 0.5)
    }

    #[test]
    fn a_cube_is_visible_exactly_when_its_value_range_reads_opacity() {
        let dims = [7u32, 5, 4];
        let n = 7 * 5 * 4;
        // Fat everywhere (invisible), one soft-tissue voxel, and a fat/bone pair whose
        // interpolation passes through soft tissue.
        let mut data = vec![-100.0f32; n];
        let at = |i: usize, j: usize, k: usize| i + 7 * (j + 5 * k);
        data[at(3, 2, 1)] = 20.0;
        data[at(5, 0, 3)] = 400.0;
        let t = table();
        let mask = CubeMask::new(&data, dims, &t);
        for k in 0..3u32 {
            for j in 0..4u32 {
                for i in 0..6u32 {
                    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                    for (di, dj, dk) in [
                        (0, 0, 0),
                        (1, 0, 0),
                        (0, 1, 0),
                        (1, 1, 0),
                        (0, 0, 1),
                        (1, 0, 1),
                        (0, 1, 1),
                        (1, 1, 1),
                    ] {
                        let v = data[at((i + di) as usize, (j + dj) as usize, (k + dk) as usize)];
                        lo = lo.min(v);
                        hi = hi.max(v);
                    }
                    assert_eq!(mask.visible(i, j, k), t.visible_in(lo, hi), "cube {i} {j} {k}");
                }
            }
        }
        // The soft voxel touches the 8 cubes around it, the bone voxel (a corner on two faces)
        // the 2 that contain it.
        assert_eq!(mask.count_visible(), 8 + 2);
    }

    #[test]
    fn a_run_of_cubes_reads_the_same_bits_as_cube_by_cube() {
        // Rows of 149 cubes cross 64-bit words; seeded noise between fat and soft tissue.
        let dims = [150u32, 4, 3];
        let mut seed = 0x9e3779b9u32;
        let data: Vec<f32> = (0..150 * 4 * 3)
            .map(|_| {
                seed ^= seed << 13;
                seed ^= seed >> 17;
                seed ^= seed << 5;
                if seed.is_multiple_of(23) { 20.0 } else { -100.0 }
            })
            .collect();
        let mask = CubeMask::new(&data, dims, &table());
        assert!(mask.count_visible() > 0);
        for k in 0..2 {
            for j in 0..3 {
                for x0 in (0..149).step_by(7) {
                    for x1 in [x0, x0 + 1, x0 + 4, x0 + 63, x0 + 64, x0 + 65, 149] {
                        let x1 = x1.min(149);
                        let any = (x0..x1).any(|i| mask.visible(i, j, k));
                        assert_eq!(mask.any_visible(x0, x1, j, k), any, "row {j} {k}, {x0}..{x1}");
                    }
                }
            }
        }
        // A brick is at distance 0 exactly when one of its cubes is visible.
        for k in 0..2u32 {
            for j in 0..3u32 {
                for i in 0..149u32 {
                    let (x0, y0, z0) = (i & !3, j & !3, k & !1);
                    let any = (z0..(z0 + 2).min(2))
                        .any(|z| (y0..(y0 + 4).min(3)).any(|y| (x0..(x0 + 4).min(149)).any(|x| mask.visible(x, y, z))));
                    assert_eq!(mask.bricks().at([i, j, k]) == 0, any, "cube {i} {j} {k}");
                }
            }
        }
    }
    #[test]
    fn the_lanes_classify_a_window_as_point_by_point() {
        use crate::raycast::Lanes;
        use crate::raycast::avx2::{Avx2, available_for_lane_tests};
        use crate::raycast::window::Window;
        let (true, Some(avx2)) = (available_for_lane_tests(), Avx2::detect(Lanes::Auto)) else {
            return;
        };
        // Rows of 149 cubes cross 32- and 64-bit words; sparse soft tissue in fat, so bricks
        // at distances 0, 1, 2 and more all occur (leaps from distance 1, 2 and 3 tested).
        let dims = [150u32, 37, 11];
        let mut seed = 0x2545f491u32;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        };
        let data: Vec<f32> = (0..150 * 37 * 11)
            .map(|_| if next() % 211 == 0 { 20.0 } else { -100.0 })
            .collect();
        let mask = CubeMask::new(&data, dims, &table());
        let (mut far, mut visible, mut outside) = (0, 0, 0);
        for w in 0..4000 {
            // Mostly inside points; the others hold bases no lane may read.
            let mut window = Window {
                inside: if w % 5 == 0 { next() as u8 } else { u8::MAX },
                ..Window::default()
            };
            for i in 0..8 {
                for (b, n) in window.b.iter_mut().zip(dims) {
                    b[i] = if window.inside & (1 << i) != 0 {
                        next() % (n - 1)
                    } else {
                        i32::MIN as u32
                    };
                }
            }
            let leap_from = 1 + (w % 3) as u8;
            assert!(mask.lanes_fit());
            let classes = avx2.classify(&mask, &window, leap_from);
            for i in 0..8 {
                let b = [window.b[0][i], window.b[1][i], window.b[2][i]];
                let inside = window.inside & (1 << i) != 0;
                // Only the last point is asked whether a leap starts there.
                let want_far = i == 7 && inside && mask.bricks().at(b) >= leap_from;
                let want_visible = inside && mask.visible(b[0], b[1], b[2]);
                assert_eq!(classes.far & (1 << i) != 0, want_far, "window {w}, point {i}, {b:?}");
                if i == 7 {
                    let d = if want_far { mask.bricks().at(b) } else { 0 };
                    assert_eq!(classes.far_distance, d, "window {w}");
                }
                assert_eq!(
                    classes.visible & (1 << i) != 0,
                    want_visible,
                    "window {w}, point {i}, {b:?}"
                );
                far += usize::from(want_far);
                visible += usize::from(want_visible);
                outside += usize::from(!inside);
            }
        }
        assert!(
            far > 200 && visible > 100 && outside > 1000,
            "{far} far, {visible} visible, {outside} outside"
        );
    }
}
