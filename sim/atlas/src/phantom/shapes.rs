//! Signed-distance primitives for the phantom (mm, negative inside).
//!
//! Distances only need to be accurate near the surface: they drive partial-volume blending over
//! about one voxel. Transcendentals go through `libm` so the phantom is bit-identical on every
//! platform (its content hash ends up in session headers).

use stylet_physics::glam::DVec3;

/// Axis-aligned box in world mm, used to visit only the voxels a part can touch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

impl Aabb {
    pub fn new(min: DVec3, max: DVec3) -> Self {
        Aabb { min, max }
    }
    pub fn around(c: DVec3, r: DVec3) -> Self {
        Aabb { min: c - r, max: c + r }
    }
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }
    pub fn grow(&self, by: f64) -> Aabb {
        Aabb {
            min: self.min - DVec3::splat(by),
            max: self.max + DVec3::splat(by),
        }
    }
    pub fn everything() -> Aabb {
        Aabb {
            min: DVec3::splat(-1e9),
            max: DVec3::splat(1e9),
        }
    }
}

/// Ellipsoid (Quílez's first-order distance estimate: exact on the surface, good close to it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipsoid {
    pub center: DVec3,
    pub radii: DVec3,
}

impl Ellipsoid {
    pub fn new(center: [f64; 3], radii: [f64; 3]) -> Self {
        Ellipsoid {
            center: DVec3::from_array(center),
            radii: DVec3::from_array(radii),
        }
    }

    pub fn sdf(&self, p: DVec3) -> f64 {
        let q = p - self.center;
        let k0 = (q / self.radii).length();
        let k1 = (q / (self.radii * self.radii)).length();
        if k1 == 0.0 {
            return -self.radii.min_element();
        }
        k0 * (k0 - 1.0) / k1
    }

    pub fn aabb(&self) -> Aabb {
        Aabb::around(self.center, self.radii)
    }
}

/// A tapered tube around the segment a→b with radius ra at a and rb at b (rounded ends).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Capsule {
    pub a: DVec3,
    pub b: DVec3,
    pub ra: f64,
    pub rb: f64,
}

impl Capsule {
    pub fn new(a: DVec3, b: DVec3, ra: f64, rb: f64) -> Self {
        Capsule { a, b, ra, rb }
    }

    /// Distance to the axis minus the local radius, and the axis parameter t ∈ [0, 1].
    pub fn sdf_t(&self, p: DVec3) -> (f64, f64) {
        let ab = self.b - self.a;
        let len2 = ab.length_squared();
        let t = if len2 > 0.0 {
            ((p - self.a).dot(ab) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let r = self.ra + t * (self.rb - self.ra);
        ((p - (self.a + ab * t)).length() - r, t)
    }

    pub fn sdf(&self, p: DVec3) -> f64 {
        self.sdf_t(p).0
    }

    pub fn aabb(&self) -> Aabb {
        let r = self.ra.max(self.rb);
        Aabb::new(self.a.min(self.b), self.a.max(self.b)).grow(r)
    }
}

/// A tube along a polyline, radius interpolated linearly along the vertices.
#[derive(Debug, Clone, PartialEq)]
pub struct Tube {
    pub segments: Vec<Capsule>,
}

impl Tube {
    pub fn new(points: &[[f64; 3]], radii: &[f64]) -> Self {
        assert_eq!(points.len(), radii.len());
        let segments = points
            .windows(2)
            .zip(radii.windows(2))
            .map(|(p, r)| Capsule::new(DVec3::from_array(p[0]), DVec3::from_array(p[1]), r[0], r[1]))
            .collect();
        Tube { segments }
    }

    pub fn sdf(&self, p: DVec3) -> f64 {
        self.segments.iter().map(|c| c.sdf(p)).fold(f64::INFINITY, f64::min)
    }

    pub fn aabb(&self) -> Aabb {
        self.segments
            .iter()
            .map(Capsule::aabb)
            .reduce(|a, b| a.union(&b))
            .expect("a tube has a segment")
    }
}

/// Smoothstep from 0 at `e0` to 1 at `e1`.
pub fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ellipsoid_distance_is_exact_on_the_axes_near_the_surface() {
        let e = Ellipsoid::new([0.0; 3], [10.0, 20.0, 30.0]);
        assert!((e.sdf(DVec3::new(11.0, 0.0, 0.0)) - 1.0).abs() < 0.1);
        assert!((e.sdf(DVec3::new(0.0, 19.0, 0.0)) + 1.0).abs() < 0.1);
        assert!(e.sdf(DVec3::ZERO) < 0.0);
    }

    #[test]
    fn capsule_tapers() {
        let c = Capsule::new(DVec3::ZERO, DVec3::new(10.0, 0.0, 0.0), 2.0, 1.0);
        assert!((c.sdf(DVec3::new(0.0, 3.0, 0.0)) - 1.0).abs() < 1e-12);
        assert!((c.sdf(DVec3::new(10.0, 3.0, 0.0)) - 2.0).abs() < 1e-12);
    }
}
