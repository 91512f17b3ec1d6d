//! Metrics of a replayed session (docs/metrics.md gives each one's unit, formula and a worked
//! example). [`MetricsCollector`] watches every replayed tick; [`MetricsCollector::finish`]
//! returns [`Metrics`]. Everything is computed from the replayed physics, in tick order, in f64:
//! the same session always gives the same numbers.

use std::collections::BTreeMap;

use serde::Serialize;
use stylet_physics::glam::DVec3;
use stylet_physics::{Event, LabelId, Role, Simulation, TickInput, TickOutput, ToolSpec};

use crate::consequences::{ConsequenceRecord, ConsequenceWatch};
use crate::live_guidance::{LiveGuidance, LiveGuidanceTrace};
use crate::needle_motion::{NeedleMotion, NeedleMotionMetrics, NeedleSample};
use crate::probe_view::{ProbeFrame, in_rendered_image};
use crate::target::TargetDistance;
use crate::tip_path::TipPath;

/// One planned insertion path of the atlas (guided mode), the type every crate shares.
pub use stylet_physics::PlannedPath;

/// Settings of the metrics that come from the rubric.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MetricParams {
    /// R: a retraction of at least this much (mm) followed by a re-advance is a redirection.
    pub redirection_mm: f64,
    /// A re-advance is an advance of at least this much (mm) from the deepest point of retraction.
    pub readvance_mm: f64,
    /// The insertion direction of an attempt is measured from its entry to this depth (mm).
    pub direction_depth_mm: f64,
}

impl Default for MetricParams {
    fn default() -> Self {
        MetricParams {
            redirection_mm: 5.0,
            readvance_mm: 2.0,
            direction_depth_mm: 10.0,
        }
    }
}

/// A risk structure the needle tip entered.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct RiskHit {
    pub structure: String,
    pub label: LabelId,
    /// First contact (s from the session start).
    pub t_s: f64,
    /// Deepest advance of the tip inside the structure (mm along the channel) over all entries.
    pub depth_mm: f64,
    /// Total time the tip spent inside (s).
    pub duration_s: f64,
    /// Separate entries into the structure.
    pub entries: u32,
    /// What hitting it does to a patient, from the atlas' label table ("pneumothorax").
    #[serde(default)]
    pub consequence: Option<String>,
    /// Tip position at first contact (world mm), for slices through the hit.
    #[serde(default)]
    pub point_mm: [f64; 3],
    /// Ticks inside (duration_s = ticks / rate, computed at the end: no summed rounding).
    #[serde(skip)]
    ticks: u64,
}

/// Workflow order (thesis: palpate → ultrasound → puncture → confirm).
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct Workflow {
    pub palpation_before_puncture: bool,
    pub ultrasound_before_puncture: bool,
    /// The target lay in the ultrasound image plane (the survey's `target_scanned` test) at some
    /// moment before the first puncture.
    #[serde(default)]
    pub target_scanned_before_puncture: bool,
    /// The target was confirmed before the needle last left the body (or the session ended).
    pub confirmed_before_withdrawal: bool,
}

/// Guided-mode metrics against a planned path.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct Guided {
    pub path: String,
    /// Distance from the scored attempt's skin entry to the planned entry point (mm).
    pub entry_distance_mm: f64,
    /// Angle between the attempt's insertion direction and the planned direction (degrees).
    pub angle_error_deg: f64,
    /// Mean and largest distance of the tip from the planned segment while in the body (mm).
    pub mean_deviation_mm: f64,
    pub max_deviation_mm: f64,
}

/// Most redirection times a score keeps (the count goes on).
pub const MAX_REDIRECTION_TIMES: usize = 1000;

