//! The needle's node tangents: the direction of the central difference at each node (one-sided
//! at the ends), normalised, or the chord's direction where two nodes coincide.
//!
//! Each tangent costs a square root and a division, and they do not depend on one another, so
//! four are worked out at once in `crate::lanes` (AVX2 where the CPU has it): every lane does
//! glam's `normalize_or` operations in its order, so the bits are those of one at a time.

use glam::DVec3;

use crate::lanes::{F4, LANES, Lane, V4, Vec4s, has_avx2};

/// `out[j] = (nodes[b] − nodes[a]).normalize_or(fallback)` with (a, b) = (0, 1) at the hub,
/// (m − 2, m − 1) at the tip and (j − 1, j + 1) between. `nodes` and `out` have the same length,
/// at least 2.
pub fn tangents(nodes: &[DVec3], fallback: DVec3, out: &mut [DVec3]) {
    assert!(
        nodes.len() >= 2 && out.len() == nodes.len(),
        "tangents need ≥ 2 nodes and one slot each"
    );
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 (checked above).
        return unsafe { tangents_avx2(nodes, fallback, out) };
    }
    tangents_in::<F4>(nodes, fallback, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn tangents_avx2(nodes: &[DVec3], fallback: DVec3, out: &mut [DVec3]) {
    tangents_in::<crate::lanes::avx::Avx>(nodes, fallback, out)
}

/// The central difference's ends at node `j` of `m`.
#[inline(always)]
fn ends(j: usize, m: usize) -> (usize, usize) {
    if j == 0 {
        (0, 1)
    } else if j == m - 1 {
        (m - 2, m - 1)
    } else {
        (j - 1, j + 1)
    }
}

#[inline(always)]
fn tangents_in<L: Lane>(nodes: &[DVec3], fallback: DVec3, out: &mut [DVec3]) {
    let m = nodes.len();
    let fb = V4 {
        x: L::splat(fallback.x),
        y: L::splat(fallback.y),
        z: L::splat(fallback.z),
    };
    for start in (0..m).step_by(LANES) {
        let n = LANES.min(m - start);
        // Unused lanes repeat the last node's difference; their results are dropped.
        let mut diff = Vec4s::default();
        for lane in 0..LANES {
            let (a, b) = ends(start + lane.min(n - 1), m);
            diff.set(lane, nodes[b] - nodes[a]);
        }
        let t = V4::<L>::load(&diff).normalize_or(fb).store();
        for (lane, o) in out[start..start + n].iter_mut().enumerate() {
            *o = t.get(lane);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// glam's one-at-a-time tangents, the reference.
    fn one_at_a_time(nodes: &[DVec3], fallback: DVec3) -> Vec<DVec3> {
        (0..nodes.len())
            .map(|j| {
                let (a, b) = ends(j, nodes.len());
                (nodes[b] - nodes[a]).normalize_or(fallback)
            })
            .collect()
    }

    #[test]
    fn four_at_a_time_give_the_bits_of_one_at_a_time() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state = crate::motion::signal::mix64(state);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let fallback = DVec3::new(0.0, 0.6, 0.8);
        for m in 2..40 {
            for case in 0..20 {
                let mut nodes: Vec<DVec3> = (0..m)
                    .map(|j| DVec3::new(next(), next(), j as f64 * 5.0) * libm::pow(10.0, (case % 7 - 3) as f64))
                    .collect();
                // Coincident nodes (the fallback), subnormal and huge differences, NaN.
                match case {
                    3 => nodes[m / 2] = nodes[(m / 2).saturating_sub(1)],
                    4 if m >= 3 => nodes[2] = nodes[0],
                    5 => nodes[m - 1] = nodes[m - 2] + DVec3::splat(1e-310),
                    6 => nodes[0].x = f64::NAN,
                    7 => nodes[m - 1] = DVec3::splat(1e300),
                    _ => {}
                }
                let mut batched = vec![DVec3::ZERO; m];
                tangents(&nodes, fallback, &mut batched);
                let mut portable = vec![DVec3::ZERO; m];
                tangents_in::<F4>(&nodes, fallback, &mut portable);
                let bits = |v: &[DVec3]| {
                    v.iter()
                        .flat_map(|d| d.to_array().map(f64::to_bits))
                        .collect::<Vec<_>>()
                };
                let reference = one_at_a_time(&nodes, fallback);
                assert_eq!(bits(&batched), bits(&reference), "m {m} case {case}");
                assert_eq!(bits(&portable), bits(&reference), "m {m} case {case}");
            }
        }
    }
}
