//! `GET /sessions/{id}`: the review of one session. The result with its reasons in words; force
//! along the needle over time with its components, the events, the structures punctured at the
//! force peaks and the instructors' timestamped comments; insertion depth; the tip path and the
//! planned path over CT slices with the guided-path deviation; for each risk hit, slices through
//! the point of first contact with the clinical consequence from the scenario; metrics beside
//! the rubric's thresholds, the replay check, the file, comments and grade overrides. While the
//! session waits for its replay the page refreshes itself.

use std::sync::Arc;

use axum::Form;
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, PreEscaped, html};
use stylet_scoring::rubric::{Rubric, metric_value};
use stylet_scoring::{Outcome, ReviewTrace, ScoreReport, metric_label};
use stylet_service::AppState;
use stylet_service::api::{check_comment, check_comment_time, check_override, may_review, reviewable};
use stylet_service::store::{Role, SessionRow, SessionStatus};
use stylet_service::traces::review_trace;

use crate::auth::{PageError, Viewer, check_csrf, fail};
use crate::charts::{comment_notes, depth_chart, force_chart, inline_svg, puncture_peaks};
use crate::figures::Figure;
use crate::layout::{count, csrf_field, page, refreshing_page, result_badge, short_time, status_badge, verified_badge};
use crate::session_access::{require_scored, visible_session};

/// The review's query: `?tick=N` shows the player's frames at tick N (the key moments' links,
/// for browsers without JavaScript).
#[derive(Debug, Default, serde::Deserialize)]
pub struct ReviewQuery {
    tick: Option<u64>,
    /// The 3D overview's turntable frame (links for browsers without JavaScript).
    turn: Option<u32>,
}

pub async fn review(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    axum::extract::Query(q): axum::extract::Query<ReviewQuery>,
) -> Result<Response, PageError> {
    let row = visible_session(&s, &v, &id).await?;
    let title = format!("{} — {} ({})", row.trainee, row.scenario, row.difficulty);
    let head = header_block(&row);
    if row.status != SessionStatus::Scored {
        let body = html! {
            (head)
            @if row.status == SessionStatus::Failed {
                p.error #scoring-error { "Scoring failed: " (row.error.clone().unwrap_or_default()) }
            } @else {
                p.notice #scoring-wait { "The session is " (row.status) ": the replay runs on the server. This page refreshes itself." }
            }
        };
        return Ok(if row.status == SessionStatus::Failed {
            page(&title, Some(&v), body).into_response()
        } else {
            refreshing_page(&title, &v, 2, body).into_response()
        });
    }
    let report: ScoreReport = row
        .score
        .clone()
        .and_then(|r| serde_json::from_value(r).ok())
        .ok_or_else(|| {
            fail(
                StatusCode::INTERNAL_SERVER_ERROR,
                "the stored score report cannot be read",
            )
        })?;
    let review = s.store.annotations(&id).await?;
    let (_, trainee_id) = s
        .store
        .session(&id)
        .await?
        .ok_or_else(|| fail(StatusCode::NOT_FOUND, "gone"))?;
    let reviewer = may_review(&s, &v.user, &trainee_id).await?;
    // Label names and the rubric of the session's atlas (loaded if the cache let it go; the
    // page still shows what it can without it).
    let scorer = s.catalogue.loaded(&row.atlas_hash).await.ok().map(|l| l.scorer);
    let label_name = |l: stylet_physics::LabelId| {
        scorer
            .as_ref()
            .and_then(|sc| sc.atlas().label_table().get(l).map(|x| x.name.clone()))
            .unwrap_or_else(|| stylet_physics::UNNAMED_STRUCTURE.to_string())
    };
    // Peaks are named for the structures a reader looks for (skin, fascia, organs, ducts, risk
    // structures), not air or the unlabelled soft tissue between them.
    let peak_name = |l: stylet_physics::LabelId| {
        let table = scorer.as_ref()?.atlas().label_table();
        let h = table.heuristic();
        (l != h.air && l != h.fat).then(|| label_name(l))
    };
    let trace = review_trace(&s, &row.file_sha256, &row.atlas_hash).await;
    let charts = match &trace {
        Ok(trace) => charts_block(trace, &row, &review, &peak_name)?,
        Err(e) => html! { p.error { "The force curves cannot be shown: " (e) } },
    };
    let rate = crate::player::tick_rate_hz(&s, &row).await;
    let player = match (&trace, rate) {
        (Ok(trace), Some(rate)) => {
            crate::player::warm(&s, &row);
            crate::player::block(&row, trace, rate, report.ticks, q.tick, &comment_notes(&review))
        }
        (Err(_), _) => html! {},
        (_, None) => html! { p.error { "The replay cannot be shown: the session file's header cannot be read." } },
    };
    let rubric = scorer.as_ref().map(|sc| sc.rubric().clone());
    let level = rubric
        .as_ref()
        .filter(|ru| ru.name == report.grade.rubric && ru.version == report.grade.rubric_version)
        .and_then(|ru| ru.level(report.exercise, report.grade.difficulty));
    let (benchmark, references) = stylet_service::experts::benchmark(&s, &row.atlas_hash, &row.scenario).await?;
    let corridor_key = if stylet_service::experts::figures_shown(&v.user, references.len()) {
        stylet_service::experts::references_key(&references)
    } else {
        "none".to_string()
    };
    let overview = crate::player::overview::block(&row, q.turn.unwrap_or(0), &corridor_key, references.len());
    let listed = stylet_service::experts::visible_references(&s, &v.user, &references).await?;
    let benchmark = crate::pages::benchmark::block(
        &v,
        &crate::pages::benchmark::BenchmarkView {
            session_id: &row.id,
            report: &report,
            benchmark: &benchmark,
            references: &references,
            level,
            reviewer,
            listed: listed.as_deref(),
            figures_shown: stylet_service::experts::figures_shown(&v.user, references.len()),
        },
    );
    let body = html! {
        (head)
        // The upload accepts only the default tick rate, so it stands in for an unreadable header.
        (grade_block(&report, &review, rate.unwrap_or(stylet_physics::DEFAULT_TICK_RATE_HZ), reviewer))
        h2 { "Replay" }
        (player)
        h2 { "Forces and depth" }
        (charts)
        h2 { "3D overview of the attempt" }
        (overview)
        h2 { "Tip path over the CT" }
        p.muted { "Axial, coronal and sagittal slices through the deepest tip position; the needle tip's path (cyan), the planned path (dashed orange) and the expert corridor (white band) projected onto each plane; partial labels in colour (legend below the slices)." }
        img.figure #tip-path src={ "/sessions/" (row.id) "/slices.png?e=" (corridor_key) } alt="Needle tip path, planned path and expert corridor over CT slices with the label overlay";
        (figure_legend(&report))
        (guided_block(&report))
        h2 { "Risk-structure hits" }
        (risk_table(&report))
        (consequence_table(&report))
        (hit_figures(&report, &row.id))
        h2 { "Against the expert benchmark" }
        (benchmark)
        h2 { "Other metrics" }
        (other_metrics(&report))
        h2 { "Metrics against the rubric (" (report.grade.rubric) " v" (report.grade.rubric_version) ", " (report.grade.difficulty) ")" }
        (rubric_table(&report, rubric.as_ref()))
        h2 { "Review" }
        (review_block(&review))
        @if reviewer { (review_forms(&v, &row.id, row.duration_s)) }
    };
    Ok(page(&title, Some(&v), body).into_response())
}