/// All metrics of one session.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct Metrics {
    pub attempts: u32,
    pub redirections: u32,
    /// When each redirection completed (s from the session start; its re-advance reached the
    /// rubric's `readvance_mm`), at most [`MAX_REDIRECTION_TIMES`]: the replay's key moments.
    #[serde(default)]
    pub redirection_times_s: Vec<f64>,
    pub risk_hits: Vec<RiskHit>,
    pub bone_contacts: u32,
    pub target_reached: bool,
    pub target_confirmed: bool,
    pub stylet_removed_in_target: bool,
    pub contrast_in_target: bool,
    /// Contrast that entered the duct system (ml; physics, eqs. 3.3.1–3.3.2).
    #[serde(default)]
    pub contrast_in_ducts_ml: f64,
    /// Contrast delivered into tissue that is not a duct (ml): extravasation.
    #[serde(default)]
    pub extravasated_ml: f64,
    /// How far the contrast filled the duct system from where it entered (mm).
    #[serde(default)]
    pub contrast_extent_mm: f64,
    /// Largest tissue displacement of the deformation over the session (mm; thesis Chapter 4).
    #[serde(default)]
    pub max_tissue_displacement_mm: f64,
    /// Largest displacement of a segmented risk structure over the session (mm): a vessel the
    /// tool pushed aside.
    #[serde(default)]
    pub max_risk_displacement_mm: f64,
    pub time_to_target_s: Option<f64>,
    pub time_total_s: f64,
    pub fluoro_time_s: f64,
    pub xray_shots: u32,
    /// Estimated dose-area product (Gy·cm²): fluoroscopy time × the scenario C-arm's rate.
    #[serde(default)]
    pub dose_area_product_gy_cm2: f64,
    pub ultrasound_time_s: f64,
    /// Share of the insertion time (needle in the body) the tip lay in the image of the
    /// ultrasound probe's last pose on the skin (the beam's thickness, inside the image): how
    /// well the trainee kept the needle in the plane they scanned. `None` without a probe in skin
    /// contact before the needle went in.
    #[serde(default)]
    pub needle_in_plane_share: Option<f64>,
    pub palpation_time_s: f64,
    pub path_length_mm: f64,
    /// The scored attempt's tip path length from its skin entry until it reached the target (else
    /// its deepest point) / the straight distance between the two points. 1 = one straight push.
    pub path_inefficiency: Option<f64>,
    pub max_force_n: f64,
    /// Root mean square of |F| over the ticks with the tool in the body or touching the skin.
    pub rms_force_n: f64,
    /// Largest distance of a needle node from the line through hub and tip (mm).
    pub max_bending_mm: f64,
    /// Area swept sideways by the simulated (bending, path-constrained) shaft inside tissue
    /// (mm²). Reports before rubric version 7 call it `tissue_damage_mm2`; that name is now the
    /// rigid needle's swept area in [`Metrics::needle_motion`], as PerkTutor defines it.
    #[serde(alias = "tissue_damage_mm2")]
    pub shaft_sweep_mm2: f64,
    pub workflow: Workflow,
    /// Tip to the nearest target voxel where the last puncture ended: its deepest point before
    /// withdrawal (mm, 0 inside the target).
    pub target_distance_mm: Option<f64>,
    /// … and at its closest while the needle was in the body.
    pub target_distance_min_mm: Option<f64>,
    pub guided: Option<Guided>,
    /// Palpation metrics, when the finger touched the skin.
    #[serde(default)]
    pub palpation: Option<PalpationMetrics>,
    /// Ultrasound-survey metrics, when the probe touched the skin.
    #[serde(default)]
    pub ultrasound: Option<UltrasoundMetrics>,
    /// Respiratory-motion metrics, when the patient breathed (docs/breathing.md).
    #[serde(default)]
    pub breathing: Option<BreathingMetrics>,
    /// The Seldinger exchange after the puncture, when a guide wire went in (docs/seldinger.md).
    #[serde(default)]
    pub drainage: Option<crate::drainage::DrainageMetrics>,
    /// The hand-held needle's motion as PerkTutor measures it (docs/metrics.md "Needle motion
    /// (PerkTutor)"); `None` in reports written before it was measured.
    #[serde(default)]
    pub needle_motion: Option<NeedleMotionMetrics>,
    /// Live ultrasound guidance, when the second hand held a probe while the needle was in the
    /// body (docs/metrics.md "Live ultrasound guidance").
    #[serde(default)]
    pub live_guidance: Option<LiveGuidance>,
    /// What the wrong punctures did to the patient, as the physics computed it (haematoma,
    /// pneumothorax, bile leak; docs/complications.md), in the order they began.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub consequences: Vec<ConsequenceRecord>,
}

/// Where in the breathing the needle reached the target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BreathPhase {
    /// Breath held at end-expiration (g ≤ 0.15 of a breath): the CT's phase, where the plan
    /// holds — the usual correct hold for PTCD.
    HeldEndExpiration,
    /// Breath held at end-inspiration (g ≥ 0.85).
    HeldEndInspiration,
    /// Breath held somewhere between.
    HeldBetween,
    /// The patient breathed.
    FreeBreathing,
}

impl BreathPhase {
    /// Of a tick: held or not, and g, the breathing signal (0 at end-expiration, ≈ 1 at
    /// end-inspiration).
    pub fn of(held: bool, g: f64) -> BreathPhase {
        match (held, g) {
            (false, _) => BreathPhase::FreeBreathing,
            (true, g) if g <= 0.15 => BreathPhase::HeldEndExpiration,
            (true, g) if g >= 0.85 => BreathPhase::HeldEndInspiration,
            (true, _) => BreathPhase::HeldBetween,
        }
    }

    /// The phase a scenario's correct hold is.
    pub fn of_hold(hold: stylet_atlas::manifest::HoldPhase) -> BreathPhase {
        match hold {
            stylet_atlas::manifest::HoldPhase::EndExpiration => BreathPhase::HeldEndExpiration,
            stylet_atlas::manifest::HoldPhase::EndInspiration => BreathPhase::HeldEndInspiration,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            BreathPhase::HeldEndExpiration => "breath held at end-expiration",
            BreathPhase::HeldEndInspiration => "breath held at end-inspiration",
            BreathPhase::HeldBetween => "breath held between expiration and inspiration",
            BreathPhase::FreeBreathing => "free breathing",
        }
    }
}

/// What the needle did in a breathing patient (docs/metrics.md "Breathing").
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct BreathingMetrics {
    /// Where in the breathing the target was first reached (`None`: never).
    pub target_reached_phase: Option<BreathPhase>,
    /// The scenario's correct hold (its `hold_phase`; end-expiration unless it says otherwise).
    #[serde(default = "end_expiration")]
    pub correct_phase: BreathPhase,
    /// The needle in the body while the patient breathed (s).
    pub needle_in_while_breathing_s: f64,
    /// How far the breathing carried the tissue at the needle's tip while the needle was in the
    /// body (mm): Σ |u(X_tip, t) − u(X_tip, t_prev)| over those ticks, the tip's reference
    /// position X_tip held fixed, so the needle's own motion does not count. A needle left in a
    /// breathing liver is dragged through it; a held breath adds nothing.
    pub tissue_slide_mm: f64,
}

fn end_expiration() -> BreathPhase {
    BreathPhase::HeldEndExpiration
}

/// What the finger found (docs/metrics.md "Palpation").
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct PalpationMetrics {
    /// Intercostal spaces the finger passed over in skin contact: runs of the sweep with no rib
    /// under the finger, between runs over a rib (from the atlas' bone geometry).
    pub spaces_crossed: u32,
    /// Of those, the spaces where the finger sank in: its indentation in the space exceeded the
    /// indentation over the neighbouring ribs by at least 0.5 mm (felt, as in Fig. 3.14).
    pub spaces_found: u32,
    /// spaces_found / spaces_crossed (0 when none was crossed).
    pub coverage: f64,
    /// Ribs passed over in skin contact.
    pub ribs_crossed: u32,
}

