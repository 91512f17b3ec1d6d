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
//! Here the grid's nodes are the CT's own voxels (a cube of `grid_nodes`³ voxels, clipped to the
//! CT), so the duct mask is the partial segmentation itself, read without interpolation. ρ is the
//! volume fraction of contrast medium in a node (1 = the node is full of undiluted medium); the
//! inflow of one update adds (delivered ml) / (node volume) at the node nearest the needle tip.
//! Contrast delivered at a node outside the ducts (parenchyma, a vessel) stays there as a stain
//! and is counted as extravasation.
//!
//! Deterministic: f64, fixed node order, a fixed number of steps per update at a fixed tick
//! sub-rate; no reductions whose order depends on anything but the node indices.

use glam::DVec3;

use crate::{LabelId, PunctureAtlas, Role, SettingsError};

mod diffusion;
use diffusion::DuctNeighbours;

/// Settings of the contrast model (part of the physics: replay uses the same values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContrastSettings {
    /// Nodes per axis of the cubic diffusion grid (one node per CT voxel; thesis default 64).
    pub grid_nodes: usize,
    /// Ticks between two diffusion updates (the sub-rate of `Simulation::step`).
    pub update_every_ticks: u32,
    /// Explicit steps of eq. 3.3.1 per update.
    pub steps_per_update: u32,
    /// τ of eq. 3.3.1; explicit steps are stable for τ ≤ 1/6 on the 6-neighbourhood.
    pub tau: f64,
    /// How fast the syringe empties through the needle (ml/s).
    pub rate_ml_per_s: f64,
    /// ρ at which a node counts as filled (visible under fluoroscopy).
    pub visible_fraction: f64,
    /// Filled duct length, from the node where contrast first entered a duct, that confirms the
    /// puncture (mm).
    pub confirm_extent_mm: f64,
    /// Diffusion runs while contrast flows into the ducts and this long after (s); then the filled
    /// tree is held as it is (what fluoroscopy shows in the minutes of a PTCD), and a session
    /// pays for the diffusion only around its injections.
    pub settle_s: f64,
}

