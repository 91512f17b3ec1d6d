//! The review trace of a session: what the dashboard draws of it. The force on the hand along
//! the insertion direction with its cutting, friction and base components (thesis §3.5.3,
//! eqs. 3.5.2–3.5.7, docs/physics.md: f = f_cut + f_friction + f_base), insertion depth, the needle
//! tip's path and the events. Session files hold the device force but not its components, so the
//! trace is taken from the replay, in the same pass that scores the session.
//!
//! A 1 kHz session is too dense for a chart, so ticks are grouped into buckets of
//! [`BUCKET_TICKS`] (20 ms at 1 kHz) and each series keeps, per bucket, the sample of largest
//! magnitude: a puncture's force peak, which lasts only a few ticks, survives decimation.
//!
//! Since version 2 the trace keeps the structures the needle cut into ([`Puncture`], to label the force peaks) and
//! the exact tip position where each risk structure was first touched ([`RiskPoint`], to draw
//! slices through it): neither can be recovered from the 20 ms buckets. Version 3: a puncture's
//! peak is the largest force while the tip is in the structure (it was the one before entry).
//! Version 7: a `complication` event marks when each haematoma, pneumothorax or bile leak began.
//! Version 8: a drainage session's phases — the puncture, then the guide wire, dilator and catheter
//! steps of the exchange ([`TracePhase`]).

use serde::{Deserialize, Serialize};
use stylet_physics::glam::DVec3;
use stylet_physics::{Event, LabelId, TickInput, TickOutput};

use crate::drainage::Step;
use crate::metrics::{Metrics, RiskHit};

/// Format version of [`ReviewTrace`] (stored traces of another version are rebuilt).
pub const TRACE_VERSION: u32 = 8;

/// At most this many punctures are kept per session (a trainee jiggling at a boundary cannot grow
/// the trace without bound).
pub const MAX_PUNCTURES: usize = 256;

/// Ticks per bucket.
pub const BUCKET_TICKS: u64 = 20;

/// A marker on the time axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TraceEvent {
    pub t_s: f64,
    /// `stylet-remove`, `xray-on`, `xray-off`, `contrast-inject`, `tool`, `risk-hit`,
    /// `target-reached`, … (docs/dashboard.md).
    pub kind: String,
    /// What a reader should see: "stylet removed", "risk hit: right lung", …
    pub label: String,
}

/// The decimated series of one session, in seconds, newtons and millimetres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReviewTrace {
    pub version: u32,
    pub physics_version: u32,
    pub bucket_s: f64,
    /// Start of every bucket.
    pub t_s: Vec<f64>,
    /// Force on the hand along the insertion direction, positive against insertion.
    pub force_n: Vec<f64>,
    pub cutting_n: Vec<f64>,
    pub friction_n: Vec<f64>,
    pub base_n: Vec<f64>,
    /// Needle length inside the body along the channel (deepest in the bucket).
    pub inserted_mm: Vec<f64>,
    /// Tip depth under the skin surface D_skin (deepest in the bucket; negative outside).
    pub tip_depth_mm: Vec<f64>,
    /// Needle tip (world mm) at the end of the bucket while the needle is in the body, else None.
    pub tip_mm: Vec<Option<[f64; 3]>>,
    pub events: Vec<TraceEvent>,
    /// Structures the needle cut into, in time order (at most [`MAX_PUNCTURES`]).
    #[serde(default)]
    pub punctures: Vec<Puncture>,
    /// Where each risk structure was first touched, in the order of the score's risk hits.
    #[serde(default)]
    pub risk_points: Vec<RiskPoint>,
    /// Sessions trained on a force-feedback device: the largest force magnitude the device was
    /// sent in each bucket (N), and the OR of its guard's flags
    /// (`stylet_recorder::device_forces::guard`); empty otherwise.
    #[serde(default)]
    pub sent_n: Vec<f64>,
    #[serde(default)]
    pub guard: Vec<u8>,
    /// Two-handed sessions: whether the needle tip was out of the second hand's live ultrasound
    /// image at some tick of each bucket with the needle in the body; empty for one-handed ones.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tip_hidden: Vec<bool>,
    /// Sessions in which a guide wire went in: the stretches of each step of the exchange, in
    /// time order, covering the session; empty for a puncture alone.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub phases: Vec<TracePhase>,
}

