//! Palpation finger and ultrasound probe: multi-proxy haptics on the skin and bone distance maps
//! (thesis §3.6, ALGORITHMS.md §3).
//!
//! Contact nodes x_i = x + Q x_i⁰ on the tool. For a node inside the skin (D_skin > 0):
//! - skin penalty (eqs. 3.6.1–3.6.3): f_skin = f_s(D_skin) v_s, v_s = −∇D_skin/‖·‖, with the cubic
//!   f_s(x) = 1.78e−2 x³ + 3.82e−3 x² + 2.28e−4 x (x in mm, N) fitted to femoral palpation data;
//! - bone penalty (eqs. 3.6.4–3.6.7): f_bone = 20 (x/5)⁻³ at x = −D_bone along v_b = −∇D_bone/‖·‖,
//!   turned towards v_s by d = v_b − 4 v_s (v_b·v_s) when they differ by more than 90°;
//! - stick–slip friction proxy (eqs. 3.6.8–3.6.11, Hayward & Armstrong 2000): the surface point
//!   s_i = x_i − D_skin v_s drags a proxy p_i with α(z) = (1/z_max) z⁸ / (z_stick⁸ + z⁸),
//!   z_stick = z_max − 1, z_max = c_fric |f_n·v_s| + 1 while the node presses on the skin (the
//!   digest's reading of the garbled condition); f_slide = k_fric (p_i − s_i).
//!
//! Device output (eqs. 3.6.12–3.6.14): the means of f_i = f_skin + f_slide + f_bone and of
//! t_i = (x_i − x) × f_i over the nodes in contact.

pub mod patterns;

use glam::{DMat3, DQuat, DVec3};

use crate::PunctureAtlas;
use crate::gradient::GradientSampler;
pub use patterns::ContactPattern;

/// Friction constants of eqs. 3.6.8–3.6.11.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactFriction {
    pub c_fric: f64,
    /// N/mm.
    pub k_fric: f64,
}

impl ContactFriction {
    /// A bare finger on skin.
    pub const FINGER: ContactFriction = ContactFriction {
        c_fric: 2.0,
        k_fric: 0.4,
    };
    /// An ultrasound probe on gel.
    pub const PROBE_WITH_GEL: ContactFriction = ContactFriction {
        c_fric: 0.4,
        k_fric: 0.3,
    };
}

/// Eq. 3.6.3: skin force magnitude for an indentation of `x` mm.
#[inline]
pub fn skin_force_n(x: f64) -> f64 {
    if x > 0.0 {
        1.78e-2 * x * x * x + 3.82e-3 * x * x + 2.28e-4 * x
    } else {
        0.0
    }
}

/// Eq. 3.6.6: bone force magnitude at a distance of `x` mm outside bone.
#[inline]
pub fn bone_force_n(x: f64) -> f64 {
    if x > 0.0 {
        let r = 5.0 / x;
        20.0 * r * r * r
    } else {
        0.0
    }
}

/// The state of one contact node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactNode {
    /// World (reference-space) position x_i.
    pub pos: DVec3,
    /// Friction proxy p_i.
    pub proxy: DVec3,
    /// Surface point s_i.
    pub surface: DVec3,
    /// Whether the node is inside the skin.
    pub in_contact: bool,
    /// Indentation D_skin (mm, > 0 in contact).
    pub depth_mm: f64,
}

/// Forces of one tick for a contact tool.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ContactForces {
    pub skin: DVec3,
    pub slide: DVec3,
    pub bone: DVec3,
    pub torque: DVec3,
    /// Nodes in contact.
    pub contacts: usize,
}

/// A finger or probe touching the skin.
#[derive(Debug, Clone)]
pub struct ContactTool {
    pattern: ContactPattern,
    friction: ContactFriction,
    nodes: Vec<ContactNode>,
}

impl ContactTool {
    pub fn new(pattern: ContactPattern, friction: ContactFriction) -> Self {
        let n = pattern.points().len();
        let idle = ContactNode {
            pos: DVec3::ZERO,
            proxy: DVec3::ZERO,
            surface: DVec3::ZERO,
            in_contact: false,
            depth_mm: 0.0,
        };
        ContactTool {
            pattern,
            friction,
            nodes: vec![idle; n],
        }
    }

