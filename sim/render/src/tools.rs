//! The tools as the renderers see them (thesis §3.2.4: drawn with correct depth against the
//! volume): the bent needle as a tube along its nodes with a hub, the fingertip, the linear and
//! the convex probe. Taken from a `Simulation` snapshot at a tick; turned into a short list of
//! analytic primitives (capsules, spheres, boxes) that both renderers intersect with the same
//! formulas (docs/rendering.md "Tools").

use stylet_physics::ProbeKind;
use stylet_physics::glam::{DVec3, Quat, Vec3};

use crate::light::Light;

/// The needle: nodes from hub to tip (mm, world space), outer diameter and the hub's size.
#[derive(Debug, Clone, PartialEq)]
pub struct NeedleShape {
    pub nodes_mm: Vec<Vec3>,
    pub diameter_mm: f32,
    /// The hub (handle) continues the shaft backwards from the first node.
    pub hub_length_mm: f32,
    pub hub_diameter_mm: f32,
}

/// What a line in the patient is: the instruments of the Seldinger exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineKind {
    GuideWire,
    Dilator,
    Catheter,
}

/// A guide wire, dilator or catheter: nodes from the skin to its tip (mm, world space), no more
/// than [`LINE_STEP_MM`] apart where the instrument runs straight, and its outer diameter.
#[derive(Debug, Clone, PartialEq)]
pub struct LineShape {
    pub kind: LineKind,
    pub nodes_mm: Vec<Vec3>,
    pub diameter_mm: f32,
}

/// The spacing the lines are drawn at (mm): a wire's 0.5 mm nodes are finer than any view
/// resolves.
pub const LINE_STEP_MM: f64 = 2.0;
/// The most nodes a line keeps (the wire is at most 400 mm).
pub const MAX_LINE_NODES: usize = 256;

/// The fingertip: a sphere at the device position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FingerShape {
    pub center_mm: Vec3,
    pub radius_mm: f32,
}

/// An ultrasound probe at the device pose: it presses along its +z axis, its transducer array
/// runs along +x (physics' contact patterns, thesis Fig. 3.8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeShape {
    pub kind: ProbeKind,
    pub position_mm: Vec3,
    pub orientation: Quat,
}

/// The tools in the scene at one moment.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ToolState {
    pub needle: Option<NeedleShape>,
    /// The guide wire, the dilator or catheter on it, the placed catheter.
    pub lines: Vec<LineShape>,
    pub finger: Option<FingerShape>,
    pub probe: Option<ProbeShape>,
}

/// The most primitives a scene's tools may produce (the GPU keeps them in a fixed buffer).
pub const MAX_PRIMITIVES: usize = 128;

/// Outer diameter of the needle hub (mm) and its length behind the first node.
pub const HUB_DIAMETER_MM: f32 = 4.0;
pub const HUB_LENGTH_MM: f32 = 20.0;
/// The fingertip sphere's radius (mm): physics' fingertip pad is a cap of this radius.
pub const FINGER_RADIUS_MM: f32 = 8.0;

/// Tool colours (linear RGB 0 … 1).
pub const SHAFT_RGB: Vec3 = Vec3::new(0.72, 0.74, 0.78);
pub const HUB_RGB: Vec3 = Vec3::new(0.15, 0.35, 0.85);
/// The exchange's instruments: a steel wire darker than the needle, a blue dilator, a white
/// catheter.
pub const WIRE_RGB: Vec3 = Vec3::new(0.50, 0.53, 0.58);
pub const DILATOR_RGB: Vec3 = Vec3::new(0.45, 0.65, 0.92);
pub const CATHETER_RGB: Vec3 = Vec3::new(0.93, 0.93, 0.90);
pub const FINGER_RGB: Vec3 = Vec3::new(0.92, 0.72, 0.60);
pub const PROBE_RGB: Vec3 = Vec3::new(0.25, 0.25, 0.28);
/// The probe's transducer face, a little lighter than its body.
pub const PROBE_FACE_RGB: Vec3 = Vec3::new(0.45, 0.47, 0.50);

