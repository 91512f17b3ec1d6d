//! The guide wire of the Seldinger technique (thesis §2.1; docs/seldinger.md): pushed through the
//! needle once the stylet is out, it follows the bile ducts' lumen ([`DuctChannel`]).
//!
//! A kinematic rod of nodes [`NODE_MM`] apart from where it leaves the needle to its tip. Each
//! node's length pushed moves the tip one node on along its course while the lumen lets it. Where
//! that would leave the lumen, the tip's lead meets the wall — the tip itself for a straight tip,
//! for a J its bend, [`J_LEAD_DEG`] off the course toward the side the wire's roll turns it to —
//! and the wall turns the tip: the outward part of the lead is taken away and the tip slides along
//! the wall, against a force of the tip load over the glancing
//! angle's cotangent (a floppy tip bends easily at a shallow angle, hardly at a steep one). A tip
//! that meets a wall head-on (the lead direction within [`HEAD_ON_DEG`] of the wall's normal) or
//! finds no way on is blocked: what is pushed further folds the wire behind the tip into a loop,
//! and the hand feels the tip's buckling load (`WireSpec::push_limit_n`). Once the fold has taken
//! up the floppy tip, the body pushes with its own, larger buckling load; where that reaches the
//! wall's puncture force a straight tip goes through the wall into the parenchyma ("left the
//! duct"), a J never (it presents its bend). Pulling back takes up the fold first, then draws the
//! tip back along its own track. Rotation is the wire's roll, transmitted to the tip 1:1.
//!
//! Which branch the wire takes at a bifurcation, whether it coils at a dead end and whether it
//! leaves the duct follow from these rules and the ducts' shape; nothing is scripted. Every step
//! is plain arithmetic and `libm`, so the same inputs give the same bits.

pub mod branches;
pub mod channel;
pub mod spec;
#[cfg(test)]
mod tests;

use glam::DVec3;

pub use branches::{HilumDistance, WrongBranchWatch};
pub use channel::DuctChannel;
pub use spec::{WireDiameter, WireSpec, WireTip};

/// Spacing of the wire's nodes (mm): one step of the tip.
pub const NODE_MM: f64 = 0.5;
/// How far a J tip's lead direction turns toward its bend (degrees).
pub const J_LEAD_DEG: f64 = 30.0;
/// A tip meets a wall head-on when its lead direction is within this of the wall's normal
/// (degrees): the wall cannot turn it.
pub const HEAD_ON_DEG: f64 = 25.0;
/// Most the hub moves in one call (mm): a hand moves far less in a tick, and the work of a call
/// stays bounded whatever a damaged input asks.
pub const MAX_MOVE_MM: f64 = 10.0;
/// Most nodes a wire has (a 400 mm wire out of the needle).
pub const MAX_NODES: usize = 800;
/// Friction of a wire in the ducts (N per mm in contact): a hydrophilic-coated wire in bile
/// slides with little resistance (Schröder 1993, Cardiovasc Intervent Radiol 16:43–48: a
/// hydrophilic coat lowers sliding friction to about a sixth of steel's). An estimate.
pub const DUCT_FRICTION_N_PER_MM: f64 = 0.0005;
/// Friction of a wire forced through the parenchyma (N per mm): an estimate, ten times the duct's.
pub const TISSUE_FRICTION_N_PER_MM: f64 = 0.005;

/// Something the wire did in a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireEvent {
    /// The tip met a wall it could not slide along; what is pushed on folds the wire.
    Blocked,
    /// The tip went through the duct wall into the parenchyma.
    LeftDuct,
    /// Drawn back, the tip is in the duct's lumen again.
    BackInDuct,
}

/// The result of one call of [`GuideWire::advance`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WireStep {
    /// The axial force resisting the hand (N; along the wire, against the push or the pull).
    pub force_n: f64,
    /// What happened, the last thing if several.
    pub event: Option<WireEvent>,
}

