//! The known displacements ũ of eq. 4.2.7 from the haptic state (thesis §4.2.1, Fig. 4.3).
//!
//! - Needle: the channel (path nodes P, reference space) and the needle (nodes N) at the same
//!   distance d back from the tip, X̃(d) on P and x̃(d) on N, the bendable-needle form of
//!   eqs. 4.2.2–4.2.3: ũ = x̃(d) − X̃(d) every half node spacing along the inserted length, plus
//!   the tissue the shaft's friction drags along: the segment's stick offset Δx_i (eq. 3.5.3)
//!   along its direction d_i. A tip resting on the skin (one path node) pushes the skin point it
//!   touched: ũ = tip − p₁. At the tip, the rigid form x̃(0) − X̃(0) = x_t − p_t of eqs.
//!   4.2.2–4.2.3 adds what the bent needle's nodes leave out: while the tip presses before it cuts
//!   (Alg. 3.5's cutting spring, f_k2·Δd² + f_k1·Δd < f_cutthresh), the device is Δd past the
//!   needle's tip along the channel's direction, and the tissue ahead of the tip gives by Δd
//!   (skin and fascia tent before they are punctured).
//! - Finger and probe: each node in contact x_i, D_skin deep, pushed the skin point above it,
//!   s* = x_i + D_skin·v_s (v_s the outward skin normal), to where the node is, and the stick of
//!   §3.6 dragged it along by the tangential part t of the proxy's offset p_i − s_i: X = s* + t, ũ = x_i − X
//!   (indentation plus tangential drag). (The contact code's s_i = x_i − D_skin·v_s lies as far
//!   below the node as the skin is above it; only p_i − s_i enters its friction.) Over a
//!   patch of 0.6 × the pattern's node spacing around it, so the sparse contact nodes press as
//!   one face rather than as separate needles.

use glam::DVec3;

use super::ToolPoint;
use crate::contact::ContactTool;
use crate::needle::tool::NeedleTool;

/// The point `a` mm back from the last node along a polyline (None beyond its first node): the
/// definition [`FromEnd`] walks incrementally.
#[cfg(test)]
fn polyline_from_end(nodes: &[DVec3], a: f64) -> Option<DVec3> {
    let mut behind = 0.0;
    for w in nodes.windows(2).rev() {
        let (p, q) = (w[1], w[0]);
        let seg = (q - p).length();
        if a - behind <= seg {
            let t = if seg > 0.0 { (a - behind) / seg } else { 0.0 };
            return Some(p + (q - p) * t);
        }
        behind += seg;
    }
    None
}

/// [`polyline_from_end`] for distances that only grow: it resumes where the last one ended, so a
/// needle's points cost one walk along its nodes, not one per point (the same partial sums in
/// the same order, so the same bits).
struct FromEnd<'a> {
    nodes: &'a [DVec3],
    /// The segment from node `j` back to node `j − 1`, and the length behind it.
    j: usize,
    behind: f64,
}

impl<'a> FromEnd<'a> {
    fn new(nodes: &'a [DVec3]) -> Self {
        FromEnd {
            nodes,
            j: nodes.len().saturating_sub(1),
            behind: 0.0,
        }
    }

    /// The point `a` mm back from the last node (`a` never less than at the last call).
    fn at(&mut self, a: f64) -> Option<DVec3> {
        while self.j >= 1 {
            let (p, q) = (self.nodes[self.j], self.nodes[self.j - 1]);
            let seg = (q - p).length();
            if a - self.behind <= seg {
                let t = if seg > 0.0 { (a - self.behind) / seg } else { 0.0 };
                return Some(p + (q - p) * t);
            }
            self.behind += seg;
            self.j -= 1;
        }
        None
    }
}

