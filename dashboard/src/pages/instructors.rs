//! Instructors' tools: `GET /review-queue`, the sessions still to review (risk hits, failures,
//! not gradeable, or simply not yet commented), and `GET /trainees/{username}`, one trainee's
//! progress over calendar time (scores per difficulty, outcomes with their reasons, risk hits).

use std::sync::Arc;

use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::Html;
use maud::{Markup, PreEscaped, html};
use plotters::prelude::*;
use stylet_render::fonts::{SANS, ensure_fonts};
use stylet_scoring::{Difficulty, Exercise, Outcome};
use stylet_service::AppState;
use stylet_service::store::{
    DatedScore, LevelTotals, QUEUE_PAGE, QueueScope, ReviewLine, Role, SessionStatus, TraineeProgress,
};

use crate::auth::{PageError, Viewer, encode_query, fail};
use crate::layout::{count, page, pager, reason_cell, score_text, short_reason, short_time};
use crate::plot::ChartError;
use crate::trends::{date_from_days, days_from_date, draw_level_lines, labelled_svg};

/// `?only=flagged&page=N`.
#[derive(Debug, Default, serde::Deserialize)]
pub struct QueueQuery {
    /// `flagged`: only risk hits, failures and sessions that could not be graded or scored.
    pub only: Option<String>,
    pub page: Option<i64>,
}

/// The result of a line in words: passed / failed / not gradeable (an override's grade when
/// overridden), or the scoring state.
pub fn outcome_badge(l: &ReviewLine) -> Markup {
    html! {
        @if l.status == SessionStatus::Failed {
            span.badge.bad { "scoring failed" }
        } @else if l.status != SessionStatus::Scored {
            span.badge.muted { (l.status) }
        } @else if l.outcome == Some(Outcome::NotGradeable) && !l.overridden {
            span.badge.warn title="the recording is incomplete: no grade is given" { "not gradeable" }
        } @else {
            @match l.passed {
                Some(true) => span.badge.ok { "passed" },
                Some(false) => span.badge.bad { "failed" },
                None => span.badge.muted { "not scored" },
            }
            @if l.overridden { " " span.badge.warn title="grade overridden by an instructor" { "overridden" } }
        }
    }
}

/// What a line practises: the scenario, with the exercise named when it is not a puncture.
fn what(l: &ReviewLine) -> Markup {
    html! {
        (l.scenario)
        @if l.exercise != Exercise::Puncture { " " span.badge.muted { (l.exercise.label()) } }
    }
}

/// Why a line failed, short (the review page has it all): the scoring error's first clause, else
/// the first reason and a link to the others.
fn why(l: &ReviewLine) -> Markup {
    html! {
        @if let Some(e) = l.error.as_deref().filter(|_| l.status == SessionStatus::Failed) {
            div.reason.muted title=(e) { (short_reason(e)) }
        } @else {
            (reason_cell(&l.id, &l.reasons))
        }
    }
}

