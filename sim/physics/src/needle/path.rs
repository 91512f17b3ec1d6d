//! The insertion channel: path nodes P = {p_1 … p_l} with tangents d_i in reference space, and the
//! per-segment friction state (thesis §3.5.1, §3.5.3; docs/physics.md).
//!
//! Only the tip node p_l moves; the others stay where they were laid down, so materials are looked
//! up at the tip (and once when a node is created).

use glam::DVec3;

/// One node of the channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathNode {
    pub pos: DVec3,
    /// d_i: the needle's direction when the node was laid down (unit).
    pub tangent: DVec3,
    /// Δx_i of eq. 3.5.3: friction offset of the segment ending at this node (mm).
    pub offset_mm: f64,
    /// f_k(p_i): tissue stiffness at the node (N/mm).
    pub stiffness_n_per_mm: f64,
    /// f_R(p_i): maximum friction of a Δp-long segment at the node (N).
    pub friction_max_n: f64,
}

/// Material parameters at the tip, evaluated through the property tree (§6.1.4).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TipMaterial {
    pub cut_spring_n_per_mm: f64,
    pub cut_spring_n_per_mm2: f64,
    pub cut_threshold_n: f64,
    pub stiffness_n_per_mm: f64,
    /// Maximum friction per Δp segment (N).
    pub friction_max_n: f64,
}

/// The channel and its fixed node spacing Δp.
///
/// Beyond the thesis: nodes given up when the tip retracts are kept (`ahead`, deepest last) as
/// the part of the channel already cut. Re-advancing along it (tip direction within
/// [`CHANNEL_ALIGNMENT_COS`] of the channel's) meets no cutting threshold and lays the old nodes
/// back; turning away from it (a redirection) forgets it. Without this, a hand's tremor would
/// ratchet the needle out of the body: Alg. 3.5 lets the tip retract freely but cut forward
/// only above the threshold.
#[derive(Debug, Clone, PartialEq)]
pub struct InsertionPath {
    nodes: Vec<PathNode>,
    ahead: Vec<PathNode>,
    spacing_mm: f64,
    /// ‖p_i − p_{i−1}‖ for every node (0 for the first): only the last nodes move, so the lengths
    /// are kept instead of recomputed (the same values, bit for bit, as computing them afresh).
    seg_mm: Vec<f64>,
    /// Σ seg_mm, summed in node order whenever a segment changes.
    inserted_mm: f64,
    /// Per node: seg_mm / Δp and the friction offset limit f_R / f_k (eq. 3.5.4), kept with the
    /// segment lengths (only the last nodes change).
    seg_ratio: Vec<f64>,
    offset_limit_mm: Vec<f64>,
}

/// Cosine of the largest angle between the tip direction and an existing channel at which the
/// needle still follows the channel (8°).
pub const CHANNEL_ALIGNMENT_COS: f64 = 0.990;

/// How many nodes one tick may add or remove (a device jump of 32 Δp in 1 ms is not a hand).
const MAX_NODE_CHANGES_PER_TICK: usize = 32;

impl InsertionPath {
    pub fn new(spacing_mm: f64) -> Self {
        InsertionPath {
            nodes: Vec::with_capacity(256),
            ahead: Vec::with_capacity(256),
            spacing_mm,
            seg_mm: Vec::with_capacity(256),
            inserted_mm: 0.0,
            seg_ratio: Vec::with_capacity(256),
            offset_limit_mm: Vec::with_capacity(256),
        }
    }