/// A stretch of a session in one step of the exchange (`crate::drainage::Step::of` its ticks).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TracePhase {
    pub step: Step,
    /// Its first tick's start and its last tick's end (s).
    pub from_s: f64,
    pub to_s: f64,
}

/// The needle tip entered a structure for the first time in an attempt (advancing, at the deepest
/// point of the attempt so far). The largest force while the tip was in it is the structure's
/// resistance to cutting: the dashboard labels that peak with the structure's name.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Puncture {
    /// Time of the largest force while the tip was in the structure (s).
    pub peak_t_s: f64,
    /// That force on the hand along the needle (N, positive against the insertion).
    pub peak_force_n: f64,
    /// Time the tip entered the structure (s).
    pub t_s: f64,
    /// The label the tip entered (the atlas' label table names it).
    pub label: LabelId,
}

/// The tip position at a risk structure's first contact (the score's `RiskHit.t_s`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RiskPoint {
    pub structure: String,
    pub label: LabelId,
    pub t_s: f64,
    /// Needle tip (world mm, RAS).
    pub point_mm: [f64; 3],
}

/// What a key moment of a session is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MomentKind {
    SkinEntry,
    RiskHit,
    TargetReached,
    Contrast,
    StyletOut,
    Redirection,
    /// A haematoma, pneumothorax or bile leak began.
    Complication,
}

impl MomentKind {
    pub fn name(self) -> &'static str {
        match self {
            MomentKind::SkinEntry => "skin entry",
            MomentKind::RiskHit => "risk hit",
            MomentKind::TargetReached => "target reached",
            MomentKind::Contrast => "contrast",
            MomentKind::StyletOut => "stylet out",
            MomentKind::Redirection => "redirection",
            MomentKind::Complication => "complication",
        }
    }
}

/// A moment worth jumping to in a replay (the simulator's viewer, the dashboard's player).
#[derive(Debug, Clone, PartialEq)]
pub struct TraceMoment {
    pub kind: MomentKind,
    /// Seconds from the start of the session.
    pub t_s: f64,
    pub label: String,
}

impl ReviewTrace {
    /// Skin entries (each time the needle enters the body), risk hits, redirections, the target
    /// reached, contrast injections and the stylet taken out, in time order.
    pub fn key_moments(&self) -> Vec<TraceMoment> {
        let mut out = Vec::new();
        let mut inside = false;
        for (k, &mm) in self.inserted_mm.iter().enumerate() {
            let now = mm > 0.0;
            if now && !inside {
                out.push(TraceMoment {
                    kind: MomentKind::SkinEntry,
                    t_s: self.t_s[k],
                    label: "skin entry".into(),
                });
            }
            inside = now;
        }
        for e in &self.events {
            let kind = match e.kind.as_str() {
                "risk-hit" => MomentKind::RiskHit,
                "target-reached" => MomentKind::TargetReached,
                "contrast-inject" => MomentKind::Contrast,
                "stylet-remove" => MomentKind::StyletOut,
                "redirection" => MomentKind::Redirection,
                "complication" => MomentKind::Complication,
                _ => continue,
            };
            out.push(TraceMoment {
                kind,
                t_s: e.t_s,
                label: e.label.clone(),
            });
        }
        out.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
        out
    }

