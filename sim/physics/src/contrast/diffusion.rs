//! One explicit step of thesis eq. 3.3.2 over the duct nodes:
//!
//!   ρᵢ⁺ = ρᵢ + τ·(Σ_{j∈N} ρⱼ − |N|·ρᵢ)
//!
//! Jacobi: every new value is computed from the old ones alone, so the order in which the nodes
//! are visited does not change a bit. Within a node the neighbours are summed in one fixed order
//! (the grid's −x, +x, −y, +y, −z, +z), so ρᵢ⁺ is the same number however the nodes are visited.
//!
//! Slots follow the grid's node order (x fastest), so inside a duct four consecutive slots are
//! often four nodes along x whose neighbours on each side are four consecutive slots as well: a
//! **quad**. A quad is stepped at once from contiguous loads of its own and its neighbours' rows
//! (AVX lanes where the CPU has it, each lane the scalar operations in their order), without a
//! neighbour index per node. The other slots are stepped one at a time from their neighbour
//! lists. Both are grouped by the neighbour count |N| (0 … 6), so every loop has a fixed number
//! of neighbours and lanes: no branch the CPU cannot predict along the duct tree's walls.

use crate::lanes::{F4, LANES, Lane, has_avx2};

/// The duct slots' neighbours, grouped by their count: quads, and single slots.
#[derive(Debug, Clone)]
pub(super) struct DuctNeighbours {
    /// How many slots the diffusion's vectors (`rho`) hold.
    slots: usize,
    /// `quads[c]`: quads whose slots have c neighbours.
    quads: [Quads; 7],
    /// `singles[c]`: the other slots with c neighbours.
    singles: [Singles; 7],
}

/// Quads with the same neighbour count C.
#[derive(Debug, Clone, Default)]
struct Quads {
    /// Each quad's first slot s (its slots are s … s + 3).
    first: Vec<u32>,
    /// C entries per quad, one after the other: the k-th neighbour t_k of its first slot (slot
    /// s + i has the k-th neighbour t_k + i).
    neighbours: Vec<u32>,
}

/// Slots with the same neighbour count C, stepped one at a time.
#[derive(Debug, Clone, Default)]
struct Singles {
    /// The slots (increasing).
    slot: Vec<u32>,
    /// C neighbour slots for each entry of `slot`, one after the other.
    neighbours: Vec<u32>,
}