/// A guide wire out of the needle.
#[derive(Debug, Clone)]
pub struct GuideWire {
    spec: WireSpec,
    /// From where it leaves the needle (first) to its tip (last).
    nodes: Vec<DVec3>,
    /// Whether each node lay in the ducts' lumen when it was laid (the first never counts), and
    /// how many of them did: the wire's length in the ducts without sampling every node each tick.
    in_lumen: Vec<bool>,
    lumen_nodes: usize,
    tip_dir: DVec3,
    /// The direction of roll 0, perpendicular to the tip's direction (carried along with it).
    up: DVec3,
    roll_rad: f64,
    /// Length pushed while the tip was blocked: a loop behind the tip (mm).
    folded_mm: f64,
    /// Push (positive) or pull (negative) not yet a whole node.
    pending_mm: f64,
    in_parenchyma: bool,
    /// The force of the wall or the fold at the tip in the last step (N).
    tip_force_n: f64,
}

impl GuideWire {
    /// A wire whose tip just leaves the needle at `exit_mm` along `dir`; `up` (perpendicular to
    /// `dir`) is where a J points at roll 0.
    pub fn new(spec: WireSpec, exit_mm: DVec3, dir: DVec3, up: DVec3) -> GuideWire {
        let tip_dir = dir.try_normalize().unwrap_or(DVec3::Z);
        let up = (up - tip_dir * up.dot(tip_dir))
            .try_normalize()
            .unwrap_or_else(|| tip_dir.any_orthonormal_vector());
        GuideWire {
            spec,
            nodes: vec![exit_mm],
            in_lumen: vec![false],
            lumen_nodes: 0,
            tip_dir,
            up,
            roll_rad: 0.0,
            folded_mm: 0.0,
            pending_mm: 0.0,
            in_parenchyma: false,
            tip_force_n: 0.0,
        }
    }

    /// A wire leaving the needle at `exit_mm` as [`GuideWire::new`], in `channel`: a needle tip
    /// that is not in the ducts' lumen sends the wire into the parenchyma, where it keeps its
    /// direction.
    pub fn from_needle(spec: WireSpec, exit_mm: DVec3, dir: DVec3, up: DVec3, channel: &DuctChannel) -> GuideWire {
        let mut wire = GuideWire::new(spec, exit_mm, dir, up);
        wire.in_parenchyma = channel.depth_mm(exit_mm) < 0.0;
        wire
    }

    /// Lays the wire's start back along `track` (from the skin to where it leaves the needle,
    /// the needle's own track), as the needle comes out over it: the wire then runs from the skin,
    /// nodes [`NODE_MM`] apart along the track, and drawing it back draws its tip out along the
    /// track. At most [`MAX_NODES`] in all.
    pub fn lay_in_track(&mut self, track: &[DVec3], channel: &DuctChannel) {
        let exit = self.nodes[0];
        let mut points: Vec<DVec3> = track.to_vec();
        points.push(exit);
        // From the exit back along the track, a node every NODE_MM.
        let mut laid = Vec::new();
        let mut carry_mm = 0.0;
        for w in points.windows(2).rev() {
            let (from, to) = (w[1], w[0]);
            let seg_mm = from.distance(to);
            let mut at_mm = NODE_MM - carry_mm;
            while at_mm <= seg_mm && laid.len() + self.nodes.len() < MAX_NODES {
                laid.push(from + (to - from) * (at_mm / seg_mm));
                at_mm += NODE_MM;
            }
            carry_mm = seg_mm - (at_mm - NODE_MM);
        }
        laid.reverse();
        laid.append(&mut self.nodes);
        self.nodes = laid;
        self.in_lumen = self.nodes.iter().map(|&p| channel.depth_mm(p) >= 0.0).collect();
        self.in_lumen[0] = false;
        self.lumen_nodes = self.in_lumen.iter().filter(|&&b| b).count();
    }

    /// Lays a node at the tip.
    fn push_node(&mut self, p: DVec3, channel: &DuctChannel) {
        let inside = channel.depth_mm(p) >= 0.0;
        self.nodes.push(p);
        self.in_lumen.push(inside);
        self.lumen_nodes += usize::from(inside);
    }

