//! The review trace of a session: what the dashboard draws of it. The force on the hand along
//! the insertion direction with its cutting, friction and base components (ALGORITHMS.md §3.5,
//! eqs. 3.5.1–3.5.6: f = f_cut + f_friction + f_base), insertion depth, the needle tip's path
//! and the events. Session files hold the device force but not its components, so the trace is
//! taken from the replay, in the same pass that scores the session.
//!
//! A 1 kHz session is too dense for a chart, so ticks are grouped into buckets of
//! [`BUCKET_TICKS`] (20 ms at 1 kHz) and each series keeps, per bucket, the sample of largest
//! magnitude: a puncture's force peak, which lasts only a few ticks, survives decimation.

use serde::{Deserialize, Serialize};
use stylet_physics::glam::DVec3;
use stylet_physics::{Event, TickInput, TickOutput};

use crate::metrics::Metrics;

/// Format version of [`ReviewTrace`] (stored traces of another version are rebuilt).
pub const TRACE_VERSION: u32 = 1;

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
}

impl ReviewTrace {
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
    in_bucket: u64,
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
            },
            in_bucket: 0,
        }
    }

    pub fn tick(&mut self, input: &TickInput, out: &TickOutput) {
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
                Event::BreathHold => "breath hold".to_string(),
                Event::BreathRelease => "breath release".to_string(),
            };
            t.events.push(TraceEvent {
                t_s: out.time_s,
                kind: e.name().to_string(),
                label,
            });
        }
    }

    /// The trace, with the scored moments added as events: risk-structure hits (first contact)
    /// and the target reached.
    pub fn finish(mut self, metrics: &Metrics) -> ReviewTrace {
        let t = &mut self.trace;
        for d in &mut t.tip_depth_mm {
            if !d.is_finite() {
                *d = 0.0;
            }
        }
        for hit in &metrics.risk_hits {
            t.events.push(TraceEvent {
                t_s: hit.t_s,
                kind: "risk-hit".into(),
                label: format!("risk hit: {}", hit.structure),
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
}
