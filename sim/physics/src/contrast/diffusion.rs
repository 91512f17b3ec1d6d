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
//! neighbour index per node. A run of such slots whose length is not a multiple of four ends
//! with a quad that overlaps the one before it: the slots in both are computed twice, from the
//! same old values, and written twice with the same bits (Jacobi). The other slots are stepped
//! one at a time from their neighbour lists, except that a neighbour that is the slot just
//! before or after (slot s − 1 first in the list, slot s + 1 next: the node's −x and +x
//! neighbours, usually) is read at s ∓ 1 without an index. Quads are grouped by the neighbour
//! count |N| (0 … 6), single slots by the listed count and by which of s ∓ 1 they read, so every
//! loop has a fixed number of neighbours and lanes: no branch the CPU cannot predict along the
//! duct tree's walls.

use crate::lanes::{F4, LANES, Lane, has_avx2};

/// The duct slots' neighbours, grouped by their count: quads, and single slots.
#[derive(Debug, Clone)]
pub(super) struct DuctNeighbours {
    /// How many slots the diffusion's vectors (`rho`) hold.
    slots: usize,
    /// `quads[c]`: quads whose slots have c neighbours.
    quads: [Quads; 7],
    /// `singles[kind][r]`: the other slots, with r listed neighbours after those of `kind`
    /// ([`Adjacent::index`]).
    singles: [[Singles; 7]; 4],
}

/// Which of its adjacent slots a single slot s reads without an index: s − 1 as its first
/// neighbour, s + 1 as its next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Adjacent {
    before: bool,
    after: bool,
}

