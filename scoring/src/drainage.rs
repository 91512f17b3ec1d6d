//! The Seldinger exchange after the puncture, measured (docs/metrics.md "Drainage"): whether the
//! guide wire reached the ducts and stayed there, each step's attempts and fluoroscopy, the
//! forces of the dilator and catheter, and where the drainage catheter ended.
//!
//! Everything comes from the physics' outputs of the replayed ticks (`TickOutput::wire`): the
//! steps are counted where the state changes (a wire appears, a dilator or catheter goes on the
//! wire), so a refused event is not an attempt; refused events are counted on their own.

use serde::{Deserialize, Serialize};
use stylet_physics::TickOutput;
use stylet_physics::seldinger::Access;
use stylet_physics::seldinger::over_wire::OverWireKind;
use stylet_physics::seldinger::pigtail::DRAINAGE_HOLES;
use stylet_physics::wire::WrongBranchWatch;

/// Wire in the ducts' lumen for the wire to count as having reached them (mm): more than a tip
/// grazing a duct's edge.
pub const WIRE_REACHED_MM: f64 = 10.0;

/// The step of the exchange a tick belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Step {
    /// Before a wire is in: the puncture and its confirmation.
    Puncture,
    /// The wire in, nothing on it.
    Wire,
    /// A dilator on the wire.
    Dilator,
    /// A catheter on the wire, or placed.
    Catheter,
}

impl Step {
    pub const ALL: [Step; 4] = [Step::Puncture, Step::Wire, Step::Dilator, Step::Catheter];

    /// The step of a tick from its output.
    pub fn of(out: &TickOutput) -> Step {
        match out.wire {
            None => Step::Puncture,
            Some(w) if w.catheter.is_some() => Step::Catheter,
            Some(w) => match w.over_wire.map(|t| t.kind) {
                None => Step::Wire,
                Some(OverWireKind::Dilator) => Step::Dilator,
                Some(OverWireKind::Catheter) => Step::Catheter,
            },
        }
    }

    pub fn label(self) -> &'static str {
        match self {
            Step::Puncture => "puncture",
            Step::Wire => "guide wire",
            Step::Dilator => "dilator",
            Step::Catheter => "drainage catheter",
        }
    }
}

/// What the exchange did (docs/metrics.md "Drainage"); present when a guide wire went in.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DrainageMetrics {
    /// At least [`WIRE_REACHED_MM`] of wire lay in the ducts at some moment.
    pub wire_reached_ducts: bool,
    /// The most wire in the ducts at once (mm).
    pub wire_in_ducts_max_mm: f64,
    /// The wire was drawn back out of the ducts after the needle came out.
    pub access_lost: bool,
    /// The wire's tip went through a duct wall into the liver.
    pub wire_left_duct: bool,
    /// The longest loop pushed into a blocked tip (mm).
    pub wire_folded_max_mm: f64,
    /// Runs of the wire's tip away from the hilum into a branch that does not lead there
    /// (`stylet_physics::wire::branches`).
    #[serde(default)]
    pub wrong_branch_entries: u32,
    /// Wires put in, dilators and catheters put on the wire.
    pub wire_attempts: u32,
    pub dilator_attempts: u32,
    pub catheter_attempts: u32,
    /// Steps the physics refused (out of order, the wrong size).
    pub refused_steps: u32,
    /// Fluoroscopy time in each step (s).
    pub fluoroscopy_puncture_s: f64,
    pub fluoroscopy_wire_s: f64,
    pub fluoroscopy_dilator_s: f64,
    pub fluoroscopy_catheter_s: f64,
    /// The largest push the hand felt on the dilator and on the catheter (N).
    pub dilator_peak_force_n: f64,
    pub catheter_peak_force_n: f64,
    /// The catheter was placed (its wire out, its pigtail formed).
    pub catheter_placed: bool,
    /// Its drainage holes in the ducts, of [`DRAINAGE_HOLES`].
    pub catheter_holes_in_ducts: u32,
    pub catheter_holes: u32,
    /// Its pigtail's loop lies in the ducts.
    pub pigtail_in_ducts: bool,
}

impl DrainageMetrics {
    /// Whether the placed catheter drains the ducts through every hole.
    pub fn drains(&self) -> bool {
        self.catheter_placed && self.catheter_holes_in_ducts == self.catheter_holes
    }
}

/// Collects [`DrainageMetrics`] tick by tick.
#[derive(Debug, Default)]
pub struct DrainageCollector {
    metrics: Option<DrainageMetrics>,
    fluoroscopy_ticks: [u64; 4],
    last_tool: Option<OverWireKind>,
    wire_was_in: bool,
    refused: u32,
    wrong_branch: WrongBranchWatch,
}

