//! The line integral of a voxel grid along a ray, by Joseph's method (Joseph 1982; docs/xray.md
//! "One ray"): the thesis' a = Σ μ(xᵢ)·Δx (§3.3) with one sample where the ray crosses each
//! voxel plane of its dominant axis, bilinear in that plane.
//!
//! In index space the ray is c(t) = c₀ + t·ċ, t in mm along the world ray. With a the axis of
//! the largest |ċₐ|, plane k (cₐ = k) is crossed at tₖ = (k − c₀ₐ)/ċₐ, and successive planes
//! are Δt = 1/|ċₐ| mm apart, so Σₖ bilinear(c(tₖ))·Δt integrates the grid's trilinear field
//! along the ray to second order with 4 voxel reads per plane (a trilinear sample at a fixed
//! step would need 8). Voxels outside the grid are 0. Planes are visited in increasing t; the
//! GPU shader (`xray.wgsl`) runs the same loop.

use stylet_physics::glam::Vec3;

/// A ray in a grid's index space: c(t) = `start` + t·`dir` for t ∈ [0, `t_max_mm`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IndexRay {
    pub start: Vec3,
    /// Index units per mm of the world ray.
    pub dir: Vec3,
    pub t_max_mm: f32,
}

/// The voxel planes of a ray's dominant axis `a` it crosses while its in-plane coordinates (axes
/// `u`, `v`) can touch the grid (−1 < c < n), clamped to 0 … n_a − 1; `None` when there are none.
struct Planes {
    a: usize,
    u: usize,
    v: usize,
    k_first: i64,
    k_last: i64,
}