/// What the probe showed (docs/metrics.md "Ultrasound survey"; PerkTutor's TargetsScanned).
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct UltrasoundMetrics {
    /// A target voxel came within 5 mm of the image plane, inside the image, while the probe
    /// touched the skin.
    pub target_scanned: bool,
    /// First such tick (s from the start).
    pub time_to_target_view_s: Option<f64>,
    /// Ticks with the target in view / rate (s).
    pub target_view_time_s: f64,
    /// Ticks with at least 3/4 of the probe face on the skin / rate (s).
    pub good_contact_time_s: f64,
}

/// One attempt: from a skin puncture until the needle leaves the body.
#[derive(Debug, Clone)]
struct Attempt {
    /// The tip's path from the skin entry: where it reached the target, its deepest point.
    path: TipPath,
    /// Tip position when the attempt first reached `direction_depth_mm` (or its last tip).
    direction_point_mm: Option<DVec3>,
    /// Per planned path: sum and max of the tip's distance from it, and the sample count.
    deviation: Vec<(f64, f64, u64)>,
}

/// Collects metrics tick by tick.
pub struct MetricsCollector<'a> {
    params: MetricParams,
    rate_hz: f64,
    /// Role of every label id (a flat table: one lookup per tick).
    roles: Vec<Role>,
    names: BTreeMap<LabelId, String>,
    /// Clinical consequences of risk labels (atlas TOML).
    consequences: BTreeMap<LabelId, String>,
    target: &'a TargetDistance,
    paths: &'a [PlannedPath],
    chosen_path: Option<String>,
    ticks: u64,
    was_in_body: bool,
    attempts: Vec<Attempt>,
    // Redirections: deepest insertion since the last turn, deepest point of the retraction.
    peak_mm: f64,
    valley_mm: Option<f64>,
    redirections: u32,
    redirection_times_s: Vec<f64>,
    risk: BTreeMap<LabelId, RiskHit>,
    risk_entry_mm: Option<(LabelId, f64)>,
    prev_tip_label: LabelId,
    bone_contacts: u32,
    was_on_bone: bool,
    first_target_tick: Option<u64>,
    stylet_in_target: bool,
    contrast_in_target: bool,
    /// The physics' contrast reached the confirmation length.
    contrast_filled: bool,
    contrast_in_ducts_ml: f64,
    extravasated_ml: f64,
    contrast_extent_mm: f64,
    max_tissue_displacement_mm: f64,
    max_risk_displacement_mm: f64,
    confirmed_tick: Option<u64>,
    last_exit_tick: Option<u64>,
    xray_ticks: u64,
    xray_shots: u32,
    was_xray: bool,
    ultrasound_ticks: u64,
    palpation_ticks: u64,
    palpation_before: bool,
    ultrasound_before: bool,
    target_scanned_before: bool,
    path_length_mm: f64,
    prev_tip_mm: Option<DVec3>,
    max_force_n: f64,
    force_sq_sum: f64,
    force_ticks: u64,
    max_bending_mm: f64,
    prev_nodes: Vec<DVec3>,
    shaft_sweep_mm2: f64,
    needle_motion: NeedleMotion,
    min_distance_mm: Option<f64>,
    /// D_bone of the atlas: which parts of a palpation sweep lie over a rib.
    bone: &'a stylet_physics::Volume<f32>,
    palpation: PalpationTrace,
    /// Ultrasound: first tick with the target in view, ticks in view, ticks in good contact.
    view_first_tick: Option<u64>,
    view_ticks: u64,
    good_contact_ticks: u64,
    probe_ticks: u64,
    /// The probe's last pose in skin contact (its image stays on the screen after the tool
    /// change), and the needle's ticks in the body with such an image / with the tip in it.
    last_probe: Option<(DVec3, stylet_physics::glam::DQuat, stylet_physics::ProbeKind)>,
    imaged_insertion_ticks: u64,
    tip_in_plane_ticks: u64,
    /// The tip in the second hand's live image while the needle is in the body.
    live_guidance: LiveGuidanceTrace,
    /// The physics' leaking sites.
    leaks: ConsequenceWatch,
    drainage: crate::drainage::DrainageCollector,
    /// With a breathing patient: the signal (g per tick), the phase the target was reached in,
    /// the ticks breathed with the needle in, the tissue slide and the last u at the tip.
    breathing: Option<BreathingTrace>,
}

/// What [`BreathingMetrics`] is collected from.
struct BreathingTrace {
    signal: stylet_physics::motion::BreathingSignal,
    target_reached_phase: Option<BreathPhase>,
    needle_in_breathing_ticks: u64,
    tissue_slide_mm: f64,
    /// The previous tick's motion time, while the needle was in the body.
    last_t: Option<f64>,
}

/// The finger's sweep, cut into runs over a rib and over an intercostal space.
#[derive(Debug, Default)]
struct PalpationTrace {
    /// Closed runs of the current contact stretch.
    runs: Vec<Run>,
    /// The run being followed.
    open: Option<Run>,
    /// A change of class seen for this many ticks (debounce: a run ends after [`RUN_MIN_TICKS`]).
    pending: u64,
    crossed: u32,
    found: u32,
    ribs: u32,
}

/// Part of a sweep over one rib or one space.
#[derive(Debug, Clone, Copy)]
struct Run {
    over_rib: bool,
    /// Deepest indentation (mm) and where (finger position).
    deepest_mm: f64,
    deepest_at: DVec3,
    /// Sums of indentation and position, and the tick count (for means).
    sum_mm: f64,
    sum_at: DVec3,
    ticks: u64,
}

