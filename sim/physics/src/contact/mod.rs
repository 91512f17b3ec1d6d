//! Palpation finger and ultrasound probe: multi-proxy haptics on the skin and bone distance maps
//! (thesis §3.6, docs/physics.md).
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

mod lanes;
pub mod patterns;
mod skin_bound;

use glam::{DMat3, DQuat, DVec3};

use crate::PunctureAtlas;
use crate::gradient::{GradientSampler, ValueGradient};
use crate::lanes::Vec4s;
pub use patterns::ContactPattern;
use skin_bound::SkinBound;

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
    /// Per node, an upper bound on D_skin where it was last ([`skin_bound`]): nodes it proves off
    /// the skin are not read. Work only: the outputs are those of reading every node.
    bounds: Vec<SkinBound>,
    /// The skin map the bounds were taken on (its values' address and count): another map
    /// starts them afresh.
    bounds_map: Option<(usize, usize)>,
    /// Nodes passed by their bound (the tests check that the bound is used).
    #[cfg(test)]
    passed: u64,
    /// A tick's queues and batches, kept between ticks so that a tick does not clear them first
    /// (they hold no state: every lane a tick reads, it wrote).
    scratch: Scratch,
}

/// The working space of one tick.
#[derive(Clone, Default)]
struct Scratch {
    probing: Queue,
    touching: Queue,
    law: Batch,
    fused: lanes::Fused,
}

impl std::fmt::Debug for Scratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Scratch")
    }
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
            bounds: vec![SkinBound::UNKNOWN; n],
            bounds_map: None,
            #[cfg(test)]
            passed: 0,
            scratch: Scratch::default(),
        }
    }

    pub fn pattern(&self) -> &ContactPattern {
        &self.pattern
    }
    pub fn nodes(&self) -> &[ContactNode] {
        &self.nodes
    }

    /// One tick for device position `x` and orientation `q` (reference space).
    ///
    /// Four nodes at a time: interior nodes read D_skin four at once
    /// (`GradientSampler::values4`), those inside the skin then both maps' values and
    /// gradients (`GradientSampler::at_interior4`) and the force law (`contact::lanes`) four at once;
    /// each gives the bits of one node at a time, and the nodes in contact are settled and
    /// summed in node order.
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
        let map_key = Some((skin.data().as_ptr() as usize, skin.data().len()));
        if self.bounds_map != map_key {
            self.bounds.fill(SkinBound::UNKNOWN);
            self.bounds_map = map_key;
        }
        let slopes_mm = skin_bound::slopes_mm(atlas.skin_distance_steps_mm());
        let c_x = grid.world_to_index(x);
        let Scratch {
            probing,
            touching,
            law,
            fused,
        } = &mut self.scratch;
        // Left empty by the last tick (each ends by emptying them).
        debug_assert!(probing.len == 0 && touching.len == 0 && law.len == 0);
        let mut tick = Tick {
            nodes: &mut self.nodes,
            bounds: &mut self.bounds,
            friction: self.friction,
            law,
            fused,
            sums: Sums::default(),
        };
        // Interior nodes wait in two queues of four: D_skin alone for every node, then both
        // maps' values and gradients for the nodes inside the skin.
        for (i, p0) in self.pattern.points().iter().enumerate() {
            let arm = rotation * *p0;
            let xi = x + arm;
            let c = c_x + grid.world_vector_to_index(arm);
            if maps.is_interior(c) {
                if let Some(bound) = tick.bounds[i].off_skin_at(c, slopes_mm) {
                    // Certainly off the skin: settled idle at once (it adds nothing to the
                    // sums, so the nodes waiting before it are unaffected).
                    tick.bounds[i] = bound;
                    tick.settle(i, arm, xi, Err(bound.upper_mm()));
                    #[cfg(test)]
                    {
                        self.passed += 1;
                    }
                    continue;
                }
                if probing.push(i, arm, xi, c) {
                    probing.probe(&maps, touching, &mut tick);
                }
                continue;
            }
            // A node near the grid's border: the interior nodes before it first (node order).
            probing.probe(&maps, touching, &mut tick);
            touching.read(&maps, &mut tick);
            tick.bounds[i] = SkinBound::UNKNOWN;
            tick.settle(i, arm, xi, maps.at_index_if(c, -1000.0, in_skin));
        }
        probing.probe(&maps, touching, &mut tick);
        touching.read(&maps, &mut tick);
        tick.law.finish(tick.nodes, tick.friction, &mut tick.sums);
        tick.sums.means()
    }
}

