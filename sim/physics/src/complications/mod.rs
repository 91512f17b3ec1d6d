//! Consequences of a wrong puncture, computed in the physics so they replay
//! (docs/complications.md): a vessel hit bleeds into a haematoma, a lung hit lets air into the
//! pleural space (pneumothorax), a bile duct left without drainage leaks bile.
//!
//! The atlas' property tree says which tissue does what ([`ComplicationKind`], inherited like
//! the material parameters). When the needle tip enters a label of such a tissue, a *site* begins
//! there: a hole of the needle's outer diameter at the tip's reference position. Each site then
//! leaks by its kind's [`leak::LeakModel`] at a fixed sub-rate of the tick; the volume is what the
//! views draw (where: around the site) and what the review's timeline marks (when it began).
//! The model reads the needle and writes only its own state: no force depends on it.
//!
//! Deterministic: f64, sites in the order they began, `libm` for `exp` and `sqrt`.

pub mod leak;

use glam::DVec3;

use crate::{LabelId, PunctureAtlas};
use leak::{LeakModel, PA_PER_CMH2O, PA_PER_MMHG};

/// What a puncture of a tissue does (an atlas declares it per tissue node).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ComplicationKind {
    /// A vein (portal, hepatic, caval): a low-pressure bleed into a haematoma.
    VenousBleed,
    /// An artery: a bleed at arterial pressure.
    ArterialBleed,
    /// The lung's pleura: air into the pleural space.
    Pneumothorax,
    /// A bile duct: bile leaks into the tissue once the needle leaves it undrained.
    BileLeak,
}

/// What forms in the patient: what the views draw and the review names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Consequence {
    Haematoma,
    Pneumothorax,
    BileLeak,
}

impl Consequence {
    pub const ALL: [Consequence; 3] = [Consequence::Haematoma, Consequence::Pneumothorax, Consequence::BileLeak];

    /// The name for people.
    pub fn name(self) -> &'static str {
        match self {
            Consequence::Haematoma => "haematoma",
            Consequence::Pneumothorax => "pneumothorax",
            Consequence::BileLeak => "bile leak",
        }
    }

    /// The key in files and JSON.
    pub fn key(self) -> &'static str {
        match self {
            Consequence::Haematoma => "haematoma",
            Consequence::Pneumothorax => "pneumothorax",
            Consequence::BileLeak => "bile_leak",
        }
    }
}

impl ComplicationKind {
    pub const ALL: [ComplicationKind; 4] = [
        ComplicationKind::VenousBleed,
        ComplicationKind::ArterialBleed,
        ComplicationKind::Pneumothorax,
        ComplicationKind::BileLeak,
    ];

    /// The key in atlas manifests.
    pub fn key(self) -> &'static str {
        match self {
            ComplicationKind::VenousBleed => "venous_bleed",
            ComplicationKind::ArterialBleed => "arterial_bleed",
            ComplicationKind::Pneumothorax => "pneumothorax",
            ComplicationKind::BileLeak => "bile_leak",
        }
    }

    pub fn consequence(self) -> Consequence {
        match self {
            ComplicationKind::VenousBleed | ComplicationKind::ArterialBleed => Consequence::Haematoma,
            ComplicationKind::Pneumothorax => Consequence::Pneumothorax,
            ComplicationKind::BileLeak => Consequence::BileLeak,
        }
    }

    /// Blood flows through the tissue: contrast delivered into it washes out.
    pub fn carries_blood(self) -> bool {
        matches!(self, ComplicationKind::VenousBleed | ComplicationKind::ArterialBleed)
    }

    /// The leak's constants (docs/complications.md gives the sources; "estimate" marks a value
    /// chosen for plausibility where we found no measurement).
    pub fn model(self) -> LeakModel {
        // Blood: 1060 kg/m³. Liver tissue around a haematoma: 3 ml/mmHg (estimate). A puncture
        // hole clots with a time constant of a minute (estimate, of the order of the bleeding
        // time, 2–9 min). Holes under 1 mm (20 G and finer) do not bleed: fine needles cross
        // vessels with impunity (Okuda et al. 1974, the 22 G Chiba needle).
        let bleed = |mmhg: f64| LeakModel {
            source_pa: mmhg * PA_PER_MMHG,
            density_kg_m3: 1060.0,
            compliance_ml_per_pa: 3.0 / PA_PER_MMHG,
            seal_time_s: 60.0,
            min_hole_mm: 1.0,
            plugged_by_needle: false,
        };
        match self {
            // Portal venous pressure 5–10 mmHg (Bosch et al. 2009).
            ComplicationKind::VenousBleed => bleed(8.0),
            // Mean arterial pressure.
            ComplicationKind::ArterialBleed => bleed(93.0),
            // Pleural pressure at rest −5 cmH₂O draws air from the punctured lung (ρ 1.2 kg/m³)
            // until the pleural space fills at the lung's compliance, 200 ml/cmH₂O (West,
            // Respiratory Physiology); the recoiling lung closes the tract within seconds
            // (estimate). Any needle can do it.
            ComplicationKind::Pneumothorax => LeakModel {
                source_pa: 5.0 * PA_PER_CMH2O,
                density_kg_m3: 1.2,
                compliance_ml_per_pa: 200.0 / PA_PER_CMH2O,
                seal_time_s: 10.0,
                min_hole_mm: 0.0,
                plugged_by_needle: false,
            },
            // An obstructed duct holds bile at 20 cmH₂O or more (normal 10–15 cmH₂O); bile
            // (1010 kg/m³) does not clot, so the tract stays open for minutes (estimate) and
            // gathers in the tissue at 5 ml/mmHg (estimate). The needle in the duct plugs it: the
            // leak starts when it comes out without a drain.
            ComplicationKind::BileLeak => LeakModel {
                source_pa: 20.0 * PA_PER_CMH2O,
                density_kg_m3: 1010.0,
                compliance_ml_per_pa: 5.0 / PA_PER_MMHG,
                seal_time_s: 300.0,
                min_hole_mm: 0.0,
                plugged_by_needle: true,
            },
        }
    }

    pub fn parse(key: &str) -> Option<ComplicationKind> {
        ComplicationKind::ALL.into_iter().find(|k| k.key() == key)
    }
}

