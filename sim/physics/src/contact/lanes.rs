//! The contact force law of one node (eqs. 3.6.1–3.6.11), four nodes at once.
//!
//! Each lane performs exactly the operations, in exactly the order, of the node-by-node law
//! (glam's `normalize_or_zero`, `dot`, `length` and the scalar formulas of `skin_force_n`,
//! `bone_force_n` and the stick–slip proxy), and IEEE 754 gives every lane's addition,
//! multiplication, division and square root the same bits whether it runs alone or beside three
//! others. Branches become selects: both sides are computed and the lane keeps the side its
//! condition picks, so a value the branch would not have computed (a NaN from 0/0) is never kept.
//! The law is written once over [`Lane`] (crate::lanes): AVX registers where the CPU has AVX2
//! (chosen at run time, [`contact_lanes`]), plain arrays elsewhere; no operation is fused.

use glam::DVec3;

use super::{ContactFriction, in_skin};
use crate::gradient::{GradientSampler, ValueGradient};
use crate::lanes::{F4, LANES, Lane, V4, Vec4s, has_avx2};

/// What the law reads for four nodes inside the skin.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct LanesIn {
    /// x_i (mm).
    pub pos: Vec4s,
    /// D_skin (> 0) and its world gradient.
    pub d_skin: [f64; LANES],
    pub grad_skin: Vec4s,
    /// D_bone and its world gradient.
    pub d_bone: [f64; LANES],
    pub grad_bone: Vec4s,
    /// Whether the node was in contact on the previous tick, and its surface point and proxy then.
    pub was_in_contact: [bool; LANES],
    pub surface: Vec4s,
    pub proxy: Vec4s,
}

/// The law's results for four nodes.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct LanesOut {
    pub f_skin: Vec4s,
    pub f_bone: Vec4s,
    pub f_slide: Vec4s,
    /// The new surface point s_i and proxy p_i.
    pub surface: Vec4s,
    pub proxy: Vec4s,
}

/// The law for four nodes: with AVX2 when the CPU has it (the same bits either way).
pub(super) fn contact_lanes(i: &LanesIn, friction: ContactFriction) -> LanesOut {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 (checked above).
        return unsafe { contact_lanes_avx2(i, friction) };
    }
    law::<F4>(i, friction)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn contact_lanes_avx2(i: &LanesIn, friction: ContactFriction) -> LanesOut {
    law::<crate::lanes::avx::Avx>(i, friction)
}

/// Where four nodes that were all in contact on the last tick are now (x_i), and their surface
/// points and proxies from then: what [`read_and_law`] reads besides the maps.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Held {
    pub pos: Vec4s,
    pub surface: Vec4s,
    pub proxy: Vec4s,
}

/// Where [`read_and_law`] leaves its results: kept by the tool between ticks (one write in
/// place; returning them by value cost a copy of half a kilobyte per call).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Fused {
    /// When all four nodes are inside the skin: their D_skin and the law's results.
    pub d_skin: [f64; LANES],
    pub law: LanesOut,
    /// When some node left the skin: the maps' reads, for settling node by node.
    pub reads: [[ValueGradient; 2]; LANES],
}

/// Both maps' values and gradients at four interior indices `cs` and, when all four nodes are
/// inside the skin, the law for them with `held` (all in contact on the last tick), the maps'
/// lanes going straight into the law: the bits of [`GradientSampler::at_interior4`] followed by
/// [`contact_lanes`], without storing the reads and loading them back. AVX2 where the CPU has it.
/// True when all four are inside the skin (`into.d_skin` and `into.law` are set), false when some
/// node left it (`into.reads` is set).
pub(super) fn read_and_law(
    maps: &GradientSampler<'_, 2>,
    cs: &[DVec3; LANES],
    held: &Held,
    friction: ContactFriction,
    into: &mut Fused,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 (checked above).
        return unsafe { read_and_law_avx2(maps, cs, held, friction, into) };
    }
    read_and_law_in::<F4>(maps, cs, held, friction, into)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn read_and_law_avx2(
    maps: &GradientSampler<'_, 2>,
    cs: &[DVec3; LANES],
    held: &Held,
    friction: ContactFriction,
    into: &mut Fused,
) -> bool {
    read_and_law_in::<crate::lanes::avx::Avx>(maps, cs, held, friction, into)
}

