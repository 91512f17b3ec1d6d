//! One haptic tick of the bendable needle (Alg. 3.3): tip direction, path update (Alg. 3.4–3.5),
//! needle shape (beam model), cutting, friction and base forces and torque (eqs. 3.5.1–3.5.8).
//!
//! Everything here is in reference space X; the caller maps the device into it (breathing, §5.4.3)
//! and supplies the tip-direction correction R⁻¹ of eq. 5.4.3.

use glam::{DQuat, DVec3, EulerRot};

use super::beam::{self, BeamScratch, Lateral};
use super::path::{InsertionPath, TipMaterial};
use super::spec::NeedleSpec;
use crate::device::DeviceProfile;
use crate::{LabelId, Param, PunctureAtlas};

/// Needle nodes along the shaft (hub to tip): 5 mm apart on a 150 mm needle.
pub const NEEDLE_NODES: usize = 31;
/// Path node spacing Δp (mm).
pub const PATH_SPACING_MM: f64 = 1.5;
/// The stylus holding the hub: stiffness of the two hub springs (N/mm per node). The virtual needle
/// is fixed to the device's stylus, so the hub is clamped in position and direction: stiff enough
/// that the clamp adds under 1 % to a cantilever's deflection (see [`cantilever_tip_deflection_mm`]).
const HUB_HOLD_N_PER_MM: f64 = 1.0e6;

/// Forces of one tick (N, N·mm), all acting at the needle's base (the handle).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NeedleForces {
    /// f_cut of eq. 3.5.2.
    pub cut: DVec3,
    /// f_fric of eq. 3.5.6 (opposing the shaft's motion).
    pub friction: DVec3,
    /// f_base of eq. 3.5.7.
    pub base: DVec3,
    /// t of eq. 3.5.8.
    pub torque: DVec3,
}

/// The needle tool's state: shape, channel, friction, stylet.
#[derive(Debug, Clone)]
pub struct NeedleTool {
    spec: NeedleSpec,
    stylet_in: bool,
    /// EI of the gauge with or without the stylet (Table A.1), kept while the stylet stays.
    ei_nmm2: f64,
    /// Needle nodes n_j (hub first) and tangents r_j, reference space.
    nodes: Vec<DVec3>,
    tangents: Vec<DVec3>,
    path: InsertionPath,
    /// f: the friction force of the previous tick (eq. 3.5.5), N along the insertion direction.
    friction_n: f64,
    last_x: Option<DVec3>,
    /// Label, CT value and insertion depth at the tip after the last tick.
    tip_label: LabelId,
    tip_hu: f64,
    scratch: Scratch,
}

#[derive(Debug, Clone, Default)]
struct Scratch {
    beam: BeamScratch,
    k: Vec<f64>,
    target: Vec<Lateral>,
    load: Vec<Lateral>,
    w: Vec<Lateral>,
}

impl NeedleTool {
    pub fn new(spec: NeedleSpec, stylet_in: bool) -> Self {
        NeedleTool {
            spec,
            stylet_in,
            ei_nmm2: spec.gauge.flexural_rigidity_nmm2(stylet_in),
            nodes: vec![DVec3::ZERO; NEEDLE_NODES],
            tangents: vec![DVec3::Z; NEEDLE_NODES],
            path: InsertionPath::new(PATH_SPACING_MM),
            friction_n: 0.0,
            last_x: None,
            tip_label: 0,
            tip_hu: crate::AIR_HU as f64,
            scratch: Scratch::default(),
        }
    }

    /// The device position of the previous tick (friction follows its axial motion).
    pub fn last_device_mm(&self) -> Option<DVec3> {
        self.last_x
    }

    pub fn spec(&self) -> &NeedleSpec {
        &self.spec
    }
    pub fn stylet_in(&self) -> bool {
        self.stylet_in
    }
    /// Removing the stylet halves the rigidity (Table A.1); the channel is kept.
    pub fn set_stylet(&mut self, inserted: bool) {
        self.stylet_in = inserted;
        self.ei_nmm2 = self.spec.gauge.flexural_rigidity_nmm2(inserted);
    }
    pub fn nodes(&self) -> &[DVec3] {
        &self.nodes
    }
    pub fn tangents(&self) -> &[DVec3] {
        &self.tangents
    }
    pub fn path(&self) -> &InsertionPath {
        &self.path
    }
    pub fn friction_n(&self) -> f64 {
        self.friction_n
    }
    pub fn tip_label(&self) -> LabelId {
        self.tip_label
    }
    pub fn tip_hu(&self) -> f64 {
        self.tip_hu
    }
    /// Inserted length along the channel (mm).
    pub fn inserted_mm(&self) -> f64 {
        self.path.inserted_length_mm()
    }

