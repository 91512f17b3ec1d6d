//! The metrics a rubric may name, per exercise (docs/metrics.md), and each one's value from a
//! session's [`Metrics`]: what rubrics grade and the expert benchmark measures.

use crate::metrics::Metrics;
use stylet_atlas::Exercise;

/// Metric names a puncture rubric may use, with their meaning (docs/metrics.md).
pub const PUNCTURE_METRICS: &[&str] = &[
    "attempts",
    "redirections",
    "risk_hits",
    "risk_time_s",
    "bone_contacts",
    "target_not_reached",
    "target_not_confirmed",
    "extravasated_ml",
    "risk_displacement_mm",
    "time_total_s",
    "fluoro_time_s",
    "xray_shots",
    "dose_area_product_gy_cm2",
    "max_force_n",
    "shaft_sweep_mm2",
    "tissue_damage_mm2",
    "time_in_tissue_s",
    "needle_path_length_mm",
    "path_in_tissue_mm",
    "path_outside_tissue_mm",
    "jerk_mm_per_s2_5",
    "depth_perception_mm",
    "reorientations",
    "path_inefficiency",
    "target_distance_mm",
    "missing_palpation",
    "missing_ultrasound",
    "missing_target_scan",
    "guided_entry_distance_mm",
    "guided_angle_error_deg",
    "guided_mean_deviation_mm",
    "target_reached_while_breathing",
    "breathing_tissue_slide_mm",
    "tip_out_of_view_share",
    "blind_advance_s",
    "tip_out_of_view_at_target",
];

/// Metrics where more is better: a deduction "above the experts" makes no sense for them.
pub const HIGHER_IS_BETTER: &[&str] = &["intercostal_spaces_found", "palpation_coverage", "good_contact_time_s"];

/// Metric names a palpation rubric may use.
pub const PALPATION_METRICS: &[&str] = &[
    "intercostal_spaces_found",
    "intercostal_spaces_missed",
    "palpation_coverage",
    "palpation_time_s",
    "time_total_s",
    "max_force_n",
];

/// Metric names an ultrasound-survey rubric may use.
pub const ULTRASOUND_METRICS: &[&str] = &[
    "target_not_scanned",
    "time_to_target_view_s",
    "good_contact_time_s",
    "poor_contact_share",
    "time_total_s",
    "max_force_n",
];

/// Metric names a drainage rubric may use: the puncture's safety and outcome, then the Seldinger
/// exchange's (docs/metrics.md "Drainage").
pub const DRAINAGE_METRICS: &[&str] = &[
    "attempts",
    "redirections",
    "risk_hits",
    "risk_time_s",
    "bone_contacts",
    "target_not_reached",
    "target_not_confirmed",
    "extravasated_ml",
    "time_total_s",
    "fluoro_time_s",
    "dose_area_product_gy_cm2",
    "max_force_n",
    "shaft_sweep_mm2",
    "missing_palpation",
    "missing_ultrasound",
    "wire_not_in_ducts",
    "wire_through_wall",
    "wire_folded_mm",
    "wrong_branch_entries",
    "access_lost",
    "wire_attempts",
    "dilator_attempts",
    "catheter_attempts",
    "refused_steps",
    "fluoro_wire_s",
    "fluoro_dilator_s",
    "fluoro_catheter_s",
    "dilator_max_force_n",
    "catheter_max_force_n",
    "catheter_not_placed",
    "catheter_holes_outside_ducts",
    "pigtail_outside_ducts",
];

/// Every metric name a rubric may use, over all exercises (a name two exercises share, like
/// `time_total_s`, comes once per exercise).
pub fn rubric_metrics() -> impl Iterator<Item = &'static str> {
    PUNCTURE_METRICS
        .iter()
        .chain(PALPATION_METRICS)
        .chain(ULTRASOUND_METRICS)
        .chain(DRAINAGE_METRICS)
        .copied()
}

/// The metric names a rubric may use for `exercise`.
pub fn exercise_metrics(exercise: Exercise) -> &'static [&'static str] {
    match exercise {
        Exercise::Puncture => PUNCTURE_METRICS,
        Exercise::Palpation => PALPATION_METRICS,
        Exercise::UltrasoundSurvey => ULTRASOUND_METRICS,
        Exercise::Drainage => DRAINAGE_METRICS,
    }
}

