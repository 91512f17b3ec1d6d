//! Curriculum reports. `GET /reports`: pick a cohort and a date range for the printable report,
//! or export the sessions CSV (columns in docs/api.md). `GET /reports/cohort?cohort=…&from=…&to=…`:
//! the printable report of one cohort over a date range: totals, pass rate per difficulty per
//! calendar week, results per exercise, why sessions failed, per trainee and per trainee and
//! difficulty. `GET /reports/cohort.pdf?…`: the same report as a PDF made on the server.

use std::sync::Arc;

use axum::extract::{Query, State};
use axum::http::{StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use maud::{Markup, PreEscaped, html};
use stylet_scoring::reasons::metric_label;
use stylet_service::AppState;
use stylet_service::api::ListQuery;
use stylet_service::store::{FailureBreakdown, FailureCause, ReportLine, Role, ScorePoint, TraineeSummary};

use crate::auth::{PageError, Viewer, encode_query, fail};
use crate::charts::sparkline;
use crate::layout::{count, page, score_text, short_time};
use crate::pages::cohort::{SPARK_POINTS, visible_cohort};
use crate::pages::sessions::filter_query;
use crate::pdf::{Col, Doc, PercentChart};
use crate::trends::{
    TREND_TITLE, TREND_X_LABEL, TREND_Y_LABEL, Trends, date_from_days, level_rgb, week_ticks, week_x_range,
};

pub async fn index(State(s): State<Arc<AppState>>, v: Viewer) -> Result<Html<String>, PageError> {
    if v.role() == Role::Trainee {
        return Err(fail(
            StatusCode::FORBIDDEN,
            "reports are for instructors and curriculum staff",
        ));
    }
    let cohorts = s.store.cohorts_for(&v.user).await?;
    Ok(page(
        "Reports",
        Some(&v),
        html! {
            h1 { "Reports" }
            h2 { "Cohort report" }
            p { "Totals, pass rate per difficulty per week, results per exercise, why sessions failed, and each trainee's results. Shown as a printable page, or downloaded as a PDF." }
            form.inline #report-form method="get" action="/reports/cohort" {
                label { "Cohort" select name="cohort" required { @for c in &cohorts { option value=(c.name) { (c.name) } } } }
                label { "From" input type="date" name="from"; }
                label { "To" input type="date" name="to"; }
                button.primary type="submit" { "Show report" }
                button type="submit" formaction="/reports/cohort.pdf" { "Download PDF" }
            }
            h2 { "Sessions CSV export" }
            p { "One row per session you may see, oldest first; the columns are described in the documentation (docs/api.md, \"Sessions CSV\")." }
            form.inline #export-form method="get" action="/api/export/sessions.csv" {
                label { "Cohort" select name="cohort" { option value="" { "all" } @for c in &cohorts { option value=(c.name) { (c.name) } } } }
                label { "From" input type="date" name="from"; }
                label { "To" input type="date" name="to"; }
                button type="submit" { "Download CSV" }
            }
            p { a #export-csv href="/api/export/sessions.csv" { "All sessions as CSV" } }
        },
    ))
}

/// Everything a cohort report shows (the page and the PDF show the same numbers).
pub struct CohortReport {
    pub name: String,
    /// "2026-09-01 to 2026-11-30", "all dates", …
    pub range: String,
    /// `YYYY-MM-DD HH:MM` (UTC).
    pub generated: String,
    pub generated_by: String,
    pub trainees: Vec<TraineeSummary>,
    pub lines: Vec<ReportLine>,
    pub recent: Vec<ScorePoint>,
    pub sessions: i64,
    pub scored: i64,
    /// Scored sessions that could not be graded (no pass, no fail).
    pub not_gradeable: i64,
    pub passed: i64,
    pub mean_score: Option<f64>,
    pub risk_hits: i64,
    pub trends: Trends,
    pub failures: FailureBreakdown,
}

impl CohortReport {
    /// Passed among the gradeable scored sessions.
    pub fn pass_rate(&self) -> String {
        pct(self.passed, self.scored - self.not_gradeable)
    }
}