fn header_block(row: &SessionRow) -> Markup {
    html! {
        h1 { "Session of " (row.trainee) " — " (row.scenario) }
        p {
            "Difficulty " strong { (row.difficulty) } " · recorded " (short_time(&row.recorded_at))
            " · uploaded " (short_time(&row.uploaded_at)) " UTC · " (format!("{:.1}", row.duration_s)) " s · "
            (status_badge(row.status)) " · "
            a #download href={ "/sessions/" (row.id) "/file" } { "download the session file (" (format!("{:.0}", row.size_bytes as f64 / 1024.0)) " KiB)" }
        }
    }
}

/// Where the replay first differed from the recording, in words: the time in seconds (at
/// `rate_hz` ticks a second) and what differed, without tick numbers or stream names.
fn divergence_text(d: &stylet_scoring::Divergence, rate_hz: u32) -> String {
    let what = match d.stream.as_str() {
        "ticks.force_n" => "the force on the needle",
        "ticks.torque_nmm" => "the torque on the needle",
        "ticks.tip_label" => "the structure at the needle tip",
        "ticks.inserted_mm" => "the insertion depth",
        "ticks" => "the recording (a stretch of it is missing)",
        // "digests", "ticks.outputs_digest": the simulation's exact state or outputs.
        _ => "the simulation's state",
    };
    format!(
        "The replay first differed from the recording at {}, in {what}.",
        crate::player::time_text(d.tick, rate_hz)
    )
}

