//! Exact Euclidean distance transforms and signed distance maps (thesis §3.6; docs/atlas.md
//! "Derived data").
//!
//! The squared distance to the nearest feature voxel, separable over the three axes, with the lower
//! envelope of parabolas of Felzenszwalb & Huttenlocher ("Distance Transforms of Sampled
//! Functions", Theory of Computing 8, 2012): for one line with samples f(q) at positions q·s,
//! D(p) = min_q ((p − q)·s)² + f(q). Anisotropic spacing enters through s. Exact up to f64
//! rounding. Lines are independent, so the parallel loops give the same bits on any thread count.

use glam::DVec3;
use rayon::prelude::*;

use crate::{Grid, Volume};

/// Larger than any squared distance inside a grid (2^28 voxels of up to 10 m).
const FAR: f64 = 1e30;

/// 1-D squared distance transform of `f` (≥ FAR = no feature) with sample spacing `s`, into `out`.
/// `v` and `z` are scratch buffers of at least `f.len()` and `f.len() + 1` entries.
fn edt_1d(f: &[f64], s: f64, out: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    edt_1d_arg(f, s, out, None, v, z)
}

/// As [`edt_1d`], also writing into `arg` the sample each position's minimum comes from.
fn edt_1d_arg(f: &[f64], s: f64, out: &mut [f64], mut arg: Option<&mut [usize]>, v: &mut [usize], z: &mut [f64]) {
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
        if let Some(a) = arg.as_deref_mut() {
            a[p] = r;
        }
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

/// No feature voxel.
pub const NO_FEATURE: u32 = u32::MAX;

/// The feature transform: for every voxel the linear index of the nearest voxel where `feature`
/// is true (Euclidean, anisotropic spacing), or [`NO_FEATURE`]. The same separable lower-envelope
/// passes as [`squared_edt`], each carrying the index of the winning sample along.
pub fn feature_transform(grid: &Grid, feature: &[bool]) -> Vec<u32> {
    assert_eq!(feature.len(), grid.len(), "mask and grid sizes differ");
    assert!(
        grid.len() < NO_FEATURE as usize,
        "grid too large for u32 feature indices"
    );
    let [nx, ny, nz] = grid.dims();
    let [sx, sy, sz] = grid.spacing_mm();
    let mut d: Vec<f32> = vec![0.0; grid.len()];
    let mut feat: Vec<u32> = vec![NO_FEATURE; grid.len()];
    let to64 = |x: f32| if x.is_finite() { x as f64 } else { FAR };
    let to32 = |x: f64| if x >= FAR { f32::INFINITY } else { x as f32 };
    type Scratch = (Vec<f64>, Vec<f64>, Vec<usize>, Vec<usize>, Vec<f64>, Vec<u32>);
    let scratch = |n: usize| -> Scratch {
        (
            vec![0.0; n],
            vec![0.0; n],
            vec![0; n],
            vec![0; n],
            vec![0.0; n + 1],
            vec![0; n],
        )
    };

    // Pass along i.
    d.par_chunks_mut(nx)
        .zip(feat.par_chunks_mut(nx))
        .zip(feature.par_chunks(nx))
        .enumerate()
        .for_each_init(
            || scratch(nx),
            |(f, o, arg, v, z, _), (row, ((drow, frow), mrow))| {
                for (x, &b) in f.iter_mut().zip(mrow) {
                    *x = if b { 0.0 } else { FAR };
                }
                edt_1d_arg(f, sx, o, Some(arg), v, z);
                for p in 0..nx {
                    drow[p] = to32(o[p]);
                    frow[p] = if o[p] >= FAR {
                        NO_FEATURE
                    } else {
                        (row * nx + arg[p]) as u32
                    };
                }
            },
        );
    // Pass along j, one k-slab per task.
    d.par_chunks_mut(nx * ny)
        .zip(feat.par_chunks_mut(nx * ny))
        .for_each_init(
            || scratch(ny),
            |(f, o, arg, v, z, fin), (slab, fslab)| {
                for i in 0..nx {
                    for j in 0..ny {
                        f[j] = to64(slab[i + nx * j]);
                        fin[j] = fslab[i + nx * j];
                    }
                    edt_1d_arg(f, sy, o, Some(arg), v, z);
                    for j in 0..ny {
                        slab[i + nx * j] = to32(o[j]);
                        fslab[i + nx * j] = if o[j] >= FAR { NO_FEATURE } else { fin[arg[j]] };
                    }
                }
            },
        );
    // Pass along k: per j-row into buffers, scattered back by k-slab.
    let columns: Vec<Vec<u32>> = (0..ny)
        .into_par_iter()
        .map_init(
            || scratch(nz),
            |(f, o, arg, v, z, fin), j| {
                let mut out = vec![NO_FEATURE; nx * nz];
                for i in 0..nx {
                    for k in 0..nz {
                        f[k] = to64(d[i + nx * (j + ny * k)]);
                        fin[k] = feat[i + nx * (j + ny * k)];
                    }
                    edt_1d_arg(f, sz, o, Some(arg), v, z);
                    for k in 0..nz {
                        out[i * nz + k] = if o[k] >= FAR { NO_FEATURE } else { fin[arg[k]] };
                    }
                }
                out
            },
        )
        .collect();
    feat.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
        for (j, col) in columns.iter().enumerate() {
            for i in 0..nx {
                slab[i + nx * j] = col[i * nz + k];
            }
        }
    });
    feat
}

