//! Contrast agent in the bile ducts (thesis §3.3, eqs. 3.3.1–3.3.2; docs/contrast.md).
//!
//! PTCD confirms the puncture by injecting contrast medium through the needle (stylet removed)
//! and watching it fill the duct tree under fluoroscopy. The thesis models the spreading as
//! diffusion on a small cubic grid centred at the puncture:
//!
//!   ρ⁺ = ρ + τ·Δρ + τ·ι                                   (eq. 3.3.1)
//!   ρᵢ⁺ = ρᵢ + τ·(Σ_{j∈N} ρⱼ − |N|·ρᵢ)   if l(xᵢ) is a duct, else ρᵢ   (eq. 3.3.2, with τ)
//!
//! where N are the 6-neighbours of node i that are themselves duct nodes. Each exchange
//! τ·(ρⱼ − ρᵢ) appears with opposite signs at i and j, so the contrast inside the ducts is
//! conserved and never reaches a non-duct node; explicit steps are stable for τ ≤ 1/6.
//!
//! Diffusion alone fills far too slowly for what a cholangiogram shows, so the inflow ι is
//! volume-driven instead of a point source (`filling`): the injected volume displaces bile along
//! the ducts from the tip outward, in order of path distance, at the front's fraction of medium;
//! diffusion dilutes and smooths behind and ahead of the front.
//!
//! The nodes are the CT's own voxels of the whole duct system of the atlas (`network`), kept
//! sparse instead of the thesis' 64³ box, so the filling reaches as far as the injected volume
//! does. ρ is the volume fraction of contrast medium in a node (1 = the node is full of
//! undiluted medium). Contrast delivered at a node outside the ducts (parenchyma, a vessel) stays
//! there as a stain and is counted as extravasation.
//!
//! Deterministic: f64, fixed node order, a fixed number of steps per update at a fixed tick
//! sub-rate; no reductions whose order depends on anything but the node indices.

use std::collections::BTreeMap;

use glam::DVec3;

use crate::{LabelId, PunctureAtlas, Role, SettingsError};

mod diffusion;
mod filling;
mod network;
use network::DuctNetwork;

/// Time constant of contrast washing out of a vessel it was delivered into (s): venous blood
/// crosses a voxel in well under a second and dilutes the bolus downstream (estimate).
pub const WASHOUT_S: f64 = 1.5;
/// A washing-out stain thinner than this is gone (volume fraction).
pub const WASHED_OUT_RHO: f64 = 1e-4;

/// Settings of the contrast model (part of the physics: replay uses the same values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContrastSettings {
    /// Volume fraction of medium at the filling front: the injected medium mixed with the bile it
    /// displaces (0.5: cholangiograms are often injected diluted 1:1, and the medium mixes with
    /// bile on its way).
    pub front_fraction: f64,
    /// Ticks between two updates (the sub-rate of `Simulation::step`).
    pub update_every_ticks: u32,
    /// Explicit diffusion steps of eq. 3.3.2 per update.
    pub steps_per_update: u32,
    /// τ of eq. 3.3.1; explicit steps are stable for τ ≤ 1/6 on the 6-neighbourhood.
    pub tau: f64,
    /// How fast the syringe empties through the needle (ml/s).
    pub rate_ml_per_s: f64,
    /// ρ at which a node counts as filled (visible under fluoroscopy).
    pub visible_fraction: f64,
    /// Filled duct length, along the ducts from the node where contrast first entered them, that
    /// confirms the puncture (mm).
    pub confirm_extent_mm: f64,
    /// Diffusion runs while contrast flows into the ducts and this long after (s); then the filled
    /// tree is held as it is (what fluoroscopy shows in the minutes of a PTCD), and a session
    /// pays for the diffusion only around its injections.
    pub settle_s: f64,
}

impl Default for ContrastSettings {
    fn default() -> Self {
        ContrastSettings {
            front_fraction: 0.5,
            update_every_ticks: 10,
            steps_per_update: 4,
            tau: 1.0 / 6.0,
            rate_ml_per_s: 1.0,
            visible_fraction: 0.05,
            confirm_extent_mm: 10.0,
            settle_s: 5.0,
        }
    }
}