/// Convex probe face: physics' pattern is 60° of a 50 mm radius along x, 16 mm wide in y.
pub const CONVEX_RADIUS_MM: f32 = stylet_physics::probe_image::CONVEX_RADIUS_MM as f32;
pub const CONVEX_HALF_ANGLE_DEG: f32 = stylet_physics::probe_image::CONVEX_HALF_ANGLE_DEG as f32;

/// One analytic shape both renderers intersect with the same closed-form `f32` formulas.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Primitive {
    /// All points within `radius` of the segment a–b.
    Capsule {
        a: Vec3,
        b: Vec3,
        radius: f32,
        rgb: Vec3,
    },
    Sphere {
        center: Vec3,
        radius: f32,
        rgb: Vec3,
    },
    /// An oriented box: `axes` are unit and orthogonal, `half_mm` the half extents along them.
    Box {
        center: Vec3,
        axes: [Vec3; 3],
        half_mm: Vec3,
        rgb: Vec3,
    },
    /// A capped cylinder (unit `axis`, half length along it) cut by a plane: only the part with
    /// (x − center)·cut_normal ≥ cut_mm is kept (cut_mm ≤ −radius keeps the whole cylinder). The
    /// convex probe's curved face is such a circular segment.
    Cylinder {
        center: Vec3,
        axis: Vec3,
        radius: f32,
        half_length_mm: f32,
        cut_normal: Vec3,
        cut_mm: f32,
        rgb: Vec3,
    },
}

/// The nearest intersection of a ray with the tools: distance along the unit ray, outward unit
/// normal at the hit, the tool's colour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolHit {
    pub t: f32,
    pub normal: Vec3,
    pub rgb: Vec3,
}

/// A ray/convex-shape interval [t_in, t_out] with the outward normals at both ends. Infinite
/// ends are ±BIG (not ∞), so the WGSL port needs no infinities.
#[derive(Clone, Copy)]
struct Span {
    t_in: f32,
    n_in: Vec3,
    t_out: f32,
    n_out: Vec3,
}

const BIG: f32 = 1.0e30;

impl Span {
    const ALL: Span = Span {
        t_in: -BIG,
        n_in: Vec3::ZERO,
        t_out: BIG,
        n_out: Vec3::ZERO,
    };

    /// Intersection with the slab |(o + t·d − c)·axis| ≤ half (outward normals ±axis); None when
    /// the ray runs parallel to the slab outside it.
    #[inline]
    fn slab(self, o_rel: Vec3, d: Vec3, axis: Vec3, half: f32) -> Option<Span> {
        let (o, v) = (o_rel.dot(axis), d.dot(axis));
        if v.abs() < 1e-12 {
            return if o.abs() <= half { Some(self) } else { None };
        }
        let (t1, t2) = ((-half - o) / v, (half - o) / v);
        // Entering through the face the ray moves toward: −axis·sign(v).
        let (near, far) = if t1 < t2 { (t1, t2) } else { (t2, t1) };
        let n_enter = if v > 0.0 { -axis } else { axis };
        self.clip(near, n_enter, far, -n_enter)
    }

    #[inline]
    fn clip(mut self, t_in: f32, n_in: Vec3, t_out: f32, n_out: Vec3) -> Option<Span> {
        if t_in > self.t_in {
            self.t_in = t_in;
            self.n_in = n_in;
        }
        if t_out < self.t_out {
            self.t_out = t_out;
            self.n_out = n_out;
        }
        (self.t_in <= self.t_out).then_some(self)
    }

    /// The first boundary crossing in (0, t_max): the entry, or the exit for a ray that starts
    /// inside.
    #[inline]
    fn first(self, t_max: f32) -> Option<(f32, Vec3)> {
        if self.t_in > 0.0 && self.t_in < t_max {
            Some((self.t_in, self.n_in))
        } else if self.t_in <= 0.0 && self.t_out > 0.0 && self.t_out < t_max {
            Some((self.t_out, self.n_out))
        } else {
            None
        }
    }
}