    fn tip_material(atlas: &PunctureAtlas, label: LabelId, hu: f64) -> TipMaterial {
        TipMaterial {
            cut_spring_n_per_mm: atlas.param_of(label, Param::CutSpringNPerMm, hu),
            cut_spring_n_per_mm2: atlas.param_of(label, Param::CutSpringNPerMm2, hu),
            cut_threshold_n: atlas.param_of(label, Param::CutThresholdN, hu),
            stiffness_n_per_mm: atlas.param_of(label, Param::StiffnessNPerMm, hu),
            friction_max_n: atlas.param_of(label, Param::FrictionMaxNPerMm, hu) * PATH_SPACING_MM,
        }
    }

    /// One tick of Alg. 3.3 for device position `x` (the tip of the needle if it were rigid) and
    /// orientation `q` (tool axis q_z = q·(0,0,1)), both in reference space. `correct_direction`
    /// maps the needle's tip tangent r_m to the path direction d_l (R⁻¹ r_m, eq. 5.4.3).
    pub fn step(
        &mut self,
        atlas: &PunctureAtlas,
        x: DVec3,
        q: DQuat,
        correct_direction: &dyn Fn(DVec3) -> DVec3,
        device: &DeviceProfile,
    ) -> NeedleForces {
        let qz = q * DVec3::Z;
        let m = NEEDLE_NODES;
        let length = self.spec.length_mm;
        // Line 6–7: the path tip follows the needle tip's direction (steering).
        let r_m = self.tangents[m - 1];
        if !self.path.is_empty() {
            let d = correct_direction(r_m).normalize_or_zero();
            if d != DVec3::ZERO {
                self.path.set_tip_tangent(d);
            }
        }
        // Material at the tip before it moves (Alg. 3.5 evaluates f(p_l)); at x on first contact.
        let depth = self.path.inserted_length_mm();
        let probe = self.path.tip().map_or(x, |t| t.pos);
        let (label, hu) = atlas.needle_label_at(probe, depth);
        let material = Self::tip_material(atlas, label, hu);
        let air = atlas.label_table().heuristic().air;
        let first_contact = self.path.is_empty() && atlas.needle_label_at(x, 0.0).0 != air;
        let mut material_at = |p: DVec3| {
            let (l, h) = atlas.needle_label_at(p, depth);
            let t = Self::tip_material(atlas, l, h);
            (t.stiffness_n_per_mm, t.friction_max_n)
        };
        // Retracting: the device is behind the tip (Alg. 3.5's backward branch).
        let retracting = self.path.len() >= 2 && self.path.tip().is_some_and(|t| (x - t.pos).dot(t.tangent) < 0.0);
        // Line 9: Alg. 3.4.
        self.path.update(
            x,
            if self.path.is_empty() { qz } else { r_m },
            &material,
            length,
            first_contact,
            &mut material_at,
        );

        if self.path.is_empty() {
            // Line 14–17: outside the patient, the needle lies on the device ray; no force.
            self.place_on_ray(x, qz);
            self.friction_n = 0.0;
            self.last_x = Some(x);
            let (l, h) = atlas.needle_label_at(x, 0.0);
            self.tip_label = l;
            self.tip_hu = h;
            return NeedleForces::default();
        }

        // Line 11: needle shape from the beam model.
        self.solve_shape(x, qz);
        let tip = *self.path.tip().expect("non-empty");
        let depth = self.path.inserted_length_mm();
        let (tip_label, tip_hu) = atlas.needle_label_at(tip.pos, depth);
        self.tip_label = tip_label;
        self.tip_hu = tip_hu;
        let tip_mat = Self::tip_material(atlas, tip_label, tip_hu);
        let d_l = tip.tangent;

        // Eq. 3.5.2: cutting force, zero when retracting (the device behind the tip this tick).
        let dd = (x - tip.pos).dot(d_l);
        let cut = if dd > 0.0 && !retracting && self.path.len() >= 2 {
            -(tip_mat.cut_spring_n_per_mm2 * dd * dd + tip_mat.cut_spring_n_per_mm * dd) * d_l
        } else {
            DVec3::ZERO
        };

        // Eqs. 3.5.3–3.5.6: friction, its change per tick limited by k_max |Δx|. The thesis prints
        // f_fric = (f + Δf) d_l; the force on the hand opposes the shaft's motion, so it is
        // −(f + Δf) d_l here (the offsets grow along the motion).
        let dx = self.last_x.map_or(0.0, |lx| (x - lx).dot(d_l));
        let f_plus = self.path.update_friction(dx);
        let limit = (device.k_max_n_per_mm * dx).abs();
        let df = (f_plus - self.friction_n).clamp(-limit, limit);
        self.friction_n += df;
        let friction = -self.friction_n * d_l;

        // Eq. 3.5.7: base force keeping the handle on the insertion line through n_1 along d_1.
        let d1 = self.path.nodes()[0].tangent;
        let rel = self.nodes[0] - x;
        let base = device.base_kappa_n_per_mm * (rel - rel.dot(d1) * d1);

        // Eq. 3.5.8: rotational spring towards q_dest (z along d_1, free twist about the shaft).
        let torque = if device.has_torque() {
            let q_dest = DQuat::from_rotation_arc(qz, d1) * q;
            let dq = q_dest.inverse() * q;
            let (ex, ey, ez) = dq.to_euler(EulerRot::XYZ);
            let kq = -(device.torque_k0_nmm_per_rad + device.torque_k_per_cm * depth / 10.0);
            q * (DVec3::new(ex, ey, ez) * kq)
        } else {
            DVec3::ZERO
        };
        self.last_x = Some(x);
        NeedleForces {
            cut,
            friction,
            base,
            torque,
        }
    }