impl Run {
    fn new(over_rib: bool, indentation_mm: f64, at: DVec3) -> Run {
        Run {
            over_rib,
            deepest_mm: indentation_mm,
            deepest_at: at,
            sum_mm: indentation_mm,
            sum_at: at,
            ticks: 1,
        }
    }
    fn add(&mut self, indentation_mm: f64, at: DVec3) {
        if indentation_mm > self.deepest_mm {
            self.deepest_mm = indentation_mm;
            self.deepest_at = at;
        }
        self.sum_mm += indentation_mm;
        self.sum_at += at;
        self.ticks += 1;
    }
    fn merge(&mut self, o: &Run) {
        if o.deepest_mm > self.deepest_mm {
            self.deepest_mm = o.deepest_mm;
            self.deepest_at = o.deepest_at;
        }
        self.sum_mm += o.sum_mm;
        self.sum_at += o.sum_at;
        self.ticks += o.ticks;
    }
    fn mean_mm(&self) -> f64 {
        self.sum_mm / self.ticks as f64
    }
    fn centre(&self) -> DVec3 {
        self.sum_at / self.ticks as f64
    }
}

/// A run shorter than this (ticks) is jitter, not a rib or a space.
const RUN_MIN_TICKS: u64 = 20;
/// How far under the finger a rib is looked for (mm along the pressing direction).
const RIB_SEARCH_MM: f64 = 30.0;
/// A space is found when the finger sank this much deeper there than over its ribs (mm).
const SPACE_SINK_MM: f64 = 0.1;
/// Good skin contact: at least this share of the probe face on the skin.
const GOOD_CONTACT_SHARE: f64 = 0.75;

impl PalpationTrace {
    /// One tick in skin contact: over a rib or not, indentation, finger position.
    fn tick(&mut self, over_rib: bool, indentation_mm: f64, at: DVec3) {
        match &mut self.open {
            None => self.open = Some(Run::new(over_rib, indentation_mm, at)),
            Some(run) if run.over_rib == over_rib => {
                run.add(indentation_mm, at);
                self.pending = 0;
            }
            Some(run) => {
                self.pending += 1;
                if self.pending >= RUN_MIN_TICKS {
                    let closed = *run;
                    self.close(closed);
                    self.open = Some(Run::new(over_rib, indentation_mm, at));
                    self.pending = 0;
                }
            }
        }
    }

    fn close(&mut self, run: Run) {
        if run.ticks >= RUN_MIN_TICKS {
            match self.runs.last_mut() {
                // A dropped short run leaves two of a kind side by side: one run.
                Some(last) if last.over_rib == run.over_rib => last.merge(&run),
                _ => self.runs.push(run),
            }
        }
    }

    /// Contact lost (or the end). A space counts only between two ribs felt in one stretch; it
    /// is found when its deepest indentation exceeds the rib level there (the ribs' mean
    /// indentations, interpolated between their centres: the chest wall's own slope is not a
    /// space) by [`SPACE_SINK_MM`].
    fn lift(&mut self) {
        if let Some(run) = self.open.take() {
            self.close(run);
        }
        self.pending = 0;
        let runs = std::mem::take(&mut self.runs);
        self.ribs += runs.iter().filter(|r| r.over_rib).count() as u32;
        for w in runs.windows(3) {
            let [before, space, after] = w else { continue };
            if !before.over_rib || space.over_rib || !after.over_rib {
                continue;
            }
            self.crossed += 1;
            let (a, b) = (
                space.deepest_at.distance(before.centre()),
                space.deepest_at.distance(after.centre()),
            );
            let t = if a + b > 0.0 { a / (a + b) } else { 0.5 };
            let rib_level = before.mean_mm() + (after.mean_mm() - before.mean_mm()) * t;
            if space.deepest_mm >= rib_level + SPACE_SINK_MM {
                self.found += 1;
            }
        }
    }
}

fn segment_distance(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 {
        ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * t)).length()
}

impl<'a> MetricsCollector<'a> {
    /// `labels`: the atlas' label table; `paths`: its planned paths; `path`: score guided mode
    /// against this one (else the one whose entry is nearest the scored attempt's entry).
    pub fn new(
        atlas: &'a stylet_physics::PunctureAtlas,
        target: &'a TargetDistance,
        paths: &'a [PlannedPath],
        path: Option<String>,
        rate_hz: u32,
        params: MetricParams,
    ) -> Self {
        let table = atlas.label_table();
        let roles = (0..=LabelId::MAX)
            .map(|id| table.get(id).map_or(Role::Neutral, |l| l.role))
            .collect();
        let names = (0..=LabelId::MAX)
            .filter_map(|id| table.get(id).map(|l| (id, l.name.clone())))
            .collect();
        MetricsCollector {
            params,
            rate_hz: rate_hz as f64,
            roles,
            names,
            consequences: BTreeMap::new(),
            target,
            paths,
            chosen_path: path,
            ticks: 0,
            was_in_body: false,
            attempts: Vec::new(),
            peak_mm: 0.0,
            valley_mm: None,
            redirections: 0,
            redirection_times_s: Vec::new(),
            risk: BTreeMap::new(),
            risk_entry_mm: None,
            prev_tip_label: 0,
            bone_contacts: 0,
            was_on_bone: false,
            first_target_tick: None,
            stylet_in_target: false,
            contrast_in_target: false,
            contrast_filled: false,
            contrast_in_ducts_ml: 0.0,
            extravasated_ml: 0.0,
            contrast_extent_mm: 0.0,
            max_tissue_displacement_mm: 0.0,
            max_risk_displacement_mm: 0.0,
            confirmed_tick: None,
            last_exit_tick: None,
            xray_ticks: 0,
            xray_shots: 0,
            was_xray: false,
            ultrasound_ticks: 0,
            palpation_ticks: 0,
            palpation_before: false,
            ultrasound_before: false,
            target_scanned_before: false,
            path_length_mm: 0.0,
            prev_tip_mm: None,
            max_force_n: 0.0,
            force_sq_sum: 0.0,
            force_ticks: 0,
            max_bending_mm: 0.0,
            prev_nodes: Vec::new(),
            shaft_sweep_mm2: 0.0,
            needle_motion: NeedleMotion::new(rate_hz),
            min_distance_mm: None,
            bone: atlas.bone_distance(),
            palpation: PalpationTrace::default(),
            view_first_tick: None,
            view_ticks: 0,
            last_probe: None,
            imaged_insertion_ticks: 0,
            tip_in_plane_ticks: 0,
            live_guidance: LiveGuidanceTrace::default(),
            leaks: ConsequenceWatch::default(),
            drainage: crate::drainage::DrainageCollector::default(),
            breathing: None,
            good_contact_ticks: 0,
            probe_ticks: 0,
        }
    }