/// Roots of t² + 2·b·t + c = 0 (a unit-direction quadratic), smaller first.
#[inline]
fn roots_unit(b: f32, c: f32) -> Option<(f32, f32)> {
    let h = b * b - c;
    if h < 0.0 {
        return None;
    }
    let s = h.sqrt();
    Some((-b - s, -b + s))
}

/// Keeps the smaller positive t below `best`.
#[inline]
fn take(best: &mut Option<(f32, Vec3)>, t: f32, n: Vec3, t_max: f32) {
    if t > 0.0 && t < t_max && best.is_none_or(|(b, _)| t < b) {
        *best = Some((t, n));
    }
}

impl Primitive {
    /// The colour of the primitive.
    pub fn rgb(&self) -> Vec3 {
        match *self {
            Primitive::Capsule { rgb, .. }
            | Primitive::Sphere { rgb, .. }
            | Primitive::Box { rgb, .. }
            | Primitive::Cylinder { rgb, .. } => rgb,
        }
    }

    /// The first crossing of the primitive's surface in (0, t_max) along the unit ray, with the
    /// outward normal there (a ray starting inside gets its exit).
    pub fn hit(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, Vec3)> {
        match *self {
            Primitive::Sphere { center, radius, .. } => {
                let oc = o - center;
                let (t0, t1) = roots_unit(oc.dot(d), oc.dot(oc) - radius * radius)?;
                let mut best = None;
                for t in [t0, t1] {
                    take(&mut best, t, (o + d * t - center) / radius, t_max);
                }
                best
            }
            Primitive::Capsule { a, b, radius, .. } => {
                // The surface is {p : dist(p, segment ab) = r}: the side of the infinite cylinder
                // where the projection y lies in (0, |ab|), the sphere around a where y ≤ 0 and the
                // sphere around b where y ≥ |ab|. Every root of each piece inside its range is a
                // crossing; the nearest positive one wins.
                let ab = b - a;
                let len = ab.length();
                let u = if len > 1e-12 { ab / len } else { Vec3::Z };
                let oa = o - a;
                let mut best = None;
                let dp = d - u * d.dot(u);
                let op = oa - u * oa.dot(u);
                let qa = dp.dot(dp);
                if qa > 1e-12 && len > 1e-12 {
                    let h = op.dot(dp) * op.dot(dp) - qa * (op.dot(op) - radius * radius);
                    if h >= 0.0 {
                        let s = h.sqrt();
                        for t in [(-op.dot(dp) - s) / qa, (-op.dot(dp) + s) / qa] {
                            let y = oa.dot(u) + t * d.dot(u);
                            if y > 0.0 && y < len {
                                let p = o + d * t;
                                take(&mut best, t, (p - (a + u * y)) / radius, t_max);
                            }
                        }
                    }
                }
                for (c, at_a) in [(a, true), (b, false)] {
                    let oc = o - c;
                    if let Some((t0, t1)) = roots_unit(oc.dot(d), oc.dot(oc) - radius * radius) {
                        for t in [t0, t1] {
                            let y = oa.dot(u) + t * d.dot(u);
                            if (at_a && y <= 0.0) || (!at_a && y >= len) {
                                take(&mut best, t, (o + d * t - c) / radius, t_max);
                            }
                        }
                    }
                }
                best
            }
            Primitive::Box {
                center, axes, half_mm, ..
            } => {
                let rel = o - center;
                let s = Span::ALL.slab(rel, d, axes[0], half_mm.x)?;
                let s = s.slab(rel, d, axes[1], half_mm.y)?;
                let s = s.slab(rel, d, axes[2], half_mm.z)?;
                s.first(t_max)
            }
            Primitive::Cylinder {
                center,
                axis,
                radius,
                half_length_mm,
                cut_normal,
                cut_mm,
                ..
            } => {
                let rel = o - center;
                let mut s = Span::ALL.slab(rel, d, axis, half_length_mm)?;
                // Side: |rel⊥ + t·d⊥| ≤ r.
                let dp = d - axis * d.dot(axis);
                let op = rel - axis * rel.dot(axis);
                let qa = dp.dot(dp);
                if qa < 1e-12 {
                    if op.dot(op) > radius * radius {
                        return None;
                    }
                } else {
                    let b = op.dot(dp);
                    let h = b * b - qa * (op.dot(op) - radius * radius);
                    if h < 0.0 {
                        return None;
                    }
                    let sq = h.sqrt();
                    let (t0, t1) = ((-b - sq) / qa, (-b + sq) / qa);
                    let n0 = (op + dp * t0) / radius;
                    let n1 = (op + dp * t1) / radius;
                    s = s.clip(t0, n0, t1, n1)?;
                }
                // Cut: (rel + t·d)·n ≥ cut, outward normal −n.
                let (on, dn) = (rel.dot(cut_normal), d.dot(cut_normal));
                if dn.abs() < 1e-12 {
                    if on < cut_mm {
                        return None;
                    }
                } else {
                    let tc = (cut_mm - on) / dn;
                    s = if dn > 0.0 {
                        s.clip(tc, -cut_normal, BIG, Vec3::ZERO)?
                    } else {
                        s.clip(-BIG, Vec3::ZERO, tc, -cut_normal)?
                    };
                }
                s.first(t_max)
            }
        }
    }
}