/// `GET /review-queue`: the viewer's sessions to review, newest first, 50 a page.
pub async fn review_queue(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Query(q): Query<QueueQuery>,
) -> Result<Html<String>, PageError> {
    if !matches!(v.role(), Role::Instructor | Role::Admin) {
        return Err(fail(
            StatusCode::FORBIDDEN,
            "the review queue is for instructors and admins",
        ));
    }
    let scope = match q.only.as_deref().map(str::trim) {
        None | Some("") => QueueScope::All,
        Some("flagged") => QueueScope::Flagged,
        Some(other) => {
            return Err(fail(
                StatusCode::BAD_REQUEST,
                format!("unknown queue filter '{other}' (only=flagged, or nothing for all)"),
            ));
        }
    };
    let page_no = q.page.unwrap_or(1).max(1);
    let (lines, total) = s
        .store
        .review_queue(&v.user, scope, QUEUE_PAGE, (page_no - 1).saturating_mul(QUEUE_PAGE))
        .await?;
    let flagged = scope == QueueScope::Flagged;
    Ok(page(
        "Needs review",
        Some(&v),
        html! {
            h1 { "Needs review" }
            p.muted {
                @if v.role() == Role::Instructor { "Sessions of your cohorts' trainees " } @else { "Sessions " }
                "that nobody has commented on or overridden yet, newest first. A comment or a grade override on the session's review page takes a session off this list."
            }
            form.inline.noprint #queue-filter method="get" action="/review-queue" {
                label.check { input type="checkbox" name="only" value="flagged" checked[flagged]; "only risk hits, failures and sessions that could not be graded" }
                button type="submit" { "Show" }
            }
            @if lines.is_empty() {
                p #queue-empty { "Nothing to review." }
            } @else {
                div.scroll { table #queue {
                    thead { tr {
                        th { "Uploaded (UTC)" } th { "Trainee" } th { "Scenario" } th { "Difficulty" }
                        th.num { "Score" } th { "Result" } th.num { "Risk hits" } th { "In the queue because" } th { "" }
                    } }
                    tbody {
                        @for l in &lines {
                            tr {
                                td { (short_time(&l.uploaded_at)) }
                                td { a href={ "/trainees/" (encode_query(&l.trainee)) } { (l.trainee) } }
                                td { (what(l)) } td { (l.difficulty) }
                                td.num { (score_text(l.score)) }
                                td { (outcome_badge(l)) }
                                td.num { (l.risk_hits.map_or("–".into(), |n| n.to_string())) }
                                td {
                                    @for (k, r) in l.queue_reasons().into_iter().enumerate() {
                                        @if k > 0 { " · " }
                                        span.reason { (r.words()) }
                                    }
                                    @if l.status == SessionStatus::Failed || l.passed == Some(false) || l.outcome == Some(Outcome::NotGradeable) {
                                        (why(l))
                                    }
                                }
                                td { a href={ "/sessions/" (l.id) } { "Review →" } }
                            }
                        }
                    }
                } }
            }
            (pager(if flagged { "only=flagged" } else { "" }, page_no, total, QUEUE_PAGE))
        },
    ))
}

/// `GET /trainees/{username}`: a trainee's progress, for the trainee, their instructors,
/// curriculum staff and admins (anyone else: 404, as for a trainee who does not exist).
pub async fn trainee_progress(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(username): Path<String>,
) -> Result<Html<String>, PageError> {
    let p = s
        .store
        .trainee_progress(&v.user, &username)
        .await?
        .ok_or_else(|| fail(StatusCode::NOT_FOUND, format!("no trainee {username}")))?;
    let own = v.user.id == p.trainee.id;
    let chart = progress_over_time_svg(
        &p.scores,
        &format!("Scores of {} over time (punctures)", p.trainee.username),
    )
    .map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    let punctures: Vec<&LevelTotals> = p.totals.iter().filter(|t| t.exercise == Exercise::Puncture).collect();
    let others: Vec<&LevelTotals> = p.totals.iter().filter(|t| t.exercise != Exercise::Puncture).collect();
    let all_link = if own {
        "/sessions".to_string()
    } else {
        format!("/sessions?trainee={}", encode_query(&p.trainee.username))
    };
    Ok(page(
        &format!("Progress of {}", p.trainee.username),
        Some(&v),
        html! {
            h1 { "Progress — " (p.trainee.username) }
            (cards(&p))
            h2 { "Punctures by difficulty" }
            (totals_table(&punctures, "puncture-totals", false))
            h2 { "Scores over time" }
            @match &chart {
                Some(svg) => div.chart-box #progress-chart { (PreEscaped(svg)) },
                None => p.muted { "No graded puncture yet." },
            }
            p.muted { "One line per difficulty, a dot per graded puncture session (the final grade: an instructor's override when there is one). Palpation and ultrasound exercises are graded on their own metrics and listed below, not drawn here." }
            @if !others.is_empty() {
                h2 { "Other exercises" }
                (totals_table(&others, "exercise-totals", true))
            }
            h2 { "Latest sessions" }
            (recent_table(&p.recent))
            @if p.total_sessions > p.recent.len() as i64 {
                p { a href=(all_link) { "All " (p.total_sessions) " sessions →" } }
            }
            h2 { "Risk-structure hits" }
            @if p.risk_sessions.is_empty() {
                p.muted #risk-sessions { "No risk structure hit." }
            } @else {
                div.scroll { table #risk-sessions {
                    thead { tr { th { "Uploaded (UTC)" } th { "Scenario" } th { "Difficulty" } th { "Structures hit" } th { "Result" } } }
                    tbody {
                        @for r in &p.risk_sessions {
                            tr {
                                td { a href={ "/sessions/" (r.line.id) } { (short_time(&r.line.uploaded_at)) } }
                                td { (what(&r.line)) } td { (r.line.difficulty) }
                                td { @if r.structures.is_empty() { (count(r.line.risk_hits.unwrap_or(0), "hit", "hits")) } @else { (r.structures.join(", ")) } }
                                td { (outcome_badge(&r.line)) }
                            }
                        }
                    }
                } }
            }
        },
    ))
}