#[inline(always)]
fn read_and_law_in<L: Lane>(
    maps: &GradientSampler<'_, 2>,
    cs: &[DVec3; LANES],
    held: &Held,
    friction: ContactFriction,
    into: &mut Fused,
) -> bool {
    let [(d_skin, grad_skin), (d_bone, grad_bone)] = maps.at_interior4_lanes::<L>(cs);
    let skin = d_skin.store();
    if !(in_skin(skin[0]) && in_skin(skin[1]) && in_skin(skin[2]) && in_skin(skin[3])) {
        let (gs, bone, gb) = (grad_skin.store(), d_bone.store(), grad_bone.store());
        for (lane, r) in into.reads.iter_mut().enumerate() {
            r[0] = ValueGradient {
                value: skin[lane],
                gradient: gs.get(lane),
            };
            r[1] = ValueGradient {
                value: bone[lane],
                gradient: gb.get(lane),
            };
        }
        return false;
    }
    let input = LawIn {
        pos: V4::load(&held.pos),
        d_skin,
        grad_skin,
        d_bone,
        grad_bone,
        was_in_contact: L::mask([true; LANES]),
        surface: V4::load(&held.surface),
        proxy: V4::load(&held.proxy),
    };
    into.d_skin = skin;
    into.law = law_lanes(input, friction);
    true
}

/// [`LanesIn`] as lanes.
struct LawIn<L: Lane> {
    pos: V4<L>,
    d_skin: L,
    grad_skin: V4<L>,
    d_bone: L,
    grad_bone: V4<L>,
    was_in_contact: L::Mask,
    surface: V4<L>,
    proxy: V4<L>,
}

#[inline(always)]
fn law<L: Lane>(i: &LanesIn, friction: ContactFriction) -> LanesOut {
    let input = LawIn {
        pos: V4::load(&i.pos),
        d_skin: L::load(i.d_skin),
        grad_skin: V4::load(&i.grad_skin),
        d_bone: L::load(i.d_bone),
        grad_bone: V4::load(&i.grad_bone),
        was_in_contact: L::mask(i.was_in_contact),
        surface: V4::load(&i.surface),
        proxy: V4::load(&i.proxy),
    };
    law_lanes(input, friction)
}

/// Eqs. 3.6.1–3.6.11 lane by lane; each line mirrors the node-by-node law (`ContactTool::step`
/// before it batched nodes; the tests keep that law as the reference).
#[inline(always)]
fn law_lanes<L: Lane>(i: LawIn<L>, friction: ContactFriction) -> LanesOut {
    let zero = L::splat(0.0);
    let one = L::splat(1.0);
    // Skin penalty (eqs. 3.6.1–3.6.3): f_s(D_skin) along v_s = −∇D_skin/‖·‖.
    let d_skin = i.d_skin;
    let vs = i.grad_skin.neg().normalize_or_zero();
    let x = d_skin;
    let cubic = L::splat(1.78e-2) * x * x * x + L::splat(3.82e-3) * x * x + L::splat(2.28e-4) * x;
    let f_skin = vs.scaled(L::select(x.gt(zero), cubic, zero));
    // Bone penalty (eqs. 3.6.4–3.6.7), turned towards v_s when more than 90° away.
    let vb = i.grad_bone.neg().normalize_or_zero();
    let vb_vs = vb.dot(vs);
    let turned = vb.sub(vs.scaled(L::splat(4.0)).scaled(vb_vs)).normalize_or_zero();
    let dir = V4::select(vb_vs.gt(zero), vb, turned);
    let x = -i.d_bone;
    let r = L::splat(5.0) / x;
    let f_bone = dir.scaled(L::select(x.gt(zero), L::splat(20.0) * r * r * r, zero));
    // Stick–slip proxy on the surface point (eqs. 3.6.8–3.6.11).
    let s_new = i.pos.sub(vs.scaled(d_skin));
    let f_n = f_skin.add(f_bone);
    let press = f_n.dot(vs).abs();
    let z_max = L::splat(friction.c_fric) * press + one;
    let z_stick = z_max - one;
    let was = i.was_in_contact;
    let s_old = V4::select(was, i.surface, s_new);
    let p_old = V4::select(was, i.proxy, s_new);
    let dvec = s_new.sub(p_old);
    let dist = dvec.length();
    let z8 = pow8(dist);
    let alpha = L::select(dist.gt(zero), one / z_max * z8 / (pow8(z_stick) + z8), zero);
    let slipped = s_new.sub(dvec.divided(dist).scaled(z_max));
    let dragged = p_old.add(dvec.scaled(s_new.sub(s_old).length() * alpha));
    let proxy = V4::select((alpha * dist).gt(one), slipped, dragged);
    let f_slide = proxy.sub(s_new).scaled(L::splat(friction.k_fric));
    LanesOut {
        f_skin: f_skin.store(),
        f_bone: f_bone.store(),
        f_slide: f_slide.store(),
        surface: s_new.store(),
        proxy: proxy.store(),
    }
}