/// The grade's cards: score, result with its reasons, attempts, the replay check. `rate_hz`: the
/// session's tick rate (for the time of a divergence); `reviewer`: whether the viewer reviews
/// this session (they also get the replay's technical figures).
fn grade_block(r: &ScoreReport, review: &serde_json::Value, rate_hz: u32, reviewer: bool) -> Markup {
    let last_override = review["overrides"].as_array().and_then(|o| o.last()).cloned();
    let (score, outcome) = match &last_override {
        Some(o) => (
            o["score"].as_f64().unwrap_or(r.grade.score),
            if o["passed"].as_bool().unwrap_or(r.grade.passed) {
                Outcome::Passed
            } else {
                Outcome::Failed
            },
        ),
        None => (r.grade.score, r.outcome),
    };
    html! {
        div.cards #grade {
            div.card { div.muted { "Score" } div.big { (format!("{score:.1}")) }
                @if last_override.is_some() { div.muted { "computed: " (format!("{:.1}", r.grade.score)) } } }
            div.card #result { div.muted { "Result" } div.big { (outcome_badge(outcome, last_override.is_some())) }
                @if let Some(o) = &last_override {
                    div { "Overridden by " (o["author"].as_str().unwrap_or("an instructor")) ": " em { (o["reason"].as_str().unwrap_or_default()) } }
                    @if r.outcome != outcome { div.muted { "computed: " (r.outcome.label()) } }
                }
                @if r.reasons.is_empty() {
                    div.muted #reasons { @match r.outcome {
                        Outcome::Passed => "Every requirement met; nothing deducted.",
                        Outcome::Failed => "The score is below the pass mark for this level.",
                        Outcome::NotGradeable => "The recording is incomplete, so it is not graded.",
                    } }
                } @else {
                    ul #reasons { @for reason in &r.reasons { li { (reason) } } }
                } }
            div.card { div.muted { "Attempts · redirections" } div.big { (r.metrics.attempts) " · " (r.metrics.redirections) } }
            @if let Some(sk) = &r.skill { (skill_card(sk)) }
            div.card #replay { div.muted { "Replay" } div.big { (verified_badge(Some(r.replay_verified))) }
                @if let Some(d) = &r.divergence { div.muted { (divergence_text(d, rate_hz)) } }
                @if r.replay_verified { div.muted { "The server re-ran the simulation and got exactly the recorded forces." } }
                @if reviewer {
                    details.muted #replay-details { summary { "Technical details" }
                        (count(r.ticks, "step", "steps")) " replayed, " (count(r.digests_checked, "state check", "state checks"))
                        ", physics v" (r.physics_version) }
                } }
        }
        @if r.incomplete { p.notice { "Incomplete recording: " (r.incomplete_reason.clone().unwrap_or_default()) } }
    }
}

/// The skill estimate beside the grade: the mean of the metrics' spreads from the expert mean
/// (+ worse), and the metrics furthest above it.
fn skill_card(sk: &stylet_scoring::benchmark::SkillEstimate) -> Markup {
    let mut furthest: Vec<&stylet_scoring::benchmark::MetricZ> = sk.metrics.iter().filter(|z| z.z > 1.0).collect();
    furthest.sort_by(|a, b| b.z.total_cmp(&a.z));
    furthest.truncate(3);
    html! {
        div.card #skill { div.muted { "Skill against the experts" } div.big { (format!("{:+.1}", sk.z_mean)) }
            div.muted { "Mean distance from the expert mean in expert spreads, over "
                (count(sk.metrics.len(), "metric", "metrics")) " and " (count(sk.experts, "expert reference", "expert references"))
                " when scored: 0 is the experts' level, + is worse. Beside the score, which passes or fails." }
            @if !furthest.is_empty() {
                div.muted { "Furthest above the experts: "
                    @for (k, z) in furthest.iter().enumerate() {
                        @if k > 0 { ", " }
                        (metric_label(&z.metric).unwrap_or(&z.metric)) " " (format!("{:+.1}", z.z))
                    }
                }
            }
        }
    }
}

/// A result badge: passed, failed or not gradeable (and whether an instructor overrode it).
fn outcome_badge(outcome: Outcome, overridden: bool) -> Markup {
    match outcome {
        Outcome::NotGradeable => html! { span.badge.warn { "not gradeable" } },
        o => result_badge(Some(o == Outcome::Passed), overridden),
    }
}

fn charts_block(
    trace: &ReviewTrace,
    row: &SessionRow,
    review: &serde_json::Value,
    peak_name: &dyn Fn(stylet_physics::LabelId) -> Option<String>,
) -> Result<Markup, PageError> {
    let svg = |c| inline_svg(&c).map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()));
    let notes = comment_notes(review);
    let mut force = force_chart(
        trace,
        &format!("Force on the hand — {} ({})", row.scenario, row.trainee),
    );
    force.peaks = puncture_peaks(trace, peak_name);
    force.notes = notes.clone();
    let mut depth = depth_chart(trace, &format!("Insertion depth — {} ({})", row.scenario, row.trainee));
    depth.notes = notes;
    let (force, depth) = (svg(force)?, svg(depth)?);
    Ok(html! {
        div.chart-box #force-chart { (PreEscaped(force)) }
        div.chart-box #depth-chart { (PreEscaped(depth)) }
        p.muted { "Forces: the sample of largest magnitude in every 20 ms, so puncture peaks are kept. Positive = against the insertion. Each force peak that broke into a structure is named (skin, fascia, liver, duct …); blue dashed lines are the instructors' comments at a moment (numbered as in the review below)." }
        @if !trace.sent_n.is_empty() {
            p.muted #device-force-note { "Trained on a force-feedback device: the purple dashed line is the force its safety guard let through to the hand (magnitude). Red spans: no force reached the hand (forces engaging, the clutch or a pause, a stalled simulation); yellow spans: less than computed (ramping in, the device's maximum, its continuous limit)." }
        }
    })
}