/// Ticks between two leak updates (10 ms at 1 kHz).
pub const UPDATE_EVERY_TICKS: u64 = 10;
/// A new entry into the same label within this distance of a site adds to that site (mm).
pub const SAME_SITE_MM: f64 = 5.0;
/// A needle node this close to a plugged kind's site closes the hole (mm).
pub const PLUG_MM: f64 = 1.5;
/// Sites one session can have (bounded memory); later punctures begin none.
pub const MAX_SITES: usize = 16;

/// One puncture that leaks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Site {
    pub kind: ComplicationKind,
    /// The label the needle entered.
    pub label: LabelId,
    /// The tick the needle entered it.
    pub began_tick: u64,
    /// Where (reference space, mm).
    pub site_mm: DVec3,
    /// The hole's diameter: the needle's outer diameter (mm).
    pub hole_mm: f64,
    /// How long the hole has leaked (s).
    pub open_s: f64,
    /// What came out so far (ml).
    pub volume_ml: f64,
}

/// Volumes by consequence (ml), summed over sites: what each tick reports.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ConsequenceVolumes {
    pub haematoma_ml: f64,
    pub pneumothorax_ml: f64,
    pub bile_leak_ml: f64,
}

impl ConsequenceVolumes {
    pub fn of(&self, c: Consequence) -> f64 {
        match c {
            Consequence::Haematoma => self.haematoma_ml,
            Consequence::Pneumothorax => self.pneumothorax_ml,
            Consequence::BileLeak => self.bile_leak_ml,
        }
    }
}

/// The complications of one session.
#[derive(Debug, Clone)]
pub struct Complications {
    /// The kind of every label whose tissue has one (from the atlas, in label order).
    kinds: Vec<(LabelId, ComplicationKind)>,
    sites: Vec<Site>,
    /// The needle tip's label on the previous tick (0: no needle in the body).
    last_tip_label: LabelId,
    /// The needle's inserted length on the previous tick (mm).
    last_inserted_mm: f64,
}

/// The needle tip on one tick, as the complications see it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeedleTip {
    /// The label the tip is in.
    pub label: LabelId,
    /// Where it is (reference space, mm).
    pub tip_mm: DVec3,
    /// How far the needle is in along its path (mm): growing while it advances.
    pub inserted_mm: f64,
    /// The needle's outer diameter: the hole it cuts (mm).
    pub outer_diameter_mm: f64,
}

/// Each label's complication kind, from its tissue (labels without one left out).
pub fn label_kinds(atlas: &PunctureAtlas) -> Vec<(LabelId, ComplicationKind)> {
    let tree = atlas.property_tree();
    atlas
        .label_table()
        .labels()
        .iter()
        .filter_map(|l| tree.resolve_complication(&l.tissue).map(|k| (l.id, k)))
        .collect()
}

impl Complications {
    pub fn new(atlas: &PunctureAtlas) -> Complications {
        Complications {
            kinds: label_kinds(atlas),
            sites: Vec::new(),
            last_tip_label: 0,
            last_inserted_mm: 0.0,
        }
    }