    /// Takes the tip's node away.
    fn pop_node(&mut self) {
        self.nodes.pop();
        if self.in_lumen.pop() == Some(true) {
            self.lumen_nodes -= 1;
        }
    }

    pub fn spec(&self) -> &WireSpec {
        &self.spec
    }

    /// The nodes from the needle to the tip.
    pub fn nodes(&self) -> &[DVec3] {
        &self.nodes
    }

    pub fn tip_mm(&self) -> DVec3 {
        *self.nodes.last().expect("a wire has its exit node")
    }

    pub fn tip_dir(&self) -> DVec3 {
        self.tip_dir
    }

    /// Feeds the bits of the whole state to `put` (a simulation's digest).
    pub fn digest_into(&self, mut put: impl FnMut(u64)) {
        put(self.nodes.len() as u64);
        for p in &self.nodes {
            p.to_array().iter().for_each(|c| put(c.to_bits()));
        }
        for v in [self.tip_dir, self.up] {
            v.to_array().iter().for_each(|c| put(c.to_bits()));
        }
        for v in [self.roll_rad, self.folded_mm, self.pending_mm, self.tip_force_n] {
            put(v.to_bits());
        }
        put(u64::from(self.in_parenchyma));
        put(self.lumen_nodes as u64);
    }

    /// Length beyond where it leaves the needle (mm), the fold included; once the needle is out
    /// over it ([`GuideWire::lay_in_track`]), beyond the skin.
    pub fn out_mm(&self) -> f64 {
        (self.nodes.len() - 1) as f64 * NODE_MM + self.folded_mm
    }

    /// The loop pushed into a blocked tip (mm).
    pub fn folded_mm(&self) -> f64 {
        self.folded_mm
    }

    /// Whether the tip went through a duct wall and is in the parenchyma.
    pub fn left_duct(&self) -> bool {
        self.in_parenchyma
    }

    /// Length of the wire in the duct lumen (mm), the fold included while the tip is inside.
    pub fn in_ducts_mm(&self) -> f64 {
        let fold = if self.in_parenchyma { 0.0 } else { self.folded_mm };
        self.lumen_nodes as f64 * NODE_MM + fold
    }

    /// Where a J points now: perpendicular to the tip, at the wire's roll from `up`.
    fn bend_dir(&self) -> DVec3 {
        let side = self.tip_dir.cross(self.up);
        self.up * libm::cos(self.roll_rad) + side * libm::sin(self.roll_rad)
    }

    /// The direction the tip leads in.
    fn lead(&self) -> DVec3 {
        match self.spec.tip {
            WireTip::Straight => self.tip_dir,
            WireTip::J => {
                let a = J_LEAD_DEG.to_radians();
                (self.tip_dir * libm::cos(a) + self.bend_dir() * libm::sin(a)).normalize()
            }
        }
    }

    /// Turns the tip to `dir`, carrying the roll's reference along (parallel transport).
    fn turn(&mut self, dir: DVec3) {
        self.tip_dir = dir;
        self.up = (self.up - dir * self.up.dot(dir))
            .try_normalize()
            .unwrap_or_else(|| dir.any_orthonormal_vector());
    }

    /// Pushes (`delta_mm` > 0) or pulls (< 0) the wire at the hub, at most [`MAX_MOVE_MM`], with
    /// the wire rolled to `roll_rad`, in `channel`; `wall_puncture_n` is the force that punctures the duct wall.
    pub fn advance(&mut self, delta_mm: f64, roll_rad: f64, channel: &DuctChannel, wall_puncture_n: f64) -> WireStep {
        if roll_rad.is_finite() {
            self.roll_rad = roll_rad;
        }
        let mut step = WireStep::default();
        if delta_mm.is_finite() {
            self.pending_mm += delta_mm.clamp(-MAX_MOVE_MM, MAX_MOVE_MM);
        }
        while self.pending_mm >= NODE_MM {
            self.pending_mm -= NODE_MM;
            if let Some(e) = self.push_one(channel, wall_puncture_n) {
                step.event = Some(e);
            }
        }
        while self.pending_mm <= -NODE_MM {
            self.pending_mm += NODE_MM;
            if let Some(e) = self.pull_one(channel) {
                step.event = Some(e);
            }
        }
        let duct_mm = self.lumen_nodes as f64 * NODE_MM;
        let tissue_mm = (self.nodes.len() - 1 - self.lumen_nodes) as f64 * NODE_MM;
        let friction = duct_mm * DUCT_FRICTION_N_PER_MM + tissue_mm * TISSUE_FRICTION_N_PER_MM;
        // Sliding friction against the way the wire moves; held still, only what the tip or its
        // fold pushes back with.
        step.force_n = if delta_mm < 0.0 {
            -friction
        } else if delta_mm > 0.0 {
            friction + self.tip_force_n
        } else {
            self.tip_force_n
        };
        step
    }

