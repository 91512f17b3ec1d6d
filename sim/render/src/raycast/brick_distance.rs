//! Empty-space leaping over many voxels at once (docs/rendering.md "One ray", step 8, CPU
//! refinements): the voxel cubes of the cube mask grouped in bricks of
//! 4 × 4 × 2 cubes, and for every brick its chessboard distance, in bricks, to the nearest
//! brick holding a visible cube. A brick at distance d ≥ 1 sits in a box of (2d − 1)³ bricks
//! without a visible cube: a ray whose sample lies in it passes every lattice point before the
//! box's exit without reading anything, and no pixel changes (only invisible cubes are passed).
//!
//! Distances are capped at 255 and computed by the two raster passes of Rosenfeld & Pfaltz
//! (1966) with the 26-neighbourhood, which are exact for the chessboard metric (tested against
//! brute force).

/// log₂ of the brick's size in cubes along x, y, z (4 × 4 × 2: about 3 × 3 × 5 mm on a CT of
/// 0.7 × 0.7 × 2.5 mm voxels).
const SHIFT: [u32; 3] = [2, 2, 1];

use stylet_physics::glam::Vec3;

/// Largest stored distance: "no visible brick within 254 bricks".
const CAP: u8 = 255;

/// Chessboard distances of the bricks to the nearest brick with a visible cube.
#[derive(Debug, Clone, PartialEq)]
pub struct BrickDistance {
    /// Cubes per axis (n − 1 for n voxels): base voxels 0 … n − 2.
    cubes: [u32; 3],
    /// Bricks per axis.
    dims: [u32; 3],
    /// One distance per brick, x fastest.
    dist: Vec<u8>,
}

impl BrickDistance {
    /// The distances for `cubes` cubes per axis; `any_visible(x0, x1, y, z)` tells whether a cube
    /// of row (y, z) with x0 ≤ x < x1 is visible.
    pub fn new(cubes: [u32; 3], any_visible: impl Fn(u32, u32, u32, u32) -> bool + Sync) -> BrickDistance {
        let dims = [0, 1, 2].map(|a| cubes[a].div_ceil(1 << SHIFT[a]));
        let [bx, by, bz] = dims.map(|n| n as usize);
        let mut dist = vec![CAP; bx * by * bz];
        {
            use rayon::prelude::*;
            // A brick is at distance 0 when any of its cubes is visible (one z-slab of bricks
            // per task).
            dist.par_chunks_mut((bx * by).max(1)).enumerate().for_each(|(k, slab)| {
                let z0 = (k as u32) << SHIFT[2];
                let z1 = (z0 + (1 << SHIFT[2])).min(cubes[2]);
                for z in z0..z1 {
                    for y in 0..cubes[1] {
                        let row = (y >> SHIFT[1]) as usize * bx;
                        for (q, d) in slab[row..row + bx].iter_mut().enumerate() {
                            let x0 = (q as u32) << SHIFT[0];
                            if *d != 0 && any_visible(x0, (x0 + (1 << SHIFT[0])).min(cubes[0]), y, z) {
                                *d = 0;
                            }
                        }
                    }
                }
            });
        }
        chessboard_passes(&mut dist, dims);
        BrickDistance { cubes, dims, dist }
    }

    /// Distance of the brick holding the cube with base voxel `b` (each b_a ≤ n_a − 2).
    #[inline(always)]
    pub fn at(&self, b: [u32; 3]) -> u8 {
        let q = [0, 1, 2].map(|a| (b[a] >> SHIFT[a]) as usize);
        let i = q[0] + self.dims[0] as usize * (q[1] + self.dims[1] as usize * q[2]);
        // Out-of-range bases (not produced by the ray loop) read distance 0: never passed.
        self.dist.get(i).copied().unwrap_or(0)
    }