impl ContrastSettings {
    /// Diffusion steps over the duct network per tick while the agent diffuses (a model of the
    /// work, not a timing): what the service compares with the default's before it replays a
    /// session's world model.
    pub fn steps_per_tick(&self) -> f64 {
        f64::from(self.steps_per_update) / f64::from(self.update_every_ticks)
    }

    /// Names the first setting outside its range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        let bad = |setting: &'static str, reason: String| Err(SettingsError::Contrast { setting, reason });
        if !(finite_pos(self.front_fraction) && self.front_fraction <= 1.0) {
            return bad(
                "front_fraction",
                format!("contrast front_fraction {} must be in (0, 1]", self.front_fraction),
            );
        }
        if !(1..=1000).contains(&self.update_every_ticks) {
            return bad(
                "update_every_ticks",
                format!(
                    "contrast update_every_ticks {} must be 1 … 1000",
                    self.update_every_ticks
                ),
            );
        }
        if !(1..=64).contains(&self.steps_per_update) {
            return bad(
                "steps_per_update",
                format!("contrast steps_per_update {} must be 1 … 64", self.steps_per_update),
            );
        }
        if !(finite_pos(self.tau) && self.tau <= 1.0 / 6.0) {
            return bad(
                "tau",
                format!("contrast tau {} must be in (0, 1/6] (explicit stability)", self.tau),
            );
        }
        if !(finite_pos(self.rate_ml_per_s) && self.rate_ml_per_s <= 100.0) {
            return bad(
                "rate_ml_per_s",
                format!("contrast rate {} ml/s must be in (0, 100]", self.rate_ml_per_s),
            );
        }
        if !(finite_pos(self.visible_fraction) && self.visible_fraction <= 1.0) {
            return bad(
                "visible_fraction",
                format!("contrast visible_fraction {} must be in (0, 1]", self.visible_fraction),
            );
        }
        if !(finite_pos(self.confirm_extent_mm) && self.confirm_extent_mm <= 200.0) {
            return bad(
                "confirm_extent_mm",
                format!(
                    "contrast confirm_extent_mm {} must be in (0, 200]",
                    self.confirm_extent_mm
                ),
            );
        }
        if !(self.settle_s.is_finite() && (0.0..=600.0).contains(&self.settle_s)) {
            return bad(
                "settle_s",
                format!("contrast settle_s {} must be 0 … 600", self.settle_s),
            );
        }
        Ok(())
    }
}

/// Where the injected contrast went (ml).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ContrastTally {
    /// Asked for by injection events.
    pub requested_ml: f64,
    /// Still in the syringe (flows at the set rate).
    pub pending_ml: f64,
    /// Entered the duct system.
    pub in_ducts_ml: f64,
    /// Of that, what the segmented ducts could not hold once full of undiluted medium: it flowed
    /// on (into ducts too small to segment, or the duodenum).
    pub left_tree_ml: f64,
    /// Entered tissue that is not a duct: extravasation.
    pub extravasated_ml: f64,
    /// Of that, what the blood carried away from a vessel it was delivered into (washout).
    pub washed_out_ml: f64,
    /// Could not flow: no needle in the body, or the stylet still in.
    pub discarded_ml: f64,
}

/// The medium in the ducts: ρ on the duct network.
#[derive(Debug, Clone)]
struct DuctMedium {
    /// ρ of every duct node (slot order), and the update's new values.
    rho: Vec<f64>,
    next_rho: Vec<f64>,
    /// The slot the current injection enters at, and the slots in order of path distance from it.
    filling_from: Option<(usize, Vec<u32>)>,
    /// Path distance along the ducts of each slot from where contrast first entered them (mm;
    /// 0 for slots that path does not reach), once it has.
    entry_distance_mm: Vec<f64>,
}

impl DuctMedium {
    /// One explicit step of eq. 3.3.2 (with τ) over the duct nodes (Jacobi: every new value from
    /// the old ones; see `diffusion`).
    fn step(&mut self, network: &DuctNetwork, tau: f64) {
        network.neighbours.step(&self.rho, &mut self.next_rho, tau);
        std::mem::swap(&mut self.rho, &mut self.next_rho);
    }
}