    /// The tip path as polylines: one per stretch of buckets with the needle in the body.
    pub fn tip_paths(&self) -> Vec<Vec<DVec3>> {
        let mut out: Vec<Vec<DVec3>> = Vec::new();
        let mut open = false;
        for p in &self.tip_mm {
            match p {
                Some(p) if open => out.last_mut().expect("open").push(DVec3::from_array(*p)),
                Some(p) => {
                    out.push(vec![DVec3::from_array(*p)]);
                    open = true;
                }
                None => open = false,
            }
        }
        out
    }

    /// Each stay of the needle in the body: the tip positions (world mm) with their depths under
    /// the skin (mm), in time order.
    pub fn tip_stays(&self) -> Vec<Vec<(DVec3, f64)>> {
        let mut out: Vec<Vec<(DVec3, f64)>> = Vec::new();
        let mut open = false;
        for (p, d) in self.tip_mm.iter().zip(&self.tip_depth_mm) {
            match p {
                Some(p) if open => out.last_mut().expect("open").push((DVec3::from_array(*p), *d)),
                Some(p) => {
                    out.push(vec![(DVec3::from_array(*p), *d)]);
                    open = true;
                }
                None => open = false,
            }
        }
        out
    }

    /// The final approach: the tip's path in the last stay in the body, from the skin entry to
    /// its deepest point (what an expert's path contributes to the expert corridor); `None` if
    /// the needle never entered.
    pub fn final_approach(&self) -> Option<Vec<DVec3>> {
        let stay = self.tip_stays().pop()?;
        let deepest = stay
            .iter()
            .enumerate()
            .fold(0, |best, (k, p)| if p.1 > stay[best].1 { k } else { best });
        Some(stay[..=deepest].iter().map(|p| p.0).collect())
    }

    /// The deepest tip position of the session, if the needle entered the body.
    pub fn deepest_tip(&self) -> Option<DVec3> {
        self.tip_mm
            .iter()
            .zip(&self.tip_depth_mm)
            .filter_map(|(p, d)| p.map(|p| (DVec3::from_array(p), *d)))
            .fold(None, |best: Option<(DVec3, f64)>, (p, d)| match best {
                Some((_, bd)) if bd >= d => best,
                _ => Some((p, d)),
            })
            .map(|(p, _)| p)
    }
}

/// Keeps the value of largest magnitude.
fn peak(slot: &mut f64, v: f64) {
    if v.is_finite() && v.abs() > slot.abs() {
        *slot = v;
    }
}

/// Collects a [`ReviewTrace`] tick by tick during a replay.
pub struct TraceCollector {
    trace: ReviewTrace,
    /// One tick (s).
    tick_s: f64,
    in_bucket: u64,
    /// Tip label of the previous tick (0 outside the body).
    prev_label: LabelId,
    /// Deepest inserted length of the current attempt (mm); labels entered in it.
    attempt_deepest_mm: f64,
    attempt_labels: Vec<LabelId>,
    /// The puncture whose structure the tip is in now (its peak still grows).
    open: Option<usize>,
    /// First tick in the body with the tip in each label: (t_s, tip).
    first_contact: std::collections::BTreeMap<LabelId, (f64, [f64; 3])>,
}

impl TraceCollector {
    pub fn new(tick_rate_hz: u32) -> TraceCollector {
        let rate = f64::from(tick_rate_hz.max(1));
        TraceCollector {
            trace: ReviewTrace {
                version: TRACE_VERSION,
                physics_version: stylet_physics::PHYSICS_VERSION,
                bucket_s: BUCKET_TICKS as f64 / rate,
                t_s: Vec::new(),
                force_n: Vec::new(),
                cutting_n: Vec::new(),
                friction_n: Vec::new(),
                base_n: Vec::new(),
                inserted_mm: Vec::new(),
                tip_depth_mm: Vec::new(),
                tip_mm: Vec::new(),
                events: Vec::new(),
                punctures: Vec::new(),
                risk_points: Vec::new(),
                sent_n: Vec::new(),
                guard: Vec::new(),
                tip_hidden: Vec::new(),
                phases: Vec::new(),
            },
            tick_s: 1.0 / rate,
            in_bucket: 0,
            prev_label: 0,
            attempt_deepest_mm: 0.0,
            attempt_labels: Vec::new(),
            open: None,
            first_contact: Default::default(),
        }
    }

