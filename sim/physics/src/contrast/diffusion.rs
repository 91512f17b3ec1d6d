//! One explicit step of thesis eq. 3.3.2 over the duct nodes:
//!
//!   ρᵢ⁺ = ρᵢ + τ·(Σ_{j∈N} ρⱼ − |N|·ρᵢ)
//!
//! Jacobi: every new value is computed from the old ones alone, so the order in which the nodes
//! are visited does not change a bit. The nodes are visited grouped by their number of duct
//! neighbours |N| (0 … 6): each group's loop reads exactly |N| neighbours, with no end-of-list
//! test per neighbour (a branch the CPU cannot predict along the duct tree's walls). Within a
//! node the neighbours are summed in the same order as before (−x, +x, −y, +y, −z, +z), so ρᵢ⁺
//! is the same number bit for bit.

/// The duct neighbours of every slot, grouped by their count.
#[derive(Debug, Clone)]
pub(super) struct DuctNeighbours {
    /// How many slots the diffusion's vectors (`rho`) hold.
    slots: usize,
    /// `groups[c]`: the slots with c duct neighbours (increasing).
    groups: [Vec<u32>; 7],
    /// `neighbours[c]`: c neighbour slots for each entry of `groups[c]`, one after the other.
    neighbours: [Vec<u32>; 7],
}

impl DuctNeighbours {
    /// From each slot's neighbour slots in summation order (`lists[s]` for slot s). Neighbours
    /// must be slots (< `lists.len()`), at most 6 per slot.
    pub(super) fn new<'a>(lists: impl ExactSizeIterator<Item = &'a [u32]>) -> DuctNeighbours {
        let slots = lists.len();
        let mut groups: [Vec<u32>; 7] = Default::default();
        let mut neighbours: [Vec<u32>; 7] = Default::default();
        for (s, list) in lists.enumerate() {
            let c = list.len();
            assert!(c <= 6, "slot {s} has {c} neighbours (at most 6)");
            assert!(
                list.iter().all(|&j| (j as usize) < slots),
                "slot {s} has a neighbour outside the {slots} slots"
            );
            groups[c].push(s as u32);
            neighbours[c].extend_from_slice(list);
        }
        DuctNeighbours {
            slots,
            groups,
            neighbours,
        }
    }

    /// Number of slots.
    pub(super) fn len(&self) -> usize {
        self.slots
    }

    /// `next` ← one step of eq. 3.3.2 from `rho` with step τ (`tau`).
    pub(super) fn step(&self, rho: &[f64], next: &mut [f64], tau: f64) {
        assert!(
            rho.len() == self.slots && next.len() == self.slots,
            "the diffusion's vectors have {} and {} values for {} slots",
            rho.len(),
            next.len(),
            self.slots
        );
        self.group::<0>(rho, next, tau);
        self.group::<1>(rho, next, tau);
        self.group::<2>(rho, next, tau);
        self.group::<3>(rho, next, tau);
        self.group::<4>(rho, next, tau);
        self.group::<5>(rho, next, tau);
        self.group::<6>(rho, next, tau);
    }

    /// The slots with `C` neighbours. Sum and count are formed as the one-list-per-slot loop
    /// formed them (0.0, then each neighbour in turn; |N| = C exactly).
    #[inline(always)]
    fn group<const C: usize>(&self, rho: &[f64], next: &mut [f64], tau: f64) {
        let slots = &self.groups[C];
        let neighbours = &self.neighbours[C];
        debug_assert_eq!(neighbours.len(), slots.len() * C);
        let count = C as f64;
        for (i, &s) in slots.iter().enumerate() {
            let s = s as usize;
            // SAFETY: `new` checked every slot and neighbour < `self.slots`, `step` that both
            // vectors hold `self.slots` values, and `neighbours[C]` holds C entries per slot.
            unsafe {
                let r = *rho.get_unchecked(s);
                let mut sum = 0.0;
                for k in 0..C {
                    sum += *rho.get_unchecked(*neighbours.get_unchecked(i * C + k) as usize);
                }
                *next.get_unchecked_mut(s) = r + tau * (sum - count * r);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The step as it was written before the grouping: one list per slot, ended by the first
    /// `u32::MAX`, visited in slot order.
    fn step_one_list_per_slot(lists: &[[u32; 6]], rho: &[f64], tau: f64) -> Vec<f64> {
        lists
            .iter()
            .enumerate()
            .map(|(s, nb)| {
                let r = rho[s];
                let mut sum = 0.0;
                let mut count = 0.0;
                for &j in nb {
                    if j == u32::MAX {
                        break;
                    }
                    sum += rho[j as usize];
                    count += 1.0;
                }
                r + tau * (sum - count * r)
            })
            .collect()
    }

    /// A SplitMix64 stream (the breathing signal's mixer): a test's random numbers.
    struct Stream(u64);
    impl Stream {
        fn next(&mut self) -> u64 {
            self.0 += 1;
            crate::motion::signal::mix64(self.0)
        }
    }

    #[test]
    fn grouped_steps_equal_one_list_per_slot_bit_for_bit() {
        let mut rng = Stream(7);
        for slots in [1usize, 2, 7, 300, 5000] {
            // Random neighbour lists of every length 0 … 6 (the grid's symmetry is not needed
            // for the step's arithmetic).
            let lists: Vec<[u32; 6]> = (0..slots)
                .map(|_| {
                    let c = (rng.next() % 7) as usize;
                    let mut l = [u32::MAX; 6];
                    for v in l.iter_mut().take(c) {
                        *v = (rng.next() % slots as u64) as u32;
                    }
                    l
                })
                .collect();
            let grouped = DuctNeighbours::new(lists.iter().map(|l| {
                let c = l.iter().position(|&j| j == u32::MAX).unwrap_or(6);
                &l[..c]
            }));
            assert_eq!(grouped.len(), slots);
            // Values over many magnitudes, zeros (both signs), subnormals and negatives.
            let mut rho: Vec<f64> = (0..slots)
                .map(|_| match rng.next() % 8 {
                    0 => 0.0,
                    1 => -0.0,
                    2 => f64::from_bits(rng.next() % (1 << 52)),
                    3 => -((rng.next() >> 11) as f64 / (1u64 << 53) as f64) * 1e-12,
                    _ => (rng.next() >> 11) as f64 / (1u64 << 53) as f64 * 10f64.powi((rng.next() % 40) as i32 - 30),
                })
                .collect();
            let mut next = vec![f64::NAN; slots];
            for tau in [1.0 / 6.0, 0.1, 1e-3] {
                for _ in 0..5 {
                    let want = step_one_list_per_slot(&lists, &rho, tau);
                    grouped.step(&rho, &mut next, tau);
                    for s in 0..slots {
                        assert_eq!(next[s].to_bits(), want[s].to_bits(), "slot {s} of {slots}, τ {tau}");
                    }
                    std::mem::swap(&mut rho, &mut next);
                }
            }
        }
    }

    #[test]
    #[should_panic(expected = "outside the 2 slots")]
    fn a_neighbour_outside_the_slots_is_refused() {
        let lists: [&[u32]; 2] = [&[1], &[2]];
        DuctNeighbours::new(lists.into_iter());
    }
}