impl DuctNeighbours {
    /// From each slot's neighbour slots in summation order (`lists[s]` for slot s). Neighbours
    /// must be slots (< `lists.len()`), at most 6 per slot.
    pub(super) fn new<'a>(lists: impl ExactSizeIterator<Item = &'a [u32]>) -> DuctNeighbours {
        let slots = lists.len();
        let mut quads: [Quads; 7] = Default::default();
        let mut singles: [Singles; 7] = Default::default();
        // The slots since the last quad that may still start one: consecutive slots with the
        // same count whose k-th neighbours are consecutive (at most three wait).
        let mut waiting: Vec<(u32, usize, [u32; 6])> = Vec::with_capacity(LANES);
        let flush = |waiting: &mut Vec<(u32, usize, [u32; 6])>, singles: &mut [Singles; 7]| {
            for (s, c, nb) in waiting.drain(..) {
                singles[c].slot.push(s);
                singles[c].neighbours.extend_from_slice(&nb[..c]);
            }
        };
        for (s, list) in lists.enumerate() {
            let c = list.len();
            assert!(c <= 6, "slot {s} has {c} neighbours (at most 6)");
            assert!(
                list.iter().all(|&j| (j as usize) < slots),
                "slot {s} has a neighbour outside the {slots} slots"
            );
            let s = s as u32;
            let mut nb = [0u32; 6];
            nb[..c].copy_from_slice(list);
            let continues = waiting.last().is_some_and(|&(ps, pc, pnb)| {
                pc == c
                    && ps + 1 == s
                    && nb[..c]
                        .iter()
                        .zip(&pnb[..c])
                        .all(|(&j, &t)| u64::from(j) == u64::from(t) + 1)
            });
            if !continues {
                flush(&mut waiting, &mut singles);
            }
            waiting.push((s, c, nb));
            if waiting.len() == LANES {
                let (first, c, nb) = waiting[0];
                quads[c].first.push(first);
                quads[c].neighbours.extend_from_slice(&nb[..c]);
                waiting.clear();
            }
        }
        flush(&mut waiting, &mut singles);
        DuctNeighbours { slots, quads, singles }
    }

    /// Number of slots.
    pub(super) fn len(&self) -> usize {
        self.slots
    }

    /// Number of slots stepped in quads.
    #[cfg(test)]
    fn slots_in_quads(&self) -> usize {
        self.quads.iter().map(|q| q.first.len() * LANES).sum()
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
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            // SAFETY: the CPU has AVX2 (checked above).
            return unsafe { self.step_avx2(rho, next, tau) };
        }
        self.step_in::<F4>(rho, next, tau);
    }

    /// The step with the portable lanes (what a CPU without AVX2 runs; a reference in tests).
    #[cfg(test)]
    fn step_portable(&self, rho: &[f64], next: &mut [f64], tau: f64) {
        self.step_in::<F4>(rho, next, tau);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn step_avx2(&self, rho: &[f64], next: &mut [f64], tau: f64) {
        self.step_in::<crate::lanes::avx::Avx>(rho, next, tau);
    }

    #[inline(always)]
    fn step_in<L: Lane>(&self, rho: &[f64], next: &mut [f64], tau: f64) {
        self.group::<0, L>(rho, next, tau);
        self.group::<1, L>(rho, next, tau);
        self.group::<2, L>(rho, next, tau);
        self.group::<3, L>(rho, next, tau);
        self.group::<4, L>(rho, next, tau);
        self.group::<5, L>(rho, next, tau);
        self.group::<6, L>(rho, next, tau);
    }

    /// The quads and single slots with `C` neighbours. Sum and count are formed as the
    /// one-list-per-slot loop formed them (0.0, then each neighbour in turn; |N| = C exactly),
    /// lane by lane in a quad.
    #[inline(always)]
    fn group<const C: usize, L: Lane>(&self, rho: &[f64], next: &mut [f64], tau: f64) {
        let (quads, singles) = (&self.quads[C], &self.singles[C]);
        debug_assert_eq!(quads.neighbours.len(), quads.first.len() * C);
        debug_assert_eq!(singles.neighbours.len(), singles.slot.len() * C);
        let (count, tau_l, count_l) = (C as f64, L::splat(tau), L::splat(C as f64));
        let (rho_p, next_p) = (rho.as_ptr(), next.as_mut_ptr());
        // SAFETY (both loops): `new` checked every slot and neighbour < `self.slots` and built
        // each quad so that its slots s … s + 3 and its neighbours t_k … t_k + 3 are slots
        // (each t_k + i is slot s + i's k-th neighbour); `step` checked that both vectors hold
        // `self.slots` values; the neighbour vectors hold C entries per quad or slot. `rho` and
        // `next` are distinct borrows.
        for (q, &first) in quads.first.iter().enumerate() {
            unsafe {
                let here = load4::<L>(rho_p, first as usize);
                let mut sum = L::splat(0.0);
                for k in 0..C {
                    sum = sum + load4::<L>(rho_p, *quads.neighbours.get_unchecked(q * C + k) as usize);
                }
                let new = here + tau_l * (sum - count_l * here);
                *next_p.add(first as usize).cast::<[f64; LANES]>() = new.store();
            }
        }
        for (i, &s) in singles.slot.iter().enumerate() {
            unsafe {
                let here = *rho_p.add(s as usize);
                let mut sum = 0.0;
                for k in 0..C {
                    sum += *rho_p.add(*singles.neighbours.get_unchecked(i * C + k) as usize);
                }
                *next_p.add(s as usize) = here + tau * (sum - count * here);
            }
        }
    }
}

/// The largest of `far` and every distance `d[s]` whose slot holds ρ ≥ `visible` (slots beyond
/// the shorter vector are not read). A maximum, so it does not depend on the order the slots are
/// compared in: compiled for AVX2 where the CPU has it (four slots at a time), portable elsewhere.
pub(super) fn farthest_visible(rho: &[f64], d: &[f64], visible: f64, far: f64) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 (checked above).
        return unsafe { farthest_visible_avx2(rho, d, visible, far) };
    }
    farthest_visible_in(rho, d, visible, far)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn farthest_visible_avx2(rho: &[f64], d: &[f64], visible: f64, far: f64) -> f64 {
    farthest_visible_in(rho, d, visible, far)
}

#[inline(always)]
fn farthest_visible_in(rho: &[f64], d: &[f64], visible: f64, mut far: f64) -> f64 {
    for (&rho, &d) in rho.iter().zip(d) {
        if d > far && rho >= visible {
            far = d;
        }
    }
    far
}