    /// The box, in index coordinates c, of the samples whose base voxel lies in the bricks at
    /// chessboard distance < `d` (≥ 1) from the brick of base voxel `b`: per axis [lo, hi), with
    /// −∞ or +∞ where the box reaches the first or last cube (the trilinear clamp sends every
    /// sample beyond there to that cube). Shrunk by `margin` (index units) on finite faces, so
    /// rounding in c(t) never lets the caller pass a sample outside it.
    #[inline(always)]
    pub fn empty_box(&self, b: [u32; 3], d: u8, margin: f32) -> [(f32, f32); 3] {
        let r = d as u32 - 1;
        [0, 1, 2].map(|a| {
            let q = b[a] >> SHIFT[a];
            let lo_q = q.saturating_sub(r);
            let hi_q = (q + r).min(self.dims[a] - 1);
            // Cubes lo_cube … hi_cube (bases), i.e. c ∈ [lo_cube, hi_cube + 1).
            let lo_cube = lo_q << SHIFT[a];
            let hi_cube = ((hi_q + 1) << SHIFT[a]) - 1;
            let lo = if lo_cube == 0 {
                f32::NEG_INFINITY
            } else {
                lo_cube as f32 + margin
            };
            let hi = if hi_cube + 1 >= self.cubes[a] {
                f32::INFINITY
            } else {
                (hi_cube + 1) as f32 - margin
            };
            (lo, hi)
        })
    }
}

/// Which way a ray runs along one axis of the index space.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Heading {
    /// c_a grows with t: the ray leaves a box by its upper face.
    Increasing,
    /// c_a shrinks with t: the ray leaves by the lower face.
    Decreasing,
    /// c_r,a = ±0: the ray never leaves by this axis.
    Parallel,
}

/// A ray c(t) = c_e + t·c_r in index space as a leap reads it, prepared once per ray: 1/c_r and
/// the face each axis leaves a box by.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeavingRay {
    ce: [f32; 3],
    inv_dc: [f32; 3],
    heading: [Heading; 3],
}

impl LeavingRay {
    pub fn new(ce: Vec3, dc: Vec3) -> LeavingRay {
        let heading = [0, 1, 2].map(|a| {
            if dc[a] > 0.0 {
                Heading::Increasing
            } else if dc[a] < 0.0 {
                Heading::Decreasing
            } else {
                Heading::Parallel
            }
        });
        LeavingRay {
            ce: ce.to_array(),
            inv_dc: dc.recip().to_array(),
            heading,
        }
    }
}

impl BrickDistance {
    /// The t at which `ray` leaves [`Self::empty_box`]`(b, d, margin)`: the least over the axes
    /// of (face − c_e,a)·(1/c_r,a) at the finite face the ray runs toward, +∞ when there is
    /// none. Only that face is worked out (the leap of docs/rendering.md step 8, taken millions
    /// of times a frame); the numbers are those of the box's faces, bit for bit.
    #[inline(always)]
    pub fn exit_t(&self, b: [u32; 3], d: u8, margin: f32, ray: &LeavingRay) -> f32 {
        let r = d as u32 - 1;
        let mut t = f32::INFINITY;
        for a in 0..3 {
            let q = b[a] >> SHIFT[a];
            let face = match ray.heading[a] {
                Heading::Increasing => {
                    // One past the last cube of the box (hi_cube + 1 of `empty_box`).
                    let end = ((q + r).min(self.dims[a] - 1) + 1) << SHIFT[a];
                    if end >= self.cubes[a] {
                        continue;
                    }
                    end as f32 - margin
                }
                Heading::Decreasing => {
                    let lo_cube = q.saturating_sub(r) << SHIFT[a];
                    if lo_cube == 0 {
                        continue;
                    }
                    lo_cube as f32 + margin
                }
                Heading::Parallel => continue,
            };
            t = t.min((face - ray.ce[a]) * ray.inv_dc[a]);
        }
        t
    }
}