    /// The clinical consequence of each risk label (from the atlas TOML), copied into its hits.
    pub fn with_consequences(mut self, consequences: BTreeMap<LabelId, String>) -> Self {
        self.consequences = consequences;
        self
    }

    fn role(&self, label: LabelId) -> Role {
        self.roles[label as usize]
    }

    /// Whether the tick just observed had the needle tip out of the second hand's live image
    /// (a two-handed session with the needle in the body).
    pub fn tip_hidden(&self) -> bool {
        self.live_guidance.tip_hidden()
    }

    /// Observes one replayed tick.
    pub fn tick(&mut self, input: &TickInput, out: &TickOutput, sim: &Simulation) {
        self.ticks += 1;
        self.leaks.tick(out.tick, sim);
        self.drainage.tick(out, sim.access());
        let tick = out.tick;
        let needle = sim.needle();
        let in_body = needle.is_some() && out.inserted_mm > 0.0;
        let tip_role = if needle.is_some() {
            self.role(out.tip_label)
        } else {
            Role::Neutral
        };

        // Attempts: one per skin puncture.
        if in_body && !self.was_in_body {
            self.attempts.push(Attempt {
                path: TipPath::enter(out.tip_mm, out.inserted_mm, tip_role == Role::Target),
                direction_point_mm: None,
                deviation: vec![(0.0, 0.0, 0); self.paths.len()],
            });
            if self.attempts.len() == 1 {
                self.palpation_before = self.palpation_ticks > 0;
                self.ultrasound_before = self.ultrasound_ticks > 0;
                self.target_scanned_before = self.view_first_tick.is_some();
            }
            self.peak_mm = out.inserted_mm;
            self.valley_mm = None;
        }
        if !in_body && self.was_in_body {
            self.last_exit_tick = Some(tick);
        }

        if let Some(n) = needle {
            let band_mm = n.spec().gauge.outer_diameter_mm() / 2.0 + stylet_physics::probe_image::ELEVATION_HALF_MM;
            let probe = match sim.second_hand().and_then(|h| h.tool_spec()) {
                Some(stylet_physics::HandTool::Probe(kind)) => Some(kind),
                _ => None,
            };
            self.live_guidance
                .tick(out, probe, in_body, band_mm, tip_role == Role::Target);
        }
        if in_body
            && let Some((position, orientation, kind)) = self.last_probe
            && let Some(n) = needle
        {
            self.imaged_insertion_ticks += 1;
            // The tip shows where the shaft does: within its radius + the beam's half thickness.
            let band_mm = n.spec().gauge.outer_diameter_mm() / 2.0 + stylet_physics::probe_image::ELEVATION_HALF_MM;
            if in_rendered_image(&ProbeFrame::new(position, orientation), kind, out.tip_mm, band_mm) {
                self.tip_in_plane_ticks += 1;
            }
        }
        if in_body {
            // Redirections: retract by ≥ R from the deepest point, then re-advance.
            match self.valley_mm {
                None if self.peak_mm - out.inserted_mm >= self.params.redirection_mm => {
                    self.valley_mm = Some(out.inserted_mm)
                }
                None => self.peak_mm = self.peak_mm.max(out.inserted_mm),
                Some(v) if out.inserted_mm - v >= self.params.readvance_mm => {
                    self.redirections += 1;
                    if self.redirection_times_s.len() < MAX_REDIRECTION_TIMES {
                        self.redirection_times_s.push(out.time_s);
                    }
                    self.valley_mm = None;
                    self.peak_mm = out.inserted_mm;
                }
                Some(v) => self.valley_mm = Some(v.min(out.inserted_mm)),
            }
            let attempt = self.attempts.last_mut().expect("an attempt is open while in the body");
            if attempt.direction_point_mm.is_none()
                && out.tip_mm.distance(attempt.path.entry_mm()) >= self.params.direction_depth_mm
            {
                attempt.direction_point_mm = Some(out.tip_mm);
            }
            for (dev, p) in attempt.deviation.iter_mut().zip(self.paths) {
                let d = segment_distance(out.tip_mm, p.entry_mm, p.target_mm);
                *dev = (dev.0 + d, dev.1.max(d), dev.2 + 1);
            }
            if let Some(prev) = self.prev_tip_mm {
                self.path_length_mm += out.tip_mm.distance(prev);
                let attempt = self.attempts.last_mut().expect("an attempt is open while in the body");
                attempt.path.step(out.tip_mm, out.inserted_mm, tip_role == Role::Target);
            }
            self.prev_tip_mm = Some(out.tip_mm);
        } else {
            self.prev_tip_mm = None;
        }

        // Risk structures: per label, entries, first contact, depth and time inside.
        if in_body && tip_role == Role::Risk {
            let label = out.tip_label;
            let entered = self.prev_tip_label != label || self.risk_entry_mm.is_none_or(|(l, _)| l != label);
            if entered {
                self.risk_entry_mm = Some((label, out.inserted_mm));
            }
            let entry_mm = self.risk_entry_mm.map_or(out.inserted_mm, |(_, e)| e);
            let name = self
                .names
                .get(&label)
                .cloned()
                .unwrap_or_else(|| stylet_physics::UNNAMED_STRUCTURE.to_string());
            let t_s = tick as f64 / self.rate_hz;
            let consequence = self.consequences.get(&label).cloned();
            let hit = self.risk.entry(label).or_insert(RiskHit {
                structure: name,
                label,
                t_s,
                depth_mm: 0.0,
                duration_s: 0.0,
                entries: 0,
                consequence,
                point_mm: out.tip_mm.to_array(),
                ticks: 0,
            });
            if entered {
                hit.entries += 1;
            }
            hit.depth_mm = hit.depth_mm.max(out.inserted_mm - entry_mm);
            hit.ticks += 1;
        } else {
            self.risk_entry_mm = None;
        }
        self.prev_tip_label = if needle.is_some() { out.tip_label } else { 0 };

        // Bone: needle tip against bone (palpating ribs with the finger is intended, not counted).
        let on_bone = tip_role == Role::Bone;
        if on_bone && !self.was_on_bone {
            self.bone_contacts += 1;
        }
        self.was_on_bone = on_bone;

        if sim.breathes() {
            self.breathing_tick(sim, out, in_body, tip_role == Role::Target && needle.is_some());
        }

        // Target and confirmation.
        if needle.is_some() && tip_role == Role::Target {
            self.first_target_tick.get_or_insert(tick);
            for e in &input.events {
                match e {
                    Event::StyletRemove => self.stylet_in_target = true,
                    Event::ContrastInject { ml } if *ml > 0.0 => self.contrast_in_target = true,
                    _ => {}
                }
            }
        }
        // Confirmation: the stylet came out in the target (bile would flow) and the contrast the
        // physics spread has filled the duct system beyond the confirmation length.
        self.contrast_filled = sim.contrast().confirmed();
        self.contrast_in_ducts_ml = out.contrast_in_ducts_ml;
        self.extravasated_ml = out.extravasated_ml;
        self.contrast_extent_mm = out.contrast_extent_mm;
        self.max_tissue_displacement_mm = self.max_tissue_displacement_mm.max(out.tissue_displacement_mm);
        self.max_risk_displacement_mm = self.max_risk_displacement_mm.max(out.risk_displacement_mm);
        if self.stylet_in_target && self.contrast_filled {
            self.confirmed_tick.get_or_insert(tick);
        }

        // Imaging and contact tools.
        if out.xray_on {
            self.xray_ticks += 1;
            if !self.was_xray {
                self.xray_shots += 1;
            }
        }
        self.was_xray = out.xray_on;
        if out.contacts > 0 {
            let press = (input.orientation * DVec3::Z).normalize_or_zero();
            match sim.tool_spec() {
                ToolSpec::Probe(kind) => {
                    self.ultrasound_ticks += 1;
                    self.last_probe = Some((input.position_mm, input.orientation, *kind));
                    let nodes = sim.contact().map_or(1, |c| c.nodes().len().max(1));
                    if out.contacts as f64 >= GOOD_CONTACT_SHARE * nodes as f64 {
                        self.good_contact_ticks += 1;
                    }
                    if self.target_in_view(input, *kind) {
                        self.view_ticks += 1;
                        self.view_first_tick.get_or_insert(tick);
                    }
                }
                ToolSpec::Finger => {
                    self.palpation_ticks += 1;
                    let over_rib = (0..=(RIB_SEARCH_MM / 1.5) as usize)
                        .any(|k| self.bone.sample(input.position_mm + press * (k as f64 * 1.5), -1000.0) > 0.0);
                    self.palpation.tick(over_rib, out.indentation_mm, input.position_mm);
                }
                ToolSpec::Needle { .. } => {}
            }
        } else if self.palpation.open.is_some() {
            self.palpation.lift();
        }
        if matches!(sim.tool_spec(), ToolSpec::Probe(_)) {
            self.probe_ticks += 1;
        }
        // A probe in the second hand scans like one in the first: the live image of a two-handed
        // session (counted once a tick when both hands hold a probe on the skin).
        if let (Some(hand), Some(stylet_physics::HandTool::Probe(kind))) =
            (out.second_hand, sim.second_hand().and_then(|h| h.tool_spec()))
        {
            self.probe_ticks += u64::from(!matches!(sim.tool_spec(), ToolSpec::Probe(_)));
            let first_hand_scanning = out.contacts > 0 && matches!(sim.tool_spec(), ToolSpec::Probe(_));
            if hand.contacts > 0 && !first_hand_scanning {
                self.ultrasound_ticks += 1;
                let nodes = sim
                    .second_hand()
                    .and_then(|h| h.contact())
                    .map_or(1, |c| c.nodes().len().max(1));
                if hand.contacts as f64 >= GOOD_CONTACT_SHARE * nodes as f64 {
                    self.good_contact_ticks += 1;
                }
                let frame = ProbeFrame::new(hand.position_mm, hand.orientation);
                if self.target.survey_points().any_in_survey_view(&frame, kind) {
                    self.view_ticks += 1;
                    self.view_first_tick.get_or_insert(tick);
                }
            }
        }

        // Forces.
        let f = out.force_n.length();
        self.max_force_n = self.max_force_n.max(f);
        if in_body || out.contacts > 0 {
            self.force_sq_sum += f * f;
            self.force_ticks += 1;
        }

        // The hand-held (rigid) needle: the device pose while the needle is in hand.
        self.needle_motion.observe(needle.map(|_| NeedleSample {
            tick,
            tip_mm: input.position_mm,
            orientation: input.orientation,
            inserted_mm: out.inserted_mm,
        }));

        // Needle shape: bending and the area the shaft sweeps sideways inside tissue.
        match needle {
            Some(n) => {
                let nodes = n.nodes();
                // Distance from the hub–tip line: |(p − hub) × chord| / |chord|, squared until the end.
                let (hub, chord) = (nodes[0], nodes[nodes.len() - 1] - nodes[0]);
                let len2 = chord.length_squared();
                if len2 > 0.0 {
                    let worst = nodes
                        .iter()
                        .map(|&p| (p - hub).cross(chord).length_squared())
                        .fold(0.0, f64::max);
                    self.max_bending_mm = self.max_bending_mm.max((worst / len2).sqrt());
                }
                if in_body && self.prev_nodes.len() == nodes.len() {
                    let seg = n.spec().length_mm / (nodes.len() - 1) as f64;
                    let inside = ((out.inserted_mm / seg).floor() as usize).min(nodes.len() - 1);
                    let tangents = n.tangents();
                    // Nodes within the inserted length from the tip: their sideways motion
                    // (perpendicular to the shaft) cuts tissue over one segment length each.
                    for j in (nodes.len() - 1 - inside)..nodes.len() - 1 {
                        let dp = nodes[j] - self.prev_nodes[j];
                        let side = dp - tangents[j] * dp.dot(tangents[j]);
                        self.shaft_sweep_mm2 += side.length() * seg;
                    }
                }
                self.prev_nodes.clear();
                self.prev_nodes.extend_from_slice(nodes);
                if in_body && let Some(d) = self.target.distance_mm(out.tip_mm) {
                    self.min_distance_mm = Some(self.min_distance_mm.map_or(d, |m| m.min(d)));
                }
            }
            None => self.prev_nodes.clear(),
        }
        self.was_in_body = in_body;
    }