/// Tool points of a needle, sampled every `step_mm` from the tip.
pub fn needle_points(needle: &NeedleTool, step_mm: f64) -> Vec<ToolPoint> {
    let path = needle.path();
    let nodes = needle.nodes();
    let Some(&tip) = nodes.last() else { return Vec::new() };
    let Some(path_tip) = path.tip() else { return Vec::new() };
    // The cutting spring's extension Δd: how far the device is past the needle's tip along the
    // channel (none while it pulls back).
    let d = path_tip.tangent;
    let tip_push = needle
        .last_device_mm()
        .map_or(DVec3::ZERO, |x| d * (x - tip).dot(d).max(0.0));
    match path.nodes().len() {
        0 => Vec::new(),
        1 => vec![ToolPoint {
            reference_mm: path.nodes()[0].pos,
            displacement_mm: tip - path.nodes()[0].pos + tip_push,
            radius_mm: 0.0,
        }],
        _ => {
            // Walk the channel from the tip back (segment i joins node i to node i − 1): the
            // channel point X̃(d), its segment's friction offset Δx_i along d_i, and the needle
            // point x̃(d) the same distance back from the needle's tip.
            let p = path.nodes();
            let mut out = Vec::new();
            let mut needle_from_end = FromEnd::new(nodes);
            let (mut i, mut behind, mut a) = (p.len() - 1, 0.0, 0.0);
            while i >= 1 {
                let seg = (p[i].pos - p[i - 1].pos).length();
                if a - behind > seg {
                    behind += seg;
                    i -= 1;
                    continue;
                }
                let t = if seg > 0.0 { (a - behind) / seg } else { 0.0 };
                let x_ref = p[i].pos + (p[i - 1].pos - p[i].pos) * t;
                let Some(x) = needle_from_end.at(a) else { break };
                out.push(ToolPoint {
                    reference_mm: x_ref,
                    displacement_mm: (x - x_ref) + p[i].tangent * p[i].offset_mm + tip_push,
                    radius_mm: 0.0,
                });
                a += step_mm;
            }
            out
        }
    }
}

/// Tool points of a finger or probe: its nodes in contact, each over its share of the face.
pub fn contact_points(tool: &ContactTool) -> Vec<ToolPoint> {
    let radius_mm = 0.6 * node_spacing_mm(tool.pattern().points());
    tool.nodes()
        .iter()
        .filter(|n| n.in_contact)
        .map(|n| {
            // s* = x_i + D·v_s = 2 x_i − s_i, dragged by the tangential part of the stick offset
            // p_i − s_i (its normal part is the contact code's lag of s_i, not tissue motion).
            let skin_point = n.pos * 2.0 - n.surface;
            let v_s = (n.pos - n.surface).normalize_or_zero();
            let lag = n.proxy - n.surface;
            let reference_mm = skin_point + (lag - v_s * lag.dot(v_s));
            ToolPoint {
                reference_mm,
                displacement_mm: n.pos - reference_mm,
                radius_mm,
            }
        })
        .collect()
}

/// The largest distance from a node of a contact pattern to its nearest neighbour (0 for one node).
fn node_spacing_mm(points: &[DVec3]) -> f64 {
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            points
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, q)| (*q - *p).length())
                .fold(f64::INFINITY, f64::min)
        })
        .filter(|d| d.is_finite())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contact_patches_cover_the_gaps_between_nodes() {
        use crate::contact::ContactPattern;
        // The fingertip's ring lies 4 mm from its centre: patches of 2.4 mm touch.
        let d = node_spacing_mm(ContactPattern::fingertip().points());
        assert!((d - 4.0).abs() < 0.2, "{d}");
        assert_eq!(node_spacing_mm(&[DVec3::ZERO]), 0.0);
    }

    #[test]
    fn the_incremental_walk_gives_the_bits_of_the_definition() {
        let mut seed = 5u64;
        let mut rnd = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..20 {
            let mut x = DVec3::ZERO;
            let nodes: Vec<DVec3> = (0..40)
                .map(|k| {
                    // Now and then a zero-length segment.
                    if k % 13 != 5 {
                        x += DVec3::new(rnd() - 0.5, rnd() - 0.5, 2.0 * rnd());
                    }
                    x
                })
                .collect();
            let mut walk = FromEnd::new(&nodes);
            let mut a = 0.0;
            while a < 200.0 {
                let (want, got) = (polyline_from_end(&nodes, a), walk.at(a));
                assert_eq!(
                    want.map(|v| v.to_array().map(f64::to_bits)),
                    got.map(|v| v.to_array().map(f64::to_bits)),
                    "a = {a}"
                );
                a += 0.37;
            }
        }
    }

    #[test]
    fn polyline_points_run_back_from_the_end() {
        let nodes = [DVec3::ZERO, DVec3::new(0.0, 0.0, 10.0), DVec3::new(0.0, 5.0, 10.0)];
        assert_eq!(polyline_from_end(&nodes, 0.0), Some(nodes[2]));
        assert_eq!(polyline_from_end(&nodes, 2.0), Some(DVec3::new(0.0, 3.0, 10.0)));
        assert_eq!(polyline_from_end(&nodes, 9.0), Some(DVec3::new(0.0, 0.0, 6.0)));
        assert_eq!(polyline_from_end(&nodes, 16.0), None);
    }
}