/// The nearest tool surface along the unit ray `dir` from `origin` with t in (0, t_max).
pub fn nearest_hit(prims: &[Primitive], origin: Vec3, dir: Vec3, t_max: f32) -> Option<ToolHit> {
    let mut best: Option<ToolHit> = None;
    for p in prims {
        let limit = best.map_or(t_max, |b| b.t);
        if let Some((t, normal)) = p.hit(origin, dir, limit) {
            best = Some(ToolHit {
                t,
                normal,
                rgb: p.rgb(),
            });
        }
    }
    best
}

/// Phong shading of a tool hit (docs/rendering.md "Tools"): with N the outward normal,
/// L = light.toward_light, V = −view_dir, H = normalize(L + V):
/// rgb·(ambient + diffuse·max(N·L, 0)) + specular·max(N·H, 0)^shininess, clamped to 0 … 1.
pub fn shade(hit: &ToolHit, light: &Light, view_dir: Vec3) -> Vec3 {
    let n = hit.normal;
    let l = light.toward_light;
    let h = (l - view_dir).normalize_or_zero();
    let diffuse = n.dot(l).max(0.0);
    let spec = n.dot(h).max(0.0).powf(light.shininess);
    (hit.rgb * (light.ambient + light.diffuse * diffuse) + Vec3::splat(light.specular * spec))
        .clamp(Vec3::ZERO, Vec3::ONE)
}

impl ProbeShape {
    /// The probe's unit axes in world space: array (+x), across (+y), pressing direction (+z).
    pub fn axes(&self) -> [Vec3; 3] {
        let q = self.orientation.normalize();
        [q * Vec3::X, q * Vec3::Y, q * Vec3::Z]
    }

    /// The probe as primitives: the face (flat box or curved cylinder segment), the head behind
    /// it and a 60 mm handle, all behind the face (toward −z).
    pub fn primitives(&self) -> Vec<Primitive> {
        let [ex, ey, ez] = self.axes();
        let p = self.position_mm;
        let boxed = |z_center: f32, half: Vec3, rgb: Vec3| Primitive::Box {
            center: p + ez * z_center,
            axes: [ex, ey, ez],
            half_mm: half,
            rgb,
        };
        match self.kind {
            ProbeKind::Linear => vec![
                // The 40 × 10 mm face (physics' linear pattern), 3 mm thick.
                boxed(-1.5, Vec3::new(20.0, 5.0, 1.5), PROBE_FACE_RGB),
                boxed(-3.0 - 7.5, Vec3::new(20.0, 5.0, 7.5), PROBE_RGB),
                boxed(-18.0 - 30.0, Vec3::new(13.0, 4.5, 30.0), PROBE_RGB),
            ],
            ProbeKind::Convex => {
                let r = CONVEX_RADIUS_MM;
                let half = CONVEX_HALF_ANGLE_DEG.to_radians();
                let chord_half = r * half.sin();
                let sagitta = r - r * half.cos();
                vec![
                    Primitive::Cylinder {
                        center: p - ez * r,
                        axis: ey,
                        radius: r,
                        half_length_mm: 8.0,
                        cut_normal: ez,
                        cut_mm: r * half.cos(),
                        rgb: PROBE_FACE_RGB,
                    },
                    boxed(-sagitta - 7.5, Vec3::new(chord_half, 8.0, 7.5), PROBE_RGB),
                    boxed(-sagitta - 15.0 - 30.0, Vec3::new(15.0, 6.0, 30.0), PROBE_RGB),
                ]
            }
        }
    }