    /// Whether a target point lies in the probe's survey view ([`crate::probe_view::in_survey_view`]):
    /// within [`crate::probe_view::VIEW_PLANE_MM`] of the image plane, inside the image.
    fn target_in_view(&self, input: &TickInput, kind: stylet_physics::ProbeKind) -> bool {
        let frame = ProbeFrame::new(input.position_mm, input.orientation);
        self.target.survey_points().any_in_survey_view(&frame, kind)
    }

    /// The metrics of everything observed.
    /// One tick of a breathing patient: the phase when the target is first reached; with the
    /// needle in the body, the time breathed and how far the breathing moved the tissue at the
    /// tip since the last tick (nothing while the breath is held: the motion time stands).
    fn breathing_tick(&mut self, sim: &Simulation, out: &TickOutput, in_body: bool, at_target: bool) {
        if self.breathing.is_none() {
            let Ok(signal) = stylet_physics::motion::BreathingSignal::new(sim.config().breathing.signal) else {
                return;
            };
            self.breathing = Some(BreathingTrace {
                signal,
                target_reached_phase: None,
                needle_in_breathing_ticks: 0,
                tissue_slide_mm: 0.0,
                last_t: None,
            });
        }
        let b = self.breathing.as_mut().expect("set above");
        let t = sim.motion_time_s();
        if at_target && self.first_target_tick.is_none() {
            b.target_reached_phase = Some(BreathPhase::of(out.breath_hold, b.signal.g(t)));
        }
        let tip = sim.needle().and_then(|n| n.nodes().last().copied());
        match (in_body, tip) {
            (true, Some(tip)) => {
                if !out.breath_hold {
                    b.needle_in_breathing_ticks += 1;
                }
                if let Some(t_prev) = b.last_t.filter(|&p| p != t) {
                    let m = sim.motion();
                    b.tissue_slide_mm += m.displacement(tip, t).distance(m.displacement(tip, t_prev));
                }
                b.last_t = Some(t);
            }
            _ => b.last_t = None,
        }
    }