    pub fn tick(&mut self, input: &TickInput, out: &TickOutput) {
        self.punctures(out, -out.force_n.dot(out.insertion_dir));
        self.phase(out);
        let t = &mut self.trace;
        if self.in_bucket == 0 {
            t.t_s.push(out.time_s);
            for s in [&mut t.force_n, &mut t.cutting_n, &mut t.friction_n, &mut t.base_n] {
                s.push(0.0);
            }
            t.inserted_mm.push(0.0);
            t.tip_depth_mm.push(f64::NEG_INFINITY);
            t.tip_mm.push(None);
        }
        self.in_bucket = (self.in_bucket + 1) % BUCKET_TICKS;
        let k = t.t_s.len() - 1;
        // Positive against the insertion direction, as the thesis plots Fig. 3.12.
        let along = |v: DVec3| -v.dot(out.insertion_dir);
        let c = &out.components;
        peak(&mut t.force_n[k], along(out.force_n));
        peak(&mut t.cutting_n[k], along(c.cut));
        peak(&mut t.friction_n[k], along(c.friction));
        peak(&mut t.base_n[k], along(c.base));
        if out.inserted_mm.is_finite() {
            t.inserted_mm[k] = t.inserted_mm[k].max(out.inserted_mm);
        }
        if out.tip_depth_mm.is_finite() {
            t.tip_depth_mm[k] = t.tip_depth_mm[k].max(out.tip_depth_mm);
        }
        t.tip_mm[k] = (out.inserted_mm > 0.0 && out.tip_mm.is_finite()).then(|| out.tip_mm.to_array());
        for e in &input.events {
            let label = match e {
                Event::StyletRemove => "stylet removed".to_string(),
                Event::StyletInsert => "stylet in".to_string(),
                Event::XrayOn => "X-ray on".to_string(),
                Event::XrayOff => "X-ray off".to_string(),
                Event::ContrastInject { ml } => format!("contrast {ml} ml"),
                Event::SelectTool(tool) => format!("tool: {}", tool.name()),
                Event::SecondTool(Some(tool)) => format!("second hand: {}", tool.tool_spec().name()),
                Event::SecondTool(None) => "second hand: empty".to_string(),
                Event::BreathHold => "breath hold".to_string(),
                Event::BreathRelease => "breath release".to_string(),
                Event::WireIn { diameter, tip } => format!("guide wire in: {}\" {}", diameter.name(), tip.name()),
                Event::NeedleOut => "needle out over the wire".to_string(),
                Event::WireOut => "guide wire out".to_string(),
                Event::DilatorIn { size_fr } => format!("dilator {size_fr} F"),
                Event::DilatorOut => "dilator out".to_string(),
                Event::CatheterIn { size_fr } => format!("catheter {size_fr} F"),
            };
            t.events.push(TraceEvent {
                t_s: out.time_s,
                kind: e.name().to_string(),
                label,
            });
        }
    }

    /// Extends the current phase by this tick, or starts the next.
    fn phase(&mut self, out: &TickOutput) {
        let step = Step::of(out);
        let (from_s, to_s) = (out.time_s, out.time_s + self.tick_s);
        match self.trace.phases.last_mut() {
            Some(p) if p.step == step => p.to_s = to_s,
            _ => self.trace.phases.push(TracePhase { step, from_s, to_s }),
        }
    }