impl Default for ContrastSettings {
    fn default() -> Self {
        ContrastSettings {
            grid_nodes: 64,
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
    /// Grid-node updates per tick while the agent diffuses (a model of the work, not a timing):
    /// what the service compares with the default's before it replays a session's world model.
    pub fn node_updates_per_tick(&self) -> f64 {
        let n = self.grid_nodes as f64;
        n * n * n * f64::from(self.steps_per_update) / f64::from(self.update_every_ticks)
    }

    /// Names the first setting outside its range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        let bad = |setting: &'static str, reason: String| Err(SettingsError::Contrast { setting, reason });
        if !(8..=160).contains(&self.grid_nodes) {
            return bad(
                "grid_nodes",
                format!("contrast grid_nodes {} must be 8 … 160", self.grid_nodes),
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
    /// Entered tissue that is not a duct: extravasation.
    pub extravasated_ml: f64,
    /// Could not flow: no needle in the body, or the stylet still in.
    pub discarded_ml: f64,
}

/// The diffusion grid, placed at the first injection into the body.
#[derive(Debug, Clone)]
struct DiffusionGrid {
    /// CT voxel index of node (0, 0, 0) and nodes per axis (the cube clipped to the CT).
    origin: [usize; 3],
    n: [usize; 3],
    node_volume_ml: f64,
    /// Per node (x fastest): its slot in `duct_rho`, or `NOT_DUCT`.
    slot: Vec<u32>,
    /// Node index of each duct slot (increasing).
    duct_nodes: Vec<u32>,
    /// Duct neighbours of each slot (slots), grouped for the steps of eq. 3.3.2.
    neighbours: DuctNeighbours,
    /// ρ of the duct nodes, and the update's new values.
    duct_rho: Vec<f64>,
    next_rho: Vec<f64>,
    /// ρ of non-duct nodes that received contrast (stains), by node index.
    stains: std::collections::BTreeMap<u32, f64>,
    /// Distance of each slot's node from where contrast first entered the ducts (mm), once it has.
    entry_distance_mm: Vec<f64>,
}

const NOT_DUCT: u32 = u32::MAX;

impl DiffusionGrid {
    /// The cube of `nodes`³ CT voxels centred at the voxel nearest `centre` (clipped to the CT).
    fn place(atlas: &PunctureAtlas, duct_labels: &[LabelId], centre: DVec3, nodes: usize) -> DiffusionGrid {
        let grid = atlas.ct().grid();
        let dims = grid.dims();
        let c = grid.world_to_index(centre);
        let mut origin = [0usize; 3];
        let mut n = [0usize; 3];
        for a in 0..3 {
            n[a] = nodes.min(dims[a]);
            let want = (c[a].round() - (n[a] / 2) as f64).max(0.0);
            let want = if want.is_finite() { want as usize } else { 0 };
            origin[a] = want.min(dims[a] - n[a]);
        }
        let partial = atlas.partial_labels();
        let count = n[0] * n[1] * n[2];
        let mut slot = vec![NOT_DUCT; count];
        let mut duct_nodes = Vec::new();
        for k in 0..n[2] {
            for j in 0..n[1] {
                // The grid's row of labels along x, read as one slice (the grid lies in the CT).
                let start = partial.grid().linear(origin[0], origin[1] + j, origin[2] + k);
                let row = &partial.data()[start..start + n[0]];
                for (i, &label) in row.iter().enumerate() {
                    if label != 0 && duct_labels.contains(&label) {
                        let node = i + n[0] * (j + n[1] * k);
                        slot[node] = duct_nodes.len() as u32;
                        duct_nodes.push(node as u32);
                    }
                }
            }
        }
        let lists = duct_neighbour_lists(n, &slot, &duct_nodes);
        let neighbours = DuctNeighbours::new(lists.iter().map(|(out, m)| &out[..*m]));
        let s = grid.spacing_mm();
        let slots = duct_nodes.len();
        debug_assert_eq!(neighbours.len(), slots);
        DiffusionGrid {
            origin,
            n,
            node_volume_ml: s[0] * s[1] * s[2] / 1000.0,
            slot,
            duct_nodes,
            neighbours,
            duct_rho: vec![0.0; slots],
            next_rho: vec![0.0; slots],
            stains: std::collections::BTreeMap::new(),
            entry_distance_mm: Vec::new(),
        }
    }

    /// Node index of the CT voxel nearest `x`, when that voxel lies in the grid.
    fn node_of(&self, atlas: &PunctureAtlas, x: DVec3) -> Option<usize> {
        let [vi, vj, vk] = atlas.ct().grid().nearest_voxel(x)?;
        let v = [vi, vj, vk];
        let mut local = [0usize; 3];
        for a in 0..3 {
            local[a] = v[a].checked_sub(self.origin[a]).filter(|&l| l < self.n[a])?;
        }
        Some(local[0] + self.n[0] * (local[1] + self.n[1] * local[2]))
    }

    /// CT voxel index of a node.
    fn voxel_of(&self, node: usize) -> [usize; 3] {
        let n = self.n;
        [
            self.origin[0] + node % n[0],
            self.origin[1] + (node / n[0]) % n[1],
            self.origin[2] + node / (n[0] * n[1]),
        ]
    }

    /// One explicit step of eq. 3.3.2 (with τ) over the duct nodes (Jacobi: every new value from
    /// the old ones; see `diffusion`).
    fn step(&mut self, tau: f64) {
        self.neighbours.step(&self.duct_rho, &mut self.next_rho, tau);
        std::mem::swap(&mut self.duct_rho, &mut self.next_rho);
    }
}

/// Each duct node's duct neighbours, as slots in summation order (−x, +x, −y, +y, −z, +z) and
/// their count, for a grid of `n` nodes (x fastest) whose node i has slot `slot[i]` (`NOT_DUCT`
/// for the others) and whose slots are the nodes `duct_nodes` (increasing).
pub(super) fn duct_neighbour_lists(n: [usize; 3], slot: &[u32], duct_nodes: &[u32]) -> Vec<([u32; 6], usize)> {
    duct_nodes
        .iter()
        .map(|&node| {
            let node = node as usize;
            let (i, j, k) = (node % n[0], (node / n[0]) % n[1], node / (n[0] * n[1]));
            let mut out = [0u32; 6];
            let mut m = 0;
            let (sy, sz) = (n[0], n[0] * n[1]);
            let candidates = [
                (i > 0).then(|| node - 1),
                (i + 1 < n[0]).then(|| node + 1),
                (j > 0).then(|| node - sy),
                (j + 1 < n[1]).then(|| node + sy),
                (k > 0).then(|| node - sz),
                (k + 1 < n[2]).then(|| node + sz),
            ];
            for nb in candidates.into_iter().flatten() {
                if slot[nb] != NOT_DUCT {
                    out[m] = slot[nb];
                    m += 1;
                }
            }
            (out, m)
        })
        .collect()
}

/// The contrast agent of one session.
#[derive(Debug, Clone)]
pub struct ContrastAgent {
    settings: ContrastSettings,
    /// The duct system: labels whose tissue lies under the target tissue's parent.
    duct_labels: Vec<LabelId>,
    tally: ContrastTally,
    grid: Option<DiffusionGrid>,
    /// World position of the node where contrast first entered a duct.
    duct_entry_mm: Option<DVec3>,
    /// Farthest filled duct node from `duct_entry_mm` so far (mm).
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
        Ok(ContrastAgent {
            settings,
            duct_labels: duct_labels(atlas),
            tally: ContrastTally::default(),
            grid: None,
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
    /// Farthest filled duct node from where contrast first entered the ducts (mm, max so far).
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
    /// rate · Δt at the node nearest `tip` (reference space; `None`: nothing can flow), then
    /// `steps_per_update` explicit steps. `dt_s` is the time since the last update.
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
        let tau = self.settings.tau;
        if self.updates_left > 0
            && let Some(g) = self.grid.as_mut()
        {
            self.updates_left -= 1;
            for _ in 0..self.settings.steps_per_update {
                g.step(tau);
            }
            self.measure_extent();
        }
    }

    /// Adds `amount` ml at the node nearest `tip` (placing the grid on first use); whether it
    /// entered a duct node of the grid.
    fn deliver(&mut self, atlas: &PunctureAtlas, tip: DVec3, amount: f64) -> bool {
        let settings = self.settings;
        let duct_labels = &self.duct_labels;
        let g = self
            .grid
            .get_or_insert_with(|| DiffusionGrid::place(atlas, duct_labels, tip, settings.grid_nodes));
        match g.node_of(atlas, tip) {
            Some(node) => {
                let rho = amount / g.node_volume_ml;
                let slot = g.slot[node];
                if slot == NOT_DUCT {
                    *g.stains.entry(node as u32).or_insert(0.0) += rho;
                    self.tally.extravasated_ml += amount;
                    false
                } else {
                    g.duct_rho[slot as usize] += rho;
                    self.tally.in_ducts_ml += amount;
                    if self.duct_entry_mm.is_none() {
                        let grid = atlas.ct().grid();
                        let [i, j, k] = g.voxel_of(node);
                        let entry = grid.voxel_to_world(i, j, k);
                        self.duct_entry_mm = Some(entry);
                        g.entry_distance_mm = g
                            .duct_nodes
                            .iter()
                            .map(|&n| {
                                let [i, j, k] = g.voxel_of(n as usize);
                                grid.voxel_to_world(i, j, k).distance(entry)
                            })
                            .collect();
                    }
                    true
                }
            }
            // The tip left the grid placed at the first injection: the thesis' model covers one
            // region. Tissue there is not tracked; a duct there is counted as in the ducts.
            None => {
                let label = atlas.partial_label_at(tip);
                if label != 0 && self.duct_labels.contains(&label) {
                    self.tally.in_ducts_ml += amount;
                } else {
                    self.tally.extravasated_ml += amount;
                }
                false
            }
        }
    }

    fn measure_extent(&mut self) {
        let Some(g) = &self.grid else {
            return;
        };
        self.filled_extent_mm = diffusion::farthest_visible(
            &g.duct_rho,
            &g.entry_distance_mm,
            self.settings.visible_fraction,
            self.filled_extent_mm,
        );
    }

    /// ρ (volume fraction of contrast medium) of every node that holds contrast, with its CT
    /// voxel index, ducts first (slot order) then stains (node order): what the X-ray reads.
    pub fn filled_voxels(&self) -> Vec<([usize; 3], f64)> {
        let Some(g) = &self.grid else {
            return Vec::new();
        };
        let ducts = g
            .duct_rho
            .iter()
            .enumerate()
            .filter(|(_, r)| **r > 0.0)
            .map(|(s, &r)| (g.voxel_of(g.duct_nodes[s] as usize), r));
        let stains = g.stains.iter().map(|(&node, &r)| (g.voxel_of(node as usize), r));
        ducts.chain(stains).collect()
    }

    /// Contrast in the grid (ml): duct nodes and stains; equals what entered the grid, up to
    /// rounding (mass conservation).
    pub fn grid_content_ml(&self) -> (f64, f64) {
        match &self.grid {
            None => (0.0, 0.0),
            Some(g) => (
                g.duct_rho.iter().sum::<f64>() * g.node_volume_ml,
                g.stains.values().sum::<f64>() * g.node_volume_ml,
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
            t.extravasated_ml,
            t.discarded_ml,
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
        if let Some(g) = &self.grid {
            for a in 0..3 {
                put(g.origin[a] as u64);
                put(g.n[a] as u64);
            }
            put(g.duct_rho.len() as u64);
            for r in &g.duct_rho {
                put(r.to_bits());
            }
            for (&node, r) in &g.stains {
                put(node as u64);
                put(r.to_bits());
            }
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
        };
        let tree = PropertyTree::new(vec![
            synthetic_atlas::body(synthetic_atlas::body_ramp()),
            tissue("liver", "body"),
            tissue("vessel", "body"),
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
        agent.grid.as_ref().unwrap().duct_rho.clone()
    }

    #[test]
    fn the_duct_system_is_the_target_tissue_family() {
        let a = atlas();
        assert_eq!(duct_labels(&a), vec![DUCT, TARGET]);
    }

    #[test]
    fn contrast_stays_in_the_ducts_and_is_conserved() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(2.0);
        let tip = DVec3::new(0.5, 0.5, 0.5);
        run(&mut c, &a, Some(tip), 300);
        let t = c.tally();
        assert_eq!(t.requested_ml, 2.0);
        assert_eq!(t.pending_ml, 0.0);
        assert_eq!(t.extravasated_ml, 0.0);
        assert!((t.in_ducts_ml - 2.0).abs() < 1e-12, "{t:?}");
        let (ducts, stains) = c.grid_content_ml();
        assert_eq!(stains, 0.0, "nothing reaches a non-duct node");
        assert!((ducts - 2.0).abs() < 1e-9, "mass {ducts} ml after 1200 steps");
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
        c.inject(0.5);
        let tip = DVec3::new(0.5, 0.5, 0.5);
        run(&mut c, &a, Some(tip), 50);
        assert_eq!(c.tally().pending_ml, 0.0, "0.5 ml at 1 ml/s is delivered within 0.5 s");
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
        c.inject(5.0);
        let tip = DVec3::new(0.5, 0.5, 0.5);
        let mut extents = Vec::new();
        for _ in 0..20 {
            run(&mut c, &a, Some(tip), 5);
            extents.push(c.filled_extent_mm());
        }
        assert!(extents.windows(2).all(|w| w[1] >= w[0]), "{extents:?}");
        assert!(extents[0] < 10.0, "not confirmed after 50 ms: {extents:?}");
        assert!(c.confirmed(), "confirmed after 1 s: {extents:?}");
        // The side branch fills from the main duct; the vessel never does.
        let branch = a.ct().grid().nearest_voxel(DVec3::new(5.5, 6.5, 0.5)).unwrap();
        let vessel = a.ct().grid().nearest_voxel(DVec3::new(0.5, 10.5, 0.5)).unwrap();
        let filled: Vec<[usize; 3]> = c.filled_voxels().into_iter().map(|(v, _)| v).collect();
        assert!(filled.contains(&branch));
        assert!(!filled.contains(&vessel));
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
        let (ducts, stains) = c.grid_content_ml();
        assert_eq!(ducts, 0.0);
        assert!((stains - 1.0).abs() < 1e-12, "the stain stays where it entered");
        assert_eq!(c.filled_voxels().len(), 1);
    }

    #[test]
    fn nothing_flows_without_a_needle_in_the_body() {
        let a = atlas();
        let mut c = agent(&a);
        c.inject(0.2);
        run(&mut c, &a, None, 30);
        let t = c.tally();
        assert!((t.discarded_ml - 0.2).abs() < 1e-12, "{t:?}");
        assert!(c.grid.is_none(), "no grid is placed");
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
            c.inject(1.5);
            run(c, &a, Some(DVec3::new(-3.5, 0.5, 0.5)), 40);
            run(c, &a, Some(DVec3::new(2.5, 0.5, 0.5)), 40);
        }
        assert_eq!(digest(&x), digest(&y));
        assert_eq!(all_rho(&x), all_rho(&y));
        let mut z = agent(&a);
        z.inject(1.5);
        run(&mut z, &a, Some(DVec3::new(-3.5, 0.5, 0.5)), 41);
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
        assert!(bad(|s| s.grid_nodes = 4).contains("grid_nodes"));
        assert!(bad(|s| s.rate_ml_per_s = f64::NAN).contains("rate"));
        assert!(bad(|s| s.update_every_ticks = 0).contains("update_every_ticks"));
    }
}