/// The four values from `p + o` as lanes (a function, not a closure: see `crate::lanes`).
///
/// # Safety
/// `p + o … p + o + 3` must be values of one allocation.
#[inline(always)]
unsafe fn load4<L: Lane>(p: *const f64, o: usize) -> L {
    // SAFETY: the caller's; `[f64; 4]` has the alignment of `f64`.
    L::load(unsafe { *p.add(o).cast::<[f64; LANES]>() })
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
    fn random_lists_step_as_one_list_per_slot_bit_for_bit() {
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
                    grouped.step_portable(&rho, &mut next, tau);
                    for s in 0..slots {
                        assert_eq!(
                            next[s].to_bits(),
                            want[s].to_bits(),
                            "slot {s} of {slots}, τ {tau} (portable)"
                        );
                    }
                    grouped.step(&rho, &mut next, tau);
                    for s in 0..slots {
                        assert_eq!(next[s].to_bits(), want[s].to_bits(), "slot {s} of {slots}, τ {tau}");
                    }
                    std::mem::swap(&mut rho, &mut next);
                }
            }
        }
    }

    /// The neighbour lists `DiffusionGrid::place` makes (`super::duct_neighbour_lists`) for the
    /// duct voxels of a mask on an n × n × n grid, as arrays ended by `u32::MAX`.
    fn grid_lists(n: usize, duct: impl Fn(usize, usize, usize) -> bool) -> Vec<[u32; 6]> {
        let mut slot = vec![u32::MAX; n * n * n];
        let mut duct_nodes = Vec::new();
        for node in 0..n * n * n {
            if duct(node % n, (node / n) % n, node / (n * n)) {
                slot[node] = duct_nodes.len() as u32;
                duct_nodes.push(node as u32);
            }
        }
        super::super::duct_neighbour_lists([n; 3], &slot, &duct_nodes)
            .into_iter()
            .map(|(list, m)| {
                let mut l = [u32::MAX; 6];
                l[..m].copy_from_slice(&list[..m]);
                l
            })
            .collect()
    }

    /// A duct tree as the phantom's: thick tubes along x, y and z that meet, with rough walls
    /// (a few voxels knocked out), so that quads, broken rows and single slots all occur.
    #[test]
    fn quads_and_single_slots_step_as_one_list_per_slot_on_a_duct_tree() {
        let n = 24;
        let mut rng = Stream(11);
        let rough: Vec<bool> = (0..n * n * n).map(|_| rng.next().is_multiple_of(40)).collect();
        let duct = |i: usize, j: usize, k: usize| {
            let d2 = |a: usize, b: usize, c: usize| (a as i64 - b as i64).pow(2) + (a as i64 - c as i64).pow(2);
            let along_x = d2(12, j, k) <= 16;
            let along_y = (i as i64 - 6).pow(2) + (k as i64 - 12).pow(2) <= 9 && j >= 12;
            let along_z = (i as i64 - 18).pow(2) + (j as i64 - 12).pow(2) <= 6;
            (along_x || along_y || along_z) && !rough[i + n * (j + n * k)]
        };
        let lists = grid_lists(n, duct);
        let slots = lists.len();
        let steps = DuctNeighbours::new(lists.iter().map(|l| {
            let c = l.iter().position(|&j| j == u32::MAX).unwrap_or(6);
            &l[..c]
        }));
        assert_eq!(steps.len(), slots);
        let in_quads = steps.slots_in_quads();
        assert!(
            in_quads > slots / 4 && in_quads < slots,
            "{in_quads} of {slots} slots in quads: both kinds must be exercised"
        );
        // Contrast entering at one slot, spreading over many magnitudes; then random values.
        let mut rho = vec![0.0; slots];
        rho[slots / 2] = 1.0;
        let mut next = vec![f64::NAN; slots];
        let mut portable = vec![f64::NAN; slots];
        for round in 0..60 {
            if round == 40 {
                for r in rho.iter_mut() {
                    *r = (rng.next() >> 11) as f64 / (1u64 << 53) as f64 * 10f64.powi((rng.next() % 40) as i32 - 30);
                }
            }
            let want = step_one_list_per_slot(&lists, &rho, 1.0 / 6.0);
            steps.step(&rho, &mut next, 1.0 / 6.0);
            steps.step_portable(&rho, &mut portable, 1.0 / 6.0);
            for s in 0..slots {
                assert_eq!(next[s].to_bits(), want[s].to_bits(), "slot {s}, step {round}");
                assert_eq!(
                    portable[s].to_bits(),
                    want[s].to_bits(),
                    "slot {s}, step {round} (portable)"
                );
            }
            std::mem::swap(&mut rho, &mut next);
        }
    }

    #[test]
    fn the_farthest_visible_node_is_the_largest_distance_holding_enough_contrast() {
        let mut rng = Stream(5);
        for n in [0usize, 1, 3, 4, 5, 17, 1000] {
            let rho: Vec<f64> = (0..n).map(|_| (rng.next() % 100) as f64 / 1000.0).collect();
            let d: Vec<f64> = (0..n).map(|_| (rng.next() % 10_000) as f64 / 100.0).collect();
            for far in [0.0, 30.0, 99.0] {
                let want = rho
                    .iter()
                    .zip(&d)
                    .filter(|(r, _)| **r >= 0.05)
                    .map(|(_, d)| *d)
                    .fold(far, f64::max);
                assert_eq!(
                    farthest_visible(&rho, &d, 0.05, far).to_bits(),
                    want.to_bits(),
                    "{n} slots, far {far}"
                );
            }
        }
        // Only slots present in both vectors count.
        assert_eq!(farthest_visible(&[1.0, 1.0], &[3.0], 0.05, 0.0), 3.0);
    }

    #[test]
    #[should_panic(expected = "outside the 2 slots")]
    fn a_neighbour_outside_the_slots_is_refused() {
        let lists: [&[u32]; 2] = [&[1], &[2]];
        DuctNeighbours::new(lists.into_iter());
    }
}