/// Signed distance map (mm, positive inside) of the iso-surface {I = `iso_hu`} of `ct`, to
/// sub-voxel accuracy; `inside` is the binary mask of the region the surface bounds.
///
/// The exact map of a binary mask puts the surface half-way between voxel centres, so a surface at
/// a slant to the grid becomes a staircase of one-voxel ledges — which a palpating finger would
/// feel. Here every voxel on either side of the mask's boundary gets a surface point s_e (where
/// the CT crosses the iso value on its edges to the other side, by linear interpolation) and a
/// normal n_e (the CT's gradient direction); every voxel then takes, from its nearest boundary
/// voxel (feature transform), the distance to that tangent plane, |(x − s_e)·n_e|, combined with
/// the lateral offset beyond 1.5 voxels (so corners keep their point distance), with the sign of
/// the mask (in the spirit of the anti-aliased EDT of Gustavson & Strand, 2011). Exact for planes,
/// smooth along slanted surfaces.
pub fn subvoxel_signed_distance(ct: &Volume<f32>, inside: &[bool], iso_hu: f64) -> Volume<f32> {
    let grid = *ct.grid();
    let [nx, ny, nz] = grid.dims();
    let sp = grid.spacing_mm();
    let h = sp[0].min(sp[1]).min(sp[2]);
    let data = ct.data();
    let neighbours = |idx: usize| -> [Option<usize>; 6] {
        let [i, j, k] = grid.unlinear(idx);
        [
            (i > 0).then(|| idx - 1),
            (i + 1 < nx).then(|| idx + 1),
            (j > 0).then(|| idx - nx),
            (j + 1 < ny).then(|| idx + nx),
            (k > 0).then(|| idx - nx * ny),
            (k + 1 < nz).then(|| idx + nx * ny),
        ]
    };
    let boundary: Vec<bool> = (0..grid.len())
        .into_par_iter()
        .map(|idx| neighbours(idx).iter().flatten().any(|&n| inside[n] != inside[idx]))
        .collect();
    let nearest = feature_transform(&grid, &boundary);
    // Surface point and normal of a boundary voxel: where I crosses the iso value on the edges to
    // its neighbours of the other class (linear interpolation between two voxels that bracket the
    // iso value: robust however narrow the CT's edge), and the CT's gradient direction.
    let surface = |e: usize| -> (DVec3, DVec3) {
        let n = neighbours(e);
        let pe = grid.linear_to_world(e);
        let (mut sum, mut count) = (DVec3::ZERO, 0.0);
        for &m in n.iter().flatten() {
            if inside[m] != inside[e] {
                let (ie, im) = (data[e] as f64, data[m] as f64);
                let t = if (im - ie).abs() > 1e-9 {
                    ((iso_hu - ie) / (im - ie)).clamp(0.0, 1.0)
                } else {
                    0.5
                };
                sum += pe + (grid.linear_to_world(m) - pe) * t;
                count += 1.0;
            }
        }
        let s = sum / count;
        let diff = |a: Option<usize>, b: Option<usize>| -> f64 {
            let (lo, lw) = a.map_or((e, 0.0), |x| (x, 1.0));
            let (hi, hw) = b.map_or((e, 0.0), |x| (x, 1.0));
            if lw + hw == 0.0 {
                0.0
            } else {
                (data[hi] as f64 - data[lo] as f64) / (lw + hw)
            }
        };
        let g = grid.index_gradient_to_world(DVec3::new(diff(n[0], n[1]), diff(n[2], n[3]), diff(n[4], n[5])));
        // The normal points into the region; fall back to the edge direction for a flat CT.
        let inward = if inside[e] { pe - s } else { s - pe };
        let normal = if g.length() > 1e-9 {
            g.normalize()
        } else {
            inward.normalize_or_zero()
        };
        let normal = if normal.dot(inward) < 0.0 && inward.length() > 1e-9 {
            inward.normalize()
        } else {
            normal
        };
        (s, normal)
    };
    // Surface point and normal once per boundary voxel, found through a dense slot map.
    let mut slot = vec![NO_FEATURE; grid.len()];
    let mut planes = Vec::new();
    for (idx, &b) in boundary.iter().enumerate() {
        if b {
            slot[idx] = planes.len() as u32;
            planes.push(idx);
        }
    }
    let planes: Vec<(DVec3, DVec3)> = planes.into_par_iter().map(surface).collect();
    let d: Vec<f32> = (0..grid.len())
        .into_par_iter()
        .map(|idx| {
            let e = nearest[idx];
            let sign: f64 = if inside[idx] { 1.0 } else { -1.0 };
            if e == NO_FEATURE {
                return (sign * f64::INFINITY) as f32;
            }
            let (s, n) = planes[slot[e as usize] as usize];
            let x = grid.linear_to_world(idx);
            // Distance to the boundary voxel's tangent plane, plus the part of the lateral offset
            // beyond what sampling the surface at voxels explains (1.5 voxels): exact for planes
            // (smooth along slanted surfaces), the distance to the point itself around corners.
            let r = x - s;
            let along = r.dot(n).abs();
            let lateral = (r - n * r.dot(n)).length();
            let excess = (lateral - 1.5 * h).max(0.0);
            (sign * (along * along + excess * excess).sqrt()) as f32
        })
        .collect();
    Volume::new(grid, d).expect("same grid")
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

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]
        /// The feature transform points at a feature voxel at the exact nearest distance.
        #[test]
        fn feature_transform_finds_a_nearest_feature(
            dims in (1usize..8, 1usize..8, 1usize..8),
            spacing in (0.5f64..2.0, 0.5f64..2.0, 0.5f64..2.0),
            seed in any::<u64>(),
        ) {
            let grid = Grid::new([dims.0, dims.1, dims.2], Affine::from_spacing([spacing.0, spacing.1, spacing.2], DVec3::ZERO)).unwrap();
            let mut state = seed | 1;
            let mask: Vec<bool> = (0..grid.len()).map(|_| {
                state ^= state << 13; state ^= state >> 7; state ^= state << 17;
                state % 7 == 0
            }).collect();
            let ft = feature_transform(&grid, &mask);
            let d2 = brute(&grid, &mask);
            for idx in 0..grid.len() {
                if d2[idx].is_infinite() {
                    prop_assert_eq!(ft[idx], NO_FEATURE);
                } else {
                    let e = ft[idx] as usize;
                    prop_assert!(mask[e]);
                    let dist2 = grid.linear_to_world(idx).distance_squared(grid.linear_to_world(e));
                    prop_assert!((dist2 - d2[idx]).abs() <= 1e-9 * d2[idx].max(1.0));
                }
            }
        }
    }

    /// A plane at a slant to the grid: the sub-voxel map follows it within 0.15 voxel near the
    /// surface (where palpation happens) and 0.3 voxel farther out, where the binary map is off by
    /// up to half a voxel in steps.
    #[test]
    fn subvoxel_map_of_a_slanted_plane_has_no_staircase() {
        let grid = Grid::new([40, 8, 40], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        // Tissue (0 HU) below the plane x = 20 + 0.1 z, air (−1000) above, with a 2 mm ramp (the
        // partial volume and point-spread function of a CT).
        let ct: Vec<f32> = (0..grid.len())
            .map(|i| {
                let p = grid.linear_to_world(i);
                let sd = (20.0 + 0.1 * p.z - p.x) / (1.0f64 + 0.01).sqrt();
                (-1000.0 + 1000.0 * (sd / 2.0 + 0.5).clamp(0.0, 1.0)) as f32
            })
            .collect();
        let ct = Volume::new(grid, ct).unwrap();
        let inside: Vec<bool> = ct.data().iter().map(|&v| v > -500.0).collect();
        let sub = subvoxel_signed_distance(&ct, &inside, -500.0);
        let bin = signed_distance_map(&grid, &inside);
        let (mut worst_sub, mut worst_near, mut worst_bin) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..grid.len() {
            let p = grid.linear_to_world(i);
            if p.z < 3.0 || p.z > 36.0 || p.x < 6.0 || p.x > 34.0 {
                continue;
            }
            let truth = (20.0 + 0.1 * p.z - p.x) / (1.01f64).sqrt();
            let err = (sub.data()[i] as f64 - truth).abs();
            worst_sub = worst_sub.max(err);
            if truth.abs() < 5.0 {
                worst_near = worst_near.max(err);
            }
            worst_bin = worst_bin.max((bin.data()[i] as f64 - truth).abs());
        }
        assert!(
            worst_near < 0.15,
            "sub-voxel map off by {worst_near} within 5 mm of the surface"
        );
        assert!(worst_sub < 0.3, "sub-voxel map off by {worst_sub}");
        assert!(worst_bin > 0.4, "binary map off by only {worst_bin}");
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
