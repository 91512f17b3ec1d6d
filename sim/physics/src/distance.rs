//! Exact Euclidean distance transforms and signed distance maps (thesis §3.6, ALGORITHMS.md §3).
//!
//! The squared distance to the nearest feature voxel, separable over the three axes, with the lower
//! envelope of parabolas of Felzenszwalb & Huttenlocher ("Distance Transforms of Sampled
//! Functions", Theory of Computing 8, 2012): for one line with samples f(q) at positions q·s,
//! D(p) = min_q ((p − q)·s)² + f(q). Anisotropic spacing enters through s. Exact up to f64
//! rounding. Lines are independent, so the parallel loops give the same bits on any thread count.

use rayon::prelude::*;

use crate::{Grid, Volume};

/// Larger than any squared distance inside a grid (2^28 voxels of up to 10 m).
const FAR: f64 = 1e30;

/// 1-D squared distance transform of `f` (≥ FAR = no feature) with sample spacing `s`, into `out`.
/// `v` and `z` are scratch buffers of at least `f.len()` and `f.len() + 1` entries.
fn edt_1d(f: &[f64], s: f64, out: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    // Lower envelope of the parabolas rooted at finite samples only (FAR ones never win).
    let mut k: isize = -1;
    for q in 0..n {
        if f[q] >= FAR {
            continue;
        }
        let pq = q as f64 * s;
        loop {
            if k < 0 {
                k = 0;
                v[0] = q;
                z[0] = f64::NEG_INFINITY;
                z[1] = f64::INFINITY;
                break;
            }
            let r = v[k as usize];
            let pr = r as f64 * s;
            // Intersection of the parabolas rooted at r and q.
            let x = ((f[q] + pq * pq) - (f[r] + pr * pr)) / (2.0 * (pq - pr));
            if x <= z[k as usize] {
                k -= 1;
                continue;
            }
            k += 1;
            v[k as usize] = q;
            z[k as usize] = x;
            z[k as usize + 1] = f64::INFINITY;
            break;
        }
    }
    if k < 0 {
        out.iter_mut().for_each(|o| *o = FAR);
        return;
    }
    let mut j = 0usize;
    for (p, o) in out.iter_mut().enumerate() {
        let pp = p as f64 * s;
        while z[j + 1] < pp {
            j += 1;
        }
        let r = v[j];
        let d = pp - r as f64 * s;
        *o = d * d + f[r];
    }
}

/// Squared Euclidean distance (mm²) from every voxel to the nearest voxel where `feature` is true;
/// 0 on feature voxels, `f32::INFINITY` everywhere if there is no feature voxel. Lines are
/// computed in f64 and stored in f32 (the maps are f32), halving the memory traffic.
pub fn squared_edt(grid: &Grid, feature: &[bool]) -> Vec<f32> {
    assert_eq!(feature.len(), grid.len(), "mask and grid sizes differ");
    let [nx, ny, nz] = grid.dims();
    let [sx, sy, sz] = grid.spacing_mm();
    let mut d: Vec<f32> = vec![0.0; grid.len()];
    let to64 = |x: f32| if x.is_finite() { x as f64 } else { FAR };
    let to32 = |x: f64| if x >= FAR { f32::INFINITY } else { x as f32 };

    // Pass along i: rows are contiguous.
    d.par_chunks_mut(nx).zip(feature.par_chunks(nx)).for_each_init(
        || (vec![0.0; nx], vec![0.0; nx], vec![0usize; nx], vec![0.0; nx + 1]),
        |(f, o, v, z), (row, feat)| {
            for (x, &b) in f.iter_mut().zip(feat) {
                *x = if b { 0.0 } else { FAR };
            }
            edt_1d(f, sx, o, v, z);
            for (r, &x) in row.iter_mut().zip(o.iter()) {
                *r = to32(x);
            }
        },
    );
    // Pass along j: one k-slab per task, columns gathered into scratch.
    d.par_chunks_mut(nx * ny).for_each_init(
        || (vec![0.0; ny], vec![0.0; ny], vec![0usize; ny], vec![0.0; ny + 1]),
        |(f, o, v, z), slab| {
            for i in 0..nx {
                for j in 0..ny {
                    f[j] = to64(slab[i + nx * j]);
                }
                edt_1d(f, sy, o, v, z);
                for j in 0..ny {
                    slab[i + nx * j] = to32(o[j]);
                }
            }
        },
    );
    // Pass along k: one j-row of columns per task into a separate buffer, then scattered back in
    // parallel over k-slabs.
    let columns: Vec<Vec<f32>> = (0..ny)
        .into_par_iter()
        .map_init(
            || (vec![0.0; nz], vec![0.0; nz], vec![0usize; nz], vec![0.0; nz + 1]),
            |(f, o, v, z), j| {
                let mut out = vec![0.0f32; nx * nz];
                for i in 0..nx {
                    for k in 0..nz {
                        f[k] = to64(d[i + nx * (j + ny * k)]);
                    }
                    edt_1d(f, sz, o, v, z);
                    for k in 0..nz {
                        out[i * nz + k] = to32(o[k]);
                    }
                }
                out
            },
        )
        .collect();
    d.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
        for (j, col) in columns.iter().enumerate() {
            for i in 0..nx {
                slab[i + nx * j] = col[i * nz + k];
            }
        }
    });
    d
}