fn planes(dims: [u32; 3], ray: &IndexRay) -> Option<Planes> {
    let d = ray.dir.to_array();
    let c0 = ray.start.to_array();
    let a = dominant_axis(d);
    let (u, v) = match a {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    if d[a].abs() < 1e-12 {
        return None;
    }
    let n = dims.map(|x| x as f32);
    // The t interval in which the in-plane coordinates can touch the grid: c ∈ (−1, n).
    let (mut t_lo, mut t_hi) = (0.0f32, ray.t_max_mm);
    for b in [u, v] {
        if d[b] == 0.0 {
            if c0[b] <= -1.0 || c0[b] >= n[b] {
                return None;
            }
        } else {
            let (ta, tb) = ((-1.0 - c0[b]) / d[b], (n[b] - c0[b]) / d[b]);
            t_lo = t_lo.max(ta.min(tb));
            t_hi = t_hi.min(ta.max(tb));
        }
    }
    if t_lo > t_hi {
        return None;
    }
    // Planes crossed inside [t_lo, t_hi], clamped to the grid's 0 … n − 1.
    let (ca, cb) = (c0[a] + t_lo * d[a], c0[a] + t_hi * d[a]);
    let k_first = ca.min(cb).ceil().max(0.0);
    let k_last = ca.max(cb).floor().min(n[a] - 1.0);
    if k_first > k_last {
        return None;
    }
    let (k_first, k_last) = (k_first as i64, k_last as i64);
    Some(Planes {
        a,
        u,
        v,
        k_first,
        k_last,
    })
}

/// ∫ v(c(t)) dt over the ray for the grid of `dims` whose voxel (i, j, k) holds
/// `voxel(i + dims₀·(j + dims₁·k))`, v its trilinear interpolation, zero outside the grid.
#[inline]
pub fn integrate(dims: [u32; 3], ray: &IndexRay, voxel: impl Fn(usize) -> f32) -> f32 {
    let Some(Planes {
        a,
        u,
        v,
        k_first,
        k_last,
    }) = planes(dims, ray)
    else {
        return 0.0;
    };
    let d = ray.dir.to_array();
    let c0 = ray.start.to_array();
    let stride = [1usize, dims[0] as usize, dims[0] as usize * dims[1] as usize];
    let (nu, nv) = (dims[u] as i64, dims[v] as i64);
    let inv = 1.0 / d[a];
    let mut sum = 0.0f32;
    let count = k_last - k_first + 1;
    for step in 0..count {
        let k = if d[a] > 0.0 { k_first + step } else { k_last - step };
        let t = (k as f32 - c0[a]) * inv;
        let (pu, pv) = (c0[u] + t * d[u], c0[v] + t * d[v]);
        let (fu0, fv0) = (floor_above_minus_one(pu), floor_above_minus_one(pv));
        let (fu, fv) = (pu - fu0, pv - fv0);
        let (iu, iv) = (fu0 as i64, fv0 as i64);
        let base = k as usize * stride[a];
        let w = [(1.0 - fu) * (1.0 - fv), fu * (1.0 - fv), (1.0 - fu) * fv, fu * fv];
        if iu >= 0 && iv >= 0 && iu + 1 < nu && iv + 1 < nv {
            let b = base + iu as usize * stride[u] + iv as usize * stride[v];
            sum += w[0] * voxel(b)
                + w[1] * voxel(b + stride[u])
                + w[2] * voxel(b + stride[v])
                + w[3] * voxel(b + stride[u] + stride[v]);
        } else {
            let mut s = 0.0f32;
            for (q, (du, dv)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
                let (cu, cv) = (iu + du, iv + dv);
                if (0..nu).contains(&cu) && (0..nv).contains(&cv) {
                    s += w[q] * voxel(base + cu as usize * stride[u] + cv as usize * stride[v]);
                }
            }
            sum += s;
        }
    }
    sum * inv.abs()
}

/// ∫ μ(X(t)) dt along a world ray of a breathing patient: the planes of [`integrate`] (one
/// sample where the straight world ray crosses each plane of its dominant axis, Δt apart), each
/// sample read by `mu` at the CT index of its reference point X = x − u(X, t), found by one
/// fixed-point step from the previous sample's X (eqs. 5.4.1–5.4.2). The planes are those of the
/// straight ray through the grid: the synthetic motion is zero outside the body, so the grid's
/// own extent bounds what moves.
pub fn integrate_warped(
    ray: &IndexRay,
    origin_mm: Vec3,
    dir: Vec3,
    dims: [u32; 3],
    u: &(dyn Fn(stylet_physics::glam::DVec3) -> stylet_physics::glam::DVec3 + Send + Sync),
    map: &crate::volume::IndexMap,
    mu: impl Fn(Vec3) -> f32,
) -> f32 {
    let Some(Planes { a, k_first, k_last, .. }) = planes(dims, ray) else {
        return 0.0;
    };
    let d = ray.dir.to_array();
    let c0 = ray.start.to_array();
    let inv = 1.0 / d[a];
    let mut sum = 0.0f32;
    let mut warp = crate::warp::Warp::new(u);
    for step in 0..(k_last - k_first + 1).max(0) {
        let k = if d[a] > 0.0 { k_first + step } else { k_last - step };
        let t = (k as f32 - c0[a]) * inv;
        sum += mu(map.point(warp.reference_of(origin_mm + dir * t)));
    }
    sum * inv.abs()
}

/// The trilinear field of a grid of `dims` voxels at index `c`, zero outside the voxels (so it
/// fades to zero over the last voxel, as [`integrate`]'s bilinear planes do): what
/// [`integrate_warped`] reads at a reference point. `voxel(i + dims₀·(j + dims₁·k))`.
#[inline]
pub fn trilinear_zero_outside(dims: [u32; 3], c: Vec3, voxel: impl Fn(usize) -> f32) -> f32 {
    let c = c.to_array();
    if (0..3).any(|a| !(c[a] > -1.0 && c[a] < dims[a] as f32)) {
        return 0.0;
    }
    let base = c.map(floor_above_minus_one);
    let f = [c[0] - base[0], c[1] - base[1], c[2] - base[2]];
    let mut sum = 0.0f32;
    for corner in 0..8usize {
        let o = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
        let idx = [0, 1, 2].map(|a| base[a] as i64 + o[a] as i64);
        if (0..3).any(|a| idx[a] < 0 || idx[a] >= dims[a] as i64) {
            continue;
        }
        let w: f32 = (0..3).map(|a| if o[a] == 1 { f[a] } else { 1.0 - f[a] }).product();
        sum += w * voxel(idx[0] as usize + dims[0] as usize * (idx[1] as usize + dims[1] as usize * idx[2] as usize));
    }
    sum
}

/// ⌊x⌋ for x > −1 by truncation: (x + 1) truncated toward zero, minus 1. The in-plane
/// coordinates the loop visits lie in (−1, n), and on x86-64 without SSE4.1 `f32::floor` is a
/// library call (it halved the frame rate). A coordinate rounding to just below −1 gives −1
/// instead of −2: its weight on the (absent) voxel −1 is then a hair below zero, and the voxel 0
/// weight a hair above — both vanish against the f32 sum. The shader uses the same formula.
#[inline]
pub fn floor_above_minus_one(x: f32) -> f32 {
    ((x + 1.0) as i32) as f32 - 1.0
}

/// The axis along which the ray moves fastest in index space (ties: the lower axis).
#[inline]
pub fn dominant_axis(d: [f32; 3]) -> usize {
    let m = d.map(f32::abs);
    if m[0] >= m[1] && m[0] >= m[2] {
        0
    } else if m[1] >= m[2] {
        1
    } else {
        2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A uniform grid integrates to value × the length of the ray inside the interpolated box.
    #[test]
    fn a_uniform_grid_gives_value_times_path_length() {
        let dims = [20, 30, 10];
        // Along x through the middle: planes 0 … 19 each 1 mm apart.
        let ray = IndexRay {
            start: Vec3::new(-5.0, 14.5, 4.5),
            dir: Vec3::X,
            t_max_mm: 100.0,
        };
        assert_eq!(integrate(dims, &ray, |_| 2.0), 40.0);
        // Diagonal in x–y, 0.5 index/mm on x: planes are 2 mm apart.
        let ray = IndexRay {
            start: Vec3::new(0.0, 3.0, 4.0),
            dir: Vec3::new(0.5, 0.25, 0.0),
            t_max_mm: 1000.0,
        };
        assert!((integrate(dims, &ray, |_| 1.0) - 40.0).abs() < 1e-4);
        // Stopping half way counts the planes before the stop.
        let ray = IndexRay {
            start: Vec3::new(0.0, 3.0, 4.0),
            dir: Vec3::X,
            t_max_mm: 9.5,
        };
        assert_eq!(integrate(dims, &ray, |_| 1.0), 10.0);
    }

    #[test]
    fn rays_that_miss_or_run_backwards_agree() {
        let dims = [8, 8, 8];
        let miss = IndexRay {
            start: Vec3::new(-5.0, 20.0, 3.0),
            dir: Vec3::X,
            t_max_mm: 100.0,
        };
        assert_eq!(integrate(dims, &miss, |_| 1.0), 0.0);
        let value = |i: usize| (i % 7) as f32 + 0.5 * (i / 64) as f32;
        let fwd = IndexRay {
            start: Vec3::new(-3.0, 1.3, 2.7),
            dir: Vec3::new(1.0, 0.2, 0.1),
            t_max_mm: 20.0,
        };
        let end = fwd.start + fwd.dir * fwd.t_max_mm;
        let back = IndexRay {
            start: end,
            dir: -fwd.dir,
            t_max_mm: fwd.t_max_mm,
        };
        let (f, b) = (integrate(dims, &fwd, value), integrate(dims, &back, value));
        assert!((f - b).abs() < 1e-4 * f.abs(), "{f} vs {b}");
    }

    /// Half a voxel outside the grid the bilinear weights fade to zero.
    #[test]
    fn the_grid_edge_fades_over_one_voxel() {
        let dims = [4, 4, 4];
        let along = |y: f32| IndexRay {
            start: Vec3::new(-1.0, y, 1.0),
            dir: Vec3::X,
            t_max_mm: 10.0,
        };
        assert_eq!(integrate(dims, &along(3.0), |_| 1.0), 4.0);
        assert_eq!(integrate(dims, &along(3.5), |_| 1.0), 2.0);
        assert_eq!(integrate(dims, &along(4.0), |_| 1.0), 0.0);
        assert_eq!(integrate(dims, &along(-0.25), |_| 1.0), 3.0);
    }
}
