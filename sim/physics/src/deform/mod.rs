//! Local tissue deformation on the voxel grid (thesis Chapter 4; docs/deformation.md).
//!
//! Tissue yields to the needle, the finger and the probe: a displacement field u on a local
//! lattice Ω_J around the tool (64³ cells, 65³ nodes, by default) minimises a regulariser (diffusion or
//! Navier–Lamé, eqs. 4.2.13, 4.2.15, weighted by the material function f_mat of eq. 4.2.17) under
//! Dirichlet conditions: u = 0 on the border of Ω_J and in hard tissue, u = ũ at tool points
//! (eqs. 4.2.5–4.2.7). The solve is a fixed amount of explicit work warm-started from the
//! previous field (Alg. 4.1), accelerated by multigrid and Fast Explicit Diffusion (§4.4).
//!
//! The deformation is visual and graded, not felt: forces come from the haptic algorithms of
//! §3.5–3.6 as in the thesis. It is part of the simulation's state ([`crate::Simulation`]): a
//! solve starts every `every_ticks` ticks from the state at that tick, and its result enters the
//! state `latency_ticks` later, so the result never depends on how long the solve took or on
//! which thread ran it; the state digest covers every bit of the field.
//!
//! One concept per module: [`lattice`] (Ω_J), [`material`] (f_mat), [`operator`] (the
//! discretised regularisers), [`solver`] (explicit steps, multigrid, FED), [`field`] (one
//! solve), [`tool_points`] (ũ from the tools), [`resample`] (the inverse map and J).

pub mod field;
pub mod lattice;
pub mod material;
pub mod operator;
pub mod resample;
pub mod solver;
pub mod state;
pub mod tool_points;

use glam::DVec3;

use crate::SettingsError;

pub use field::{DeformField, solve};
pub use lattice::Lattice;
pub use operator::Regulariser;
pub use solver::Schedule;
pub use state::{DeformState, start_background_threads};

/// A tool point of eq. 4.2.7: the tissue at `reference_mm` (reference space) is displaced by
/// `displacement_mm` (it sits at reference + displacement in the world). With a `radius_mm`, the
/// condition holds on every lattice node within that distance (a patch of a finger or probe face
/// between its sparse contact nodes); without, on the nearest node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolPoint {
    pub reference_mm: DVec3,
    pub displacement_mm: DVec3,
    pub radius_mm: f64,
}

/// Deformation settings: part of the world model, recorded in every session header, so replay
/// solves exactly what the simulator solved.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeformSettings {
    pub enabled: bool,
    /// Cells per axis of Ω_J (a multiple of 2^(levels−1), 8 … 128). The lattice has cells + 1
    /// nodes per axis, so every coarse level's nodes are every second fine node, border on
    /// border, and a load symmetric about the centre node gives a symmetric field.
    pub cells: u32,
    /// Node spacing h (mm).
    pub spacing_mm: f64,
    /// A solve starts every this many ticks.
    pub every_ticks: u32,
    /// Its result enters the state this many ticks later (1 … every_ticks).
    pub latency_ticks: u32,
    pub regulariser: Regulariser,
    /// k of f_mat (eq. 4.2.17), per HU. The thesis' 0.001 barely separates soft tissues.
    pub material_k_per_hu: f64,
    /// s of f_mat (HU).
    pub material_s_hu: f64,
    pub schedule: Schedule,
}

impl Default for DeformSettings {
    fn default() -> Self {
        DeformSettings {
            // Opt-in (scripts: `deformation on`): on 2 cores a 64-cell solve slows a replay to
            // about 5× real time.
            enabled: false,
            cells: 64,
            spacing_mm: 1.0,
            every_ticks: 100,
            latency_ticks: 100,
            regulariser: Regulariser::LinearElastic { poisson_ratio: 0.45 },
            material_k_per_hu: 0.01,
            material_s_hu: 175.0,
            // Four levels (65³ → 9³): as close to the converged field frame by frame as three
            // levels with 40 steps on 17³, for less work (docs/deformation.md).
            schedule: Schedule {
                levels: 4,
                cycles: 1,
                pre_steps: 1,
                post_steps: 1,
                coarsest_steps: 20,
                fed_cycle_steps: 10,
            },
        }
    }
}