/// The contrast agent of one session.
#[derive(Debug, Clone)]
pub struct ContrastAgent {
    settings: ContrastSettings,
    /// The duct system: labels whose tissue lies under the target tissue's parent.
    duct_labels: Vec<LabelId>,
    tally: ContrastTally,
    /// The atlas' duct voxels, built with the agent (a scan of the labels at the start of a
    /// session, never in the haptic loop).
    network: DuctNetwork,
    /// The medium, from the first delivery into the ducts or a stain on.
    medium: Option<DuctMedium>,
    /// ρ of non-duct voxels that received contrast (stains), by CT linear voxel index.
    stains: BTreeMap<usize, f64>,
    /// Labels of tissues blood flows through: a stain there washes out.
    blood_labels: Vec<LabelId>,
    /// World position of the node where contrast first entered a duct.
    duct_entry_mm: Option<DVec3>,
    /// Farthest filled duct node from `duct_entry_mm` along the ducts so far (mm).
    filled_extent_mm: f64,
    /// Diffusion updates left before the tree is held (see `ContrastSettings::settle_s`).
    updates_left: u64,
}

/// The labels of the duct system the target belongs to: the target labels, and every label
/// whose tissue is, or lies under, the parent tissue of a target's tissue (PTCD: "bile duct" and
/// "right hepatic duct", both under `bile_duct`). A parent that is the property tree's root
/// (everything lies under it) is not used: then the family is the target's own tissue.
pub fn duct_labels(atlas: &PunctureAtlas) -> Vec<LabelId> {
    let table = atlas.label_table();
    let tree = atlas.property_tree();
    let families: Vec<&str> = table
        .with_role(Role::Target)
        .map(|t| match tree.parent(&t.tissue) {
            Some(parent) if tree.parent(parent).is_some() => parent,
            _ => t.tissue.as_str(),
        })
        .collect();
    let mut ids: Vec<LabelId> = table
        .labels()
        .iter()
        .filter(|l| {
            l.role == Role::Target
                || tree
                    .lineage(&l.tissue)
                    .is_some_and(|lin| lin.iter().any(|t| families.contains(t)))
        })
        .map(|l| l.id)
        .collect();
    ids.sort_unstable();
    ids.dedup();
    ids
}

impl ContrastAgent {
    /// An agent for `atlas` with `settings`, refused when a setting is out of range.
    pub fn new(atlas: &PunctureAtlas, settings: ContrastSettings) -> Result<Self, SettingsError> {
        settings.validate()?;
        let duct_labels = duct_labels(atlas);
        Ok(ContrastAgent {
            settings,
            network: DuctNetwork::build(atlas, &duct_labels),
            duct_labels,
            tally: ContrastTally::default(),
            medium: None,
            stains: BTreeMap::new(),
            blood_labels: crate::complications::label_kinds(atlas)
                .into_iter()
                .filter(|(_, k)| k.carries_blood())
                .map(|(l, _)| l)
                .collect(),
            duct_entry_mm: None,
            filled_extent_mm: 0.0,
            updates_left: 0,
        })
    }

    pub fn settings(&self) -> &ContrastSettings {
        &self.settings
    }
    pub fn tally(&self) -> ContrastTally {
        self.tally
    }
    pub fn duct_labels(&self) -> &[LabelId] {
        &self.duct_labels
    }
    /// Farthest filled duct node along the ducts from where contrast first entered them (mm,
    /// max so far).
    pub fn filled_extent_mm(&self) -> f64 {
        self.filled_extent_mm
    }
    /// Contrast has filled the duct system beyond `confirm_extent_mm`.
    pub fn confirmed(&self) -> bool {
        self.filled_extent_mm >= self.settings.confirm_extent_mm
    }

    /// An injection event: `ml` more in the syringe (non-finite or ≤ 0: ignored).
    pub fn inject(&mut self, ml: f64) {
        if ml.is_finite() && ml > 0.0 {
            self.tally.requested_ml += ml;
            self.tally.pending_ml += ml;
        }
    }