/// "48 %", or "–" when there is nothing to divide by.
/// A mean skill estimate against the experts: signed, one decimal ("+1.3"); "–" without one.
pub fn skill_text(z: Option<f64>) -> String {
    z.map_or("–".into(), |z| format!("{z:+.1}"))
}

pub fn pct(a: i64, b: i64) -> String {
    if b > 0 {
        format!("{:.0} %", 100.0 * a as f64 / b as f64)
    } else {
        "–".into()
    }
}

/// Why sessions failed, in words for people (never a metric identifier).
pub fn cause_text(cause: &FailureCause) -> String {
    let label = |m: &str| metric_label(m).unwrap_or("another requirement");
    match cause {
        FailureCause::Requirement(m) => format!("requirement not met: {}", label(m)),
        FailureCause::BelowPassMark(Some(m)) => {
            format!("score below the pass mark (most points lost on {})", label(m))
        }
        FailureCause::BelowPassMark(None) => "score below the pass mark".into(),
        FailureCause::Override => "failed by an instructor's override".into(),
    }
}

async fn gather(s: &AppState, v: &Viewer, q: &ListQuery) -> Result<CohortReport, PageError> {
    let name = q
        .cohort
        .clone()
        .filter(|c| !c.is_empty())
        .ok_or_else(|| fail(StatusCode::BAD_REQUEST, "choose a cohort"))?;
    let cohort_id = visible_cohort(s, v, &name).await?;
    let filter = q.filter(s).await?;
    let lines = s.store.cohort_report(&cohort_id, &filter).await?;
    let trainees = s.store.cohort_summary(&cohort_id, &filter).await?;
    let recent = s.store.recent_scores(&cohort_id, &filter, SPARK_POINTS).await?;
    let days = s.store.cohort_day_counts(&cohort_id, &filter).await?;
    let failures = s.store.cohort_failures(&cohort_id, &filter).await?;
    let trends = Trends::from_days(&days);
    let sessions: i64 = trainees.iter().map(|t| t.sessions).sum();
    let scored: i64 = trainees.iter().map(|t| t.scored).sum();
    let passed: i64 = trainees.iter().map(|t| t.passed).sum();
    let weighted: f64 = lines
        .iter()
        .filter_map(|l| l.mean_score.map(|m| m * l.scored as f64))
        .sum();
    let range = match (
        q.from.as_deref().filter(|d| !d.is_empty()),
        q.to.as_deref().filter(|d| !d.is_empty()),
    ) {
        (Some(a), Some(b)) => format!("{a} to {b}"),
        (Some(a), None) => format!("from {a}"),
        (None, Some(b)) => format!("until {b}"),
        (None, None) => "all dates".to_string(),
    };
    Ok(CohortReport {
        name,
        range,
        generated: short_time(&humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string()),
        generated_by: v.user.username.clone(),
        mean_score: (scored > 0).then(|| weighted / scored as f64),
        risk_hits: lines.iter().map(|l| l.risk_hits).sum(),
        not_gradeable: trends.not_gradeable(),
        trainees,
        lines,
        recent,
        sessions,
        scored,
        passed,
        trends,
        failures,
    })
}

const NOTE: &str = "Scores are final grades (an instructor's override where there is one); dates are upload dates (UTC). \
    Pass rates count passed and failed sessions only: sessions that could not be graded (a recording cut or damaged) are \
    counted on their own, and palpation, ultrasound-survey and drainage exercises are reported per exercise, not as punctures.";