    /// Bounding sphere of the probe's head (face and head box; the handle is far from the
    /// skin): the sphere whose shadow stands for the probe's (Alg. 3.2).
    pub fn head_sphere(&self) -> (Vec3, f32) {
        let [_, _, ez] = self.axes();
        let (half, depth) = match self.kind {
            ProbeKind::Linear => (Vec3::new(20.0, 5.0, 9.0), 18.0),
            ProbeKind::Convex => {
                let r = CONVEX_RADIUS_MM;
                let half = CONVEX_HALF_ANGLE_DEG.to_radians();
                let depth = r - r * half.cos() + 15.0;
                (Vec3::new(r * half.sin(), 8.0, depth * 0.5), depth)
            }
        };
        (self.position_mm - ez * (depth * 0.5), half.length())
    }
}

impl NeedleShape {
    /// Unit direction of the last segment (the tip tangent), or +z for a degenerate needle.
    pub fn tip_tangent(&self) -> Vec3 {
        let n = self.nodes_mm.len();
        if n < 2 {
            return Vec3::Z;
        }
        (self.nodes_mm[n - 1] - self.nodes_mm[n - 2]).normalize_or(Vec3::Z)
    }

    /// The tip (last node).
    pub fn tip_mm(&self) -> Vec3 {
        self.nodes_mm.last().copied().unwrap_or(Vec3::ZERO)
    }

    /// Shaft length along the nodes (mm).
    pub fn length_mm(&self) -> f32 {
        self.nodes_mm.windows(2).map(|w| (w[1] - w[0]).length()).sum()
    }
}

impl ToolState {
    /// The tools as at most [`MAX_PRIMITIVES`] primitives: the needle's segments as capsules of
    /// half its outer diameter (every k-th node when there are too many), the hub as a thicker
    /// capsule continuing backwards from the first node, the fingertip sphere, the probe's boxes
    /// (and the convex probe's curved face), the guide wire, dilator and catheter as capsules
    /// like the needle's (the needle and the lines share what the other tools leave).
    pub fn primitives(&self) -> Vec<Primitive> {
        let mut out = Vec::new();
        if let Some(p) = &self.probe {
            out.extend(p.primitives());
        }
        if let Some(f) = &self.finger {
            out.push(Primitive::Sphere {
                center: f.center_mm,
                radius: f.radius_mm,
                rgb: FINGER_RGB,
            });
        }
        // What is left after the hub is shared between the needle and the exchange's lines.
        let needle = self.needle.as_ref().filter(|n| n.nodes_mm.len() >= 2);
        let polylines = usize::from(needle.is_some()) + self.lines.len();
        let budget = (MAX_PRIMITIVES - out.len() - 1) / polylines.max(1);
        for l in &self.lines {
            let rgb = match l.kind {
                LineKind::GuideWire => WIRE_RGB,
                LineKind::Dilator => DILATOR_RGB,
                LineKind::Catheter => CATHETER_RGB,
            };
            push_polyline(&mut out, &l.nodes_mm, l.diameter_mm * 0.5, rgb, budget);
        }
        if let Some(n) = needle {
            push_polyline(&mut out, &n.nodes_mm, n.diameter_mm * 0.5, SHAFT_RGB, budget);
            // The hub: from the first node back by its length, its rounded ends inside that span.
            let back = -(n.nodes_mm[1] - n.nodes_mm[0]).normalize_or(Vec3::Z);
            let rh = n.hub_diameter_mm * 0.5;
            let len = n.hub_length_mm.max(2.0 * rh);
            out.push(Primitive::Capsule {
                a: n.nodes_mm[0] + back * rh,
                b: n.nodes_mm[0] + back * (len - rh),
                radius: rh,
                rgb: HUB_RGB,
            });
        }
        debug_assert!(out.len() <= MAX_PRIMITIVES);
        out
    }