    pub fn pattern(&self) -> &ContactPattern {
        &self.pattern
    }
    pub fn nodes(&self) -> &[ContactNode] {
        &self.nodes
    }

    /// One tick for device position `x` and orientation `q` (reference space).
    pub fn step(&mut self, atlas: &PunctureAtlas, x: DVec3, q: DQuat) -> ContactForces {
        let skin = atlas.skin_distance();
        let bone = atlas.bone_distance();
        // Both maps lie on the CT's grid (PunctureAtlas checks it): one index per node for both,
        // and their values and gradients from one gather.
        let grid = *skin.grid();
        let maps = GradientSampler::on_one_grid([skin, bone]).expect("the distance maps share the CT's grid");
        // The pattern's geometry once per tick: the rotation as a matrix, and the device
        // position in index units (each node's index is then c_x + A⁻¹ Q x_i⁰).
        let rotation = DMat3::from_quat(q);
        let c_x = grid.world_to_index(x);
        let (mut sum_f_skin, mut sum_f_slide, mut sum_f_bone, mut sum_t) =
            (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
        let mut n = 0usize;
        for (node, p0) in self.nodes.iter_mut().zip(self.pattern.points()) {
            let arm = rotation * *p0;
            let xi = x + arm;
            node.pos = xi;
            let c = c_x + grid.world_vector_to_index(arm);
            // D_skin first; the gradients and D_bone only for a node inside the skin.
            let Ok([skin_at, bone_at]) = maps.at_index_if(c, -1000.0, |d_skin| !(d_skin <= 0.0)) else {
                // Not touching: the proxy waits at the node (no stick across lifts).
                node.in_contact = false;
                node.depth_mm = 0.0;
                node.surface = xi;
                node.proxy = xi;
                continue;
            };
            let d_skin = skin_at.value;
            let vs = (-skin_at.gradient).normalize_or_zero();
            let f_skin = skin_force_n(d_skin) * vs;
            // Bone penalty, turned towards the skin normal when pointing more than 90° away.
            let d_bone = bone_at.value;
            let vb = (-bone_at.gradient).normalize_or_zero();
            // (vb is a unit vector or zero already: only the turned direction needs normalising.)
            let dir = if vb.dot(vs) > 0.0 {
                vb
            } else {
                (vb - 4.0 * vs * vb.dot(vs)).normalize_or_zero()
            };
            let f_bone = bone_force_n(-d_bone) * dir;
            // Stick–slip proxy on the surface point.
            let s_new = xi - d_skin * vs;
            let f_n = f_skin + f_bone;
            let press = f_n.dot(vs).abs();
            let z_max = self.friction.c_fric * press + 1.0;
            let z_stick = z_max - 1.0;
            let s_old = if node.in_contact { node.surface } else { s_new };
            let p_old = if node.in_contact { node.proxy } else { s_new };
            let dvec = s_new - p_old;
            let dist = dvec.length();
            let alpha = if dist > 0.0 {
                let z8 = powi8(dist);
                (1.0 / z_max) * z8 / (powi8(z_stick) + z8)
            } else {
                0.0
            };
            let proxy = if alpha * dist > 1.0 {
                s_new - (dvec / dist) * z_max
            } else {
                p_old + (s_new - s_old).length() * alpha * dvec
            };
            let f_slide = self.friction.k_fric * (proxy - s_new);
            node.in_contact = true;
            node.depth_mm = d_skin;
            node.surface = s_new;
            node.proxy = proxy;
            let f_i = f_skin + f_slide + f_bone;
            sum_f_skin += f_skin;
            sum_f_slide += f_slide;
            sum_f_bone += f_bone;
            sum_t += arm.cross(f_i);
            n += 1;
        }
        if n == 0 {
            return ContactForces::default();
        }
        let k = 1.0 / n as f64;
        ContactForces {
            skin: sum_f_skin * k,
            slide: sum_f_slide * k,
            bone: sum_f_bone * k,
            torque: sum_t * k,
            contacts: n,
        }
    }
}

#[inline]
fn powi8(x: f64) -> f64 {
    let x2 = x * x;
    let x4 = x2 * x2;
    x4 * x4
}