fn cards(p: &TraineeProgress) -> Markup {
    let punct = p.totals.iter().filter(|t| t.exercise == Exercise::Puncture);
    let (graded, passed) = punct.fold((0, 0), |(g, ps), t| (g + t.scored, ps + t.passed));
    let risk: i64 = p.totals.iter().map(|t| t.risk_hits).sum();
    html! {
        div.cards {
            div.card { div.muted { "Sessions" } div.big { (p.total_sessions) } }
            div.card { div.muted { "Punctures scored / passed" } div.big { (graded) " / " (passed) } }
            div.card { div.muted { "Risk-structure hits" } div.big { (risk) } }
            @if let Some(last) = p.recent.first() {
                div.card { div.muted { "Last session (UTC)" } div.big { (short_time(&last.uploaded_at).get(..10).unwrap_or("")) } }
            }
        }
    }
}

/// Totals per level; `with_exercise` names the exercise of each line (the non-puncture table).
fn totals_table(totals: &[&LevelTotals], id: &str, with_exercise: bool) -> Markup {
    html! {
        @if totals.is_empty() {
            p.muted { "No sessions yet." }
        } @else {
            div.scroll { table id=(id) {
                thead { tr {
                    @if with_exercise { th { "Exercise" } }
                    th { "Difficulty" } th.num { "Sessions" } th.num { "Scored" } th.num { "Passed" }
                    th.num { "Pass rate" } th.num { "Mean score" } th.num { "Risk hits" }
                } }
                tbody {
                    @for t in totals {
                        tr {
                            @if with_exercise { td { (t.exercise.label()) } }
                            td { (t.difficulty) }
                            td.num { (t.sessions) } td.num { (t.scored) } td.num { (t.passed) }
                            td.num { @if t.scored > 0 { (format!("{:.0} %", 100.0 * t.passed as f64 / t.scored as f64)) } @else { "–" } }
                            td.num { (score_text(t.mean_score)) }
                            td.num { (t.risk_hits) }
                        }
                    }
                }
            } }
        }
    }
}

fn recent_table(lines: &[ReviewLine]) -> Markup {
    html! {
        @if lines.is_empty() {
            p.muted { "No sessions yet." }
        } @else {
            div.scroll { table #recent {
                thead { tr {
                    th { "Uploaded (UTC)" } th { "Scenario" } th { "Difficulty" } th.num { "Score" } th { "Result" }
                    th.num { "Attempts" } th.num { "Risk hits" } th { "Why" }
                } }
                tbody {
                    @for l in lines {
                        tr {
                            td { a href={ "/sessions/" (l.id) } { (short_time(&l.uploaded_at)) } }
                            td { (what(l)) } td { (l.difficulty) }
                            td.num { (score_text(l.score)) }
                            td { (outcome_badge(l)) }
                            td.num { (l.attempts.map_or("–".into(), |n| n.to_string())) }
                            td.num { (l.risk_hits.map_or("–".into(), |n| n.to_string())) }
                            td { (why(l)) }
                        }
                    }
                }
            } }
        }
    }
}

/// Days since 1970-01-01 of an RFC 3339 time, with the time of day as a fraction (sessions of
/// one day side by side, not on top of each other).
fn day_of(rfc3339: &str) -> Option<f64> {
    let day = days_from_date(rfc3339.get(..10)?)?;
    let hms = rfc3339.get(11..19).unwrap_or("00:00:00");
    let mut parts = hms.split(':').map(|p| p.parse::<f64>().unwrap_or(0.0));
    let (h, m, s) = (
        parts.next().unwrap_or(0.0),
        parts.next().unwrap_or(0.0),
        parts.next().unwrap_or(0.0),
    );
    Some(day as f64 + (h * 3600.0 + m * 60.0 + s) / 86_400.0)
}

pub const PROGRESS_X_LABEL: &str = "upload date (UTC)";
pub const PROGRESS_Y_LABEL: &str = "score (0–100)";