    /// Follows the tip through the labels: an advancing entry into a structure not yet entered in
    /// this attempt is a puncture. The tissue at the tip is what the cutting force works against
    /// (Alg. 3.5 evaluates the material at the tip), so a structure's peak is the largest force
    /// while the tip is in it, until it moves on.
    fn punctures(&mut self, out: &TickOutput, force_n: f64) {
        let in_body = out.inserted_mm > 0.0 && out.inserted_mm.is_finite() && out.tip_mm.is_finite();
        if !in_body {
            // Out of the body (or another tool): the next skin entry starts a new attempt.
            self.prev_label = 0;
            self.attempt_deepest_mm = 0.0;
            self.attempt_labels.clear();
            self.open = None;
            return;
        }
        let label = out.tip_label;
        self.first_contact
            .entry(label)
            .or_insert((out.time_s, out.tip_mm.to_array()));
        let advancing = out.inserted_mm >= self.attempt_deepest_mm;
        self.attempt_deepest_mm = self.attempt_deepest_mm.max(out.inserted_mm);
        if label != self.prev_label {
            self.open = None;
            if label != 0 && advancing && !self.attempt_labels.contains(&label) {
                self.attempt_labels.push(label);
                if self.trace.punctures.len() < MAX_PUNCTURES {
                    self.trace.punctures.push(Puncture {
                        peak_t_s: out.time_s,
                        peak_force_n: if force_n.is_finite() { force_n } else { 0.0 },
                        t_s: out.time_s,
                        label,
                    });
                    self.open = Some(self.trace.punctures.len() - 1);
                }
            }
        }
        if let Some(p) = self.open.map(|k| &mut self.trace.punctures[k])
            && force_n.is_finite()
            && force_n > p.peak_force_n
        {
            p.peak_t_s = out.time_s;
            p.peak_force_n = force_n;
        }
        self.prev_label = label;
    }

    /// The tip where each hit structure was first touched (the same tick the metrics count as
    /// first contact: the first in the body with the tip in its label).
    fn add_risk_points(&mut self, hits: &[RiskHit]) {
        for hit in hits {
            if let Some((t_s, p)) = self.first_contact.get(&hit.label) {
                self.trace.risk_points.push(RiskPoint {
                    structure: hit.structure.clone(),
                    label: hit.label,
                    t_s: *t_s,
                    point_mm: *p,
                });
            }
        }
    }

    /// Marks the bucket of the tick just traced when the needle tip was out of the live image
    /// (the buckets before stay unmarked).
    pub fn tip_hidden(&mut self, hidden: bool) {
        let t = &mut self.trace;
        if !hidden {
            return;
        }
        t.tip_hidden.resize(t.t_s.len(), false);
        if let Some(last) = t.tip_hidden.last_mut() {
            *last = true;
        }
    }

    /// The force a force-feedback device was sent, bucket by bucket beside the replayed force
    /// (read from the file, not replayed: it depends on the device, not on the poses). Ticks
    /// count from `first_tick`, the session's first.
    pub fn device_forces(&mut self, first_tick: u64, forces: &[stylet_recorder::device_forces::DeviceForceRecord]) {
        if forces.is_empty() {
            return;
        }
        let t = &mut self.trace;
        let n = t.t_s.len();
        t.sent_n = vec![0.0; n];
        t.guard = vec![0; n];
        for f in forces {
            let Some(k) = f.tick.checked_sub(first_tick).map(|d| (d / BUCKET_TICKS) as usize) else {
                continue;
            };
            if k < n {
                let magnitude = DVec3::from_array(f.sent_n).length();
                if magnitude.is_finite() {
                    t.sent_n[k] = t.sent_n[k].max(magnitude);
                }
                t.guard[k] |= f.guard;
            }
        }
    }