    pub fn finish(mut self) -> Metrics {
        if self.palpation.open.is_some() {
            self.palpation.lift();
        }
        // No puncture at all: whatever palpation and ultrasound there was came "before" it.
        if self.attempts.is_empty() {
            self.palpation_before = self.palpation_ticks > 0;
            self.ultrasound_before = self.ultrasound_ticks > 0;
            self.target_scanned_before = self.view_first_tick.is_some();
        }
        let palpation = (self.palpation_ticks > 0).then(|| PalpationMetrics {
            spaces_crossed: self.palpation.crossed,
            spaces_found: self.palpation.found,
            coverage: if self.palpation.crossed > 0 {
                self.palpation.found as f64 / self.palpation.crossed as f64
            } else {
                0.0
            },
            ribs_crossed: self.palpation.ribs,
        });
        let ultrasound = (self.probe_ticks > 0).then(|| UltrasoundMetrics {
            target_scanned: self.view_first_tick.is_some(),
            time_to_target_view_s: self.view_first_tick.map(|t| t as f64 / self.rate_hz),
            target_view_time_s: self.view_ticks as f64 / self.rate_hz,
            good_contact_time_s: self.good_contact_ticks as f64 / self.rate_hz,
        });
        let rate = self.rate_hz;
        // The scored attempt: the first that reached the target, else the last.
        let scored = self
            .attempts
            .iter()
            .position(|a| a.path.reached_target_mm().is_some())
            .or(self.attempts.len().checked_sub(1));
        let path_inefficiency = scored.and_then(|i| self.attempts[i].path.inefficiency());
        let guided = scored.and_then(|i| {
            let a = &self.attempts[i];
            let entry_mm = a.path.entry_mm();
            let k = match &self.chosen_path {
                Some(name) => self.paths.iter().position(|p| &p.name == name)?,
                None => (0..self.paths.len()).min_by(|&x, &y| {
                    entry_mm
                        .distance(self.paths[x].entry_mm)
                        .total_cmp(&entry_mm.distance(self.paths[y].entry_mm))
                })?,
            };
            let p = &self.paths[k];
            let dir_point = a.direction_point_mm.unwrap_or(a.path.last_mm());
            let (planned, actual) = (
                (p.target_mm - p.entry_mm).normalize_or_zero(),
                (dir_point - entry_mm).normalize_or_zero(),
            );
            let (sum, max, n) = a.deviation[k];
            Some(Guided {
                path: p.name.clone(),
                entry_distance_mm: entry_mm.distance(p.entry_mm),
                angle_error_deg: libm::acos(planned.dot(actual).clamp(-1.0, 1.0)).to_degrees(),
                mean_deviation_mm: if n > 0 { sum / n as f64 } else { 0.0 },
                max_deviation_mm: max,
            })
        });
        let target_confirmed = self.stylet_in_target && self.contrast_filled;
        Metrics {
            attempts: self.attempts.len() as u32,
            redirections: self.redirections,
            redirection_times_s: self.redirection_times_s,
            risk_hits: self
                .risk
                .into_values()
                .map(|h| RiskHit {
                    duration_s: h.ticks as f64 / rate,
                    ..h
                })
                .collect(),
            bone_contacts: self.bone_contacts,
            target_reached: self.first_target_tick.is_some(),
            target_confirmed,
            stylet_removed_in_target: self.stylet_in_target,
            contrast_in_target: self.contrast_in_target,
            contrast_in_ducts_ml: self.contrast_in_ducts_ml,
            extravasated_ml: self.extravasated_ml,
            contrast_extent_mm: self.contrast_extent_mm,
            max_tissue_displacement_mm: self.max_tissue_displacement_mm,
            max_risk_displacement_mm: self.max_risk_displacement_mm,
            time_to_target_s: self.first_target_tick.map(|t| t as f64 / rate),
            time_total_s: self.ticks as f64 / rate,
            fluoro_time_s: self.xray_ticks as f64 / rate,
            xray_shots: self.xray_shots,
            // Set by the scorer, which knows the scenario's C-arm.
            dose_area_product_gy_cm2: 0.0,
            ultrasound_time_s: self.ultrasound_ticks as f64 / rate,
            needle_in_plane_share: (self.imaged_insertion_ticks > 0)
                .then(|| self.tip_in_plane_ticks as f64 / self.imaged_insertion_ticks as f64),
            palpation_time_s: self.palpation_ticks as f64 / rate,
            path_length_mm: self.path_length_mm,
            path_inefficiency,
            max_force_n: self.max_force_n,
            rms_force_n: if self.force_ticks > 0 {
                (self.force_sq_sum / self.force_ticks as f64).sqrt()
            } else {
                0.0
            },
            max_bending_mm: self.max_bending_mm,
            shaft_sweep_mm2: self.shaft_sweep_mm2,
            workflow: Workflow {
                palpation_before_puncture: self.palpation_before,
                ultrasound_before_puncture: self.ultrasound_before,
                target_scanned_before_puncture: self.target_scanned_before,
                confirmed_before_withdrawal: match (self.confirmed_tick, self.last_exit_tick) {
                    (Some(c), Some(e)) => c < e,
                    (Some(_), None) => true,
                    (None, _) => false,
                },
            },
            target_distance_mm: self
                .attempts
                .last()
                .and_then(|a| self.target.distance_mm(a.path.deepest_mm())),
            target_distance_min_mm: self.min_distance_mm,
            guided,
            palpation,
            ultrasound,
            breathing: self.breathing.map(|b| BreathingMetrics {
                target_reached_phase: b.target_reached_phase,
                correct_phase: BreathPhase::HeldEndExpiration,
                needle_in_while_breathing_s: b.needle_in_breathing_ticks as f64 / rate,
                tissue_slide_mm: b.tissue_slide_mm,
            }),
            needle_motion: Some(self.needle_motion.finish()),
            drainage: self.drainage.finish(rate),
            live_guidance: self.live_guidance.finish(rate),
            consequences: self.leaks.finish(rate, |l| {
                self.names
                    .get(&l)
                    .cloned()
                    .unwrap_or_else(|| stylet_physics::UNNAMED_STRUCTURE.to_string())
            }),
        }
    }
}

