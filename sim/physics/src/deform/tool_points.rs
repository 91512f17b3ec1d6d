//! The known displacements ũ of eq. 4.2.7 from the haptic state (thesis §4.2.1, Fig. 4.3).
//!
//! - Needle: the channel (path nodes P, reference space) and the needle (nodes N) at the same
//!   distance d back from the tip, X̃(d) on P and x̃(d) on N, the bendable-needle form of
//!   eqs. 4.2.2–4.2.3: ũ = x̃(d) − X̃(d) every half node spacing along the inserted length. A tip
//!   resting on the skin (one path node) pushes the skin point it touched: ũ = tip − p₁.
//! - Finger and probe: each node in contact drags the skin point under its friction proxy to
//!   where the node is, ũ = x_i − p_i (indentation plus the tangential stick of §3.6).

use glam::DVec3;

use super::ToolPoint;
use crate::contact::ContactTool;
use crate::needle::tool::NeedleTool;

/// The point `a` mm back from the last node along a polyline (None beyond its first node).
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

/// Tool points of a needle, sampled every `step_mm` from the tip.
pub fn needle_points(needle: &NeedleTool, step_mm: f64) -> Vec<ToolPoint> {
    let path = needle.path();
    let nodes = needle.nodes();
    let Some(&tip) = nodes.last() else { return Vec::new() };
    match path.nodes().len() {
        0 => Vec::new(),
        1 => vec![ToolPoint {
            reference_mm: path.nodes()[0].pos,
            displacement_mm: tip - path.nodes()[0].pos,
        }],
        _ => {
            let len = path.inserted_length_mm();
            let count = (len / step_mm) as usize + 1;
            let mut out = Vec::with_capacity(count);
            path.points_from_tip((0..count).map(|i| (i, i as f64 * step_mm)), |i, x_ref, _| {
                if let Some(x) = polyline_from_end(nodes, i as f64 * step_mm) {
                    out.push(ToolPoint {
                        reference_mm: x_ref,
                        displacement_mm: x - x_ref,
                    });
                }
            });
            out
        }
    }
}

/// Tool points of a finger or probe: its nodes in contact.
pub fn contact_points(tool: &ContactTool) -> Vec<ToolPoint> {
    tool.nodes()
        .iter()
        .filter(|n| n.in_contact)
        .map(|n| ToolPoint {
            reference_mm: n.proxy,
            displacement_mm: n.pos - n.proxy,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polyline_points_run_back_from_the_end() {
        let nodes = [DVec3::ZERO, DVec3::new(0.0, 0.0, 10.0), DVec3::new(0.0, 5.0, 10.0)];
        assert_eq!(polyline_from_end(&nodes, 0.0), Some(nodes[2]));
        assert_eq!(polyline_from_end(&nodes, 2.0), Some(DVec3::new(0.0, 3.0, 10.0)));
        assert_eq!(polyline_from_end(&nodes, 9.0), Some(DVec3::new(0.0, 0.0, 6.0)));
        assert_eq!(polyline_from_end(&nodes, 16.0), None);
    }
}
