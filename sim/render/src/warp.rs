//! The breathing warp along one ray, scan line or beam (thesis eqs. 5.4.1–5.4.2; docs/breathing.md
//! "Views"): each sample's reference position X is found by one fixed-point step continued from
//! the previous sample, X⁺ = x⁺ − u(X + d, t) with d = x⁺ − x, so a march pays one evaluation of
//! u per sample. The ray caster, the radiograph and the ultrasound use it; `motion.wgsl` is the
//! GPU's copy.

use stylet_physics::glam::{DVec3, Vec3};

/// A march's fixed point.
pub struct Warp<'a> {
    /// u(·, t) at the frame's moment.
    u: &'a (dyn Fn(DVec3) -> DVec3 + Send + Sync),
    prev: Option<(Vec3, Vec3)>,
}

impl<'a> Warp<'a> {
    pub fn new(u: &'a (dyn Fn(DVec3) -> DVec3 + Send + Sync)) -> Warp<'a> {
        Warp { u, prev: None }
    }

    /// Reference position X of world sample `x`: continues the fixed point from the previous
    /// sample, or starts it at X = x.
    #[inline]
    pub fn reference_of(&mut self, x: Vec3) -> Vec3 {
        let (x_prev, big_x_prev) = self.prev.unwrap_or((x, x));
        let d = x - x_prev;
        let u = (self.u)((big_x_prev + d).as_dvec3());
        let big_x = (x.as_dvec3() - u).as_vec3();
        self.prev = Some((x, big_x));
        big_x
    }

    /// The next sample starts the fixed point afresh (X = x).
    pub fn restart(&mut self) {
        self.prev = None;
    }
}
