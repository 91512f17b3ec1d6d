//! Ω_J: the local cubic lattice of the deformation (thesis §4.2.1, Fig. 4.2), axis-aligned in
//! world space with isotropic spacing h, n nodes per axis. Node (i, j, k) sits at
//! origin + h·(i, j, k); node index i + n·(j + n·k).

use glam::DVec3;

/// Geometry of one lattice (one multigrid level).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lattice {
    /// Nodes per axis.
    pub n: usize,
    /// Node spacing h (mm).
    pub h_mm: f64,
    /// World position of node (0, 0, 0) (mm).
    pub origin_mm: DVec3,
}

impl Lattice {
    pub fn len(&self) -> usize {
        self.n * self.n * self.n
    }
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.n * (j + self.n * k)
    }
    #[inline]
    pub fn ijk(&self, idx: usize) -> [usize; 3] {
        let n = self.n;
        [idx % n, (idx / n) % n, idx / (n * n)]
    }
    #[inline]
    pub fn position(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.origin_mm + self.h_mm * DVec3::new(i as f64, j as f64, k as f64)
    }
    /// Nodes on the faces of the cube carry the border condition u = 0 (eq. 4.2.5).
    #[inline]
    pub fn is_border(&self, i: usize, j: usize, k: usize) -> bool {
        let m = self.n - 1;
        i == 0 || j == 0 || k == 0 || i == m || j == m || k == m
    }
    /// World box [first node, last node] (mm).
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let far = self.h_mm * (self.n - 1) as f64;
        (self.origin_mm, self.origin_mm + DVec3::splat(far))
    }
    pub fn centre(&self) -> DVec3 {
        self.origin_mm + DVec3::splat(0.5 * self.h_mm * (self.n - 1) as f64)
    }
    /// The next coarser level: every second node (coarse node c is fine node 2c; with an odd
    /// node count the borders coincide).
    pub fn coarse(&self) -> Lattice {
        Lattice {
            n: (self.n - 1) / 2 + 1,
            h_mm: 2.0 * self.h_mm,
            origin_mm: self.origin_mm,
        }
    }
    /// The node nearest to `x`, if `x` lies within half a spacing of the lattice.
    pub fn nearest(&self, x: DVec3) -> Option<[usize; 3]> {
        let c = (x - self.origin_mm) / self.h_mm;
        let mut out = [0usize; 3];
        for a in 0..3 {
            let r = libm::round(c[a]);
            if !(r >= 0.0 && r <= (self.n - 1) as f64) {
                return None;
            }
            out[a] = r as usize;
        }
        Some(out)
    }

    /// Trilinear interpolation of a nodal field at `x`; zero outside the lattice (u = 0 beyond
    /// ∂Ω_J, eq. 4.2.5).
    pub fn sample(&self, field: &[DVec3], x: DVec3) -> DVec3 {
        self.sample_with(|i| field[i], x)
    }

    /// [`Lattice::sample`] of a field given node by node.
    #[inline]
    pub fn sample_with(&self, field: impl Fn(usize) -> DVec3, x: DVec3) -> DVec3 {
        let c = (x - self.origin_mm) / self.h_mm;
        let m = (self.n - 1) as f64;
        if !(c.x >= 0.0 && c.y >= 0.0 && c.z >= 0.0 && c.x <= m && c.y <= m && c.z <= m) {
            return DVec3::ZERO;
        }
        let last = self.n - 2;
        let (i, j, k) = (
            (c.x as usize).min(last),
            (c.y as usize).min(last),
            (c.z as usize).min(last),
        );
        let (fx, fy, fz) = (c.x - i as f64, c.y - j as f64, c.z - k as f64);
        let v = |di: usize, dj: usize, dk: usize| field(self.index(i + di, j + dj, k + dk));
        let x00 = v(0, 0, 0) * (1.0 - fx) + v(1, 0, 0) * fx;
        let x10 = v(0, 1, 0) * (1.0 - fx) + v(1, 1, 0) * fx;
        let x01 = v(0, 0, 1) * (1.0 - fx) + v(1, 0, 1) * fx;
        let x11 = v(0, 1, 1) * (1.0 - fx) + v(1, 1, 1) * fx;
        let y0 = x00 * (1.0 - fy) + x10 * fy;
        let y1 = x01 * (1.0 - fy) + x11 * fy;
        y0 * (1.0 - fz) + y1 * fz
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indices_positions_and_sampling_agree() {
        let l = Lattice {
            n: 8,
            h_mm: 2.0,
            origin_mm: DVec3::new(-3.0, 1.0, 5.0),
        };
        let idx = l.index(3, 4, 5);
        assert_eq!(l.ijk(idx), [3, 4, 5]);
        assert_eq!(l.nearest(l.position(3, 4, 5) + DVec3::splat(0.9)), Some([3, 4, 5]));
        assert_eq!(l.nearest(l.origin_mm - DVec3::splat(1.1)), None);
        // A linear field is reproduced exactly by trilinear sampling.
        let f: Vec<DVec3> = (0..l.len())
            .map(|i| {
                let [a, b, c] = l.ijk(i);
                let p = l.position(a, b, c);
                DVec3::new(p.x + 2.0 * p.y, -p.z, 0.5 * p.x)
            })
            .collect();
        let x = DVec3::new(2.3, 7.7, 13.1);
        let s = l.sample(&f, x);
        assert!((s - DVec3::new(x.x + 2.0 * x.y, -x.z, 0.5 * x.x)).length() < 1e-12);
        assert_eq!(l.sample(&f, DVec3::splat(-100.0)), DVec3::ZERO);
        assert_eq!(l.coarse().n, 4);
        assert_eq!(Lattice { n: 65, ..l }.coarse().n, 33);
    }
}