    pub fn nodes(&self) -> &[PathNode] {
        &self.nodes
    }
    pub fn len(&self) -> usize {
        self.nodes.len()
    }
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }
    pub fn spacing_mm(&self) -> f64 {
        self.spacing_mm
    }
    pub fn clear(&mut self) {
        self.nodes.clear();
        self.ahead.clear();
        self.seg_mm.clear();
        self.seg_ratio.clear();
        self.offset_limit_mm.clear();
        self.inserted_mm = 0.0;
    }

    /// Recomputes the segment lengths from node `from` on (after nodes there changed).
    fn refresh_segments(&mut self, from: usize) {
        let from = from.min(self.nodes.len());
        self.seg_mm.truncate(from);
        self.seg_ratio.truncate(from);
        self.offset_limit_mm.truncate(from);
        for i in from..self.nodes.len() {
            let len = if i == 0 {
                0.0
            } else {
                self.nodes[i].pos.distance(self.nodes[i - 1].pos)
            };
            self.seg_mm.push(len);
            self.seg_ratio.push(len / self.spacing_mm);
            let n = &self.nodes[i];
            self.offset_limit_mm.push(if n.stiffness_n_per_mm > 0.0 {
                n.friction_max_n / n.stiffness_n_per_mm
            } else {
                0.0
            });
        }
        self.inserted_mm = self.seg_mm.iter().skip(1).sum();
    }

    /// The part of the channel cut earlier and retracted from (deepest node last).
    pub fn ahead(&self) -> &[PathNode] {
        &self.ahead
    }

    /// Whether the tip, moving along its direction, follows the channel cut earlier.
    fn in_existing_channel(&self) -> bool {
        match (self.ahead.last(), self.nodes.last()) {
            (Some(next), Some(tip)) => next.tangent.dot(tip.tangent) >= CHANNEL_ALIGNMENT_COS,
            _ => false,
        }
    }
    pub fn tip(&self) -> Option<&PathNode> {
        self.nodes.last()
    }
    /// Steering (Alg. 3.3 lines 6–7): the tip node takes the needle tip's direction.
    pub fn set_tip_tangent(&mut self, d: DVec3) {
        if let Some(tip) = self.nodes.last_mut() {
            tip.tangent = d;
        }
    }

    /// Inserted length Σ ‖p_i − p_{i−1}‖ (mm).
    pub fn inserted_length_mm(&self) -> f64 {
        self.inserted_mm
    }

    /// Alg. 3.5, compPTipMov: the tip's movement for device position `x`. Forward (Δd ≥ 0) only
    /// when the cutting force f_k2·Δd² + f_k1·Δd exceeds f_cutthresh and the needle is not fully
    /// inserted, by exactly as much as leaves the spring at the threshold; backward freely, towards
    /// the node behind the tip. Needs at least two nodes.
    pub fn tip_movement(&self, x: DVec3, m: &TipMaterial, needle_length_mm: f64) -> DVec3 {
        let l = self.nodes.len();
        debug_assert!(l >= 2);
        let tip = self.nodes[l - 1];
        let d = tip.tangent;
        let dd = (x - tip.pos).dot(d);
        if dd >= 0.0 {
            let (k1, k2) = (m.cut_spring_n_per_mm, m.cut_spring_n_per_mm2);
            // In the channel cut earlier there is nothing left to cut.
            let t = if self.in_existing_channel() {
                0.0
            } else {
                m.cut_threshold_n
            };
            let f = k2 * dd * dd + k1 * dd;
            if f > t && self.inserted_length_mm() < needle_length_mm {
                let advance = if k2 == 0.0 {
                    // Linear spring: leave the extension t / k1 (the OCR writes f_cut for f_cutthresh).
                    if k1 > 0.0 { dd - t / k1 } else { dd }
                } else {
                    let a = 0.5 * k1 / k2;
                    let b = t / k2;
                    dd + a - (a * a + b).sqrt()
                };
                d * advance.max(0.0)
            } else {
                DVec3::ZERO
            }
        } else {
            let back = tip.pos - self.nodes[l - 2].pos;
            let len = back.length();
            if len > 0.0 { back * (dd / len) } else { d * dd }
        }
    }

    /// Alg. 3.4, updatePathNodes, for device position `x`. `material_at` gives the friction
    /// parameters of a new node from its position; `first_contact` says whether the device tip
    /// touches tissue (l(x) ≠ air). Returns whether the path changed its number of nodes.
    pub fn update(
        &mut self,
        x: DVec3,
        direction: DVec3,
        tip: &TipMaterial,
        needle_length_mm: f64,
        first_contact: bool,
        material_at: &mut dyn FnMut(DVec3) -> (f64, f64),
    ) {
        let dp = self.spacing_mm;
        let mut min_len = self.nodes.len();
        self.update_nodes(
            x,
            direction,
            tip,
            needle_length_mm,
            first_contact,
            material_at,
            &mut min_len,
            dp,
        );
        self.refresh_segments(min_len.saturating_sub(2));
    }

    #[allow(clippy::too_many_arguments)]
    fn update_nodes(
        &mut self,
        x: DVec3,
        direction: DVec3,
        tip: &TipMaterial,
        needle_length_mm: f64,
        first_contact: bool,
        material_at: &mut dyn FnMut(DVec3) -> (f64, f64),
        min_len: &mut usize,
        dp: f64,
    ) {
        match self.nodes.len() {
            0 => {
                if first_contact {
                    self.nodes.push(PathNode {
                        pos: x,
                        tangent: direction,
                        offset_mm: 0.0,
                        stiffness_n_per_mm: tip.stiffness_n_per_mm,
                        friction_max_n: tip.friction_max_n,
                    });
                }
            }
            1 => {
                let p1 = self.nodes[0];
                let dd = (x - p1.pos).dot(p1.tangent);
                if dd > 0.0 {
                    let pos = p1.pos + p1.tangent * dd;
                    let (k, r) = material_at(pos);
                    self.nodes.push(PathNode {
                        pos,
                        tangent: p1.tangent,
                        offset_mm: 0.0,
                        stiffness_n_per_mm: k,
                        friction_max_n: r,
                    });
                } else if dd < 0.0 {
                    self.clear();
                    *min_len = 0;
                }
            }
            _ => {
                if !self.ahead.is_empty() && !self.in_existing_channel() {
                    // Turned away from the old channel: cutting new tissue from here on.
                    self.ahead.clear();
                }
                let mv = self.tip_movement(x, tip, needle_length_mm);
                let l = self.nodes.len();
                self.nodes[l - 1].pos += mv;
                self.nodes[l - 1].stiffness_n_per_mm = tip.stiffness_n_per_mm;
                self.nodes[l - 1].friction_max_n = tip.friction_max_n;
                for _ in 0..MAX_NODE_CHANGES_PER_TICK {
                    let l = self.nodes.len();
                    if l < 2 {
                        break;
                    }
                    let (prev, tip_node) = (self.nodes[l - 2], self.nodes[l - 1]);
                    let dl = (tip_node.pos - prev.pos).dot(prev.tangent);
                    if dl > 1.5 * dp {
                        // Insert a node Δp ahead of p_{l−1}, i.e. just behind the tip.
                        let node = match self.ahead.pop() {
                            // Back in the old channel: its node again.
                            Some(old) => PathNode { offset_mm: 0.0, ..old },
                            None => {
                                let pos = prev.pos + prev.tangent * dp;
                                let (k, r) = material_at(pos);
                                PathNode {
                                    pos,
                                    tangent: tip_node.tangent,
                                    offset_mm: 0.0,
                                    stiffness_n_per_mm: k,
                                    friction_max_n: r,
                                }
                            }
                        };
                        self.nodes.insert(l - 1, node);
                    } else if dl < 0.5 * dp && l > 2 {
                        // The tip came back to the node behind it: remove that node.
                        let removed = self.nodes.remove(l - 2);
                        *min_len = (*min_len).min(self.nodes.len());
                        // The tip inherits the removed segment's friction state (the offset of
                        // the tissue the tip now sits in); the node stays as channel ahead.
                        self.nodes[l - 2].offset_mm = removed.offset_mm;
                        self.ahead.push(removed);
                    } else if dl < 0.0 {
                        // Only two nodes and the tip is behind the first: withdrawn.
                        self.clear();
                        *min_len = 0;
                        break;
                    } else {
                        break;
                    }
                }
            }
        }
    }

    /// Eqs. 3.5.3–3.5.4: moves every segment's friction offset by the device's axial motion `dx`
    /// (clamped to ±f_R/f_k) and returns the total friction f⁺ (N, positive when the offsets point
    /// along the insertion direction).
    pub fn update_friction(&mut self, dx: f64) -> f64 {
        let mut total = 0.0;
        let (ratio, limit) = (&self.seg_ratio, &self.offset_limit_mm);
        for ((n, &ratio), &limit) in self.nodes.iter_mut().zip(ratio).zip(limit).skip(1) {
            n.offset_mm = (n.offset_mm + dx).clamp(-limit, limit);
            total += n.stiffness_n_per_mm * ratio * n.offset_mm;
        }
        total
    }

    /// The channel points at distances `a` back from the tip along the path, with the tissue
    /// stiffness there, for increasing `a`, in one pass over the channel (O(l + queries)): calls
    /// `found(id, point, stiffness)` for each `(id, a)` that lies within the channel; the rest
    /// are beyond the first node (outside the body).
    pub fn points_from_tip(
        &self,
        queries: impl IntoIterator<Item = (usize, f64)>,
        mut found: impl FnMut(usize, DVec3, f64),
    ) {
        let l = self.nodes.len();
        if l < 2 {
            return;
        }
        // Segment i runs from node i (nearer the tip) back to node i − 1; `behind` is the arc
        // length from the tip to node i.
        let (mut i, mut behind) = (l - 1, 0.0);
        for (id, a) in queries {
            debug_assert!(a >= behind, "queries must come in increasing order");
            while a - behind > self.seg_mm[i] {
                behind += self.seg_mm[i];
                i -= 1;
                if i == 0 {
                    return;
                }
            }
            let (p, q, seg) = (self.nodes[i].pos, self.nodes[i - 1].pos, self.seg_mm[i]);
            let t = if seg > 0.0 { (a - behind) / seg } else { 0.0 };
            found(id, p + (q - p) * t, self.nodes[i].stiffness_n_per_mm);
        }
    }

    /// The channel point `a` mm back from the tip (see [`InsertionPath::points_from_tip`]).
    pub fn point_from_tip(&self, a: f64) -> Option<(DVec3, f64)> {
        let mut r = None;
        self.points_from_tip([(0, a)], |_, p, k| r = Some((p, k)));
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mat(k1: f64, t: f64) -> TipMaterial {
        TipMaterial {
            cut_spring_n_per_mm: k1,
            cut_spring_n_per_mm2: 0.0,
            cut_threshold_n: t,
            stiffness_n_per_mm: 0.5,
            friction_max_n: 0.015,
        }
    }

    fn path_along_z(n: usize) -> InsertionPath {
        let mut p = InsertionPath::new(1.5);
        for i in 0..n {
            p.nodes.push(PathNode {
                pos: DVec3::new(0.0, 0.0, 1.5 * i as f64),
                tangent: DVec3::Z,
                offset_mm: 0.0,
                stiffness_n_per_mm: 0.5,
                friction_max_n: 0.015,
            });
        }
        p.refresh_segments(0);
        p
    }

    #[test]
    fn the_tip_advances_only_beyond_the_cutting_threshold() {
        let p = path_along_z(3);
        let tip = 3.0;
        // 0.5 N/mm spring, 2.5 N threshold: below 5 mm of extension nothing moves.
        assert_eq!(
            p.tip_movement(DVec3::new(0.0, 0.0, tip + 4.9), &mat(0.5, 2.5), 150.0),
            DVec3::ZERO
        );
        // At 6 mm the tip moves 1 mm, leaving exactly the threshold on the spring.
        let mv = p.tip_movement(DVec3::new(0.0, 0.0, tip + 6.0), &mat(0.5, 2.5), 150.0);
        assert!((mv.z - 1.0).abs() < 1e-12, "{mv}");
        // Fully inserted: no advance.
        assert_eq!(
            p.tip_movement(DVec3::new(0.0, 0.0, tip + 6.0), &mat(0.5, 2.5), 3.0),
            DVec3::ZERO
        );
        // Backward is free, along the channel.
        let mv = p.tip_movement(DVec3::new(0.0, 0.0, tip - 1.0), &mat(0.5, 2.5), 150.0);
        assert!((mv.z + 1.0).abs() < 1e-12);
    }

    #[test]
    fn quadratic_spring_leaves_the_threshold() {
        let p = path_along_z(3);
        let m = TipMaterial {
            cut_spring_n_per_mm2: 0.1,
            ..mat(0.5, 2.5)
        };
        let x = DVec3::new(0.0, 0.0, 3.0 + 8.0);
        let mv = p.tip_movement(x, &m, 150.0);
        let left = 8.0 - mv.z;
        let f = 0.1 * left * left + 0.5 * left;
        assert!((f - 2.5).abs() < 1e-9, "{f}");
    }

    #[test]
    fn nodes_are_laid_down_and_picked_up() {
        let mut p = InsertionPath::new(1.5);
        let m = mat(0.2, 0.0);
        let mut mat_at = |_: DVec3| (0.5, 0.015);
        p.update(DVec3::ZERO, DVec3::Z, &m, 150.0, true, &mut mat_at);
        assert_eq!(p.len(), 1);
        for i in 1..=40 {
            p.update(
                DVec3::new(0.0, 0.0, 0.5 * i as f64),
                DVec3::Z,
                &m,
                150.0,
                true,
                &mut mat_at,
            );
        }
        let n = p.len();
        assert!((p.inserted_length_mm() - 20.0).abs() < 1e-9);
        assert!((13..=15).contains(&n), "{n} nodes for 20 mm at 1.5 mm spacing");
        for i in (0..40).rev() {
            p.update(
                DVec3::new(0.0, 0.0, 0.5 * i as f64 - 0.25),
                DVec3::Z,
                &m,
                150.0,
                true,
                &mut mat_at,
            );
        }
        assert!(p.is_empty(), "withdrawn: {} nodes left", p.len());
    }

    /// Retracting and re-advancing along the same direction needs no cutting force: the channel
    /// is already cut; turning away from it cuts anew.
    #[test]
    fn the_cut_channel_is_remembered() {
        let mut p = InsertionPath::new(1.5);
        let m = mat(0.5, 1.0); // 2 mm of extension before the tip cuts
        let mut mat_at = |_: DVec3| (0.5, 0.015);
        let z = |v: f64| DVec3::new(0.0, 0.0, v);
        p.update(z(0.0), DVec3::Z, &m, 150.0, true, &mut mat_at);
        for i in 1..=60 {
            p.update(z(0.5 * i as f64), DVec3::Z, &m, 150.0, true, &mut mat_at);
        }
        let deep = p.inserted_length_mm();
        assert!((deep - 28.0).abs() < 1e-9, "{deep}"); // 30 mm minus the 2 mm spring
        for i in 1..=20 {
            p.update(z(30.0 - 0.5 * i as f64), DVec3::Z, &m, 150.0, true, &mut mat_at);
        }
        assert!((p.inserted_length_mm() - 20.0).abs() < 1e-6 && !p.ahead().is_empty());
        // Forward again: the tip follows the device without lagging by the spring extension.
        for i in 1..=14 {
            p.update(z(20.0 + 0.5 * i as f64), DVec3::Z, &m, 150.0, true, &mut mat_at);
        }
        assert!(
            (p.inserted_length_mm() - 27.0).abs() < 1e-6,
            "{}",
            p.inserted_length_mm()
        );
        // A new direction: the old channel is forgotten.
        p.set_tip_tangent(DVec3::new(0.3, 0.0, 1.0).normalize());
        p.update(z(27.5), DVec3::Z, &m, 150.0, true, &mut mat_at);
        assert!(p.ahead().is_empty());
    }

    #[test]
    fn friction_saturates_per_segment_and_flips_with_motion() {
        let mut p = path_along_z(11);
        let f = p.update_friction(1.0);
        // 10 segments × f_R = 0.015 N each once saturated.
        assert!((f - 0.15).abs() < 1e-12, "{f}");
        let f = p.update_friction(-2.0);
        assert!((f + 0.15).abs() < 1e-12, "{f}");
    }

    #[test]
    fn points_back_from_the_tip() {
        let p = path_along_z(5);
        let (q, _) = p.point_from_tip(2.0).unwrap();
        assert!((q.z - 4.0).abs() < 1e-12);
        assert!(p.point_from_tip(6.5).is_none());
        assert_eq!(p.point_from_tip(6.0).unwrap().0, DVec3::ZERO);
        // One pass answers many queries in order; the ones beyond the channel are left out.
        let mut got = Vec::new();
        p.points_from_tip(
            [(7, 0.0), (8, 1.5), (9, 2.25), (10, 5.9), (11, 6.1), (12, 9.0)],
            |id, q, _| got.push((id, q.z)),
        );
        let want = [(7, 6.0), (8, 4.5), (9, 3.75), (10, 0.1)];
        assert_eq!(got.len(), want.len());
        for ((id, z), (wid, wz)) in got.iter().zip(want) {
            assert!(*id == wid && (z - wz).abs() < 1e-12, "{got:?}");
        }
    }
}