/// The figure's line legend, also in text (the PNG carries it too).
fn figure_legend(r: &ScoreReport) -> Markup {
    let swatch = |css: &str| html! { span aria-hidden="true" style={ "display:inline-block;width:2.2rem;vertical-align:middle;margin-right:.4rem;border-top:" (css) } {} };
    html! {
        ul.muted #tip-path-legend style="list-style:none;padding-left:0" {
            li { (swatch("3px solid #00e6ff")) "needle tip path" }
            @if let Some(g) = &r.metrics.guided { li { (swatch("3px dashed #ffaa00")) "planned path '" (g.path) "' (the path the deviation below is measured against)" } }
            li { (swatch("1px solid #ffdc50")) "crosshair: the deepest tip position" }
        }
    }
}

/// How far the scored attempt was from the planned path (guided mode, docs/metrics.md).
fn guided_block(r: &ScoreReport) -> Markup {
    html! {
        @match &r.metrics.guided {
            Some(g) => {
                h3 { "Deviation from the planned path '" (g.path) "'" }
                div.cards #guided {
                    div.card { div.muted { "Entry point" } div.big { (format!("{:.1} mm", g.entry_distance_mm)) } div.muted { "from the planned skin entry" } }
                    div.card { div.muted { "Direction" } div.big { (format!("{:.1}°", g.angle_error_deg)) } div.muted { "off the planned direction" } }
                    div.card { div.muted { "Tip distance from the planned line" } div.big { (format!("{:.1} mm", g.mean_deviation_mm)) }
                        div.muted { "mean; largest " (format!("{:.1} mm", g.max_deviation_mm)) } }
                }
            }
            None => p.muted #guided { "No planned path to compare with (the atlas has none, or the needle never entered the body)." }
        }
    }
}

/// For each risk hit: its clinical consequence (scenario TOML) and slices through the point where
/// the tip first touched it.
fn hit_figures(r: &ScoreReport, id: &str) -> Markup {
    html! {
        @for (n, h) in r.metrics.risk_hits.iter().enumerate() {
            div.hit id={ "hit-" (n) } {
                h3 { "Hit " (n + 1) ": " (h.structure) " at " (format!("{:.2} s", h.t_s)) }
                @match &h.consequence {
                    Some(c) => p.consequence { strong { "Clinical consequence: " } (c) },
                    None => p.consequence.muted { "The scenario names no clinical consequence for this structure." },
                }
                p.muted { "Axial and coronal slices through the point where the tip first touched the " (h.structure)
                    " (red ring; crosshair), " (format!("{:.1} mm", h.depth_mm)) " deep at most, "
                    (format!("{:.2} s", h.duration_s)) " inside; the needle tip's path (cyan) and the planned path (dashed orange) projected." }
                img.figure.hit-slices src={ "/sessions/" (id) "/hits/" (n + 1) "/slices.png" }
                    alt={ "CT slices through the point where the needle touched the " (h.structure) ", marked with a red ring" };
            }
        }
    }
}

fn risk_table(r: &ScoreReport) -> Markup {
    html! {
        @if r.metrics.risk_hits.is_empty() {
            p #risk-hits { span.badge.ok { "none" } " No risk structure was touched." }
        } @else {
            table #risk-hits {
                thead { tr { th { "Structure" } th.num { "First contact (s)" } th.num { "Deepest (mm)" } th.num { "Time inside (s)" } th.num { "Entries" } } }
                tbody { @for h in &r.metrics.risk_hits { tr {
                    td { span.badge.bad { (h.structure) } }
                    td.num { (format!("{:.2}", h.t_s)) } td.num { (format!("{:.1}", h.depth_mm)) }
                    td.num { (format!("{:.2}", h.duration_s)) } td.num { (h.entries) }
                } } }
            }
        }
    }
}

/// What the wrong punctures did to the patient (haematoma, pneumothorax, bile leak), as the
/// physics computed it; the force chart marks when each began.
fn consequence_table(r: &ScoreReport) -> Markup {
    html! {
        @if !r.metrics.consequences.is_empty() {
            h3 { "What the punctures did to the patient" }
            table #consequences {
                thead { tr { th { "Consequence" } th { "Structure punctured" } th.num { "Punctured (s)" } th.num { "Began (s)" } th.num { "By the end (ml)" } } }
                tbody { @for c in &r.metrics.consequences { tr {
                    td { span.badge.bad { (c.kind.name()) } }
                    td { (c.structure) }
                    td.num { (format!("{:.2}", c.punctured_s)) } td.num { (format!("{:.2}", c.began_s)) }
                    td.num { (format!("{:.1}", c.volume_ml)) }
                } } }
            }
            p.muted { "Blood, air or bile let out by the end of the session (docs/complications.md): a haematoma grows around a vessel hit with a needle of 19 G or larger, a pneumothorax follows any lung puncture, a bile duct left without a drain leaks once the needle is out." }
        }
    }
}