/// Metrics to test rubrics and benchmarks with.
#[cfg(test)]
pub(crate) mod tests_support {
    use super::{Metrics, NeedleMotionMetrics, Workflow};

    /// The worked example of docs/metrics.md "Rubrics".
    pub fn example() -> Metrics {
        Metrics {
            attempts: 2,
            redirections: 3,
            redirection_times_s: vec![4.0, 9.0, 15.0],
            risk_hits: Vec::new(),
            bone_contacts: 0,
            target_reached: true,
            target_confirmed: true,
            stylet_removed_in_target: true,
            contrast_in_target: true,
            contrast_in_ducts_ml: 2.0,
            extravasated_ml: 0.0,
            contrast_extent_mm: 30.0,
            max_tissue_displacement_mm: 3.0,
            max_risk_displacement_mm: 0.5,
            time_to_target_s: Some(20.0),
            time_total_s: 60.0,
            fluoro_time_s: 40.0,
            xray_shots: 2,
            dose_area_product_gy_cm2: 1.7,
            ultrasound_time_s: 10.0,
            needle_in_plane_share: None,
            palpation_time_s: 0.0,
            path_length_mm: 100.0,
            path_inefficiency: Some(1.1),
            max_force_n: 3.0,
            rms_force_n: 1.0,
            max_bending_mm: 1.0,
            shaft_sweep_mm2: 0.0,
            workflow: Workflow {
                palpation_before_puncture: false,
                ultrasound_before_puncture: true,
                target_scanned_before_puncture: true,
                confirmed_before_withdrawal: true,
            },
            target_distance_mm: Some(0.0),
            target_distance_min_mm: Some(0.0),
            guided: None,
            palpation: None,
            ultrasound: None,
            breathing: None,
            drainage: None,
            needle_motion: Some(NeedleMotionMetrics::default()),
            live_guidance: None,
            consequences: Vec::new(),
        }
    }

    /// The worked example changed by `f`.
    pub fn metrics_with(f: impl FnOnce(&mut Metrics)) -> Metrics {
        let mut m = example();
        f(&mut m);
        m
    }
}