fn trends_section(r: &CohortReport) -> Result<Markup, PageError> {
    let chart = crate::trends::trend_chart_svg(&r.trends)
        .map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    Ok(html! {
        h2 { "Pass rate per week" }
        @match chart {
            Some(svg) => div.chart-box #trend-chart { (PreEscaped(svg)) },
            None => p.muted { "No graded puncture sessions in this range." },
        }
        @if !r.trends.weeks.is_empty() {
            details {
                summary { "The numbers per week" }
                div.scroll { table #report-weeks {
                    thead { tr { th { "Week of (Monday)" } th { "Difficulty" } th.num { "Passed / graded" } th.num { "Pass rate" } } }
                    tbody { @for w in r.trends.weeks.iter().rev() { tr {
                        td { (date_from_days(w.week)) } td { (w.difficulty) }
                        td.num { (w.passed) " / " (w.graded) } td.num { (pct(w.passed, w.graded)) }
                    } } }
                } }
            }
        }
        h2 { "By exercise" }
        @if r.trends.exercises.is_empty() { p.muted { "No scored sessions in this range." } }
        @else {
            div.scroll { table #report-exercises {
                thead { tr { th { "Exercise" } th.num { "Scored" } th.num { "Passed" } th.num { "Failed" } th.num { "Not gradeable" } th.num { "Pass rate" } } }
                tbody { @for e in &r.trends.exercises { tr {
                    td { (e.exercise.label()) } td.num { (e.scored) } td.num { (e.passed) } td.num { (e.failed()) }
                    td.num { (e.not_gradeable) } td.num { (pct(e.passed, e.scored - e.not_gradeable)) }
                } } }
            } }
        }
        h2 { "Why sessions failed" }
        @if r.failures.failed == 0 { p.muted { "No failed sessions in this range." } }
        @else {
            p.muted {
                (count(r.failures.failed, "failed session", "failed sessions"))
                @if r.failures.examined < r.failures.failed { "; the reasons of the latest " (r.failures.examined) " are counted" }
                ". A session that missed two requirements counts under both."
            }
            div.scroll { table #report-failures {
                thead { tr { th { "Exercise" } th { "Reason" } th.num { "Sessions" } th.num { "Share of failed" } } }
                tbody { @for (exercise, cause, n) in &r.failures.causes { tr {
                    td { (exercise.label()) } td { (cause_text(cause)) } td.num { (n) } td.num { (pct(*n, r.failures.examined)) }
                } } }
            } }
        }
    })
}

pub async fn cohort_report(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Query(q): Query<ListQuery>,
) -> Result<Html<String>, PageError> {
    let r = gather(&s, &v, &q).await?;
    let trends = trends_section(&r)?;
    let name = &r.name;
    Ok(page(
        &format!("Report — cohort {name}"),
        Some(&v),
        html! {
            h1 #report-title { "Cohort " (name) " — training report, " (r.range) }
            p.muted { "Generated " (r.generated) " UTC by " (r.generated_by) ". " (NOTE) }
            p.noprint {
                button type="button" data-action="print" hidden { "Print" } " "
                a #report-pdf href={ "/reports/cohort.pdf?" (filter_query(&q)) } { "Download as PDF" } " · "
                a href={ "/api/export/sessions.csv?" (filter_query(&q)) } { "These sessions as CSV" }
            }
            div.cards {
                div.card { div.muted { "Trainees" } div.big { (r.trainees.len()) } }
                div.card { div.muted { "Sessions (scored)" } div.big { (r.sessions) " (" (r.scored) ")" } }
                div.card { div.muted { "Pass rate" } div.big #report-pass-rate { (r.pass_rate()) } }
                div.card { div.muted { "Not gradeable" } div.big { (r.not_gradeable) } }
                div.card { div.muted { "Mean score" } div.big { (score_text(r.mean_score)) } }
                div.card { div.muted { "Risk-structure hits" } div.big { (r.risk_hits) } }
            }
            (trends)
            h2 { "Trainees" }
            div.scroll { table #report-trainees {
                thead { tr { th { "Trainee" } th.num { "Sessions" } th.num { "Passed / scored" } th.num { "Pass rate" } th.num { "Mean score" } th { "Latest scores" } } }
                tbody { @for t in &r.trainees {
                    @let points: Vec<(f64, bool)> = r.recent.iter().filter(|p| p.trainee == t.username).map(|p| (p.score, p.passed)).collect();
                    tr {
                        td { (t.username) } td.num { (t.sessions) } td.num { (t.passed) " / " (t.scored) }
                        td.num { (pct(t.passed, t.scored)) } td.num { (score_text(t.mean_score)) }
                        td { (PreEscaped(sparkline(&points))) }
                    }
                } }
            } }
            h2 { "By trainee and difficulty" }
            @if r.lines.is_empty() { p.muted { "No sessions in this range." } }
            @else {
                div.scroll { table #report-lines {
                    thead { tr {
                        th { "Trainee" } th { "Difficulty" } th.num { "Sessions" } th.num { "Passed / scored" }
                        th.num { "Mean score" } th.num { "Best score" } th.num { "Mean attempts" } th.num { "Risk hits" } th.num title="Mean skill estimate against the scenario's experts: their spreads from the expert mean, 0 their level, + worse" { "Skill vs experts" } th { "First – last upload" }
                    } }
                    tbody { @for l in &r.lines { tr {
                        td { (l.trainee) } td { (l.difficulty) } td.num { (l.sessions) } td.num { (l.passed) " / " (l.scored) }
                        td.num { (score_text(l.mean_score)) } td.num { (score_text(l.best_score)) }
                        td.num { (l.mean_attempts.map_or("–".into(), |a| format!("{a:.1}"))) } td.num { (l.risk_hits) }
                        td.num { (skill_text(l.mean_skill_z)) }
                        td { (l.first_upload.as_deref().map(short_time).unwrap_or_default()) " – " (l.last_upload.as_deref().map(short_time).unwrap_or_default()) }
                    } } }
                } }
            }
            p.noprint { a href={ "/cohorts/" (encode_query(name)) } { "Cohort view →" } }
        },
    ))
}