impl DrainageCollector {
    /// Observes a tick; `access`: the simulation's exchange after it.
    pub fn tick(&mut self, out: &TickOutput, access: Option<&Access>) {
        let step = Step::of(out);
        if out.xray_on {
            self.fluoroscopy_ticks[step as usize] += 1;
        }
        self.refused += u32::from(out.refused.is_some());
        let Some(w) = out.wire else {
            self.wire_was_in = false;
            self.last_tool = None;
            return;
        };
        let m = self.metrics.get_or_insert(DrainageMetrics {
            wire_reached_ducts: false,
            wire_in_ducts_max_mm: 0.0,
            access_lost: false,
            wire_left_duct: false,
            wire_folded_max_mm: 0.0,
            wrong_branch_entries: 0,
            wire_attempts: 0,
            dilator_attempts: 0,
            catheter_attempts: 0,
            refused_steps: 0,
            fluoroscopy_puncture_s: 0.0,
            fluoroscopy_wire_s: 0.0,
            fluoroscopy_dilator_s: 0.0,
            fluoroscopy_catheter_s: 0.0,
            dilator_peak_force_n: 0.0,
            catheter_peak_force_n: 0.0,
            catheter_placed: false,
            catheter_holes_in_ducts: 0,
            catheter_holes: DRAINAGE_HOLES as u32,
            pigtail_in_ducts: false,
        });
        if !self.wire_was_in {
            m.wire_attempts += 1;
        }
        self.wire_was_in = true;
        m.wire_in_ducts_max_mm = m.wire_in_ducts_max_mm.max(w.in_ducts_mm);
        m.wire_reached_ducts |= m.wire_in_ducts_max_mm >= WIRE_REACHED_MM;
        m.access_lost |= w.access_lost;
        m.wire_left_duct |= w.left_duct;
        m.wire_folded_max_mm = m.wire_folded_max_mm.max(w.folded_mm);
        // The tip in the ducts' own frame (the wire is laid in the reference anatomy).
        if let Some((a, wire)) = access.and_then(|a| a.wire().map(|wire| (a, wire))) {
            self.wrong_branch.observe(a.channel().from_hilum_mm(wire.tip_mm()));
        }
        m.wrong_branch_entries = self.wrong_branch.entries();
        let tool = w.over_wire.map(|t| t.kind);
        if tool.is_some() && tool != self.last_tool {
            match tool {
                Some(OverWireKind::Dilator) => m.dilator_attempts += 1,
                Some(OverWireKind::Catheter) => m.catheter_attempts += 1,
                None => {}
            }
        }
        self.last_tool = tool;
        match tool {
            Some(OverWireKind::Dilator) => m.dilator_peak_force_n = m.dilator_peak_force_n.max(w.force_n),
            Some(OverWireKind::Catheter) => m.catheter_peak_force_n = m.catheter_peak_force_n.max(w.force_n),
            None => {}
        }
        if let Some(c) = w.catheter {
            m.catheter_placed = true;
            m.catheter_holes_in_ducts = u32::from(c.holes_in_ducts);
            m.pigtail_in_ducts = c.pigtail_in_ducts;
        }
    }

    /// The metrics at the end, `None` when no wire went in; `rate`: ticks per second.
    pub fn finish(self, rate: f64) -> Option<DrainageMetrics> {
        let mut m = self.metrics?;
        let [p, w, d, c] = self.fluoroscopy_ticks.map(|t| t as f64 / rate);
        m.fluoroscopy_puncture_s = p;
        m.fluoroscopy_wire_s = w;
        m.fluoroscopy_dilator_s = d;
        m.fluoroscopy_catheter_s = c;
        m.refused_steps = self.refused;
        Some(m)
    }
}

/// What went wrong in the exchange, in plain words for the trainee (nothing when it went well).
pub fn findings(m: &DrainageMetrics) -> Vec<String> {
    let mut out = Vec::new();
    if !m.wire_reached_ducts {
        out.push(format!(
            "The guide wire never lay in the ducts (at most {:.0} mm): advance it through the needle into the duct before \
             the needle comes out.",
            m.wire_in_ducts_max_mm
        ));
    }
    if m.wire_left_duct {
        out.push(
            "The guide wire went through the duct wall into the liver: a straight wire pushed against a blocked tip \
             perforates; draw it back and turn a J tip into the duct."
                .to_string(),
        );
    }
    if m.wrong_branch_entries > 0 {
        let n = m.wrong_branch_entries;
        out.push(format!(
            "The guide wire ran into {} away from the hilum: steer it centrally, toward the common bile \
             duct, by turning the J before advancing.",
            if n == 1 {
                "a branch".to_string()
            } else {
                format!("{n} branches")
            }
        ));
    }
    if m.access_lost {
        out.push(
            "The guide wire was drawn back out of the ducts after the needle came out: the access was lost."
                .to_string(),
        );
    }
    if m.catheter_placed && !m.drains() {
        let outside = m.catheter_holes - m.catheter_holes_in_ducts;
        out.push(format!(
            "The catheter's side holes lie outside the duct ({outside} of {}): bile would leak. Advance the catheter \
             farther over the wire before the wire comes out.",
            m.catheter_holes
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn placed() -> DrainageMetrics {
        DrainageMetrics {
            wire_reached_ducts: true,
            wire_in_ducts_max_mm: 60.0,
            access_lost: false,
            wire_left_duct: false,
            wire_folded_max_mm: 0.0,
            wrong_branch_entries: 0,
            wire_attempts: 1,
            dilator_attempts: 1,
            catheter_attempts: 1,
            refused_steps: 0,
            fluoroscopy_puncture_s: 1.0,
            fluoroscopy_wire_s: 1.0,
            fluoroscopy_dilator_s: 0.0,
            fluoroscopy_catheter_s: 1.0,
            dilator_peak_force_n: 3.0,
            catheter_peak_force_n: 2.0,
            catheter_placed: true,
            catheter_holes_in_ducts: 6,
            catheter_holes: 6,
            pigtail_in_ducts: true,
        }
    }

    #[test]
    fn wrong_branches_are_named_and_counted() {
        assert!(findings(&placed()).is_empty());
        let one = findings(&DrainageMetrics {
            wrong_branch_entries: 1,
            ..placed()
        });
        assert_eq!(one.len(), 1);
        assert!(
            one[0].starts_with("The guide wire ran into a branch away from the hilum"),
            "{one:?}"
        );
        let two = findings(&DrainageMetrics {
            wrong_branch_entries: 2,
            ..placed()
        });
        assert!(two[0].contains("ran into 2 branches"), "{two:?}");
    }
}
