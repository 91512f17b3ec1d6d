//! Eight consecutive lattice points of one ray placed and located at once (docs/rendering.md
//! "Sample lanes"): t_k = (k + j)·Δ, c = c_e + t·c_r and `Grid3::locate` (the inside rule, the
//! clamp, the base voxel and the fractions) for k … k + 7, on AVX2 lanes where the CPU has them.
//! Every number is the one the march computes one point at a time, bit for bit; the march then
//! visits the points in order and drops the rest of a window when it leaps. Without the lanes
//! each point is placed only when the march reaches it (`Placer::point`).

use stylet_physics::glam::Vec3;

use super::batch::Avx2;
use super::sampler::{Cell, Grid3};

/// Points per window.
pub const POINTS: usize = 8;

/// Lattice points k … k + 7 of a ray, located in the CT grid.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Window {
    /// t of each point.
    pub t: [f32; POINTS],
    /// Base voxel per axis and point (meaningful where `inside` is set).
    pub b: [[u32; POINTS]; 3],
    /// Fractions per axis and point.
    pub f: [[f32; POINTS]; 3],
    /// Bit i: point i lies in the sampling domain (`Grid3::locate` gave a cell).
    pub inside: u8,
}

impl Default for Window {
    fn default() -> Self {
        Window {
            t: [0.0; POINTS],
            b: [[0; POINTS]; 3],
            f: [[0.0; POINTS]; 3],
            inside: 0,
        }
    }
}

impl Window {
    /// Point `i`'s base voxel and fractions, inside or not.
    #[inline(always)]
    pub fn cell_at(&self, i: usize) -> Cell {
        Cell {
            b: [self.b[0][i], self.b[1][i], self.b[2][i]],
            f: [self.f[0][i], self.f[1][i], self.f[2][i]],
        }
    }

    /// Point `i`'s cell, when it lies inside.
    #[inline(always)]
    pub fn cell(&self, i: usize) -> Option<Cell> {
        (self.inside & (1 << i) != 0).then(|| self.cell_at(i))
    }
}

/// A ray's lattice in CT index space: c(t) = `ce` + t·`dc` at t_k = (k + `j`)·`step`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Lattice {
    pub ce: Vec3,
    pub dc: Vec3,
    pub j: f32,
    pub step: f32,
}

/// How the window is computed: AVX2 lanes, or one point at a time (the reference).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Placer {
    avx2: Option<Avx2>,
}

impl Placer {
    /// AVX2 lanes when `avx2` is given, else one point at a time.
    pub fn new(avx2: Option<Avx2>) -> Placer {
        Placer { avx2 }
    }

    /// Points k … k + 7 of `lattice`, located in `grid` (one with ≥ 2 voxels per axis:
    /// `Grid3::is_fast`), on the lanes. Without them nothing is placed ahead: [`Self::point`]
    /// places each point when the march asks for it (a leap would waste the rest). `k` + 7 must
    /// fit an `i32`.
    #[inline(always)]
    pub fn place(&self, grid: &Grid3, lattice: &Lattice, k: u32, out: &mut Window) {
        assert!(
            k <= i32::MAX as u32 - (POINTS as u32 - 1),
            "lattice index {k} out of range"
        );
        #[cfg(target_arch = "x86_64")]
        if self.avx2.is_some() {
            // SAFETY: an `Avx2` exists only when the CPU has AVX2 (`Avx2::detect`).
            unsafe { avx2::place(grid, lattice, k, out) };
        }
        let _ = (grid, lattice, out);
    }

    /// Whether points are placed on the lanes (the march is compiled once for each answer).
    pub fn uses_lanes(&self) -> bool {
        self.avx2.is_some()
    }

    /// Point k + `i` of the window [`Self::place`] placed at k: its t and, when it lies inside,
    /// its cell. `LANES` must be [`Self::uses_lanes`] (a constant, so the march's loop has no
    /// branch for it).
    #[inline(always)]
    pub fn point<const LANES: bool>(
        &self,
        grid: &Grid3,
        lattice: &Lattice,
        window: &Window,
        k: u32,
        i: usize,
    ) -> (f32, Option<Cell>) {
        debug_assert_eq!(LANES, self.avx2.is_some());
        if LANES {
            (window.t[i], window.cell(i))
        } else {
            let t = super::march::lattice(k + i as u32, lattice.j, lattice.step);
            (t, grid.locate(lattice.ce + lattice.dc * t))
        }
    }
}