fn other_metrics(r: &ScoreReport) -> Markup {
    let m = &r.metrics;
    let opt = |v: Option<f64>, unit: &str| v.map_or("–".to_string(), |v| format!("{v:.1} {unit}"));
    let yes = |b: bool| if b { "yes" } else { "no" };
    let rows: Vec<(&str, String)> = vec![
        (
            "Target reached",
            format!("{} (at {})", yes(m.target_reached), opt(m.time_to_target_s, "s")),
        ),
        ("Target confirmed", yes(m.target_confirmed).to_string()),
        ("Total time", format!("{:.1} s", m.time_total_s)),
        (
            "Fluoroscopy",
            format!(
                "{:.1} s, {}",
                m.fluoro_time_s,
                count(m.xray_shots, "X-ray shot", "X-ray shots")
            ),
        ),
        (
            "Palpation · ultrasound",
            format!("{:.1} s · {:.1} s", m.palpation_time_s, m.ultrasound_time_s),
        ),
        (
            "Needle tip in the ultrasound image",
            m.needle_in_plane_share
                .map_or("no ultrasound before the puncture".to_string(), |s| {
                    format!("{:.0} % of the insertion time", 100.0 * s)
                }),
        ),
        ("Path length in the body", format!("{:.1} mm", m.path_length_mm)),
        (
            "Largest force · RMS",
            format!("{:.2} N · {:.2} N", m.max_force_n, m.rms_force_n),
        ),
        ("Needle bending (max)", format!("{:.2} mm", m.max_bending_mm)),
        (
            "Tissue swept by the bending shaft",
            format!("{:.0} mm²", m.shaft_sweep_mm2),
        ),
        (
            "Tissue displaced (max) · risk structures",
            format!(
                "{:.1} mm · {:.1} mm",
                m.max_tissue_displacement_mm, m.max_risk_displacement_mm
            ),
        ),
        ("Bone contacts", m.bone_contacts.to_string()),
        ("Distance to the target", opt(m.target_distance_mm, "mm")),
    ];
    let mut rows = rows;
    if let Some(n) = &m.needle_motion {
        // The hand-held needle as a tracker sees it (PerkTutor's definitions, docs/metrics.md).
        rows.push((
            "Needle in tissue: time · path (outside)",
            format!(
                "{:.1} s · {:.1} mm ({:.1} mm)",
                n.time_in_tissue_s, n.path_in_tissue_mm, n.path_outside_tissue_mm
            ),
        ));
        rows.push((
            "Tissue damage (area swept by the needle line)",
            format!("{:.0} mm²", n.tissue_damage_mm2),
        ));
        rows.push((
            "Needle jerk · motion along its axis · reorientations",
            format!(
                "{:.3e} mm/s^2.5 · {:.1} mm · {}",
                n.jerk_mm_per_s2_5, n.depth_perception_mm, n.reorientations
            ),
        ));
    }
    if let Some(g) = &m.live_guidance {
        // Two hands: the probe imaged live while the needle advanced.
        rows.push((
            "Live ultrasound: needle tip in view · longest blind advance · at the target",
            format!(
                "{:.0} % of the insertion · {:.1} s · {}",
                100.0 * g.needle_tip_visible_share,
                g.longest_blind_advance_s,
                match g.tip_in_view_at_target_entry {
                    Some(true) => "in view",
                    Some(false) => "out of view",
                    None => "target not reached",
                }
            ),
        ));
    }
    if let Some(b) = &m.breathing {
        rows.push((
            "Breathing: target reached",
            b.target_reached_phase
                .map_or("target not reached".to_string(), |p| p.as_str().to_string()),
        ));
        rows.push((
            "Breathing: needle in while breathing · tissue carried past the tip",
            format!("{:.1} s · {:.0} mm", b.needle_in_while_breathing_s, b.tissue_slide_mm),
        ));
    }
    html! {
        table #metrics { tbody { @for (k, v) in rows { tr { th { (k) } td { (v) } } } } }
    }
}