    /// The sites, in the order they began.
    pub fn sites(&self) -> &[Site] {
        &self.sites
    }

    pub fn kind_of(&self, label: LabelId) -> Option<ComplicationKind> {
        self.kinds.iter().find(|(l, _)| *l == label).map(|(_, k)| *k)
    }

    /// The needle of this tick (`None`: no needle in hand). A tip entering a label of a
    /// complicating tissue while the needle advances begins a site there; withdrawing back
    /// through the tract cuts nothing new, and neither does an entry within [`SAME_SITE_MM`] of
    /// a site of the same kind (the same hole, or the next label of one duct).
    pub fn observe(&mut self, tick: u64, tip: Option<NeedleTip>) {
        let Some(tip) = tip else {
            self.last_tip_label = 0;
            self.last_inserted_mm = 0.0;
            return;
        };
        let entered = tip.label != self.last_tip_label && tip.inserted_mm > self.last_inserted_mm;
        self.last_tip_label = tip.label;
        self.last_inserted_mm = tip.inserted_mm;
        let Some(kind) = self.kind_of(tip.label).filter(|_| entered) else {
            return;
        };
        if tip.outer_diameter_mm < kind.model().min_hole_mm {
            return;
        }
        let near = self
            .sites
            .iter()
            .any(|s| s.kind == kind && s.site_mm.distance(tip.tip_mm) <= SAME_SITE_MM);
        if near || self.sites.len() >= MAX_SITES {
            return;
        }
        self.sites.push(Site {
            kind,
            label: tip.label,
            began_tick: tick,
            site_mm: tip.tip_mm,
            hole_mm: tip.outer_diameter_mm,
            open_s: 0.0,
            volume_ml: 0.0,
        });
    }

    /// One leak update of `dt_s`; `needle` is the needle's nodes (reference space) if one is in
    /// hand: it plugs the sites of kinds it closes while a node lies within [`PLUG_MM`].
    /// Sites of one kind in one label fill one space (one pleural space, one haematoma bed):
    /// its back pressure is what all of them let out.
    pub fn update(&mut self, dt_s: f64, needle: Option<&[DVec3]>) {
        for i in 0..self.sites.len() {
            let s = self.sites[i];
            let model = s.kind.model();
            if model.plugged_by_needle && needle.is_some_and(|n| passes_near(n, s.site_mm, PLUG_MM)) {
                continue;
            }
            let space_ml: f64 = self
                .sites
                .iter()
                .filter(|o| o.kind == s.kind && o.label == s.label)
                .map(|o| o.volume_ml)
                .sum();
            let q = model.rate_ml_per_s(s.hole_mm, s.open_s, space_ml);
            let room_ml = (model.limit_ml() - space_ml).max(0.0);
            let s = &mut self.sites[i];
            s.volume_ml += (q * dt_s).min(room_ml);
            s.open_s += dt_s;
        }
    }

    /// Volumes by consequence, summed over the sites.
    pub fn volumes(&self) -> ConsequenceVolumes {
        let mut v = ConsequenceVolumes::default();
        for s in &self.sites {
            match s.kind.consequence() {
                Consequence::Haematoma => v.haematoma_ml += s.volume_ml,
                Consequence::Pneumothorax => v.pneumothorax_ml += s.volume_ml,
                Consequence::BileLeak => v.bile_leak_ml += s.volume_ml,
            }
        }
        v
    }

    /// Feeds the state to a digest, in a fixed order (nothing while no site has begun).
    pub fn digest_into(&self, mut put: impl FnMut(u64)) {
        if self.sites.is_empty() {
            return;
        }
        put(u64::from(self.last_tip_label));
        put(self.last_inserted_mm.to_bits());
        for s in &self.sites {
            put(s.kind as u64);
            put(u64::from(s.label));
            put(s.began_tick);
            for v in s.site_mm.to_array() {
                put(v.to_bits());
            }
            for v in [s.hole_mm, s.open_s, s.volume_ml] {
                put(v.to_bits());
            }
        }
    }
}

/// Whether the polyline `nodes` passes within `radius_mm` of `p`.
fn passes_near(nodes: &[DVec3], p: DVec3, radius_mm: f64) -> bool {
    let r2 = radius_mm * radius_mm;
    if nodes.len() == 1 {
        return nodes[0].distance_squared(p) <= r2;
    }
    nodes.windows(2).any(|w| {
        let (a, b) = (w[0], w[1]);
        let ab = b - a;
        let len2 = ab.length_squared();
        let t = if len2 > 0.0 {
            ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (a + ab * t).distance_squared(p) <= r2
    })
}

#[cfg(test)]
mod tests;