impl Adjacent {
    /// The adjacent slots the list `nb` of slot `s` starts with.
    fn of(s: u32, nb: &[u32]) -> Adjacent {
        let s = u64::from(s);
        let before = nb.first().is_some_and(|&j| u64::from(j) + 1 == s);
        let after = nb.get(usize::from(before)).is_some_and(|&j| u64::from(j) == s + 1);
        Adjacent { before, after }
    }
    /// How many list entries they stand for.
    fn count(self) -> usize {
        usize::from(self.before) + usize::from(self.after)
    }
    fn index(self) -> usize {
        usize::from(self.before) | usize::from(self.after) << 1
    }
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

/// Slots with the same adjacent slots read and R listed neighbours, stepped one at a time.
#[derive(Debug, Clone, Default)]
struct Singles {
    /// The slots (increasing).
    slot: Vec<u32>,
    /// R neighbour slots for each entry of `slot`, one after the other (those after the
    /// adjacent ones, in summation order).
    neighbours: Vec<u32>,
}

impl DuctNeighbours {
    /// From each slot's neighbour slots in summation order (`lists[s]` for slot s). Neighbours
    /// must be slots (< `lists.len()`), at most 6 per slot.
    pub(super) fn new<'a>(lists: impl ExactSizeIterator<Item = &'a [u32]>) -> DuctNeighbours {
        let slots = lists.len();
        let mut quads: [Quads; 7] = Default::default();
        let mut singles: [[Singles; 7]; 4] = Default::default();
        // The slots since the last quad that may still start one: consecutive slots with the
        // same count whose k-th neighbours are consecutive (at most three wait).
        let mut waiting: Vec<(u32, usize, [u32; 6])> = Vec::with_capacity(LANES);
        // Whether the run the waiting slots belong to has a quad already, and its last slot.
        let mut run_has_quad = false;
        let mut previous: Option<(u32, usize, [u32; 6])> = None;
        // The end of a run: its waiting slots form a quad with the run's last slots before them
        // (overlapping its last quad) when it has one, else they are single slots.
        let flush = |waiting: &mut Vec<(u32, usize, [u32; 6])>,
                     run_has_quad: bool,
                     quads: &mut [Quads; 7],
                     singles: &mut [[Singles; 7]; 4]| {
            if run_has_quad && let Some(&(s, c, nb)) = waiting.first() {
                // Slot s − back + i has the k-th neighbour nb_k − back + i (the run continues).
                let back = (LANES - waiting.len()) as u32;
                quads[c].first.push(s - back);
                quads[c].neighbours.extend(nb[..c].iter().map(|&t| t - back));
                waiting.clear();
                return;
            }
            for (s, c, nb) in waiting.drain(..) {
                let adjacent = Adjacent::of(s, &nb[..c]);
                let group = &mut singles[adjacent.index()][c - adjacent.count()];
                group.slot.push(s);
                group.neighbours.extend_from_slice(&nb[adjacent.count()..c]);
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
            // Continues the run of the slot before (waiting, or the last of a quad).
            let continues = previous.is_some_and(|(ps, pc, pnb): (u32, usize, [u32; 6])| {
                pc == c
                    && ps + 1 == s
                    && nb[..c]
                        .iter()
                        .zip(&pnb[..c])
                        .all(|(&j, &t)| u64::from(j) == u64::from(t) + 1)
            });
            if !continues {
                flush(&mut waiting, run_has_quad, &mut quads, &mut singles);
                run_has_quad = false;
            }
            waiting.push((s, c, nb));
            previous = Some((s, c, nb));
            if waiting.len() == LANES {
                let (first, c, nb) = waiting[0];
                quads[c].first.push(first);
                quads[c].neighbours.extend_from_slice(&nb[..c]);
                waiting.clear();
                run_has_quad = true;
            }
        }
        flush(&mut waiting, run_has_quad, &mut quads, &mut singles);
        DuctNeighbours { slots, quads, singles }
    }

    /// Number of slots.
    pub(super) fn len(&self) -> usize {
        self.slots
    }

    /// Number of slots stepped in quads (those of overlapping quads once).
    #[cfg(test)]
    fn slots_in_quads(&self) -> usize {
        let mut covered = vec![false; self.slots];
        for q in &self.quads {
            for &first in &q.first {
                covered[first as usize..first as usize + LANES].fill(true);
            }
        }
        covered.iter().filter(|&&c| c).count()
    }

    /// Number of single slots that read s − 1 or s + 1 without an index.
    #[cfg(test)]
    fn singles_reading_adjacent(&self) -> [usize; 2] {
        let mut n = [0; 2];
        for (kind, groups) in self.singles.iter().enumerate() {
            let slots: usize = groups.iter().map(|g| g.slot.len()).sum();
            n[0] += if kind & 1 != 0 { slots } else { 0 };
            n[1] += if kind & 2 != 0 { slots } else { 0 };
        }
        n
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
        self.quads::<0, L>(rho, next, tau);
        self.quads::<1, L>(rho, next, tau);
        self.quads::<2, L>(rho, next, tau);
        self.quads::<3, L>(rho, next, tau);
        self.quads::<4, L>(rho, next, tau);
        self.quads::<5, L>(rho, next, tau);
        self.quads::<6, L>(rho, next, tau);
        // Every (s − 1, s + 1, R) with at most six neighbours in all.
        macro_rules! singles {
            ($($before:literal $after:literal $r:literal),*) => {
                $(self.singles::<$before, $after, $r>(rho, next, tau);)*
            };
        }
        singles!(
            false false 0, true false 0, false true 0, true true 0,
            false false 1, true false 1, false true 1, true true 1,
            false false 2, true false 2, false true 2, true true 2,
            false false 3, true false 3, false true 3, true true 3,
            false false 4, true false 4, false true 4, true true 4,
            false false 5, true false 5, false true 5,
            false false 6
        );
    }

    /// The quads with `C` neighbours. Sum and count are formed lane by lane as the
    /// one-list-per-slot loop formed them (0.0, then each neighbour in turn; |N| = C exactly).
    #[inline(always)]
    fn quads<const C: usize, L: Lane>(&self, rho: &[f64], next: &mut [f64], tau: f64) {
        let quads = &self.quads[C];
        debug_assert_eq!(quads.neighbours.len(), quads.first.len() * C);
        let (tau_l, count_l) = (L::splat(tau), L::splat(C as f64));
        let (rho_p, next_p) = (rho.as_ptr(), next.as_mut_ptr());
        for (q, &first) in quads.first.iter().enumerate() {
            // SAFETY: `new` checked every slot and neighbour < `self.slots` and built each quad so
            // that its slots s … s + 3 and its neighbours t_k … t_k + 3 are slots (each t_k + i is
            // slot s + i's k-th neighbour); `step` checked that both vectors hold `self.slots`
            // values; the neighbour vector holds C entries per quad. `rho` and `next` are distinct
            // borrows.
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
    }

    /// The single slots that read s − 1 first (`BEFORE`), then s + 1 (`AFTER`), then `R` listed
    /// neighbours: sum and count as the one-list-per-slot loop formed them (0.0, then each
    /// neighbour in list order; |N| = BEFORE + AFTER + R exactly).
    #[inline(always)]
    fn singles<const BEFORE: bool, const AFTER: bool, const R: usize>(&self, rho: &[f64], next: &mut [f64], tau: f64) {
        let kind = Adjacent {
            before: BEFORE,
            after: AFTER,
        };
        let singles = &self.singles[kind.index()][R];
        debug_assert_eq!(singles.neighbours.len(), singles.slot.len() * R);
        let count = (kind.count() + R) as f64;
        let (rho_p, next_p) = (rho.as_ptr(), next.as_mut_ptr());
        for (i, &s) in singles.slot.iter().enumerate() {
            // SAFETY: `new` checked every slot and neighbour < `self.slots`, and put a slot here
            // only when s − 1 (`BEFORE`) and s + 1 (`AFTER`) are among its neighbours, so slots;
            // `step` checked that both vectors hold `self.slots` values; the neighbour vector holds
            // R entries per slot. `rho` and `next` are distinct borrows.
            unsafe {
                let s = s as usize;
                let here = *rho_p.add(s);
                let mut sum = 0.0;
                if BEFORE {
                    sum += *rho_p.add(s - 1);
                }
                if AFTER {
                    sum += *rho_p.add(s + 1);
                }
                for k in 0..R {
                    sum += *rho_p.add(*singles.neighbours.get_unchecked(i * R + k) as usize);
                }
                *next_p.add(s) = here + tau * (sum - count * here);
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
            // Often s − 1 first and s + 1 next, as a node's −x and +x neighbours are.
            let lists: Vec<[u32; 6]> = (0..slots)
                .map(|s| {
                    let c = (rng.next() % 7) as usize;
                    let mut l = [u32::MAX; 6];
                    for v in l.iter_mut().take(c) {
                        *v = (rng.next() % slots as u64) as u32;
                    }
                    let mut k = 0;
                    if c > k && s > 0 && rng.next().is_multiple_of(2) {
                        l[k] = s as u32 - 1;
                        k += 1;
                    }
                    if c > k && s + 1 < slots && rng.next().is_multiple_of(2) {
                        l[k] = s as u32 + 1;
                    }
                    l
                })
                .collect();
            let grouped = DuctNeighbours::new(lists.iter().map(|l| {
                let c = l.iter().position(|&j| j == u32::MAX).unwrap_or(6);
                &l[..c]
            }));
            assert_eq!(grouped.len(), slots);
            if slots >= 300 {
                let [before, after] = grouped.singles_reading_adjacent();
                assert!(before > slots / 8 && after > slots / 8, "{before}, {after} of {slots}");
            }
            // Values over many magnitudes, zeros (both signs), subnormals and negatives.
            let mut rho: Vec<f64> = (0..slots)
                .map(|_| match rng.next() % 8 {
                    0 => 0.0,
                    1 => -0.0,
                    2 => f64::from_bits(rng.next() % (1 << 52)),
                    3 => -((rng.next() >> 11) as f64 / (1u64 << 53) as f64) * 1e-12,
                    _ => {
                        (rng.next() >> 11) as f64 / (1u64 << 53) as f64
                            * libm::pow(10.0, ((rng.next() % 40) as i32 - 30) as f64)
                    }
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

    /// The neighbour lists the duct network makes (`super::super::network`: −x, +x, −y, +y, −z,
    /// +z, duct voxels only) for the duct voxels of a mask on an n × n × n grid, as arrays ended
    /// by `u32::MAX`.
    fn grid_lists(n: usize, duct: impl Fn(usize, usize, usize) -> bool) -> Vec<[u32; 6]> {
        let mut slot = vec![u32::MAX; n * n * n];
        let mut duct_nodes = Vec::new();
        for node in 0..n * n * n {
            if duct(node % n, (node / n) % n, node / (n * n)) {
                slot[node] = duct_nodes.len() as u32;
                duct_nodes.push(node as u32);
            }
        }
        duct_nodes
            .iter()
            .map(|&node| {
                let node = node as usize;
                let (i, j, k) = (node % n, (node / n) % n, node / (n * n));
                let candidates = [
                    (i > 0).then(|| node - 1),
                    (i + 1 < n).then(|| node + 1),
                    (j > 0).then(|| node - n),
                    (j + 1 < n).then(|| node + n),
                    (k > 0).then(|| node - n * n),
                    (k + 1 < n).then(|| node + n * n),
                ];
                let mut l = [u32::MAX; 6];
                let mut m = 0;
                for nb in candidates.into_iter().flatten() {
                    if slot[nb] != u32::MAX {
                        l[m] = slot[nb];
                        m += 1;
                    }
                }
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
        let quads: usize = steps.quads.iter().map(|q| q.first.len()).sum();
        assert!(
            quads * LANES > in_quads + 40,
            "overlapping quads at the ends of runs: {quads} quads over {in_quads} slots"
        );
        let [before, after] = steps.singles_reading_adjacent();
        assert!(
            before > 20 && after > 20,
            "single slots reading s − 1 ({before}) and s + 1 ({after})"
        );
        // Contrast entering at one slot, spreading over many magnitudes; then random values.
        let mut rho = vec![0.0; slots];
        rho[slots / 2] = 1.0;
        let mut next = vec![f64::NAN; slots];
        let mut portable = vec![f64::NAN; slots];
        for round in 0..60 {
            if round == 40 {
                for r in rho.iter_mut() {
                    *r = (rng.next() >> 11) as f64 / (1u64 << 53) as f64
                        * libm::pow(10.0, ((rng.next() % 40) as i32 - 30) as f64);
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