    /// One update (every `update_every_ticks` ticks): the syringe delivers up to
    /// rate · Δt at the voxel nearest `tip` (reference space; `None`: nothing can flow), then
    /// `steps_per_update` explicit diffusion steps. `dt_s` is the time since the last update.
    pub fn update(&mut self, atlas: &PunctureAtlas, tip: Option<DVec3>, dt_s: f64) {
        let settle_updates = if dt_s > 0.0 {
            (self.settings.settle_s / dt_s).ceil() as u64
        } else {
            0
        };
        let amount = self.tally.pending_ml.min(self.settings.rate_ml_per_s * dt_s);
        if amount > 0.0 {
            self.tally.pending_ml -= amount;
            if self.tally.pending_ml < 1e-12 {
                self.tally.pending_ml = 0.0;
            }
            match tip {
                None => self.tally.discarded_ml += amount,
                Some(tip) => {
                    if self.deliver(atlas, tip, amount) {
                        // This update's steps, then the settling ones.
                        self.updates_left = 1 + settle_updates;
                    }
                }
            }
        }
        self.wash_out(atlas, dt_s);
        let tau = self.settings.tau;
        if self.updates_left > 0
            && let Some(m) = self.medium.as_mut()
        {
            self.updates_left -= 1;
            for _ in 0..self.settings.steps_per_update {
                m.step(&self.network, tau);
            }
            self.filled_extent_mm = diffusion::farthest_visible(
                &m.rho,
                &m.entry_distance_mm,
                self.settings.visible_fraction,
                self.filled_extent_mm,
            );
        }
    }

    /// Blood carries contrast out of the vessel it was delivered into: a stain in a vessel
    /// decays as e^(−t/τ) with τ = [`WASHOUT_S`], where a stain in parenchyma stays (on the
    /// cholangiogram a vessel flashes and clears, the liver blushes and holds).
    fn wash_out(&mut self, atlas: &PunctureAtlas, dt_s: f64) {
        if self.blood_labels.is_empty() || self.stains.is_empty() || dt_s <= 0.0 {
            return;
        }
        let labels = atlas.partial_labels().data();
        let keep = libm::exp(-dt_s / WASHOUT_S);
        let node_ml = self.network.node_volume_ml;
        let blood = &self.blood_labels;
        let mut washed = 0.0;
        self.stains.retain(|&voxel, rho| {
            if !labels.get(voxel).is_some_and(|l| blood.contains(l)) {
                return true;
            }
            let left = *rho * keep;
            let gone = if left < WASHED_OUT_RHO { *rho } else { *rho - left };
            washed += gone * node_ml;
            *rho -= gone;
            *rho > 0.0
        });
        self.tally.washed_out_ml += washed;
    }

    /// Delivers `amount` ml at the voxel nearest `tip`: into the ducts by volume-driven filling
    /// when it is a duct voxel, else as a stain. Whether it entered the ducts.
    fn deliver(&mut self, atlas: &PunctureAtlas, tip: DVec3, amount: f64) -> bool {
        let grid = *atlas.ct().grid();
        let Some([i, j, k]) = grid.nearest_voxel(tip) else {
            // Outside the CT: no tissue we know of holds it.
            self.tally.extravasated_ml += amount;
            return false;
        };
        let voxel = grid.linear(i, j, k);
        let network = &self.network;
        let m = self.medium.get_or_insert_with(|| DuctMedium {
            rho: vec![0.0; network.len()],
            next_rho: vec![0.0; network.len()],
            filling_from: None,
            entry_distance_mm: Vec::new(),
        });
        let Some(entry) = network.slot_of(voxel) else {
            *self.stains.entry(voxel).or_insert(0.0) += amount / network.node_volume_ml;
            self.tally.extravasated_ml += amount;
            return false;
        };
        if m.filling_from.as_ref().is_none_or(|(from, _)| *from != entry) {
            let (distance, order) = network.paths_from(entry);
            if self.duct_entry_mm.is_none() {
                self.duct_entry_mm = Some(grid.voxel_to_world(i, j, k));
                m.entry_distance_mm = distance
                    .into_iter()
                    .map(|d| if d.is_finite() { d } else { 0.0 })
                    .collect();
            }
            m.filling_from = Some((entry, order));
        }
        let order = m.filling_from.as_ref().map_or(&[][..], |(_, o)| o.as_slice());
        let left = filling::fill(
            &mut m.rho,
            order,
            network.node_volume_ml,
            self.settings.front_fraction,
            amount,
        );
        self.tally.in_ducts_ml += amount;
        self.tally.left_tree_ml += left;
        true
    }

