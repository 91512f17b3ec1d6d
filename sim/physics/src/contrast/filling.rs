//! Volume-driven filling of the ducts: what an injection pushes into the duct tree.
//!
//! Diffusion alone (eq. 3.3.1) spreads a few millilitres over a few voxels in the seconds of an
//! injection: far too slow for what fluoroscopy shows (2–5 ml opacify a visible part of the
//! intrahepatic tree within seconds). Injected medium *displaces* the bile ahead of it along the
//! ducts. Here a delivered volume v is placed from the entry node outward in order of path
//! distance along the ducts: each node is topped up to the front's fraction ρ_f of medium (the
//! injected medium mixed with the bile it meets), the nearest first, until v is placed:
//!
//!   Σ_{i in path order} (ρ_f − ρᵢ)⁺ · V_node = v.
//!
//! Nodes behind the front that diffusion has diluted are topped up again first, as the column of
//! medium behind the front is pushed on. Once every node the entry connects to holds ρ_f, the
//! rest raises them towards undiluted medium (ρ = 1) in the same order; what still does not fit
//! has left the segmented tree (into ducts too small to segment, or the duodenum). Diffusion
//! behind and ahead of the front (eq. 3.3.2) then dilutes and smooths it.

/// Places `amount_ml` of medium along `order` (slots by increasing path distance from the entry)
/// in `rho` (volume fraction per slot): first up to `front_fraction`, then up to 1. Returns what
/// did not fit (ml).
pub(super) fn fill(rho: &mut [f64], order: &[u32], node_volume_ml: f64, front_fraction: f64, amount_ml: f64) -> f64 {
    let mut left_ml = amount_ml;
    for cap in [front_fraction, 1.0] {
        for &s in order {
            if left_ml <= 0.0 {
                return 0.0;
            }
            let r = &mut rho[s as usize];
            let room_ml = (cap - *r) * node_volume_ml;
            if room_ml > 0.0 {
                let take_ml = room_ml.min(left_ml);
                *r += take_ml / node_volume_ml;
                left_ml -= take_ml;
            }
        }
    }
    left_ml.max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_nearest_nodes_fill_to_the_front_first() {
        let mut rho = vec![0.0; 5];
        let order = [2, 3, 1, 4, 0];
        // 0.12 ml into nodes of 0.1 ml at ρ_f = 0.5: 0.05 ml to each of the two nearest, the
        // remaining 0.02 ml to the third.
        assert_eq!(fill(&mut rho, &order, 0.1, 0.5, 0.12), 0.0);
        let want = [0.0, 0.2, 0.5, 0.5, 0.0];
        assert!(rho.iter().zip(want).all(|(r, w)| (r - w).abs() < 1e-12), "{rho:?}");
    }

    #[test]
    fn a_diluted_node_behind_the_front_is_topped_up_before_the_front_moves() {
        let mut rho = vec![0.3, 0.5, 0.0];
        fill(&mut rho, &[0, 1, 2], 1.0, 0.5, 0.3);
        let want = [0.5, 0.5, 0.1];
        assert!(rho.iter().zip(want).all(|(r, w)| (r - w).abs() < 1e-12), "{rho:?}");
    }

    #[test]
    fn a_full_tree_takes_undiluted_medium_and_then_overflows() {
        let mut rho = vec![0.5, 0.5];
        let left = fill(&mut rho, &[1, 0], 1.0, 0.5, 1.5);
        assert_eq!(rho, vec![1.0, 1.0]);
        assert!((left - 0.5).abs() < 1e-15);
    }

    #[test]
    fn what_is_placed_plus_what_is_left_is_what_was_delivered() {
        let mut rho: Vec<f64> = (0..50).map(|i| f64::from(i % 7) * 0.1).collect();
        let before: f64 = rho.iter().sum();
        let order: Vec<u32> = (0..50).rev().collect();
        for amount in [0.0, 0.013, 0.7, 3.0] {
            let at_start: f64 = rho.iter().sum();
            let left = fill(&mut rho, &order, 0.02, 0.4, amount);
            let placed = (rho.iter().sum::<f64>() - at_start) * 0.02;
            assert!((placed + left - amount).abs() < 1e-12, "{amount}: {placed} + {left}");
            assert!(rho.iter().all(|&r| r <= 1.0));
        }
        assert!(rho.iter().sum::<f64>() > before);
    }
}