/// Rosenfeld–Pfaltz chessboard distance transform in place (values already 0 or `CAP`): a
/// forward raster pass taking 1 + the least of the 13 neighbours before each brick, then a
/// backward pass over the 13 after it; saturating at `CAP`. Runs on a copy padded by one brick
/// of `CAP` on every side, so no neighbour needs a bounds test.
fn chessboard_passes(dist: &mut [u8], dims: [u32; 3]) {
    let [nx, ny, nz] = dims.map(|n| n as usize);
    if dist.is_empty() {
        return;
    }
    let (px, py) = (nx + 2, ny + 2);
    let at = |x: usize, y: usize, z: usize| x + px * (y + py * z);
    let mut pad = vec![CAP; px * py * (nz + 2)];
    for z in 0..nz {
        for y in 0..ny {
            let row = nx * (y + ny * z);
            let p = at(1, y + 1, z + 1);
            pad[p..p + nx].copy_from_slice(&dist[row..row + nx]);
        }
    }
    // Offsets of the 13 neighbours that come before a brick in raster order (z, then y, then x).
    let mut before = [0usize; 13];
    let mut n = 0;
    for dz in -1..=1isize {
        for dy in -1..=1isize {
            for dx in -1..=1isize {
                if (dz, dy, dx) < (0, 0, 0) {
                    before[n] = (-(dx + px as isize * (dy + py as isize * dz))) as usize;
                    n += 1;
                }
            }
        }
    }
    let least = |pad: &[u8], i: usize, forward: bool| {
        before.iter().fold(pad[i], |d, &o| {
            let q = if forward { i - o } else { i + o };
            d.min(pad[q].saturating_add(1))
        })
    };
    for z in 1..=nz {
        for y in 1..=ny {
            for x in 1..=nx {
                let i = at(x, y, z);
                pad[i] = least(&pad, i, true);
            }
        }
    }
    for z in (1..=nz).rev() {
        for y in (1..=ny).rev() {
            for x in (1..=nx).rev() {
                let i = at(x, y, z);
                pad[i] = least(&pad, i, false);
            }
        }
    }
    for z in 0..nz {
        for y in 0..ny {
            let row = nx * (y + ny * z);
            let p = at(1, y + 1, z + 1);
            dist[row..row + nx].copy_from_slice(&pad[p..p + nx]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force chessboard distance to the nearest brick marked 0.
    fn brute(zero: &[bool], dims: [u32; 3]) -> Vec<u8> {
        let [nx, ny, nz] = dims.map(|n| n as i64);
        let mut out = vec![CAP; zero.len()];
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let mut best = CAP as i64;
                    for zz in 0..nz {
                        for yy in 0..ny {
                            for xx in 0..nx {
                                if zero[(xx + nx * (yy + ny * zz)) as usize] {
                                    let d = (x - xx).abs().max((y - yy).abs()).max((z - zz).abs());
                                    best = best.min(d);
                                }
                            }
                        }
                    }
                    out[(x + nx * (y + ny * z)) as usize] = best as u8;
                }
            }
        }
        out
    }

    #[test]
    fn the_two_passes_give_the_exact_chessboard_distance() {
        let mut seed = 0x2545f491u64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for case in 0..40 {
            let dims = [1 + (rnd() % 9) as u32, 1 + (rnd() % 7) as u32, 1 + (rnd() % 6) as u32];
            let n = (dims[0] * dims[1] * dims[2]) as usize;
            // From none to many seeds.
            let density = rnd() % 40;
            let zero: Vec<bool> = (0..n).map(|_| rnd() % 100 < density).collect();
            let mut dist: Vec<u8> = zero.iter().map(|&z| if z { 0 } else { CAP }).collect();
            chessboard_passes(&mut dist, dims);
            assert_eq!(dist, brute(&zero, dims), "case {case}, dims {dims:?}");
        }
    }

    #[test]
    fn a_brick_is_near_exactly_when_one_of_its_cubes_is_visible() {
        // 17 × 9 × 5 cubes: bricks of 4 × 4 × 2 → 5 × 3 × 3 bricks; one visible cube.
        let cubes = [17u32, 9, 5];
        let bd = BrickDistance::new(cubes, |x0, x1, y, z| (x0..x1).contains(&9) && (y, z) == (4, 3));
        assert_eq!(bd.dims, [5, 3, 3]);
        // Its brick (2, 1, 1) is at distance 0, the brick of cube (0, 0, 0) at 2.
        assert_eq!(bd.at([9, 4, 3]), 0);
        assert_eq!(bd.at([8, 7, 2]), 0);
        assert_eq!(bd.at([0, 0, 0]), 2);
        assert_eq!(bd.at([16, 8, 4]), 2);
        assert_eq!(bd.at([13, 0, 0]), 1);
        // Nothing visible: every brick at the cap.
        let none = BrickDistance::new(cubes, |_, _, _, _| false);
        assert!(none.dist.iter().all(|&d| d == CAP));
    }

    #[test]
    fn the_empty_box_covers_the_near_bricks_and_opens_at_the_grid_ends() {
        let cubes = [17u32, 9, 5];
        let bd = BrickDistance::new(cubes, |x0, x1, y, z| (x0..x1).contains(&9) && (y, z) == (4, 3));
        // Brick (0, 0, 0) at distance 2: bricks 0 … 1 on each axis are empty of visible cubes.
        let b = bd.empty_box([1, 1, 0], 2, 1e-3);
        assert_eq!(b[0], (f32::NEG_INFINITY, 8.0 - 1e-3));
        assert_eq!(b[1], (f32::NEG_INFINITY, 8.0 - 1e-3));
        assert_eq!(b[2], (f32::NEG_INFINITY, 4.0 - 1e-3));
        // The last brick on x (cubes 16 …) reaches the last cube: open to +∞.
        let b = bd.empty_box([16, 8, 4], 1, 1e-3);
        assert_eq!(b[0], (16.0 + 1e-3, f32::INFINITY));
        assert_eq!(b[1], (8.0 + 1e-3, f32::INFINITY));
        assert_eq!(b[2], (4.0 + 1e-3, f32::INFINITY));
    }

    /// The leap's exit as the march took it before `exit_t`: the face of `empty_box` the ray runs
    /// toward on each axis, skipped when infinite.
    fn exit_through_the_box(bd: &BrickDistance, b: [u32; 3], d: u8, ce: Vec3, dc: Vec3) -> f32 {
        let bx = bd.empty_box(b, d, 1e-3);
        let inv_dc = dc.recip();
        let mut t_exit = f32::INFINITY;
        for a in 0..3 {
            let face = if dc[a] > 0.0 {
                bx[a].1
            } else if dc[a] < 0.0 {
                bx[a].0
            } else {
                continue;
            };
            if face.is_finite() {
                t_exit = t_exit.min((face - ce[a]) * inv_dc[a]);
            }
        }
        t_exit
    }

    #[test]
    fn the_exit_is_that_of_the_empty_box_bit_for_bit() {
        let cubes = [37u32, 23, 11];
        let bd = BrickDistance::new(cubes, |x0, x1, y, z| (x0..x1).contains(&20) && (y, z) == (11, 5));
        let (mut finite, mut infinite) = (0, 0);
        for r in 0..3000u32 {
            let f = r as f32;
            let b = [r * 7 % cubes[0], r * 5 % cubes[1], r * 3 % cubes[2]];
            let d = bd.at(b).max(1 + (r % 4) as u8);
            let ce = Vec3::new((f * 0.37).sin() * 30.0, (f * 0.11).cos() * 20.0, (f * 0.23).sin() * 9.0);
            let dc = match r % 6 {
                0 => Vec3::new(0.0, -0.0, (f * 0.7).cos()),
                1 => Vec3::new(-0.0, 0.3, 0.0),
                _ => Vec3::new((f * 1.3).cos(), (f * 0.7).sin(), (f * 2.1).cos()) * 0.8,
            };
            let want = exit_through_the_box(&bd, b, d, ce, dc);
            let got = bd.exit_t(b, d, 1e-3, &LeavingRay::new(ce, dc));
            assert_eq!(got.to_bits(), want.to_bits(), "b {b:?}, d {d}, ce {ce}, dc {dc}");
            if want.is_finite() {
                finite += 1;
            } else {
                infinite += 1;
            }
        }
        assert!(finite > 1000 && infinite > 50, "{finite} finite, {infinite} infinite");
    }
}