impl DeformSettings {
    /// No deformation (the physics of versions ≤ 3; today's default).
    pub fn off() -> Self {
        DeformSettings {
            enabled: false,
            ..DeformSettings::default()
        }
    }

    /// The default settings, switched on.
    pub fn on() -> Self {
        DeformSettings {
            enabled: true,
            ..DeformSettings::default()
        }
    }

    /// What these settings cost a replay, from the schedule alone (no solve): the service
    /// compares it with the default's before it accepts a session for scoring, so a header
    /// cannot ask a scoring worker for a 129³ lattice solved every tick.
    pub fn cost(&self) -> DeformCost {
        if !self.enabled {
            return DeformCost {
                nodes: 0,
                node_updates_per_tick: 0.0,
            };
        }
        let s = &self.schedule;
        let nodes_at = |level: u32| -> f64 {
            let n = f64::from(self.cells >> level) + 1.0;
            n * n * n
        };
        let coarsest = s.levels - 1;
        // Coarsest level: its steps (FED rounds them up to whole cycles).
        let coarsest_steps = match self.regulariser {
            Regulariser::Diffusion if s.fed_cycle_steps > 0 => {
                s.coarsest_steps.div_ceil(s.fed_cycle_steps) * s.fed_cycle_steps
            }
            _ => s.coarsest_steps,
        };
        let mut per_cycle = f64::from(coarsest_steps) * nodes_at(coarsest);
        // Finer levels: smoothing steps and a residual on the level, the coarse residual,
        // injection, restriction and prolongation on the level below.
        for level in 0..coarsest {
            per_cycle += f64::from(s.pre_steps + s.post_steps + 1) * nodes_at(level) + 4.0 * nodes_at(level + 1);
        }
        // Placing Ω_J samples the CT and the labels at every node; the field is hashed once.
        let per_solve = f64::from(s.cycles) * per_cycle + 2.0 * nodes_at(0);
        DeformCost {
            nodes: (nodes_at(0) as u64),
            node_updates_per_tick: per_solve / f64::from(self.every_ticks),
        }
    }

    /// Checks every value, naming the first one out of range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let bad = |setting: &'static str, reason: String| Err(SettingsError::Deformation { setting, reason });
        let s = &self.schedule;
        if !(1..=4).contains(&s.levels) {
            return bad("levels", format!("deformation levels {} must be 1 … 4", s.levels));
        }
        let unit = 1u32 << (s.levels - 1);
        if !(8..=128).contains(&self.cells) || !self.cells.is_multiple_of(unit) || self.cells / unit < 4 {
            return bad(
                "cells",
                format!(
                    "deformation cells {} must be 8 … 128, a multiple of {unit}, with ≥ 4 cells on the coarsest level",
                    self.cells
                ),
            );
        }
        if !(self.spacing_mm.is_finite() && (0.1..=10.0).contains(&self.spacing_mm)) {
            return bad(
                "spacing_mm",
                format!("deformation spacing {} mm must be 0.1 … 10", self.spacing_mm),
            );
        }
        if !(1..=10_000).contains(&self.every_ticks) {
            return bad(
                "every_ticks",
                format!("deformation every_ticks {} must be 1 … 10000", self.every_ticks),
            );
        }
        if !(1..=self.every_ticks).contains(&self.latency_ticks) {
            return bad(
                "latency_ticks",
                format!(
                    "deformation latency_ticks {} must be 1 … every_ticks ({})",
                    self.latency_ticks, self.every_ticks
                ),
            );
        }
        self.regulariser.validate()?;
        if !(self.material_k_per_hu.is_finite() && (0.0..=1.0).contains(&self.material_k_per_hu)) {
            return bad(
                "material_k_per_hu",
                format!("material k {} /HU must be 0 … 1", self.material_k_per_hu),
            );
        }
        if !(self.material_s_hu.is_finite() && (-1000.0..=3000.0).contains(&self.material_s_hu)) {
            return bad(
                "material_s_hu",
                format!("material s {} HU must be −1000 … 3000", self.material_s_hu),
            );
        }
        for (what, v) in [
            ("cycles", s.cycles),
            ("pre_steps", s.pre_steps),
            ("post_steps", s.post_steps),
            ("coarsest_steps", s.coarsest_steps),
            ("fed_cycle_steps", s.fed_cycle_steps),
        ] {
            if v > 1000 {
                return bad(what, format!("deformation {what} {v} must be ≤ 1000"));
            }
        }
        if s.cycles == 0 || s.coarsest_steps == 0 {
            let setting = if s.cycles == 0 { "cycles" } else { "coarsest_steps" };
            return bad(setting, "deformation cycles and coarsest_steps must be ≥ 1".into());
        }
        Ok(())
    }
}