/// `GET /reports/cohort.pdf?cohort=…&from=…&to=…`: the cohort report as a PDF (the same
/// authorization and numbers as the page), made on the server.
pub async fn cohort_report_pdf(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Query(q): Query<ListQuery>,
) -> Result<Response, PageError> {
    let r = gather(&s, &v, &q).await?;
    let bytes = tokio::task::spawn_blocking(move || report_pdf(&r))
        .await
        .map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    let safe: String = q
        .cohort
        .unwrap_or_default()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .take(64)
        .collect();
    Ok((
        [
            (header::CONTENT_TYPE, "application/pdf".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"stylet-cohort-{safe}-report.pdf\""),
            ),
            (header::CACHE_CONTROL, "private, no-store".to_string()),
        ],
        bytes,
    )
        .into_response())
}

/// The report laid out on A4 pages.
pub fn report_pdf(r: &CohortReport) -> Vec<u8> {
    let title = format!("Cohort {} — training report, {}", r.name, r.range);
    let mut d = Doc::new(&title);
    d.title(&title);
    d.paragraph(
        &format!("Generated {} UTC by {}. {NOTE}", r.generated, r.generated_by),
        8.5,
    );
    d.heading("Totals");
    let totals = vec![vec![
        r.trainees.len().to_string(),
        r.sessions.to_string(),
        r.scored.to_string(),
        r.pass_rate(),
        r.not_gradeable.to_string(),
        score_text(r.mean_score),
        r.risk_hits.to_string(),
    ]];
    let c = |title: &'static str, width: f32, right: bool| Col { title, width, right };
    d.table(
        &[
            c("Trainees", 60.0, true),
            c("Sessions", 60.0, true),
            c("Scored", 60.0, true),
            c("Pass rate", 70.0, true),
            c("Not gradeable", 80.0, true),
            c("Mean score", 75.0, true),
            c("Risk-structure hits", 100.0, true),
        ],
        &totals,
    );
    d.heading("Pass rate per week");
    let series = r.trends.series();
    if series.is_empty() {
        d.paragraph("No graded puncture sessions in this range.", 9.0);
    } else {
        let (lo, hi) = series
            .iter()
            .flat_map(|(_, p)| p.iter().map(|(w, _)| *w))
            .fold((i64::MAX, i64::MIN), |(a, b), w| (a.min(w), b.max(w)));
        d.percent_chart(&PercentChart {
            title: TREND_TITLE.into(),
            x_label: TREND_X_LABEL.into(),
            y_label: TREND_Y_LABEL.into(),
            x_range: week_x_range(lo, hi),
            x_ticks: week_ticks(lo, hi)
                .into_iter()
                .map(|w| (w, date_from_days(w as i64)))
                .collect(),
            series: series
                .iter()
                .map(|(level, pts)| {
                    (
                        level.to_string(),
                        level_rgb(*level),
                        pts.iter().map(|(w, p)| (*w as f64, *p)).collect(),
                    )
                })
                .collect(),
        });
        let rows: Vec<Vec<String>> = r
            .trends
            .weeks
            .iter()
            .map(|w| {
                vec![
                    date_from_days(w.week),
                    w.difficulty.clone(),
                    format!("{} / {}", w.passed, w.graded),
                    pct(w.passed, w.graded),
                ]
            })
            .collect();
        d.table(
            &[
                c("Week of (Monday)", 110.0, false),
                c("Difficulty", 90.0, false),
                c("Passed / graded", 100.0, true),
                c("Pass rate", 70.0, true),
            ],
            &rows,
        );
    }
    d.heading("By exercise");
    let rows: Vec<Vec<String>> = r
        .trends
        .exercises
        .iter()
        .map(|e| {
            vec![
                e.exercise.label().to_string(),
                e.scored.to_string(),
                e.passed.to_string(),
                e.failed().to_string(),
                e.not_gradeable.to_string(),
                pct(e.passed, e.scored - e.not_gradeable),
            ]
        })
        .collect();
    d.table(
        &[
            c("Exercise", 120.0, false),
            c("Scored", 60.0, true),
            c("Passed", 60.0, true),
            c("Failed", 60.0, true),
            c("Not gradeable", 80.0, true),
            c("Pass rate", 70.0, true),
        ],
        &rows,
    );
    d.heading("Why sessions failed");
    if r.failures.failed == 0 {
        d.paragraph("No failed sessions in this range.", 9.0);
    } else {
        let mut note = count(r.failures.failed, "failed session", "failed sessions");
        if r.failures.examined < r.failures.failed {
            note += &format!("; the reasons of the latest {} are counted", r.failures.examined);
        }
        note += ". A session that missed two requirements counts under both.";
        d.paragraph(&note, 8.5);
        let rows: Vec<Vec<String>> = r
            .failures
            .causes
            .iter()
            .map(|(e, cause, n)| {
                vec![
                    e.label().to_string(),
                    cause_text(cause),
                    n.to_string(),
                    pct(*n, r.failures.examined),
                ]
            })
            .collect();
        d.table(
            &[
                c("Exercise", 95.0, false),
                c("Reason", 290.0, false),
                c("Sessions", 60.0, true),
                c("Share of failed", 66.0, true),
            ],
            &rows,
        );
    }
    d.heading("Trainees");
    let rows: Vec<Vec<String>> = r
        .trainees
        .iter()
        .map(|t| {
            vec![
                t.username.clone(),
                t.sessions.to_string(),
                format!("{} / {}", t.passed, t.scored),
                pct(t.passed, t.scored),
                score_text(t.mean_score),
                t.last_upload.as_deref().map(short_time).unwrap_or_else(|| "–".into()),
            ]
        })
        .collect();
    d.table(
        &[
            c("Trainee", 130.0, false),
            c("Sessions", 60.0, true),
            c("Passed / scored", 90.0, true),
            c("Pass rate", 65.0, true),
            c("Mean score", 70.0, true),
            c("Last upload (UTC)", 96.0, false),
        ],
        &rows,
    );
    d.heading("By trainee and difficulty");
    let rows: Vec<Vec<String>> = r
        .lines
        .iter()
        .map(|l| {
            vec![
                l.trainee.clone(),
                l.difficulty.clone(),
                l.sessions.to_string(),
                format!("{} / {}", l.passed, l.scored),
                score_text(l.mean_score),
                score_text(l.best_score),
                l.mean_attempts.map_or("–".into(), |a| format!("{a:.1}")),
                l.risk_hits.to_string(),
                skill_text(l.mean_skill_z),
            ]
        })
        .collect();
    d.table(
        &[
            c("Trainee", 87.0, false),
            c("Difficulty", 52.0, false),
            c("Sessions", 44.0, true),
            c("Passed / scored", 74.0, true),
            c("Mean score", 55.0, true),
            c("Best score", 50.0, true),
            c("Mean attempts", 68.0, true),
            c("Risk hits", 41.0, true),
            // The mean skill estimate against the experts (docs/metrics.md "Skill estimate").
            c("Skill (z)", 40.0, true),
        ],
        &rows,
    );
    d.finish()
}