/// D_skin > 0 (or NaN): the node is inside the skin, and the gradients and D_bone are read.
#[inline(always)]
fn in_skin(d_skin: f64) -> bool {
    !(d_skin <= 0.0)
}

/// One tick's nodes, force-law batch, fused reads and sums.
struct Tick<'n> {
    nodes: &'n mut [ContactNode],
    bounds: &'n mut [SkinBound],
    friction: ContactFriction,
    law: &'n mut Batch,
    fused: &'n mut lanes::Fused,
    sums: Sums,
}

impl Tick<'_> {
    /// Node `i` at `xi` with its maps read (`Err(D_skin)` off the skin): idle, or queued for the
    /// force law.
    #[inline(always)]
    fn settle(&mut self, i: usize, arm: DVec3, xi: DVec3, read: Result<[ValueGradient; 2], f64>) {
        let node = &mut self.nodes[i];
        node.pos = xi;
        let Ok([skin_at, bone_at]) = read else {
            // Not touching: the proxy waits at the node (no stick across lifts).
            node.in_contact = false;
            node.depth_mm = 0.0;
            node.surface = xi;
            node.proxy = xi;
            return;
        };
        let lane = self.law.len;
        let l = &mut self.law.input;
        l.pos.set(lane, xi);
        l.d_skin[lane] = skin_at.value;
        l.grad_skin.set(lane, skin_at.gradient);
        l.d_bone[lane] = bone_at.value;
        l.grad_bone.set(lane, bone_at.gradient);
        l.was_in_contact[lane] = node.in_contact;
        l.surface.set(lane, node.surface);
        l.proxy.set(lane, node.proxy);
        self.law.nodes[lane] = (i, arm);
        self.law.len += 1;
        if self.law.len == crate::lanes::LANES {
            self.law.finish(self.nodes, self.friction, &mut self.sums);
        }
    }
}

/// Up to four interior nodes waiting for a batched read.
#[derive(Clone, Default)]
struct Queue {
    /// Each lane's node index, lever arm and position.
    nodes: [(usize, DVec3, DVec3); crate::lanes::LANES],
    /// Each lane's continuous index.
    c: [DVec3; crate::lanes::LANES],
    len: usize,
}

impl Queue {
    /// Queues a node; true when the queue is full.
    #[inline(always)]
    fn push(&mut self, i: usize, arm: DVec3, xi: DVec3, c: DVec3) -> bool {
        self.nodes[self.len] = (i, arm, xi);
        self.c[self.len] = c;
        self.len += 1;
        self.len == crate::lanes::LANES
    }

    /// The indices with unused lanes repeating the first (their results are ignored).
    #[inline(always)]
    fn indices(&mut self) -> &[DVec3; crate::lanes::LANES] {
        for lane in self.len..crate::lanes::LANES {
            self.c[lane] = self.c[0];
        }
        &self.c
    }

    /// D_skin at the queued nodes: those off the skin are settled idle, the others queued in
    /// `touching` (in node order). Four nodes that all touched on the last tick are read in full
    /// at once instead.
    fn probe(&mut self, maps: &GradientSampler<'_, 2>, touching: &mut Queue, tick: &mut Tick) {
        if self.len == 0 {
            return;
        }
        if self.len == crate::lanes::LANES && self.nodes.iter().all(|&(i, ..)| tick.nodes[i].in_contact) {
            // Four nodes that touched on the last tick most likely still do: everything is read
            // at once (the same bits as D_skin first; only the work differs), and when all four
            // still touch, the reads go straight into the force law. The nodes queued before
            // them are settled, and their law run, first (sums in node order).
            touching.read(maps, tick);
            let nodes = &tick.nodes;
            let held = lanes::Held {
                pos: Vec4s::from_lanes(self.nodes.map(|(_, _, xi)| xi)),
                surface: Vec4s::from_lanes(self.nodes.map(|(i, ..)| nodes[i].surface)),
                proxy: Vec4s::from_lanes(self.nodes.map(|(i, ..)| nodes[i].proxy)),
            };
            let all_in = lanes::read_and_law(maps, &self.c, &held, tick.friction, tick.fused);
            for (lane, &(i, ..)) in self.nodes.iter().enumerate() {
                let d = if all_in {
                    tick.fused.d_skin[lane]
                } else {
                    tick.fused.reads[lane][0].value
                };
                tick.bounds[i] = SkinBound::read(self.c[lane], d);
            }
            if all_in {
                tick.law.finish(tick.nodes, tick.friction, &mut tick.sums);
                let fused = &*tick.fused;
                for (lane, &(i, arm, xi)) in self.nodes.iter().enumerate() {
                    tick.nodes[i].pos = xi;
                    store_lane(
                        &mut tick.nodes[i],
                        arm,
                        fused.d_skin[lane],
                        &fused.law,
                        lane,
                        &mut tick.sums,
                    );
                }
            } else {
                for (lane, &(i, arm, xi)) in self.nodes.iter().enumerate() {
                    let read = tick.fused.reads[lane];
                    let d = read[0].value;
                    tick.settle(i, arm, xi, if in_skin(d) { Ok(read) } else { Err(d) });
                }
            }
            self.len = 0;
            return;
        }
        let d_skin = maps.values4(self.indices());
        for (&(i, arm, xi), (d, c)) in self.nodes.iter().zip(d_skin.into_iter().zip(self.c)).take(self.len) {
            tick.bounds[i] = SkinBound::read(c, d);
            if in_skin(d) {
                if touching.push(i, arm, xi, c) {
                    touching.read(maps, tick);
                }
            } else {
                tick.settle(i, arm, xi, Err(d));
            }
        }
        self.len = 0;
    }