/// The work and memory a replay with some [`DeformSettings`] needs: nodes of Ω_J (each holds a
/// few dozen bytes across the levels and buffers) and lattice-node updates per tick (a model
/// that counts sweeps, not a timing).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeformCost {
    pub nodes: u64,
    pub node_updates_per_tick: f64,
}

impl DeformCost {
    /// The most a session may ask a scoring worker for: the default settings' nodes, and their
    /// work per tick with a quarter's headroom, so sessions recorded under the earlier default
    /// (three levels, 40 steps on 17³: 1.1× today's work) still score.
    pub fn replay_budget() -> DeformCost {
        let d = DeformSettings::on().cost();
        DeformCost {
            nodes: d.nodes,
            node_updates_per_tick: 1.25 * d.node_updates_per_tick,
        }
    }

    /// Whether this costs no more than `budget`, in memory and in work.
    pub fn within(&self, budget: &DeformCost) -> bool {
        self.nodes <= budget.nodes && self.node_updates_per_tick <= budget.node_updates_per_tick
    }
}

/// FNV-1a over 64-bit words (a field has ~800 000 of them; hashing words, not bytes, keeps the
/// digest of a 64³ field under a millisecond).
pub(crate) struct Fnv64(u64);

impl Fnv64 {
    pub(crate) fn new() -> Self {
        Fnv64(0xcbf2_9ce4_8422_2325)
    }
    pub(crate) fn u64(&mut self, v: u64) {
        self.0 ^= v;
        self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        self.0 ^= self.0 >> 29;
    }
    pub(crate) fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    pub(crate) fn finish(&self) -> u64 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cost_grows_with_what_a_header_may_ask_for() {
        let on = DeformSettings::on();
        let budget = DeformCost::replay_budget();
        assert!(
            budget.nodes == 65 * 65 * 65 && budget.node_updates_per_tick > 0.0,
            "{budget:?}"
        );
        assert_eq!(DeformSettings::off().cost().node_updates_per_tick, 0.0);
        assert!(on.cost().within(&budget));
        // Material and latency do not change the work.
        let softer = DeformSettings {
            material_k_per_hu: 0.05,
            latency_ticks: 10,
            ..on
        };
        assert!(softer.cost().within(&budget));
        // The default before four levels.
        let three_levels = DeformSettings {
            schedule: Schedule {
                levels: 3,
                coarsest_steps: 40,
                ..on.schedule
            },
            ..on
        };
        assert!(three_levels.cost().within(&budget), "{:?}", three_levels.cost());
        // What an attacker would ask for: each alone is over the budget.
        let schedule = on.schedule;
        let dearer = [
            DeformSettings {
                cells: 128,
                every_ticks: 10_000,
                latency_ticks: 1,
                ..on
            },
            DeformSettings {
                every_ticks: 1,
                latency_ticks: 1,
                ..on
            },
            DeformSettings {
                schedule: Schedule {
                    cycles: 1000,
                    ..schedule
                },
                ..on
            },
            DeformSettings {
                schedule: Schedule {
                    pre_steps: 1000,
                    ..schedule
                },
                ..on
            },
            DeformSettings {
                schedule: Schedule {
                    coarsest_steps: 1000,
                    ..schedule
                },
                ..on
            },
            DeformSettings {
                schedule: Schedule {
                    levels: 1,
                    coarsest_steps: 40,
                    ..schedule
                },
                ..on
            },
        ];
        for d in dearer {
            d.validate().expect("valid, only dear");
            assert!(!d.cost().within(&budget), "{d:?}: {:?}", d.cost());
        }
        // Cheaper ones pass: fewer cells, or solves half as often.
        let cheaper = [
            DeformSettings { cells: 32, ..on },
            DeformSettings {
                every_ticks: 200,
                latency_ticks: 200,
                ..on
            },
        ];
        for d in cheaper {
            assert!(d.cost().within(&budget), "{d:?}");
        }
    }
}