/// Signed Euclidean distance map (mm), positive inside the mask (§3.6): inside voxels hold the
/// distance to the nearest outside voxel centre, outside voxels minus the distance to the nearest
/// inside voxel centre, so the surface lies where trilinear interpolation crosses zero. An empty
/// (or full) mask gives −∞ (or +∞) everywhere.
pub fn signed_distance_map(grid: &Grid, inside: &[bool]) -> Volume<f32> {
    let outside: Vec<bool> = inside.iter().map(|&b| !b).collect();
    let (to_outside, to_inside) = rayon::join(|| squared_edt(grid, &outside), || squared_edt(grid, inside));
    let data = inside
        .par_iter()
        .zip(to_outside.par_iter().zip(to_inside.par_iter()))
        .map(|(&ins, (&a, &b))| if ins { a.sqrt() } else { -b.sqrt() })
        .collect();
    Volume::new(*grid, data).expect("same grid")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Affine;
    use glam::DVec3;
    use proptest::prelude::*;

    fn brute(grid: &Grid, feature: &[bool]) -> Vec<f64> {
        // Same summation order as the separable passes: ((x² + y²) + z²).
        let [nx, ny, nz] = grid.dims();
        let [sx, sy, sz] = grid.spacing_mm();
        let feats: Vec<[usize; 3]> = (0..grid.len())
            .filter(|&i| feature[i])
            .map(|i| grid.unlinear(i))
            .collect();
        let mut out = vec![f64::INFINITY; grid.len()];
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let mut best = f64::INFINITY;
                    for f in &feats {
                        let dx = (i as f64 - f[0] as f64) * sx;
                        let dy = (j as f64 - f[1] as f64) * sy;
                        let dz = (k as f64 - f[2] as f64) * sz;
                        best = best.min(dx * dx + dy * dy + dz * dz);
                    }
                    out[grid.linear(i, j, k)] = best;
                }
            }
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// The separable transform equals brute force on random masks and anisotropic spacings.
        #[test]
        fn edt_equals_brute_force(
            dims in (1usize..9, 1usize..9, 1usize..9),
            spacing in (0.3f64..3.0, 0.3f64..3.0, 0.3f64..3.0),
            density in 0.0f64..0.5,
            seed in any::<u64>(),
        ) {
            let grid = Grid::new([dims.0, dims.1, dims.2], Affine::from_spacing([spacing.0, spacing.1, spacing.2], DVec3::ZERO)).unwrap();
            let mut state = seed | 1;
            let mask: Vec<bool> = (0..grid.len()).map(|_| {
                state ^= state << 13; state ^= state >> 7; state ^= state << 17;
                ((state >> 11) as f64 / (1u64 << 53) as f64) < density
            }).collect();
            let fast = squared_edt(&grid, &mask);
            let slow = brute(&grid, &mask);
            for (a, b) in fast.iter().zip(&slow) {
                if b.is_infinite() {
                    prop_assert!(a.is_infinite());
                } else {
                    // Exact up to the final rounding to f32.
                    prop_assert!((*a as f64 - b).abs() <= 1e-6 * b.max(1.0), "fast {} vs brute {}", a, b);
                }
            }
        }
    }

    #[test]
    fn signed_map_of_a_ball() {
        let grid = Grid::new([21, 21, 21], Affine::from_spacing([1.0; 3], DVec3::splat(-10.0))).unwrap();
        let inside: Vec<bool> = (0..grid.len())
            .map(|i| {
                let [a, b, c] = grid.unlinear(i);
                grid.voxel_to_world(a, b, c).length() <= 6.0
            })
            .collect();
        let d = signed_distance_map(&grid, &inside);
        // Centre: ~6–7 mm from the nearest outside voxel centre; far corner: outside.
        let c = d.get(10, 10, 10);
        assert!((6.0..=7.0).contains(&c), "{c}");
        assert!(d.get(0, 0, 0) < -10.0);
        // The zero crossing along +x lies between the last inside (6) and first outside (7) voxel.
        let z = d.sample(DVec3::new(6.5, 0.0, 0.0), 0.0);
        assert!(z.abs() < 1e-6, "{z}");
    }
}