/// Every metric the level's rubric uses: its value, the requirement and whether it holds, the
/// deduction rule and the points it cost.
fn rubric_table(r: &ScoreReport, rubric: Option<&Rubric>) -> Markup {
    let level = rubric
        .filter(|ru| ru.name == r.grade.rubric && ru.version == r.grade.rubric_version)
        .and_then(|ru| ru.level(r.exercise, r.grade.difficulty));
    let Some(level) = level else {
        return html! { p.muted { "This server no longer has rubric " (r.grade.rubric) " v" (r.grade.rubric_version) "; the deductions applied:" }
        ul { @for d in &r.grade.deductions { li { (d.metric) ": −" (format!("{:.1}", d.points)) } } } };
    };
    let mut names: Vec<&str> = level.require.iter().map(|q| q.metric.as_str()).collect();
    for d in &level.deduct {
        if !names.contains(&d.metric.as_str()) {
            names.push(&d.metric);
        }
    }
    let fmt = |v: f64| {
        if v.fract() == 0.0 {
            format!("{v:.0}")
        } else {
            format!("{v:.2}")
        }
    };
    html! {
        table #rubric {
            thead { tr { th { "Metric" } th.num { "Value" } th { "Requirement" } th { "Deduction rule" } th.num { "Deducted" } } }
            tbody {
                @for name in names {
                    @let value = metric_value(&r.metrics, name);
                    @let req = level.require.iter().find(|q| q.metric == name);
                    @let rule = level.deduct.iter().find(|d| d.metric == name);
                    @let applied = r.grade.deductions.iter().find(|d| d.metric == name && d.relative.is_none()).map_or(0.0, |d| d.points);
                    tr {
                        td { (metric_label(name).unwrap_or(name)) }
                        td.num { (value.map_or("–".into(), fmt)) }
                        td {
                            @if let Some(q) = req {
                                @let holds = value.is_some_and(|v| q.min.is_none_or(|m| v >= m) && q.max.is_none_or(|m| v <= m));
                                @if let Some(m) = q.min { "≥ " (fmt(m)) " " }
                                @if let Some(m) = q.max { "≤ " (fmt(m)) " " }
                                @if holds { span.badge.ok { "met" } } @else { span.badge.bad { "not met" } }
                            } @else { span.muted { "–" } }
                        }
                        td { @if let Some(d) = rule {
                            (fmt(d.points)) " per unit above " (fmt(d.free))
                            @if let Some(m) = d.max_points { " (at most " (fmt(m)) ")" }
                        } }
                        td.num { @if applied > 0.0 { "−" (format!("{applied:.1}")) } @else { "0" } }
                    }
                }
                @for d in &level.relative {
                    @let value = metric_value(&r.metrics, &d.metric);
                    @let applied = r.grade.deductions.iter().find(|a| a.metric == d.metric && a.relative.is_some());
                    tr.relative {
                        td { (metric_label(&d.metric).unwrap_or(&d.metric)) }
                        td.num { (value.map_or("–".into(), fmt)) }
                        td { span.muted { "–" } }
                        td { (fmt(d.points)) " per unit above the expert mean + " (fmt(d.spreads)) " spread" @if d.spreads != 1.0 { "s" }
                            @if let Some(m) = d.max_points { " (at most " (fmt(m)) ")" }
                            @if let Some(a) = applied { @if let (Some(free), Some(rel)) = (a.free, a.relative) {
                                br; span.muted { "= " (fmt(rel.mean)) " + " (fmt(d.spreads)) " × " (fmt(rel.spread)) " = " (fmt(free)) }
                            } }
                        }
                        td.num { @match applied { Some(a) => { "−" (format!("{:.1}", a.points)) }, None => "0" } }
                    }
                }
                tr { th { "Score" } td.num { strong { (format!("{:.1}", r.grade.score)) } } td colspan="3" { "pass at ≥ " (fmt(level.pass_score)) " with every requirement met" } }
            }
        }
    }
}

fn review_block(review: &serde_json::Value) -> Markup {
    let empty = Vec::new();
    let comments = review["comments"].as_array().unwrap_or(&empty);
    let overrides = review["overrides"].as_array().unwrap_or(&empty);
    let s = |v: &serde_json::Value| v.as_str().unwrap_or_default().to_string();
    html! {
        @if comments.is_empty() && overrides.is_empty() { p.muted #review { "No comments or overrides." } }
        @else {
            ul #review {
                @for (n, c) in comments.iter().enumerate() { li.comment {
                    @if let Some(t) = c["at_s"].as_f64() { span.badge.muted.moment title="marked on the charts" { "[" (n + 1) "] at " (format!("{t:.2} s")) } " " }
                    strong { (s(&c["author"])) } " (" (short_time(&s(&c["at"]))) "): " (s(&c["body"])) } }
                @for o in overrides { li.override {
                    strong { (s(&o["author"])) } " (" (short_time(&s(&o["at"]))) ") overrode the grade: "
                    (o["score"].as_f64().map_or("?".into(), |v| format!("{v:.1}"))) ", "
                    (if o["passed"].as_bool() == Some(true) { "passed" } else { "failed" })
                    " — reason: " em { (s(&o["reason"])) }
                } }
            }
        }
    }
}

fn review_forms(v: &Viewer, id: &str, duration_s: f64) -> Markup {
    html! {
        div.grid2.noprint {
            form #comment-form method="post" action={ "/sessions/" (id) "/comment" } {
                (csrf_field(v))
                label { "Comment for the trainee" textarea name="body" rows="3" cols="50" required {} }
                label { "At a moment (seconds into the session, optional; marked on the charts)"
                    input type="number" name="at_s" min="0" max=(format!("{:.3}", duration_s)) step="0.01"; }
                p { button.primary type="submit" { "Add comment" } }
            }
            form #override-form method="post" action={ "/sessions/" (id) "/override" } {
                (csrf_field(v))
                div.inline {
                    label { "New score (0–100)" input type="number" name="score" min="0" max="100" step="0.1" required; }
                    label { "Result" select name="passed" { option value="true" { "passed" } option value="false" { "failed" } } }
                }
                label { "Reason (required, kept in the audit log)" textarea name="reason" rows="2" cols="50" required {} }
                p { button.primary type="submit" { "Override the grade" } }
            }
        }
        @if v.role() == Role::Admin {
            form #delete-form.noprint method="post" action={ "/sessions/" (id) "/delete" } {
                (csrf_field(v))
                label.check {
                    input type="checkbox" name="confirm" value="yes" required;
                    " Delete this session for good: its file, score, comments and overrides (audited)"
                }
                p { button type="submit" { "Delete the session" } }
            }
        }
    }
}

#[derive(serde::Deserialize)]
pub struct DeleteForm {
    csrf: String,
    #[serde(default)]
    confirm: String,
}