    /// Both maps' values and gradients at the queued nodes (all inside the skin), settled in
    /// order.
    fn read(&mut self, maps: &GradientSampler<'_, 2>, tick: &mut Tick) {
        if self.len == 0 {
            return;
        }
        let reads = maps.at_interior4(self.indices());
        for (&(i, arm, xi), read) in self.nodes.iter().zip(reads).take(self.len) {
            tick.settle(i, arm, xi, Ok(read));
        }
        self.len = 0;
    }
}

/// Up to four nodes inside the skin waiting for the force law.
#[derive(Clone, Default)]
struct Batch {
    input: lanes::LanesIn,
    /// Each lane's node index and lever arm Q x_i⁰.
    nodes: [(usize, DVec3); crate::lanes::LANES],
    len: usize,
}

impl Batch {
    /// Runs the law for the waiting nodes, stores their state and adds their forces to `sums`
    /// in node order. Unused lanes compute on stale inputs and are ignored.
    fn finish(&mut self, nodes: &mut [ContactNode], friction: ContactFriction, sums: &mut Sums) {
        if self.len == 0 {
            return;
        }
        let out = lanes::contact_lanes(&self.input, friction);
        for (lane, &(i, arm)) in self.nodes.iter().enumerate().take(self.len) {
            store_lane(&mut nodes[i], arm, self.input.d_skin[lane], &out, lane, sums);
        }
        self.len = 0;
    }
}

/// The law's results of `lane` (a node inside the skin at depth `d_skin`, lever arm `arm`) into
/// the node's state and the sums.
#[inline(always)]
fn store_lane(node: &mut ContactNode, arm: DVec3, d_skin: f64, out: &lanes::LanesOut, lane: usize, sums: &mut Sums) {
    node.in_contact = true;
    node.depth_mm = d_skin;
    node.surface = out.surface.get(lane);
    node.proxy = out.proxy.get(lane);
    sums.add(arm, out.f_skin.get(lane), out.f_slide.get(lane), out.f_bone.get(lane));
}

/// Running sums of eqs. 3.6.12–3.6.14 over the nodes in contact.
#[derive(Default)]
struct Sums {
    f_skin: DVec3,
    f_slide: DVec3,
    f_bone: DVec3,
    torque: DVec3,
    n: usize,
}

impl Sums {
    fn add(&mut self, arm: DVec3, f_skin: DVec3, f_slide: DVec3, f_bone: DVec3) {
        let f_i = f_skin + f_slide + f_bone;
        self.f_skin += f_skin;
        self.f_slide += f_slide;
        self.f_bone += f_bone;
        self.torque += arm.cross(f_i);
        self.n += 1;
    }

