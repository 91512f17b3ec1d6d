//! What the session's wrong punctures did to the patient, as the physics computed it
//! (docs/complications.md): each leaking site's consequence, the structure, when it began and
//! what had come out by the end. Reported with the metrics and marked on the review's timeline;
//! the rubric already deducts for the risk hit itself, so nothing here changes a grade.

use serde::{Deserialize, Serialize};
use stylet_physics::complications::{Consequence, Site};
use stylet_physics::{LabelId, Simulation};

/// What formed, as written in reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ConsequenceKind {
    Haematoma,
    Pneumothorax,
    BileLeak,
}

impl ConsequenceKind {
    pub fn of(c: Consequence) -> ConsequenceKind {
        match c {
            Consequence::Haematoma => ConsequenceKind::Haematoma,
            Consequence::Pneumothorax => ConsequenceKind::Pneumothorax,
            Consequence::BileLeak => ConsequenceKind::BileLeak,
        }
    }

    /// The name for people.
    pub fn name(self) -> &'static str {
        match self {
            ConsequenceKind::Haematoma => "haematoma",
            ConsequenceKind::Pneumothorax => "pneumothorax",
            ConsequenceKind::BileLeak => "bile leak",
        }
    }
}

/// One leaking puncture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConsequenceRecord {
    pub kind: ConsequenceKind,
    /// The structure punctured (the atlas' label name) and its label.
    pub structure: String,
    pub label: LabelId,
    /// When the needle made the hole (s from the session start).
    pub punctured_s: f64,
    /// When it began to leak: at once for a bleed or the lung, once the needle had left it for
    /// a bile duct (s from the session start; the puncture's time if it never leaked).
    pub began_s: f64,
    /// What had come out by the end of the session (ml: blood, air or bile).
    pub volume_ml: f64,
}

/// Follows the physics' leaking sites over a replay.
#[derive(Debug, Clone, Default)]
pub struct ConsequenceWatch {
    sites: Vec<Site>,
    /// The tick each site first held a volume.
    first_leak_tick: Vec<Option<u64>>,
}

impl ConsequenceWatch {
    /// Observes the simulation after tick `tick` (a copy of at most a few sites, only once one
    /// began).
    pub fn tick(&mut self, tick: u64, sim: &Simulation) {
        let now = sim.complications().sites();
        if now.is_empty() {
            return;
        }
        self.sites.clear();
        self.sites.extend_from_slice(now);
        self.first_leak_tick.resize(now.len(), None);
        for (first, s) in self.first_leak_tick.iter_mut().zip(now) {
            if first.is_none() && s.volume_ml > 0.0 {
                *first = Some(tick);
            }
        }
    }

    /// The records, in the order the sites began; `rate_hz` turns ticks into seconds.
    pub fn finish(&self, rate_hz: f64, name: impl Fn(LabelId) -> String) -> Vec<ConsequenceRecord> {
        self.sites
            .iter()
            .zip(&self.first_leak_tick)
            .map(|(s, first)| ConsequenceRecord {
                kind: ConsequenceKind::of(s.kind.consequence()),
                structure: name(s.label),
                label: s.label,
                punctured_s: s.began_tick as f64 / rate_hz,
                began_s: first.unwrap_or(s.began_tick) as f64 / rate_hz,
                volume_ml: s.volume_ml,
            })
            .collect()
    }
}