    /// ρ (volume fraction of contrast medium) of every voxel that holds contrast, with its CT
    /// voxel index, ducts first (slot order) then stains (voxel order): what the X-ray reads.
    pub fn filled_voxels(&self) -> Vec<([usize; 3], f64)> {
        let Some(m) = &self.medium else {
            return Vec::new();
        };
        let grid = self.network.grid();
        let ducts = m
            .rho
            .iter()
            .enumerate()
            .filter(|(_, r)| **r > 0.0)
            .map(|(s, &r)| (self.network.voxel(s), r));
        let stains = self.stains.iter().map(|(&v, &r)| (grid.unlinear(v), r));
        ducts.chain(stains).collect()
    }

    /// Contrast held (ml): in the duct nodes, and in stains. The first equals what entered the
    /// ducts less what left the tree, up to rounding (mass conservation).
    pub fn content_ml(&self) -> (f64, f64) {
        match &self.medium {
            None => (0.0, 0.0),
            Some(m) => (
                m.rho.iter().sum::<f64>() * self.network.node_volume_ml,
                self.stains.values().sum::<f64>() * self.network.node_volume_ml,
            ),
        }
    }

    /// Feeds the whole state to a digest, in a fixed order.
    pub fn digest_into(&self, mut put: impl FnMut(u64)) {
        let t = &self.tally;
        for v in [
            t.requested_ml,
            t.pending_ml,
            t.in_ducts_ml,
            t.left_tree_ml,
            t.extravasated_ml,
            t.discarded_ml,
            t.washed_out_ml,
        ] {
            put(v.to_bits());
        }
        put(self.filled_extent_mm.to_bits());
        put(self.updates_left);
        if let Some(e) = self.duct_entry_mm {
            for v in e.to_array() {
                put(v.to_bits());
            }
        }
        if let Some(m) = &self.medium {
            put(m.rho.len() as u64);
            for r in &m.rho {
                put(r.to_bits());
            }
        }
        for (&voxel, r) in &self.stains {
            put(voxel as u64);
            put(r.to_bits());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Affine, Grid, PropertyTree, TissueSpec, Volume, synthetic_atlas};

    const DUCT: LabelId = 20;
    const TARGET: LabelId = 21;
    const LIVER: LabelId = 10;
    const VESSEL: LabelId = 11;

    /// A 40³ atlas at 1 mm: liver everywhere inside a 30 mm cube, a duct along x (y = z = 0)
    /// whose middle third is the target duct, a side branch along +y at x = 5, and a separate
    /// vessel tube along x at y = 10 that touches no duct.
    fn atlas() -> PunctureAtlas {
        let n = 40;
        let g = Grid::new([n; 3], Affine::from_spacing([1.0; 3], DVec3::splat(-19.5))).unwrap();
        let mut labels = vec![0u16; g.len()];
        for (i, l) in labels.iter_mut().enumerate() {
            let [a, b, c] = g.unlinear(i);
            let p = g.voxel_to_world(a, b, c);
            let (ax, ay, az) = (p.x.abs(), p.y.abs(), p.z.abs());
            if ax > 15.0 || ay > 15.0 || az > 15.0 {
                continue;
            }
            *l = if ay < 1.0 && az < 1.0 {
                if ax < 5.0 { TARGET } else { DUCT }
            } else if (p.x - 5.5).abs() < 1.0 && p.y > 0.0 && az < 1.0 {
                DUCT
            } else if (p.y - 10.5).abs() < 1.0 && az < 1.0 {
                VESSEL
            } else {
                LIVER
            };
        }
        let ct = vec![40.0f32; g.len()];
        let table = synthetic_atlas::label_table(
            "body",
            &[
                (synthetic_atlas::RISK, "risk", Role::Risk, "body"),
                (LIVER, "liver", Role::Organ, "liver"),
                (VESSEL, "portal vein", Role::Risk, "vessel"),
                (DUCT, "bile duct", Role::Organ, "bile_duct"),
                (TARGET, "right hepatic duct", Role::Target, "target_duct"),
            ],
        )
        .unwrap();
        let tissue = |name: &str, parent: &str| TissueSpec {
            name: name.into(),
            parent: Some(parent.into()),
            params: Default::default(),
            color_rgba: None,
            complication: None,
        };
        let tree = PropertyTree::new(vec![
            synthetic_atlas::body(synthetic_atlas::body_ramp()),
            tissue("liver", "body"),
            TissueSpec {
                complication: Some(crate::ComplicationKind::VenousBleed),
                ..tissue("vessel", "body")
            },
            tissue("bile_duct", "liver"),
            tissue("target_duct", "bile_duct"),
        ])
        .unwrap();
        PunctureAtlas::new(
            Volume::new(g, ct).unwrap(),
            Volume::new(g, labels).unwrap(),
            table,
            tree,
            synthetic_atlas::THRESHOLDS,
        )
        .unwrap()
    }

    fn agent(atlas: &PunctureAtlas) -> ContrastAgent {
        ContrastAgent::new(atlas, ContrastSettings::default()).unwrap()
    }

    /// Runs `updates` updates of 10 ms with the tip at `tip`.
    fn run(agent: &mut ContrastAgent, atlas: &PunctureAtlas, tip: Option<DVec3>, updates: usize) {
        for _ in 0..updates {
            agent.update(atlas, tip, 0.01);
        }
    }

    fn all_rho(agent: &ContrastAgent) -> Vec<f64> {
        agent.medium.as_ref().unwrap().rho.clone()
    }

    #[test]
    fn the_duct_system_is_the_target_tissue_family() {
        let a = atlas();
        assert_eq!(duct_labels(&a), vec![DUCT, TARGET]);
    }

    /// The test atlas' ducts: 2 × 2 voxels of 1 mm³ in cross-section, 30 mm along x (120
    /// voxels), and a side branch of 1 × 2 voxels 15 mm long, 28 of them outside the duct: 0.148 ml.
    const TREE_ML: f64 = 0.148;

    #[test]
    fn contrast_stays_in_the_ducts_and_is_conserved() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(0.05);
        let tip = DVec3::new(0.5, 0.5, 0.5);
        run(&mut c, &a, Some(tip), 300);
        let t = c.tally();
        assert_eq!(t.requested_ml, 0.05);
        assert_eq!(t.pending_ml, 0.0);
        assert_eq!(t.extravasated_ml, 0.0);
        assert_eq!(t.left_tree_ml, 0.0);
        assert!((t.in_ducts_ml - 0.05).abs() < 1e-12, "{t:?}");
        let (ducts, stains) = c.content_ml();
        assert_eq!(stains, 0.0, "nothing reaches a non-duct node");
        assert!((ducts - 0.05).abs() < 1e-12, "mass {ducts} ml after 1200 steps");
        // Every node holding contrast is a duct voxel.
        for ([i, j, k], rho) in c.filled_voxels() {
            let l = a.partial_labels().get(i, j, k);
            assert!(l == DUCT || l == TARGET, "ρ {rho} at label {l}");
        }
    }