    /// The device output: the means over the nodes in contact (zero without contact).
    fn means(&self) -> ContactForces {
        if self.n == 0 {
            return ContactForces::default();
        }
        let k = 1.0 / self.n as f64;
        ContactForces {
            skin: self.f_skin * k,
            slide: self.f_slide * k,
            bone: self.f_bone * k,
            torque: self.torque * k,
            contacts: self.n,
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::{DQuat, DVec3};

    use super::*;
    use crate::properties::ParamValue;
    use crate::test_rng::unit;
    use crate::{Affine, Grid, synthetic_atlas};

    /// A 56 × 48 × 30 atlas of anisotropic voxels (0.9 × 0.8 × 1.6 mm): a body (40 HU) whose skin
    /// is an ellipsoid cap, air above it, and a rib-like bone bar (700 HU) 12 mm under the top.
    fn atlas() -> PunctureAtlas {
        let g = Grid::new(
            [56, 48, 30],
            Affine::from_spacing([0.9, 0.8, 1.6], DVec3::new(-25.0, -19.0, -30.0)),
        )
        .unwrap();
        let mut ct = vec![-1000.0f32; g.len()];
        for (i, v) in ct.iter_mut().enumerate() {
            let [a, b, c] = g.unlinear(i);
            let p = g.voxel_to_world(a, b, c);
            // Ellipsoid centred 40 mm below the origin: the top of the body is curved.
            let (a, b, c) = (p.x / 60.0, p.y / 50.0, (p.z + 40.0) / 45.0);
            let r = a * a + b * b + c * c;
            if r < 1.0 {
                *v = if (p.z + 8.0).abs() < 2.5 && p.y.abs() < 12.0 {
                    700.0
                } else {
                    40.0
                };
            }
        }
        synthetic_atlas::atlas_with(g, ct, vec![0; g.len()], &[], ParamValue::Scalar(0.5)).unwrap()
    }

    fn bits(v: DVec3) -> [u64; 3] {
        v.to_array().map(f64::to_bits)
    }

    /// Passing the nodes the bound proves off the skin changes the work, not the bits: every
    /// tool, stepped along a wandering path that presses into the curved skin, tilts, slides,
    /// lifts into the air and runs into the grid's border, gives the forces and node states of
    /// a tool that reads every node (its bounds forgotten before each tick), and many nodes are
    /// passed.
    #[test]
    fn passing_nodes_off_the_skin_gives_the_bits_of_reading_them() {
        let atlas = atlas();
        for (pattern, friction) in [
            (ContactPattern::fingertip(), ContactFriction::FINGER),
            (ContactPattern::linear_probe(), ContactFriction::PROBE_WITH_GEL),
            (ContactPattern::convex_probe(), ContactFriction::PROBE_WITH_GEL),
        ] {
            let kind = pattern.kind();
            let mut passing = ContactTool::new(pattern.clone(), friction);
            let mut reading = ContactTool::new(pattern, friction);
            let mut rng = 0x5EED_u64;
            let (mut x, mut tilt) = (DVec3::new(0.0, 0.0, 8.0), DVec3::ZERO);
            let (mut contacts, mut idle) = (0u64, 0u64);
            for tick in 0..6_000 {
                // Down into the skin, then wandering (0.2 mm a tick at most), with lifts into
                // the air and a run to the border every 1 500 ticks.
                let phase = tick % 1_500;
                let dz = if phase < 300 {
                    -0.05
                } else if phase < 900 {
                    0.02 * (unit(&mut rng) - 0.55)
                } else if phase < 1_100 {
                    0.06
                } else {
                    -0.04
                };
                let side = if phase >= 1_100 && tick >= 3_000 { 0.15 } else { 0.0 };
                x += DVec3::new(0.1 * (unit(&mut rng) - 0.5) + side, 0.1 * (unit(&mut rng) - 0.5), dz);
                if phase == 1_499 {
                    x = DVec3::new(0.0, 0.0, 8.0);
                }
                tilt += DVec3::new(0.004 * (unit(&mut rng) - 0.5), 0.004 * (unit(&mut rng) - 0.5), 0.0);
                let q = DQuat::from_rotation_x(tilt.x) * DQuat::from_rotation_y(tilt.y);
                reading.bounds.fill(SkinBound::UNKNOWN);
                let (a, b) = (passing.step(&atlas, x, q), reading.step(&atlas, x, q));
                assert_eq!(a.contacts, b.contacts, "{kind:?} tick {tick}");
                for (fa, fb) in [
                    (a.skin, b.skin),
                    (a.slide, b.slide),
                    (a.bone, b.bone),
                    (a.torque, b.torque),
                ] {
                    assert_eq!(bits(fa), bits(fb), "{kind:?} tick {tick}");
                }
                for (na, nb) in passing.nodes().iter().zip(reading.nodes()) {
                    assert_eq!(na.in_contact, nb.in_contact, "{kind:?} tick {tick}");
                    assert_eq!(na.depth_mm.to_bits(), nb.depth_mm.to_bits());
                    for (va, vb) in [(na.pos, nb.pos), (na.proxy, nb.proxy), (na.surface, nb.surface)] {
                        assert_eq!(bits(va), bits(vb), "{kind:?} tick {tick}");
                    }
                }
                contacts += a.contacts as u64;
                idle += (passing.nodes().len() - a.contacts) as u64;
            }
            assert_eq!(reading.passed, 0);
            assert!(
                contacts > 20_000 && passing.passed > 1_000,
                "{kind:?}: {contacts} node-ticks in contact, {idle} off the skin, {} passed",
                passing.passed
            );
        }
    }
}