/// Whether the session tried `exercise` at all: for a puncture or a drainage (whose first step is
/// the puncture) the needle entered the skin, for a palpation the finger and for an ultrasound survey the probe touched it. A session that did not
/// is not graded on everything it lacks (which would leave points for what it never risked): it
/// scores 0 and says so ([`not_attempted_text`]).
pub fn attempted(m: &Metrics, exercise: Exercise) -> bool {
    match exercise {
        Exercise::Puncture | Exercise::Drainage => m.attempts > 0,
        Exercise::Palpation => m.palpation.is_some(),
        Exercise::UltrasoundSurvey => m.ultrasound.is_some(),
    }
}

/// What a session that did not try `exercise` is told.
pub fn not_attempted_text(exercise: Exercise) -> &'static str {
    match exercise {
        Exercise::Puncture | Exercise::Drainage => "Not attempted: the needle never entered the skin.",
        Exercise::Palpation => "Not attempted: the finger never touched the skin.",
        Exercise::UltrasoundSurvey => "Not attempted: the probe never touched the skin.",
    }
}

/// The value of a rubric metric (absent guided or distance metrics count as 0: nothing to judge;
/// `None` for a name no rubric may use, and for a needle-motion metric of a report older than it).
pub fn metric_value(m: &Metrics, name: &str) -> Option<f64> {
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    Some(match name {
        "attempts" => m.attempts as f64,
        "redirections" => m.redirections as f64,
        "risk_hits" => m.risk_hits.len() as f64,
        "risk_time_s" => m.risk_hits.iter().map(|h| h.duration_s).sum(),
        "bone_contacts" => m.bone_contacts as f64,
        "target_not_reached" => flag(!m.target_reached),
        "target_not_confirmed" => flag(!m.target_confirmed),
        "extravasated_ml" => m.extravasated_ml,
        "risk_displacement_mm" => m.max_risk_displacement_mm,
        "time_total_s" => m.time_total_s,
        "fluoro_time_s" => m.fluoro_time_s,
        "xray_shots" => m.xray_shots as f64,
        "dose_area_product_gy_cm2" => m.dose_area_product_gy_cm2,
        "max_force_n" => m.max_force_n,
        "shaft_sweep_mm2" => m.shaft_sweep_mm2,
        // The hand-held needle's motion (PerkTutor's definitions); absent only in a report
        // written before it was measured.
        "tissue_damage_mm2" => m.needle_motion?.tissue_damage_mm2,
        "time_in_tissue_s" => m.needle_motion?.time_in_tissue_s,
        "needle_path_length_mm" => m.needle_motion?.path_length_mm,
        "path_in_tissue_mm" => m.needle_motion?.path_in_tissue_mm,
        "path_outside_tissue_mm" => m.needle_motion?.path_outside_tissue_mm,
        "jerk_mm_per_s2_5" => m.needle_motion?.jerk_mm_per_s2_5,
        "depth_perception_mm" => m.needle_motion?.depth_perception_mm,
        "reorientations" => m.needle_motion?.reorientations as f64,
        "path_inefficiency" => m.path_inefficiency.unwrap_or(0.0),
        "target_distance_mm" => m.target_distance_mm.unwrap_or(0.0),
        "missing_palpation" => flag(!m.workflow.palpation_before_puncture),
        "missing_ultrasound" => flag(!m.workflow.ultrasound_before_puncture),
        "missing_target_scan" => flag(!m.workflow.target_scanned_before_puncture),
        "guided_entry_distance_mm" => m.guided.as_ref().map_or(0.0, |g| g.entry_distance_mm),
        "guided_angle_error_deg" => m.guided.as_ref().map_or(0.0, |g| g.angle_error_deg),
        "guided_mean_deviation_mm" => m.guided.as_ref().map_or(0.0, |g| g.mean_deviation_mm),
        // Breathing (0 when the patient did not breathe): the target reached in any phase but the
        // scenario's correct hold, and the tissue the breathing carried past the needle.
        "target_reached_while_breathing" => flag(
            m.breathing
                .as_ref()
                .is_some_and(|b| b.target_reached_phase.is_some_and(|p| p != b.correct_phase)),
        ),
        "breathing_tissue_slide_mm" => m.breathing.as_ref().map_or(0.0, |b| b.tissue_slide_mm),
        // Live ultrasound guidance (0 when the second hand held no probe: nothing to judge).
        "tip_out_of_view_share" => m.live_guidance.map_or(0.0, |g| 1.0 - g.needle_tip_visible_share),
        "blind_advance_s" => m.live_guidance.map_or(0.0, |g| g.longest_blind_advance_s),
        "tip_out_of_view_at_target" => flag(
            m.live_guidance
                .is_some_and(|g| g.tip_in_view_at_target_entry == Some(false)),
        ),
        // Palpation (0 when the finger never touched the skin).
        "intercostal_spaces_found" => m.palpation.as_ref().map_or(0.0, |p| p.spaces_found as f64),
        "intercostal_spaces_missed" => m
            .palpation
            .as_ref()
            .map_or(0.0, |p| p.spaces_crossed.saturating_sub(p.spaces_found) as f64),
        "palpation_coverage" => m.palpation.as_ref().map_or(0.0, |p| p.coverage),
        "palpation_time_s" => m.palpation_time_s,
        // Ultrasound survey (a target never shown takes the whole session to its first view).
        "target_not_scanned" => flag(!m.ultrasound.as_ref().is_some_and(|u| u.target_scanned)),
        "time_to_target_view_s" => m
            .ultrasound
            .as_ref()
            .and_then(|u| u.time_to_target_view_s)
            .unwrap_or(m.time_total_s),
        "good_contact_time_s" => m.ultrasound.as_ref().map_or(0.0, |u| u.good_contact_time_s),
        "poor_contact_share" => m.ultrasound.as_ref().map_or(1.0, |u| {
            if m.ultrasound_time_s > 0.0 {
                (1.0 - u.good_contact_time_s / m.ultrasound_time_s).clamp(0.0, 1.0)
            } else {
                1.0
            }
        }),
        // The Seldinger exchange (docs/metrics.md "Drainage"): a session without a wire never
        // had one in the ducts nor placed a catheter, and did nothing else of the exchange.
        "wire_not_in_ducts" => flag(!m.drainage.as_ref().is_some_and(|d| d.wire_reached_ducts)),
        "wire_through_wall" => flag(m.drainage.as_ref().is_some_and(|d| d.wire_left_duct)),
        "wire_folded_mm" => m.drainage.as_ref().map_or(0.0, |d| d.wire_folded_max_mm),
        "wrong_branch_entries" => m.drainage.as_ref().map_or(0.0, |d| f64::from(d.wrong_branch_entries)),
        "access_lost" => flag(m.drainage.as_ref().is_some_and(|d| d.access_lost)),
        "wire_attempts" => m.drainage.as_ref().map_or(0.0, |d| f64::from(d.wire_attempts)),
        "dilator_attempts" => m.drainage.as_ref().map_or(0.0, |d| f64::from(d.dilator_attempts)),
        "catheter_attempts" => m.drainage.as_ref().map_or(0.0, |d| f64::from(d.catheter_attempts)),
        "refused_steps" => m.drainage.as_ref().map_or(0.0, |d| f64::from(d.refused_steps)),
        "fluoro_wire_s" => m.drainage.as_ref().map_or(0.0, |d| d.fluoroscopy_wire_s),
        "fluoro_dilator_s" => m.drainage.as_ref().map_or(0.0, |d| d.fluoroscopy_dilator_s),
        "fluoro_catheter_s" => m.drainage.as_ref().map_or(0.0, |d| d.fluoroscopy_catheter_s),
        "dilator_max_force_n" => m.drainage.as_ref().map_or(0.0, |d| d.dilator_peak_force_n),
        "catheter_max_force_n" => m.drainage.as_ref().map_or(0.0, |d| d.catheter_peak_force_n),
        "catheter_not_placed" => flag(!m.drainage.as_ref().is_some_and(|d| d.catheter_placed)),
        "catheter_holes_outside_ducts" => m.drainage.as_ref().map_or(0.0, |d| {
            if d.catheter_placed {
                f64::from(d.catheter_holes.saturating_sub(d.catheter_holes_in_ducts))
            } else {
                0.0
            }
        }),
        "pigtail_outside_ducts" => flag(
            m.drainage
                .as_ref()
                .is_some_and(|d| d.catheter_placed && !d.pigtail_in_ducts),
        ),
        _ => return None,
    })
}
