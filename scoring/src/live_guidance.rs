//! Live ultrasound guidance (docs/metrics.md "Live ultrasound guidance"): in a two-handed session
//! the second hand holds the probe while the first advances the needle, and the trainee should
//! keep the tip in the live image — a tip advanced out of view is a tip that may be in a vessel.
//!
//! "In view" is the rendered image's test (`stylet_physics::probe_image`, the beam's thickness
//! plus the needle's radius), evaluated each tick for the probe's pose of that tick: the image
//! follows the probe, unlike the one-handed procedure's frozen last image.

use serde::{Deserialize, Serialize};
use stylet_physics::{ProbeKind, TickOutput};

use crate::probe_view::{ProbeFrame, in_rendered_image};

/// What a two-handed session's live guidance measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LiveGuidance {
    /// Ticks with the tip visible in the live image / ticks with the needle in the body while
    /// the second hand held a probe (0 … 1).
    pub needle_tip_visible_share: f64,
    /// The longest time the needle was advanced while its tip was out of the live image (s):
    /// the advancing ticks of one stretch out of view, from the tip leaving the image (or the
    /// skin entry) until it shows again or the needle leaves the body.
    pub longest_blind_advance_s: f64,
    /// Whether the tip was in the live image on the tick it first entered the target (`None`:
    /// it never did while the probe was held).
    pub tip_in_view_at_target_entry: Option<bool>,
}

/// Collects [`LiveGuidance`] tick by tick.
#[derive(Debug, Clone, Default)]
pub struct LiveGuidanceTrace {
    insertion_ticks: u64,
    visible_ticks: u64,
    /// Advancing ticks of the current stretch out of view, and the longest such stretch.
    blind_advance_ticks: u64,
    longest_blind_advance_ticks: u64,
    last_inserted_mm: Option<f64>,
    target_entry_visible: Option<bool>,
    /// The last tick counted and its tip was out of view (for the review's timeline).
    hidden: bool,
}

impl LiveGuidanceTrace {
    /// One replayed tick. `probe`: the probe the second hand holds this tick (none: empty hand,
    /// a finger or a one-handed session); `in_body`: the needle is in the body; `band_mm`: how far
    /// off the image plane the tip still shows (the needle's radius + the beam's half
    /// thickness); `tip_in_target`: the tip is in the target this tick.
    pub fn tick(
        &mut self,
        out: &TickOutput,
        probe: Option<ProbeKind>,
        in_body: bool,
        band_mm: f64,
        tip_in_target: bool,
    ) {
        self.hidden = false;
        let (Some(hand), Some(kind), true) = (out.second_hand, probe, in_body) else {
            self.blind_advance_ticks = 0;
            self.last_inserted_mm = None;
            return;
        };
        self.insertion_ticks += 1;
        let visible = hand.contacts > 0
            && in_rendered_image(
                &ProbeFrame::new(hand.position_mm, hand.orientation),
                kind,
                out.tip_mm,
                band_mm,
            );
        self.hidden = !visible;
        let advancing = self.last_inserted_mm.is_some_and(|last| out.inserted_mm > last);
        self.last_inserted_mm = Some(out.inserted_mm);
        if visible {
            self.visible_ticks += 1;
            self.blind_advance_ticks = 0;
        } else if advancing {
            self.blind_advance_ticks += 1;
            self.longest_blind_advance_ticks = self.longest_blind_advance_ticks.max(self.blind_advance_ticks);
        }
        if tip_in_target && self.target_entry_visible.is_none() {
            self.target_entry_visible = Some(visible);
        }
    }

    /// Whether the last tick had the needle in the body, the probe in the second hand and the tip
    /// out of its live image.
    pub fn tip_hidden(&self) -> bool {
        self.hidden
    }

    /// The metrics, or `None` when the needle was never in the body while the second hand held a
    /// probe (a one-handed session).
    pub fn finish(&self, rate_hz: f64) -> Option<LiveGuidance> {
        (self.insertion_ticks > 0).then(|| LiveGuidance {
            needle_tip_visible_share: self.visible_ticks as f64 / self.insertion_ticks as f64,
            longest_blind_advance_s: self.longest_blind_advance_ticks as f64 / rate_hz,
            tip_in_view_at_target_entry: self.target_entry_visible,
        })
    }
}