/// The reference: the march's own formulas, one point after the other (the lanes' test).
#[cfg(test)]
fn place_one_at_a_time(grid: &Grid3, lattice: &Lattice, k: u32, out: &mut Window) {
    let Lattice { ce, dc, j, step } = *lattice;
    out.inside = 0;
    for i in 0..POINTS {
        let t = super::march::lattice(k + i as u32, j, step);
        out.t[i] = t;
        if let Some(cell) = grid.locate(ce + dc * t) {
            out.inside |= 1 << i;
            for a in 0..3 {
                out.b[a][i] = cell.b[a];
                out.f[a][i] = cell.f[a];
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::super::sampler::Grid3;
    use super::{Lattice, POINTS, Window};

    /// `place_one_at_a_time` on eight lanes.
    ///
    /// # Safety
    /// AVX2; `k` + 7 ≤ `i32::MAX`.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn place(grid: &Grid3, lattice: &Lattice, k: u32, out: &mut Window) {
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::batch::{Lanes, avx2_for_lane_tests};

    #[test]
    fn lanes_place_the_bits_of_one_point_at_a_time() {
        let lanes_here = avx2_for_lane_tests();
        let dims = [9u32, 7, 5];
        let data = vec![0.0f32; 9 * 7 * 5];
        let grid = Grid3::new(&data, dims);
        let lanes = Placer::new(Avx2::detect(Lanes::Auto));
        let one = Placer::new(Avx2::detect(Lanes::OneAtATime));
        assert_eq!(lanes.uses_lanes(), lanes_here);
        assert!(!one.uses_lanes());
        // A CPU without AVX2 runs the pairs without lanes.
        assert!(!Placer::new(Avx2::detect(Lanes::PairsWithoutSimd)).uses_lanes());
        let (mut a, mut b) = (Window::default(), Window::default());
        let mut inside = 0u32;
        let mut outside = 0u32;
        for r in 0..400 {
            let f = r as f32;
            // Rays from outside the box, through it and along its faces, of every direction.
            let ce = Vec3::new(
                4.0 + (f * 0.71).sin() * 7.0,
                3.0 + (f * 0.37).cos() * 6.0,
                2.0 + (f * 0.13).sin() * 4.0,
            );
            let dc = match r % 5 {
                0 => Vec3::new(1.0, 0.0, 0.0),
                1 => Vec3::new(-0.0, -0.3, 0.2),
                _ => Vec3::new((f * 1.3).cos(), (f * 0.7).sin(), (f * 2.1).cos()) * 0.4,
            };
            let ce = if r % 7 == 0 { Vec3::new(-0.5, -0.0, 4.5) } else { ce };
            // x stays −0 along the ray: the clamp must keep the zero's sign, as `f32::clamp`.
            let (ce, dc) = if r % 11 == 0 {
                (Vec3::new(-0.0, 2.0, 1.0), Vec3::new(-0.0, 0.1, 0.1))
            } else {
                (ce, dc)
            };
            let (j, step) = ((f * 0.618).fract(), if r % 3 == 0 { 0.5 } else { 0.35 });
            for k in [0u32, 1, 2, 3, 5, 8, 13, 17, 24, 40, 1_000_000, i32::MAX as u32 - 7] {
                let lattice = Lattice { ce, dc, j, step };
                lanes.place(&grid, &lattice, k, &mut a);
                place_one_at_a_time(&grid, &lattice, k, &mut b);
                // What the march reads, with and without lanes.
                for i in 0..POINTS {
                    let (ta, ca) = if lanes.uses_lanes() {
                        lanes.point::<true>(&grid, &lattice, &a, k, i)
                    } else {
                        lanes.point::<false>(&grid, &lattice, &a, k, i)
                    };
                    let (tb, cb) = one.point::<false>(&grid, &lattice, &Window::default(), k, i);
                    assert_eq!(ta.to_bits(), tb.to_bits(), "ray {r}, k {k}, point {i}");
                    assert_eq!(
                        ca.map(|c| (c.b, c.f.map(f32::to_bits))),
                        cb.map(|c| (c.b, c.f.map(f32::to_bits)))
                    );
                }
                assert_eq!(a.t.map(f32::to_bits), b.t.map(f32::to_bits), "ray {r}, k {k}");
                assert_eq!(a.inside, b.inside, "ray {r}, k {k}");
                for i in 0..POINTS {
                    let (ca, cb) = (a.cell(i), b.cell(i));
                    assert_eq!(ca.map(|c| c.b), cb.map(|c| c.b), "ray {r}, k {k}, point {i}");
                    assert_eq!(
                        ca.map(|c| c.f.map(f32::to_bits)),
                        cb.map(|c| c.f.map(f32::to_bits)),
                        "ray {r}, k {k}, point {i}"
                    );
                    // And the march's own formulas.
                    let t = (((k + i as u32) as f32) + j) * step;
                    assert_eq!(a.t[i].to_bits(), t.to_bits());
                    let want = grid.locate(ce + dc * t);
                    assert_eq!(
                        ca.map(|c| (c.b, c.f.map(f32::to_bits))),
                        want.map(|c| (c.b, c.f.map(f32::to_bits)))
                    );
                    if want.is_some() {
                        inside += 1;
                    } else {
                        outside += 1;
                    }
                }
            }
        }
        assert!(inside > 1000 && outside > 1000, "{inside} inside, {outside} outside");
    }

    #[test]
    #[should_panic(expected = "out of range")]
    fn a_lattice_index_past_i32_is_refused() {
        let data = vec![0.0f32; 8];
        let grid = Grid3::new(&data, [2, 2, 2]);
        let mut w = Window::default();
        let lattice = Lattice {
            ce: Vec3::ZERO,
            dc: Vec3::X,
            j: 0.0,
            step: 1.0,
        };
        Placer::new(Avx2::detect(Lanes::Auto)).place(&grid, &lattice, i32::MAX as u32, &mut w);
    }
}