    /// The trace, with the scored moments added as events: risk-structure hits (first contact),
    /// redirections and the target reached.
    pub fn finish(mut self, metrics: &Metrics) -> ReviewTrace {
        self.add_risk_points(&metrics.risk_hits);
        let t = &mut self.trace;
        if t.phases.iter().all(|p| p.step == Step::Puncture) {
            t.phases.clear();
        }
        for d in &mut t.tip_depth_mm {
            if !d.is_finite() {
                *d = 0.0;
            }
        }
        if !t.tip_hidden.is_empty() {
            t.tip_hidden.resize(t.t_s.len(), false);
        }
        for hit in &metrics.risk_hits {
            t.events.push(TraceEvent {
                t_s: hit.t_s,
                kind: "risk-hit".into(),
                label: format!("risk hit: {}", hit.structure),
            });
        }
        for c in &metrics.consequences {
            t.events.push(TraceEvent {
                t_s: c.began_s,
                kind: "complication".into(),
                label: format!("{} began: {}", c.kind.name(), c.structure),
            });
        }
        for (n, &t_s) in metrics.redirection_times_s.iter().enumerate() {
            t.events.push(TraceEvent {
                t_s,
                kind: "redirection".into(),
                label: format!("redirection {}", n + 1),
            });
        }
        if let Some(s) = metrics.time_to_target_s {
            t.events.push(TraceEvent {
                t_s: s,
                kind: "target-reached".into(),
                label: "target reached".into(),
            });
        }
        t.events.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
        self.trace
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_physics::glam::DQuat;

    /// One tick of a needle along +z: tip at `depth` mm, in `label`, pushing back with `force` N.
    fn out(tick: u64, depth: f64, label: LabelId, force: f64) -> TickOutput {
        TickOutput {
            tick,
            time_s: tick as f64 / 1000.0,
            force_n: DVec3::new(0.0, 0.0, -force),
            torque_nmm: DVec3::ZERO,
            components: Default::default(),
            insertion_dir: DVec3::Z,
            tip_label: label,
            inserted_mm: depth,
            tip_mm: DVec3::new(1.0, 2.0, depth),
            tip_depth_mm: depth,
            stylet_in: true,
            xray_on: false,
            ..Default::default()
        }
    }

    fn collect(ticks: &[(f64, LabelId, f64)]) -> TraceCollector {
        let mut c = TraceCollector::new(1000);
        let input = TickInput::pose(DVec3::ZERO, DQuat::IDENTITY);
        for (k, (d, l, f)) in ticks.iter().enumerate() {
            c.tick(&input, &out(k as u64, *d, *l, *f));
        }
        c
    }

    #[test]
    fn punctures_are_advancing_entries_with_the_peak_while_inside() {
        // Skin (peak 2.5 N), fat (1.5 N), fascia (1.2 N); back into fat and on into the fascia
        // again: no new puncture, and the fascia's closed peak stays; out, and a second attempt
        // punctures the skin again.
        let c = collect(&[
            (0.0, 0, 0.0),
            (0.2, 2, 1.0),
            (0.4, 2, 2.5),
            (2.5, 3, 0.3),
            (3.0, 3, 1.0),
            (3.5, 3, 1.5),
            (4.0, 30, 0.2),
            (4.1, 30, 1.2),
            (3.0, 3, -0.2),
            (4.0, 30, 5.0),
            (0.0, 0, 0.0),
            (0.5, 2, 0.1),
            (0.6, 2, 0.9),
        ]);
        let p: Vec<(LabelId, f64, f64, f64)> = c
            .trace
            .punctures
            .iter()
            .map(|p| (p.label, p.peak_t_s, p.peak_force_n, p.t_s))
            .collect();
        assert_eq!(
            p,
            vec![
                (2, 0.002, 2.5, 0.001),
                (3, 0.005, 1.5, 0.003),
                (30, 0.007, 1.2, 0.006),
                (2, 0.012, 0.9, 0.011),
            ]
        );
    }

    #[test]
    fn risk_points_are_the_tip_at_first_contact() {
        let c = collect(&[
            (0.0, 0, 0.0),
            (1.0, 2, 0.0),
            (5.0, 40, 0.0),
            (6.0, 40, 0.0),
            (2.0, 3, 0.0),
            (5.5, 40, 0.0),
        ]);
        let mut c = c;
        let hit: RiskHit = serde_json::from_value(serde_json::json!({"structure": "right lung", "label": 40,
            "t_s": 0.002, "depth_mm": 1.0, "duration_s": 0.003, "entries": 2}))
        .unwrap();
        c.add_risk_points(&[hit]);
        let trace = c.trace;
        assert_eq!(trace.risk_points.len(), 1);
        assert_eq!(trace.risk_points[0].point_mm, [1.0, 2.0, 5.0]);
        assert_eq!(trace.risk_points[0].t_s, 0.002);
        assert_eq!(trace.risk_points[0].structure, "right lung");
    }

    #[test]
    fn the_final_approach_is_the_last_stay_up_to_its_deepest_point() {
        let p = |z: f64| Some([0.0, 0.0, z]);
        let trace = ReviewTrace {
            version: TRACE_VERSION,
            physics_version: 0,
            bucket_s: 0.02,
            t_s: (0..8).map(|k| k as f64 * 0.02).collect(),
            force_n: vec![0.0; 8],
            cutting_n: vec![0.0; 8],
            friction_n: vec![0.0; 8],
            base_n: vec![0.0; 8],
            inserted_mm: vec![0.0; 8],
            // A first stay, out, then a second stay that goes 30 mm deep and backs out to 20.
            tip_depth_mm: vec![5.0, 9.0, -1.0, 2.0, 12.0, 30.0, 20.0, -1.0],
            tip_mm: vec![p(-5.0), p(-9.0), None, p(-2.0), p(-12.0), p(-30.0), p(-20.0), None],
            events: Vec::new(),
            punctures: Vec::new(),
            risk_points: Vec::new(),
            sent_n: Vec::new(),
            guard: Vec::new(),
            tip_hidden: Vec::new(),
            phases: Vec::new(),
        };
        assert_eq!(trace.tip_stays().len(), 2);
        let path: Vec<f64> = trace.final_approach().unwrap().iter().map(|v| v.z).collect();
        assert_eq!(path, [-2.0, -12.0, -30.0]);
        let empty = ReviewTrace {
            tip_mm: vec![None; 8],
            ..trace
        };
        assert_eq!(empty.final_approach(), None);
    }

    #[test]
    fn peaks_survive_decimation() {
        let mut s = 0.0;
        for v in [0.1, -0.3, 2.5, 0.2, -0.1] {
            peak(&mut s, v);
        }
        assert_eq!(s, 2.5);
        let mut s = 0.0;
        for v in [0.1, -0.9, 0.5, f64::NAN] {
            peak(&mut s, v);
        }
        assert_eq!(s, -0.9);
    }

    #[test]
    fn device_forces_fill_their_buckets_beside_the_replayed_force() {
        use stylet_recorder::device_forces::{DeviceForceRecord, guard};
        // 50 ticks: three buckets of 20 (the last of 10).
        let mut c = collect(&vec![(0.0, 0, 0.0); 50]);
        let forces: Vec<DeviceForceRecord> = (100..150)
            .map(|tick| DeviceForceRecord {
                tick,
                sent_n: [0.0, 0.0, (tick - 100) as f64 * 0.1],
                guard: if tick == 125 { guard::CLAMPED } else { 0 },
            })
            .collect();
        c.device_forces(100, &forces);
        let t = &c.trace;
        assert_eq!(t.sent_n.len(), 3);
        assert!(
            (t.sent_n[0] - 1.9).abs() < 1e-9 && (t.sent_n[2] - 4.9).abs() < 1e-9,
            "{:?}",
            t.sent_n
        );
        assert_eq!(t.guard, [0, guard::CLAMPED, 0]);
        // A session without a device keeps both empty.
        let mut plain = collect(&[(0.0, 0, 0.0)]);
        plain.device_forces(0, &[]);
        assert!(plain.trace.sent_n.is_empty() && plain.trace.guard.is_empty());
    }
}