    /// The tools of a simulation after its latest tick with the device at `input`'s pose.
    ///
    /// The needle comes from `sim.needle()` (nodes hub first, in reference space, moved into the
    /// world by the breathing motion x = X + u(X, t) of the tick), with the gauge's outer diameter
    /// and a 20 × 4 mm hub. Before the first tick the needle has no shape yet; it is then laid on the device ray
    /// (tip at the device position, back along the tool axis q·(0, 0, 1)), as the physics does
    /// outside the patient. Contact tools take the device pose: the fingertip sphere sits behind
    /// the pad's apex (centre at position − 8 mm·axis), a probe's face at the position. A
    /// non-finite pose draws no contact tool. The second hand's tool of a two-handed session
    /// comes at its own pose.
    pub fn from_simulation(sim: &stylet_physics::Simulation, input: &stylet_physics::TickInput) -> ToolState {
        let q = input.orientation;
        let pose_ok = input.position_mm.is_finite() && q.is_finite() && q.length_squared() > 1e-12;
        let pos = input.position_mm.as_vec3();
        let orientation = if pose_ok {
            q.normalize().as_quat()
        } else {
            Quat::IDENTITY
        };
        let axis = orientation * Vec3::Z;
        let mut state = ToolState::default();
        if let Some(n) = sim.needle() {
            let spec = n.spec();
            let (model, t) = (sim.motion(), sim.motion_time_s());
            let mut nodes: Vec<Vec3> = if sim.breathes() {
                n.nodes()
                    .iter()
                    .map(|&p| (p + model.displacement(p, t)).as_vec3())
                    .collect()
            } else {
                n.nodes().iter().map(|p| p.as_vec3()).collect()
            };
            let m = nodes.len().max(2);
            let degenerate = nodes.len() < 2 || (nodes[nodes.len() - 1] - nodes[0]).length() < 1e-3;
            if degenerate && pose_ok {
                let h = spec.length_mm as f32 / (m - 1) as f32;
                nodes = (0..m).map(|j| pos - axis * (h * (m - 1 - j) as f32)).collect();
            }
            let diameter_mm = spec.gauge.outer_diameter_mm() as f32;
            state.needle = Some(NeedleShape {
                nodes_mm: nodes,
                diameter_mm,
                hub_length_mm: HUB_LENGTH_MM,
                hub_diameter_mm: HUB_DIAMETER_MM,
            });
        }
        if let Some(a) = sim.access() {
            state.lines = lines_of(a, &|p| {
                if sim.breathes() {
                    (p + sim.motion().displacement(p, sim.motion_time_s())).as_vec3()
                } else {
                    p.as_vec3()
                }
            });
        }
        if let Some(c) = sim.contact()
            && pose_ok
        {
            use stylet_physics::contact::patterns::ContactKind;
            match c.pattern().kind() {
                ContactKind::Finger => {
                    state.finger = Some(FingerShape {
                        center_mm: pos - axis * FINGER_RADIUS_MM,
                        radius_mm: FINGER_RADIUS_MM,
                    })
                }
                ContactKind::LinearProbe | ContactKind::ConvexProbe => {
                    state.probe = Some(ProbeShape {
                        kind: if c.pattern().kind() == ContactKind::LinearProbe {
                            ProbeKind::Linear
                        } else {
                            ProbeKind::Convex
                        },
                        position_mm: pos,
                        orientation,
                    })
                }
            }
        }
        // The second hand's tool at its pose of the tick (a two-handed session): the probe that
        // images live while the first hand holds the needle. A tool kind the first hand already
        // shows keeps the first hand's.
        if let Some(h) = sim.second_hand()
            && let Some(tool) = h.tool_spec()
        {
            let (p, q) = h.pose();
            let (pos, orientation) = (p.as_vec3(), q.normalize().as_quat());
            match tool {
                stylet_physics::HandTool::Finger if state.finger.is_none() => {
                    let axis = orientation * Vec3::Z;
                    state.finger = Some(FingerShape {
                        center_mm: pos - axis * FINGER_RADIUS_MM,
                        radius_mm: FINGER_RADIUS_MM,
                    })
                }
                stylet_physics::HandTool::Probe(kind) if state.probe.is_none() => {
                    state.probe = Some(ProbeShape {
                        kind,
                        position_mm: pos,
                        orientation,
                    })
                }
                _ => {}
            }
        }
        state
    }
}