    fn place_on_ray(&mut self, x: DVec3, qz: DVec3) {
        let m = NEEDLE_NODES;
        let h = self.spec.length_mm / (m - 1) as f64;
        for j in 0..m {
            self.nodes[j] = x - qz * (h * (m - 1 - j) as f64);
            self.tangents[j] = qz;
        }
    }

    /// The needle between the hand (hub held at v along q_z, eq. 3.5.1) and the channel: the beam
    /// of [`beam`] in the frame of the chord from v to the tip path node.
    fn solve_shape(&mut self, x: DVec3, qz: DVec3) {
        let m = NEEDLE_NODES;
        let len = self.spec.length_mm;
        let h = len / (m - 1) as f64;
        let inserted = self.path.inserted_length_mm();
        let p1 = self.path.nodes()[0].pos;
        let tip = self.path.tip().expect("non-empty").pos;
        // Eq. 3.5.1: where the hub would be, from the entry back along the device axis.
        let v = p1 - qz * (len - inserted).max(0.0);
        let chord = tip - v;
        let chord_len = chord.length();
        if chord_len < 1e-6 {
            self.place_on_ray(x, qz);
            return;
        }
        let e = chord / chord_len;
        let (u1, u2) = e.any_orthonormal_pair();
        let hc = chord_len / (m - 1) as f64;
        let lateral = |p: DVec3| -> Lateral {
            let r = p - v;
            [r.dot(u1), r.dot(u2)]
        };
        let s = &mut self.scratch;
        for buf in [&mut s.target, &mut s.load, &mut s.w] {
            buf.clear();
            buf.resize(m, [0.0; 2]);
        }
        s.k.clear();
        s.k.resize(m, 0.0);
        // The hand: the hub at v and its direction along q_z.
        s.k[0] = HUB_HOLD_N_PER_MM;
        s.k[1] = HUB_HOLD_N_PER_MM;
        s.target[1] = lateral(v + qz * h);
        // The tissue: needle node j, a_j from the tip, sits on the channel point a_j back from the
        // tip with the tissue's spring f_k, scaled from Δp to the node spacing h.
        let queries = (2..m - 1)
            .rev()
            .map(|j| (j, (m - 1 - j) as f64 * h))
            .take_while(|&(_, a)| a < inserted);
        self.path.points_from_tip(queries, |j, p, k| {
            s.k[j] = k * h / PATH_SPACING_MM;
            s.target[j] = lateral(p);
        });
        // The tip node, like the thesis' tip rigid body, hangs on a full (unprojected) spring of
        // the tissue's stiffness at the channel's end: the uncut tissue ahead resists the tip's
        // sideways motion only elastically, so a bent needle turns its tip (steering).
        let tip_k = self.path.tip().expect("non-empty").stiffness_n_per_mm;
        s.k[m - 1] = tip_k * h / PATH_SPACING_MM;
        let ei = self.ei_nmm2;
        if !beam::solve(ei, h, &s.k, &s.target, &s.load, &mut s.w, &mut s.beam) {
            self.place_on_ray(x, qz);
            return;
        }
        for j in 0..m {
            let w = s.w[j];
            self.nodes[j] = v + e * (hc * j as f64) + u1 * w[0] + u2 * w[1];
        }
        super::tangents::tangents(&self.nodes, e, &mut self.tangents);
    }
}

/// The simulator's needle as a cantilever, the thesis' bench test (Table A.1): hub clamped as the
/// stylus holds it (nodes 0 and 1, which clamps the beam half a node spacing from the hub), a
/// lateral force `force_n` at the tip, `free_length_mm` between clamp and tip; returns the tip's
/// lateral deflection (mm) from the same beam model and node count the simulation uses.
pub fn cantilever_tip_deflection_mm(
    gauge: super::spec::Gauge,
    stylet_in: bool,
    free_length_mm: f64,
    force_n: f64,
) -> f64 {
    let m = NEEDLE_NODES;
    // The clamp sits at 0.5 h: a needle of length L + h/2 has a free length L.
    let h = free_length_mm / (m as f64 - 1.5);
    let mut k = vec![0.0; m];
    k[0] = HUB_HOLD_N_PER_MM;
    k[1] = HUB_HOLD_N_PER_MM;
    let target = vec![[0.0; 2]; m];
    let mut load = vec![[0.0; 2]; m];
    load[m - 1] = [force_n, 0.0];
    let mut w = vec![[0.0; 2]; m];
    let ok = beam::solve(
        gauge.flexural_rigidity_nmm2(stylet_in),
        h,
        &k,
        &target,
        &load,
        &mut w,
        &mut BeamScratch::default(),
    );
    assert!(ok, "a clamped beam is never singular");
    w[m - 1][0]
}