/// POST /sessions/{id}/delete (admins, with the confirmation box ticked).
pub async fn delete(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    Form(f): Form<DeleteForm>,
) -> Result<Redirect, PageError> {
    check_csrf(&v, &f.csrf)?;
    if f.confirm != "yes" {
        return Err(fail(StatusCode::BAD_REQUEST, "tick the box to confirm the deletion"));
    }
    stylet_service::api::remove_session(&s, &v.user, &id).await?;
    Ok(Redirect::to("/sessions"))
}

#[derive(serde::Deserialize)]
pub struct CommentForm {
    csrf: String,
    body: String,
    /// Seconds into the session (empty: about the whole session).
    #[serde(default)]
    at_s: String,
}

pub async fn comment(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    Form(f): Form<CommentForm>,
) -> Result<Redirect, PageError> {
    check_csrf(&v, &f.csrf)?;
    let text = check_comment(&f.body)?;
    let at_s = match f.at_s.trim() {
        "" => None,
        t => Some(
            t.parse::<f64>()
                .map_err(|_| fail(StatusCode::BAD_REQUEST, format!("'{t}' is not a time in seconds")))?,
        ),
    };
    let row = visible_session(&s, &v, &id).await?;
    let at_s = check_comment_time(at_s, row.duration_s)?;
    reviewable(&s, &v.user, &id).await?;
    s.store.add_comment(&id, &v.user, text, at_s).await?;
    Ok(Redirect::to(&format!("/sessions/{id}#review")))
}

#[derive(serde::Deserialize)]
pub struct OverrideForm {
    csrf: String,
    score: String,
    passed: String,
    reason: String,
}

pub async fn override_grade(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    Form(f): Form<OverrideForm>,
) -> Result<Redirect, PageError> {
    check_csrf(&v, &f.csrf)?;
    let score: f64 = f
        .score
        .trim()
        .parse()
        .map_err(|_| fail(StatusCode::BAD_REQUEST, format!("'{}' is not a score", f.score)))?;
    let passed = match f.passed.as_str() {
        "true" => true,
        "false" => false,
        other => {
            return Err(fail(
                StatusCode::BAD_REQUEST,
                format!("result '{other}' is neither passed nor failed"),
            ));
        }
    };
    let reason = check_override(score, &f.reason)?;
    reviewable(&s, &v.user, &id).await?;
    s.store.override_grade(&id, &v.user, score, passed, reason).await?;
    Ok(Redirect::to(&format!("/sessions/{id}#grade")))
}

/// `GET /sessions/{id}/file`: the session file as uploaded.
pub async fn file(State(s): State<Arc<AppState>>, v: Viewer, Path(id): Path<String>) -> Result<Response, PageError> {
    let row = visible_session(&s, &v, &id).await?;
    let cannot_read = |e: &dyn std::fmt::Display| {
        tracing::error!(error = %e, session = %id, "stored session file missing");
        fail(StatusCode::INTERNAL_SERVER_ERROR, "the stored file cannot be read")
    };
    let path = s.session_copy(&row.file_sha256).await.map_err(|e| cannot_read(&e))?;
    let bytes = tokio::fs::read(path).await.map_err(|e| cannot_read(&e))?;
    let safe = |t: &str| -> String {
        t.chars()
            .map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' })
            .collect()
    };
    let name = format!(
        "{}-{}-{}.mcap",
        safe(&row.trainee),
        safe(&row.scenario),
        safe(row.uploaded_at.get(..10).unwrap_or("session"))
    );
    Ok((
        [
            (header::CONTENT_TYPE, "application/octet-stream".to_string()),
            (header::CONTENT_DISPOSITION, format!("attachment; filename=\"{name}\"")),
        ],
        bytes,
    )
        .into_response())
}

/// `GET /sessions/{id}/slices.png`: the tip path over CT slices.
pub async fn slices(State(s): State<Arc<AppState>>, v: Viewer, Path(id): Path<String>) -> Result<Response, PageError> {
    let row = visible_session(&s, &v, &id).await?;
    require_scored(&row)?;
    let title = format!("{} — {} ({}), tip path", row.trainee, row.scenario, row.difficulty);
    let corridor = crate::player::overview::expert_corridor(&s, &v.user, &row.atlas_hash, &row.scenario).await?;
    figure_response(&s, &row, Figure::TipPath, &title, corridor).await
}

/// `GET /sessions/{id}/hits/{n}/slices.png`: axial and coronal slices through the point where the
/// tip first touched the `n`th risk structure (1-based, as listed on the review), marked.
pub async fn hit_slices(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path((id, n)): Path<(String, String)>,
) -> Result<Response, PageError> {
    let row = visible_session(&s, &v, &id).await?;
    require_scored(&row)?;
    let n: usize = n
        .parse()
        .ok()
        .filter(|n| (1..=1000).contains(n))
        .ok_or_else(|| fail(StatusCode::NOT_FOUND, format!("no risk hit {n}")))?;
    let title = format!("{} — {} ({}), risk hit {n}", row.trainee, row.scenario, row.difficulty);
    figure_response(&s, &row, Figure::Hit(n - 1), &title, (None, String::new())).await
}

