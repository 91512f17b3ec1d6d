//! How a ray's window of eight lattice points is placed: all at once on the AVX2 lanes
//! (`Avx2::place`), or each point only when the march reaches it (the reference).

use super::avx2::Avx2;
use super::cell::Cell;
use super::sampler::Grid3;
use super::window::{Lattice, POINTS, Window};

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
        if let Some(avx2) = self.avx2 {
            avx2.place(grid, lattice, k, out);
        }
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
            let t = super::window::lattice(k + i as u32, lattice.j, lattice.step);
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
        let t = super::window::lattice(k + i as u32, j, step);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::Lanes;
    use crate::raycast::avx2::available_for_lane_tests;
    use stylet_physics::glam::Vec3;

    #[test]
    fn lanes_place_the_bits_of_one_point_at_a_time() {
        let lanes_here = available_for_lane_tests();
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