    /// One node's push.
    fn push_one(&mut self, channel: &DuctChannel, wall_puncture_n: f64) -> Option<WireEvent> {
        if self.nodes.len() >= MAX_NODES {
            self.folded_mm += NODE_MM;
            return None;
        }
        let tip = self.tip_mm();
        let r = self.spec.radius_mm();
        if self.in_parenchyma {
            // Through tissue the tip keeps its direction.
            self.push_node(tip + self.tip_dir * NODE_MM, channel);
            self.tip_force_n = 0.0;
            return None;
        }
        let free = |p: DVec3| channel.depth_mm(p) >= r;
        let course = self.tip_dir;
        if free(tip + course * NODE_MM) {
            self.push_node(tip + course * NODE_MM, channel);
            self.tip_force_n = 0.0;
            return None;
        }
        // At a wall the tip's lead meets it (a J's bend first) and the wall turns the tip, unless
        // it meets it head-on.
        let lead = self.lead();
        let normal = channel.inward(tip + lead * NODE_MM);
        let outward = -lead.dot(normal);
        let head_on = normal == DVec3::ZERO || outward > libm::cos(HEAD_ON_DEG.to_radians());
        if !head_on {
            let along = (lead + normal * outward.max(0.0)).normalize();
            for dir in [along, (along + normal * 0.5).normalize()] {
                if free(tip + dir * NODE_MM) {
                    self.push_node(tip + dir * NODE_MM, channel);
                    self.turn(dir);
                    let sin_glance = outward.clamp(0.0, 1.0);
                    let cot = libm::sqrt(1.0 - sin_glance * sin_glance) / sin_glance.max(1e-3);
                    self.tip_force_n = (self.spec.tip_load_n() / cot.max(1e-3)).min(self.spec.push_limit_n(0.0));
                    return None;
                }
            }
        }
        // Blocked: the wire folds behind the tip (the loop stays until the wire is drawn back);
        // pushed hard enough, a straight tip goes through.
        let first = self.tip_force_n < self.spec.push_limit_n(self.folded_mm);
        self.folded_mm += NODE_MM;
        self.tip_force_n = self.spec.push_limit_n(self.folded_mm);
        if self.spec.tip == WireTip::Straight && head_on && self.tip_force_n >= wall_puncture_n {
            self.in_parenchyma = true;
            self.push_node(tip + self.tip_dir * NODE_MM, channel);
            return Some(WireEvent::LeftDuct);
        }
        first.then_some(WireEvent::Blocked)
    }

    /// One node's pull: the fold first, then the tip back along its track.
    fn pull_one(&mut self, channel: &DuctChannel) -> Option<WireEvent> {
        self.tip_force_n = 0.0;
        if self.folded_mm > 0.0 {
            self.folded_mm = (self.folded_mm - NODE_MM).max(0.0);
            return None;
        }
        if self.nodes.len() < 2 {
            return None;
        }
        self.pop_node();
        let n = self.nodes.len();
        if n >= 2 {
            let dir = (self.nodes[n - 1] - self.nodes[n - 2])
                .try_normalize()
                .unwrap_or(self.tip_dir);
            self.turn(dir);
        }
        if self.in_parenchyma && channel.depth_mm(self.tip_mm()) >= 0.0 {
            self.in_parenchyma = false;
            return Some(WireEvent::BackInDuct);
        }
        None
    }
}