async fn figure_response(
    s: &AppState,
    row: &SessionRow,
    figure: Figure,
    title: &str,
    corridor: (Option<Arc<stylet_render::corridor::Corridor>>, String),
) -> Result<Response, PageError> {
    let report: ScoreReport = row
        .score
        .clone()
        .and_then(|r| serde_json::from_value(r).ok())
        .ok_or_else(|| {
            fail(
                StatusCode::INTERNAL_SERVER_ERROR,
                "the stored score report cannot be read",
            )
        })?;
    let png = crate::figures::session_figure(s, &row.file_sha256, &row.atlas_hash, &report, figure, title, corridor)
        .await
        .map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?
        .ok_or_else(|| fail(StatusCode::NOT_FOUND, "the session has no such risk hit"))?;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "private, max-age=3600"),
        ],
        png,
    )
        .into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stored score report (failed at expert level, one X-ray shot, replay verified).
    fn report() -> ScoreReport {
        serde_json::from_str(include_str!("../../../service/tests/data/report.json")).unwrap()
    }

    #[test]
    fn the_consequences_of_a_wrong_puncture_are_listed_in_words() {
        let mut r = report();
        assert_eq!(consequence_table(&r).into_string(), "", "none, no table");
        r.metrics.consequences = vec![stylet_scoring::consequences::ConsequenceRecord {
            kind: stylet_scoring::consequences::ConsequenceKind::Haematoma,
            structure: "portal vein".into(),
            label: 11,
            punctured_s: 7.62,
            began_s: 7.63,
            volume_ml: 16.1,
        }];
        let html = consequence_table(&r).into_string();
        assert!(html.contains("haematoma") && html.contains("portal vein"), "{html}");
        assert!(html.contains("7.62") && html.contains("16.1"), "{html}");
    }

    #[test]
    fn the_skill_estimate_is_shown_beside_the_grade_in_words() {
        let mut r = report();
        let plain = grade_block(&r, &serde_json::json!({}), 1000, false).into_string();
        assert!(!plain.contains("id=\"skill\""), "no estimate, no card");
        r.skill = Some(stylet_scoring::benchmark::SkillEstimate {
            experts: 4,
            z_mean: 1.3,
            metrics: vec![
                stylet_scoring::benchmark::MetricZ {
                    metric: "time_total_s".into(),
                    z: 3.0,
                },
                stylet_scoring::benchmark::MetricZ {
                    metric: "attempts".into(),
                    z: -0.5,
                },
            ],
        });
        let html = grade_block(&r, &serde_json::json!({}), 1000, false).into_string();
        assert!(html.contains("id=\"skill\"") && html.contains("+1.3"), "{html}");
        assert!(
            html.contains("2 metrics") && html.contains("4 expert references"),
            "{html}"
        );
        assert!(
            html.contains("total time +3.0") && !html.contains("attempts -0.5"),
            "{html}"
        );
        assert!(!html.contains("time_total_s"), "no identifier in the page: {html}");
    }

    #[test]
    fn the_replay_card_speaks_in_seconds_not_ticks_or_digests() {
        let mut r = report();
        r.divergence = Some(stylet_scoring::Divergence {
            tick: 4304,
            stream: "ticks.force_n".into(),
            recorded: "1.0".into(),
            replayed: "1.1".into(),
        });
        let html = grade_block(&r, &serde_json::json!({}), 1000, false).into_string();
        assert!(
            html.contains("4.30 s") && html.contains("force on the needle"),
            "{html}"
        );
        for jargon in ["tick", "digest", "ticks.force_n", "Technical details"] {
            assert!(!html.contains(jargon), "{jargon} in {html}");
        }
        // Reviewers also get the replay's figures, still without jargon.
        let staff = grade_block(&r, &serde_json::json!({}), 1000, true).into_string();
        assert!(
            staff.contains("Technical details") && staff.contains("state checks"),
            "{staff}"
        );
        for jargon in ["tick", "digest"] {
            assert!(!staff.contains(jargon), "{jargon} in {staff}");
        }
    }

    #[test]
    fn a_divergence_names_what_differed_in_words() {
        let d = |stream: &str| stylet_scoring::Divergence {
            tick: 1500,
            stream: stream.into(),
            recorded: String::new(),
            replayed: String::new(),
        };
        assert_eq!(
            divergence_text(&d("ticks.inserted_mm"), 1000),
            "The replay first differed from the recording at 1.50 s, in the insertion depth."
        );
        assert!(divergence_text(&d("digests"), 1000).ends_with("in the simulation's state."));
        // A rate of 0 (an unreadable header) does not divide by zero.
        assert!(divergence_text(&d("ticks"), 0).contains("1500.00 s"));
    }

    #[test]
    fn one_x_ray_shot_is_one_shot() {
        let r = report();
        assert_eq!(r.metrics.xray_shots, 1);
        let html = other_metrics(&r).into_string();
        assert!(html.contains("1 X-ray shot<") && !html.contains("1 shots"), "{html}");
    }
}