/// Capsules of `radius` along `nodes`, at most `budget` of them (every k-th node when there are
/// more segments).
fn push_polyline(out: &mut Vec<Primitive>, nodes: &[Vec3], radius: f32, rgb: Vec3, budget: usize) {
    if budget == 0 || nodes.len() < 2 {
        return;
    }
    let segs = nodes.len() - 1;
    let stride = segs.div_ceil(budget).max(1);
    let mut i = 0;
    while i < segs {
        let j = (i + stride).min(segs);
        out.push(Primitive::Capsule {
            a: nodes[i],
            b: nodes[j],
            radius,
            rgb,
        });
        i = j;
    }
}

/// The instruments of a Seldinger exchange as lines in the world (`to_world`: a reference-space
/// point where the breathing patient has it now): the wire, the dilator or catheter on it as far
/// as its tip, the placed catheter with its pigtail.
pub fn lines_of(access: &stylet_physics::Access, to_world: &dyn Fn(DVec3) -> Vec3) -> Vec<LineShape> {
    use stylet_physics::seldinger::over_wire::OverWireKind;
    let line = |kind, nodes: Vec<DVec3>, diameter_mm: f64| LineShape {
        kind,
        nodes_mm: nodes.iter().map(|&p| to_world(p)).collect(),
        diameter_mm: diameter_mm as f32,
    };
    let mut out = Vec::new();
    if let Some(w) = access.wire() {
        let path = w.nodes();
        out.push(line(
            LineKind::GuideWire,
            coarse(path, f64::INFINITY),
            w.spec().diameter.mm(),
        ));
        if let Some(t) = access.on_wire() {
            let kind = match t.kind {
                OverWireKind::Dilator => LineKind::Dilator,
                OverWireKind::Catheter => LineKind::Catheter,
            };
            out.push(line(kind, coarse(path, t.inserted_mm()), t.diameter_mm()));
        }
    }
    if let Some((size_fr, p)) = access.placed_catheter() {
        // The straight part coarse, the loop as formed.
        let mut nodes = coarse(&p.nodes[..=p.loop_from], f64::INFINITY);
        nodes.extend_from_slice(&p.nodes[p.loop_from + 1..]);
        out.push(line(LineKind::Catheter, nodes, f64::from(size_fr) / 3.0));
    }
    out
}

/// `nodes` up to `until_mm` along them, a node every [`LINE_STEP_MM`] (wider for a long line, at
/// most [`MAX_LINE_NODES`]) and the last one kept.
fn coarse(nodes: &[DVec3], until_mm: f64) -> Vec<DVec3> {
    use stylet_physics::seldinger::over_wire::{point_at, resample};
    let length_mm: f64 = nodes.windows(2).map(|w| w[0].distance(w[1])).sum();
    let end_mm = until_mm.min(length_mm);
    let step_mm = LINE_STEP_MM.max(end_mm / (MAX_LINE_NODES - 2) as f64);
    let (mut out, _) = resample(nodes, step_mm);
    out.truncate((end_mm / step_mm) as usize + 1);
    let (end, _) = point_at(nodes, end_mm);
    if out.last() != Some(&end) {
        out.push(end);
    }
    out
}