/// Scores over calendar time: one line per difficulty with a dot per session, x the upload date
/// with date labels; `None` without a dated score.
pub fn progress_over_time_svg(scores: &[DatedScore], title: &str) -> Result<Option<String>, ChartError> {
    let points: Vec<(f64, &DatedScore)> = scores
        .iter()
        .filter_map(|p| Some((day_of(&p.uploaded_at)?, p)))
        .collect();
    let Some((lo, hi)) = points.iter().map(|(x, _)| *x).fold(None, |acc: Option<(f64, f64)>, x| {
        Some(acc.map_or((x, x), |(a, b)| (a.min(x), b.max(x))))
    }) else {
        return Ok(None);
    };
    ensure_fonts();
    // From the first session's midnight (its date labels the axis) to just after the last
    // session: 3 % of the span on each side, at least 0.15 day, and no date after the last
    // session's day.
    let pad_days = ((hi - lo) * 0.03).max(0.15);
    let (x0, x1) = (lo.floor().min(lo - pad_days) - 0.05, hi + pad_days);
    let last_day = hi.floor();
    let span_days = x1 - x0;
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, crate::charts::CHART_SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let mut c = ChartBuilder::on(&root)
            .caption(title, (SANS, 26))
            .margin(16)
            .x_label_area_size(56)
            .y_label_area_size(72)
            .build_cartesian_2d(x0..x1, 0.0..100.0)?;
        // Whole days only: a date on a tick at midnight, nothing between or after the last day.
        let label = |x: &f64| {
            let d = x.round();
            if (x - d).abs() < 1e-6 && d <= last_day {
                date_from_days(d as i64)
            } else {
                String::new()
            }
        };
        c.configure_mesh()
            .x_label_formatter(&label)
            .x_labels((span_days as usize).clamp(2, 8))
            .x_desc(PROGRESS_X_LABEL)
            .y_desc(PROGRESS_Y_LABEL)
            .axis_desc_style((SANS, 20))
            .label_style((SANS, 16))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()?;
        let lines: Vec<(Difficulty, Vec<(f64, f64)>)> = Difficulty::ALL
            .into_iter()
            .map(|level| {
                let pts = points
                    .iter()
                    .filter(|(_, p)| p.difficulty == level.as_str())
                    .map(|(x, p)| (*x, p.score))
                    .collect();
                (level, pts)
            })
            .filter(|(_, pts): &(Difficulty, Vec<(f64, f64)>)| !pts.is_empty())
            .collect();
        draw_level_lines(&mut c, &lines)?;
        root.present()?;
    }
    Ok(Some(labelled_svg(&out, title)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trends::level_rgb;

    fn texts(svg: &str) -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|s| Some(s.split_once('>')?.1.split_once("</text>")?.0.trim().to_string()))
            .collect()
    }

    fn point(at: &str, level: &str, score: f64) -> DatedScore {
        DatedScore {
            session_id: at.into(),
            uploaded_at: at.into(),
            difficulty: level.into(),
            score,
            passed: score >= 70.0,
        }
    }

    #[test]
    fn the_progress_chart_has_dates_on_x_one_line_per_difficulty_and_a_legend() {
        let svg = progress_over_time_svg(
            &[
                point("2026-11-02T09:00:00.000000Z", "beginner", 40.0),
                point("2026-11-09T10:30:00.000000Z", "beginner", 80.0),
                point("2026-11-20T16:00:00.000000Z", "advanced", 65.0),
            ],
            "Scores of tina over time (punctures)",
        )
        .unwrap()
        .expect("a chart");
        let t = texts(&svg);
        for want in [
            "Scores of tina over time (punctures)",
            PROGRESS_X_LABEL,
            PROGRESS_Y_LABEL,
            "beginner",
            "advanced",
        ] {
            assert!(t.iter().any(|x| x == want), "no {want:?} in {t:?}");
        }
        assert!(!t.iter().any(|x| x == "expert"), "a level without sessions has no line");
        // Dates label the x axis, within the sessions' span.
        let dates: Vec<&String> = t.iter().filter(|x| x.starts_with("2026-11-")).collect();
        assert!(dates.len() >= 2, "{t:?}");
        assert!(
            dates
                .iter()
                .all(|d| d.as_str() >= "2026-11-01" && d.as_str() <= "2026-11-21"),
            "{dates:?}"
        );
        // One line per difficulty in the level's colour.
        let (r, g, b) = level_rgb(Difficulty::Advanced);
        assert!(svg.to_uppercase().contains(&format!("#{r:02X}{g:02X}{b:02X}")));
        assert!(svg.starts_with("<svg class=\"chart\" role=\"img\""));
        assert_eq!(progress_over_time_svg(&[], "x").unwrap(), None);
    }

    fn review_line(status: SessionStatus, error: Option<&str>, reasons: &[&str]) -> ReviewLine {
        ReviewLine {
            id: "s-7".into(),
            trainee: "tina".into(),
            scenario: "success-intercostal".into(),
            difficulty: "beginner".into(),
            status,
            uploaded_at: "2026-11-23T14:05:09Z".into(),
            score: Some(20.0),
            passed: Some(false),
            overridden: false,
            attempts: Some(3),
            risk_hits: Some(1),
            error: error.map(str::to_string),
            exercise: Exercise::Puncture,
            outcome: Some(Outcome::Failed),
            reasons: reasons.iter().map(|r| r.to_string()).collect(),
        }
    }

    #[test]
    fn a_line_says_why_in_one_short_reason_with_a_link_to_the_rest() {
        let l = review_line(
            SessionStatus::Scored,
            None,
            &[
                "The needle entered the right lung at 3.2 s, 4.1 mm deep (pneumothorax risk).",
                "3 attempts: at most 2 allowed.",
                "The target was not reached.",
                "Score 20 is below the pass mark of 60 for beginner: −30 for the right lung, −40 because the target was not reached.",
            ],
        );
        let html = why(&l).into_string();
        assert_eq!(html.matches("class=\"reason").count(), 1, "{html}");
        assert!(
            html.contains(">The needle entered the right lung at 3.2 s, 4.1 mm deep. <"),
            "{html}"
        );
        assert!(
            html.contains("href=\"/sessions/s-7#reasons\"") && html.contains("+3 more"),
            "{html}"
        );
        assert!(!html.contains("3 attempts") && !html.contains("pass mark"), "{html}");
        // A scoring error: its first clause, whole on hover.
        let failed = review_line(
            SessionStatus::Failed,
            Some("the session cannot be replayed: the recording has a gap of 12 ticks at 4.30 s. Record it again."),
            &[],
        );
        let html = why(&failed).into_string();
        assert!(
            html.contains(">the session cannot be replayed: the recording has a gap of 12 ticks at 4.30 s.<"),
            "{html}"
        );
        assert!(!html.contains("more</a>"), "{html}");
    }

    #[test]
    fn the_progress_chart_ends_at_the_last_session() {
        let svg = progress_over_time_svg(&[point("2026-11-02T09:00:00.000000Z", "beginner", 40.0)], "x")
            .unwrap()
            .unwrap();
        let dates: Vec<String> = texts(&svg).into_iter().filter(|t| t.starts_with("2026-")).collect();
        assert!(
            !dates.is_empty() && dates.iter().all(|d| d.as_str() <= "2026-11-02"),
            "{dates:?}"
        );
        // Several weeks: the last date labelled is no later than the last session's day.
        let svg = progress_over_time_svg(
            &[
                point("2026-10-06T09:00:00.000000Z", "beginner", 40.0),
                point("2026-10-20T09:00:00.000000Z", "beginner", 60.0),
                point("2026-11-02T15:00:00.000000Z", "beginner", 80.0),
            ],
            "x",
        )
        .unwrap()
        .unwrap();
        let dates: Vec<String> = texts(&svg).into_iter().filter(|t| t.starts_with("2026-")).collect();
        assert!(
            dates.len() >= 2
                && dates
                    .iter()
                    .all(|d| d.as_str() >= "2026-10-06" && d.as_str() <= "2026-11-02"),
            "{dates:?}"
        );
    }

    #[test]
    fn sessions_of_one_day_lie_side_by_side() {
        let a = day_of("2026-11-02T06:00:00.000000Z").unwrap();
        let b = day_of("2026-11-02T18:00:00.000000Z").unwrap();
        assert!((b - a - 0.5).abs() < 1e-9);
        assert_eq!(
            day_of("2026-11-02T00:00:00Z").unwrap(),
            days_from_date("2026-11-02").unwrap() as f64
        );
        assert_eq!(day_of("garbage"), None);
    }
}