    #[test]
    fn explicit_steps_are_stable_at_a_sixth() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(0.05);
        let tip = DVec3::new(0.5, 0.5, 0.5);
        run(&mut c, &a, Some(tip), 50);
        assert_eq!(c.tally().pending_ml, 0.0, "0.05 ml at 1 ml/s is delivered within 50 ms");
        // No inflow now: a convex combination each step, so the maximum never grows and no
        // value turns negative (τ = 1/6, at most 6 neighbours).
        let mut max = all_rho(&c).iter().cloned().fold(0.0, f64::max);
        for _ in 0..200 {
            run(&mut c, &a, Some(tip), 1);
            let r = all_rho(&c);
            let now = r.iter().cloned().fold(0.0, f64::max);
            assert!(now <= max + 1e-15, "max grew from {max} to {now}");
            assert!(r.iter().all(|&v| v >= 0.0));
            max = now;
        }
    }

    #[test]
    fn the_filled_tree_grows_from_the_puncture() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(0.08);
        let tip = DVec3::new(0.5, 0.5, 0.5);
        let mut extents = Vec::new();
        for _ in 0..20 {
            run(&mut c, &a, Some(tip), 1);
            extents.push(c.filled_extent_mm());
        }
        assert!(extents.windows(2).all(|w| w[1] >= w[0]), "{extents:?}");
        assert!(extents[0] < 10.0, "0.01 ml is not enough to confirm: {extents:?}");
        assert!(c.confirmed(), "0.08 ml is: {extents:?}");
        // The side branch fills from the main duct; the vessel never does.
        let branch = a.ct().grid().nearest_voxel(DVec3::new(5.5, 6.5, 0.5)).unwrap();
        let vessel = a.ct().grid().nearest_voxel(DVec3::new(0.5, 10.5, 0.5)).unwrap();
        let filled: Vec<[usize; 3]> = c.filled_voxels().into_iter().map(|(v, _)| v).collect();
        assert!(filled.contains(&branch));
        assert!(!filled.contains(&vessel));
    }

    #[test]
    fn the_injected_volume_fills_the_ducts_it_displaces_bile_from() {
        let a = atlas();
        let front = ContrastSettings::default().front_fraction;
        let tip = DVec3::new(-14.5, 0.5, 0.5);
        let mut extents = Vec::new();
        for ml in [0.01, 0.02, 0.04] {
            let mut c = agent(&a);
            c.inject(ml);
            // The updates that deliver it (1 ml/s, 10 ms each), each with its diffusion steps.
            run(&mut c, &a, Some(tip), (ml / 0.01f64).round() as usize);
            assert_eq!(c.tally().pending_ml, 0.0);
            // The filled nodes hold at least the injected volume at the front's fraction: the
            // volume pushed the medium along, diffusion only spread it further.
            let visible = c.filled_voxels().iter().filter(|(_, r)| *r >= 0.05).count() as f64;
            assert!(visible >= ml / (front * 0.001) - 1e-9, "{ml} ml: {visible} voxels");
            extents.push(c.filled_extent_mm());
        }
        // From the duct's end along its 4 mm² cross-section, v ml at half strength fill
        // v / (0.5 · 4 mm²) of it (5, 10, 20 mm); diffusion carries the visible front a few
        // millimetres further.
        for (ml, extent) in [0.01, 0.02, 0.04].into_iter().zip(&extents) {
            let filled_mm = ml * 1000.0 / (front * 4.0);
            assert!((filled_mm - 1.0..filled_mm + 4.0).contains(extent), "{extents:?}");
        }
    }

    #[test]
    fn what_the_tree_cannot_hold_leaves_it() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(0.5);
        run(&mut c, &a, Some(DVec3::new(0.5, 0.5, 0.5)), 600);
        let t = c.tally();
        assert!((t.in_ducts_ml - 0.5).abs() < 1e-12);
        assert!((t.left_tree_ml - (0.5 - TREE_ML)).abs() < 1e-9, "{t:?}");
        let (ducts, _) = c.content_ml();
        assert!((ducts - TREE_ML).abs() < 1e-9, "{ducts}");
        assert!(all_rho(&c).iter().all(|&r| (r - 1.0).abs() < 1e-9));
    }

    #[test]
    fn the_tree_is_held_once_it_has_settled() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(0.1);
        let tip = DVec3::new(0.5, 0.5, 0.5);
        // 0.1 s of inflow, then settle_s = 5 s of diffusion at 10 ms per update.
        run(&mut c, &a, Some(tip), 10 + 499);
        let settled = all_rho(&c);
        run(&mut c, &a, Some(tip), 1);
        assert_ne!(all_rho(&c), settled, "still diffusing at the last settling update");
        let held = all_rho(&c);
        run(&mut c, &a, Some(tip), 100);
        assert_eq!(all_rho(&c), held, "held after settling");
    }

    #[test]
    fn injecting_outside_a_duct_is_extravasation() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(1.0);
        let liver = DVec3::new(-6.5, 6.5, 6.5);
        run(&mut c, &a, Some(liver), 150);
        let t = c.tally();
        assert!((t.extravasated_ml - 1.0).abs() < 1e-12, "{t:?}");
        assert_eq!(t.in_ducts_ml, 0.0);
        assert_eq!(c.filled_extent_mm(), 0.0);
        assert!(!c.confirmed());
        let (ducts, stains) = c.content_ml();
        assert_eq!(ducts, 0.0);
        assert!((stains - 1.0).abs() < 1e-12, "the stain stays where it entered");
        assert_eq!(c.filled_voxels().len(), 1);
    }

    #[test]
    fn contrast_in_a_vessel_washes_out_where_in_the_liver_it_stays() {
        let a = atlas();
        let vessel = DVec3::new(0.5, 10.5, 0.5);
        let liver = DVec3::new(-6.5, 6.5, 6.5);
        let mut stained = Vec::new();
        for tip in [vessel, liver] {
            let mut c = agent(&a);
            c.inject(0.05);
            // 50 ms of flow at 1 ml/s, then 3 s with the needle out.
            run(&mut c, &a, Some(tip), 5);
            let delivered = c.content_ml().1;
            run(&mut c, &a, None, 300);
            stained.push((delivered, c.content_ml().1, c.tally()));
        }
        let (delivered, left, t) = stained[0];
        assert!((delivered - 0.05).abs() < 0.01, "{delivered}");
        // e^(−3 s / 1.5 s) ≈ 0.135 of the stain is left in the vessel …
        assert!(
            (left / delivered - libm::exp(-2.0)).abs() < 0.03,
            "{left} of {delivered}"
        );
        assert!((t.washed_out_ml + left - t.extravasated_ml).abs() < 1e-12, "{t:?}");
        // … and all of it in the liver.
        let (delivered, left, t) = stained[1];
        assert_eq!(left, delivered);
        assert_eq!(t.washed_out_ml, 0.0);
    }

    #[test]
    fn nothing_flows_without_a_needle_in_the_body() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(0.2);
        run(&mut c, &a, None, 30);
        let t = c.tally();
        assert!((t.discarded_ml - 0.2).abs() < 1e-12, "{t:?}");
        assert!(c.medium.is_none(), "no medium anywhere");
    }

    #[test]
    fn same_inputs_give_the_same_state() {
        let a = atlas();
        let digest = |c: &ContrastAgent| {
            let mut h = 0xcbf2_9ce4_8422_2325u64;
            c.digest_into(|v| h = (h ^ v).wrapping_mul(0x0000_0100_0000_01b3));
            h
        };
        let mut x = agent(&a);
        let mut y = agent(&a);
        for c in [&mut x, &mut y] {
            c.inject(0.06);
            run(c, &a, Some(DVec3::new(-3.5, 0.5, 0.5)), 4);
            run(c, &a, Some(DVec3::new(2.5, 0.5, 0.5)), 40);
        }
        assert_eq!(digest(&x), digest(&y));
        assert_eq!(all_rho(&x), all_rho(&y));
        let mut z = agent(&a);
        z.inject(0.06);
        run(&mut z, &a, Some(DVec3::new(-3.5, 0.5, 0.5)), 5);
        run(&mut z, &a, Some(DVec3::new(2.5, 0.5, 0.5)), 39);
        assert_ne!(digest(&x), digest(&z));
    }

    #[test]
    fn settings_out_of_range_are_named() {
        let a = atlas();
        let bad = |f: fn(&mut ContrastSettings)| {
            let mut s = ContrastSettings::default();
            f(&mut s);
            ContrastAgent::new(&a, s).unwrap_err().to_string()
        };
        assert!(bad(|s| s.tau = 0.2).contains("tau"));
        assert!(bad(|s| s.front_fraction = 1.5).contains("front_fraction"));
        assert!(bad(|s| s.rate_ml_per_s = f64::NAN).contains("rate"));
        assert!(bad(|s| s.update_every_ticks = 0).contains("update_every_ticks"));
    }
}