#[inline(always)]
fn pow8<L: Lane>(x: L) -> L {
    let x2 = x * x;
    let x4 = x2 * x2;
    x4 * x4
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contact::{bone_force_n, skin_force_n};
    use crate::{Affine, Grid, Volume};

    /// The node-by-node law as `ContactTool::step` computed it before nodes were batched
    /// (physics version 9): the reference every lane must match bit for bit.
    #[allow(clippy::too_many_arguments)]
    fn node_by_node(
        friction: ContactFriction,
        xi: DVec3,
        d_skin: f64,
        grad_skin: DVec3,
        d_bone: f64,
        grad_bone: DVec3,
        was_in_contact: bool,
        surface: DVec3,
        proxy: DVec3,
    ) -> ([DVec3; 5], [bool; 3]) {
        fn powi8(x: f64) -> f64 {
            let x2 = x * x;
            let x4 = x2 * x2;
            x4 * x4
        }
        let vs = (-grad_skin).normalize_or_zero();
        let f_skin = skin_force_n(d_skin) * vs;
        let vb = (-grad_bone).normalize_or_zero();
        let dir = if vb.dot(vs) > 0.0 {
            vb
        } else {
            (vb - 4.0 * vs * vb.dot(vs)).normalize_or_zero()
        };
        let f_bone = bone_force_n(-d_bone) * dir;
        let s_new = xi - d_skin * vs;
        let f_n = f_skin + f_bone;
        let press = f_n.dot(vs).abs();
        let z_max = friction.c_fric * press + 1.0;
        let z_stick = z_max - 1.0;
        let s_old = if was_in_contact { surface } else { s_new };
        let p_old = if was_in_contact { proxy } else { s_new };
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
        let f_slide = friction.k_fric * (proxy - s_new);
        // Which branches this node took: turned bone direction, slip, bone force.
        let branches = [vb.dot(vs) <= 0.0, alpha * dist > 1.0, d_bone < 0.0];
        ([f_skin, f_bone, f_slide, s_new, proxy], branches)
    }

    /// SplitMix64 in [0, 1).
    struct Rng(u64);
    impl Rng {
        fn unit(&mut self) -> f64 {
            crate::test_rng::unit(&mut self.0)
        }
        fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.unit()
        }
        fn vec(&mut self, r: f64) -> DVec3 {
            DVec3::new(self.range(-r, r), self.range(-r, r), self.range(-r, r))
        }
        /// A gradient: mostly unit-ish, sometimes zero, tiny or huge (normalize's edge cases).
        fn gradient(&mut self) -> DVec3 {
            match (self.unit() * 10.0) as u32 {
                0 => DVec3::ZERO,
                1 => self.vec(1e-160),
                2 => self.vec(1e160),
                _ => self.vec(1.5),
            }
        }
    }

    fn bits(v: DVec3) -> [u64; 3] {
        v.to_array().map(f64::to_bits)
    }

    /// Every lane gives the node-by-node law's bits, with and without AVX2, over random nodes
    /// that cover contact onset, sticking, slipping, bone behind and beside the skin normal,
    /// zero and degenerate gradients and a proxy on the surface point (distance 0).
    #[test]
    fn each_lane_gives_the_bits_of_the_node_by_node_law() {
        let mut rng = Rng(0x5EED);
        // How often each branch of the law was taken, and its other side.
        let mut taken = [[0u32; 2]; 3];
        for friction in [ContactFriction::FINGER, ContactFriction::PROBE_WITH_GEL] {
            for _ in 0..20_000 {
                let mut input = LanesIn::default();
                let mut nodes = Vec::new();
                for lane in 0..LANES {
                    let xi = rng.vec(200.0);
                    let d_skin = match (rng.unit() * 8.0) as u32 {
                        0 => 1e-9,
                        _ => rng.range(0.0, 25.0),
                    };
                    let d_bone = rng.range(-40.0, 10.0);
                    let (gs, gb) = (rng.gradient(), rng.gradient());
                    let was = rng.unit() < 0.7;
                    let surface = xi + rng.vec(3.0);
                    let proxy = match (rng.unit() * 4.0) as u32 {
                        // On the new surface point: dist = 0.
                        0 => xi - d_skin * (-gs).normalize_or_zero(),
                        1 => surface + rng.vec(20.0),
                        _ => surface + rng.vec(0.5),
                    };
                    input.pos.set(lane, xi);
                    input.d_skin[lane] = d_skin;
                    input.grad_skin.set(lane, gs);
                    input.d_bone[lane] = d_bone;
                    input.grad_bone.set(lane, gb);
                    input.was_in_contact[lane] = was;
                    input.surface.set(lane, surface);
                    input.proxy.set(lane, proxy);
                    nodes.push(node_by_node(friction, xi, d_skin, gs, d_bone, gb, was, surface, proxy));
                }
                let plain = law::<F4>(&input, friction);
                let dispatched = contact_lanes(&input, friction);
                for (lane, (want, branches)) in nodes.iter().enumerate() {
                    for (t, &b) in taken.iter_mut().zip(branches) {
                        t[usize::from(b)] += 1;
                    }
                    for out in [&plain, &dispatched] {
                        let got = [out.f_skin, out.f_bone, out.f_slide, out.surface, out.proxy].map(|v| v.get(lane));
                        for (g, w) in got.iter().zip(want) {
                            assert_eq!(bits(*g), bits(*w), "lane {lane}: {got:?} vs {want:?}");
                        }
                    }
                }
            }
        }
        assert!(
            taken.iter().flatten().all(|&n| n > 1000),
            "every branch both ways, often: {taken:?} (turned, slipped, bone force; not/taken)"
        );
    }

    /// A skin and a bone distance map on an anisotropic 24 × 20 × 16 grid: D_skin positive below
    /// a curved skin surface, D_bone positive inside a tilted slab.
    fn maps() -> (Volume<f32>, Volume<f32>) {
        let g = Grid::new(
            [24, 20, 16],
            Affine::from_spacing([1.5, 1.2, 2.5], DVec3::new(-18.0, -12.0, -20.0)),
        )
        .unwrap();
        let (mut skin, mut bone) = (Vec::new(), Vec::new());
        for k in 0..16 {
            for j in 0..20 {
                for i in 0..24 {
                    let p = g.voxel_to_world(i, j, k);
                    skin.push((-p.z + 0.02 * p.x * p.x - 0.3 * libm::sin(0.2 * p.y)) as f32);
                    bone.push((4.0 - (0.3 * p.x + p.z + 12.0).abs()) as f32);
                }
            }
        }
        (Volume::new(g, skin).unwrap(), Volume::new(g, bone).unwrap())
    }

    /// Reading both maps and running the law in one pass gives the bits of the two steps it
    /// replaces (`at_interior4`, then `contact_lanes` with every node in contact on the last
    /// tick), with and without AVX2; and when a node is off the skin it gives the reads alone,
    /// those of `at_interior4`.
    #[test]
    fn reading_straight_into_the_law_gives_the_bits_of_reads_then_law() {
        let (skin, bone) = maps();
        let sampler = GradientSampler::on_one_grid([&skin, &bone]).unwrap();
        let mut rng = Rng(0xFEED);
        let (mut laws, mut reads) = (0, 0);
        for friction in [ContactFriction::FINGER, ContactFriction::PROBE_WITH_GEL] {
            for _ in 0..5_000 {
                // Interior indices (1 ≤ c < n − 2), mostly below the skin.
                let cs: [DVec3; LANES] = std::array::from_fn(|_| {
                    DVec3::new(rng.range(1.0, 20.999), rng.range(1.0, 16.999), rng.range(1.0, 12.999))
                });
                let mut held = Held::default();
                for lane in 0..LANES {
                    let xi = sampler_world(&skin, cs[lane]);
                    held.pos.set(lane, xi);
                    held.surface.set(lane, xi + rng.vec(2.0));
                    let reach = if rng.unit() < 0.5 { 0.3 } else { 8.0 };
                    held.proxy.set(lane, xi + rng.vec(reach));
                }
                let separate = sampler.at_interior4(&cs);
                let mut fused = [Fused::default(); 2];
                let all_in = [
                    read_and_law(&sampler, &cs, &held, friction, &mut fused[0]),
                    read_and_law_in::<F4>(&sampler, &cs, &held, friction, &mut fused[1]),
                ];
                if separate.iter().all(|r| in_skin(r[0].value)) {
                    let mut input = LanesIn {
                        pos: held.pos,
                        was_in_contact: [true; LANES],
                        surface: held.surface,
                        proxy: held.proxy,
                        ..LanesIn::default()
                    };
                    for (lane, [s, b]) in separate.iter().enumerate() {
                        input.d_skin[lane] = s.value;
                        input.grad_skin.set(lane, s.gradient);
                        input.d_bone[lane] = b.value;
                        input.grad_bone.set(lane, b.gradient);
                    }
                    let want = contact_lanes(&input, friction);
                    for (got, all_in) in fused.iter().zip(all_in) {
                        assert!(all_in, "every node is in the skin at {cs:?}");
                        let (d_skin, out) = (got.d_skin, got.law);
                        assert_eq!(d_skin.map(f64::to_bits), input.d_skin.map(f64::to_bits));
                        for (g, w) in [
                            (out.f_skin, want.f_skin),
                            (out.f_bone, want.f_bone),
                            (out.f_slide, want.f_slide),
                            (out.surface, want.surface),
                            (out.proxy, want.proxy),
                        ] {
                            for lane in 0..LANES {
                                assert_eq!(bits(g.get(lane)), bits(w.get(lane)), "lane {lane} at {cs:?}");
                            }
                        }
                    }
                    laws += 1;
                } else {
                    for (got, all_in) in fused.iter().zip(all_in) {
                        assert!(!all_in, "a node is off the skin at {cs:?}");
                        let r = got.reads;
                        for (g, w) in r.iter().flatten().zip(separate.iter().flatten()) {
                            assert_eq!(g.value.to_bits(), w.value.to_bits());
                            assert_eq!(bits(g.gradient), bits(w.gradient));
                        }
                    }
                    reads += 1;
                }
            }
        }
        assert!(
            laws > 1000 && reads > 1000,
            "both outcomes, often: {laws} laws, {reads} reads"
        );
    }

    /// The world point of continuous index `c` on `v`'s grid.
    fn sampler_world(v: &Volume<f32>, c: DVec3) -> DVec3 {
        v.grid().affine().apply(c)
    }
}
