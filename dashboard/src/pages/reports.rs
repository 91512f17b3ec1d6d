//! Curriculum reports. `GET /reports`: pick a cohort and a date range for the printable report,
//! or export the sessions CSV (columns in docs/api.md). `GET /reports/cohort?cohort=…&from=…&to=…`:
//! the printable report of one cohort over a date range.

use std::sync::Arc;

use axum::extract::{Query, State};
use axum::http::{HeaderMap, StatusCode, Uri};
use axum::response::Html;
use maud::{PreEscaped, html};
use stylet_service::AppState;
use stylet_service::api::ListQuery;

use crate::auth::{PageError, encode_query, fail, viewer};
use crate::charts::sparkline;
use crate::layout::{page, score_text, short_time};
use crate::pages::cohort::{SPARK_POINTS, visible_cohort};
use crate::pages::sessions::filter_query;

pub async fn index(State(s): State<Arc<AppState>>, headers: HeaderMap, uri: Uri) -> Result<Html<String>, PageError> {
    let v = viewer(&s, &headers, &uri).await?;
    if v.role() == "trainee" {
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
            h2 { "Printable cohort report" }
            form.inline #report-form method="get" action="/reports/cohort" {
                label { "Cohort" select name="cohort" required { @for c in &cohorts { option value=(c.name) { (c.name) } } } }
                label { "From" input type="date" name="from"; }
                label { "To" input type="date" name="to"; }
                button.primary type="submit" { "Show report" }
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

pub async fn cohort_report(
    State(s): State<Arc<AppState>>,
    headers: HeaderMap,
    uri: Uri,
    Query(q): Query<ListQuery>,
) -> Result<Html<String>, PageError> {
    let v = viewer(&s, &headers, &uri).await?;
    let name = q
        .cohort
        .clone()
        .filter(|c| !c.is_empty())
        .ok_or_else(|| fail(StatusCode::BAD_REQUEST, "choose a cohort"))?;
    let cohort_id = visible_cohort(&s, &v, &name).await?;
    let filter = q.filter(&s).await?;
    let lines = s.store.cohort_report(&cohort_id, &filter).await?;
    let trainees = s.store.cohort_summary(&cohort_id, &filter).await?;
    let recent = s.store.recent_scores(&cohort_id, &filter, SPARK_POINTS).await?;
    let sessions: i64 = trainees.iter().map(|t| t.sessions).sum();
    let scored: i64 = trainees.iter().map(|t| t.scored).sum();
    let passed: i64 = trainees.iter().map(|t| t.passed).sum();
    let weighted: f64 = lines
        .iter()
        .filter_map(|l| l.mean_score.map(|m| m * l.scored as f64))
        .sum();
    let mean = (scored > 0).then(|| weighted / scored as f64);
    let risk: i64 = lines.iter().map(|l| l.risk_hits).sum();
    let range = match (
        q.from.as_deref().filter(|d| !d.is_empty()),
        q.to.as_deref().filter(|d| !d.is_empty()),
    ) {
        (Some(a), Some(b)) => format!("{a} to {b}"),
        (Some(a), None) => format!("from {a}"),
        (None, Some(b)) => format!("until {b}"),
        (None, None) => "all dates".to_string(),
    };
    let generated = short_time(&humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string());
    let pct = |a: i64, b: i64| {
        if b > 0 {
            format!("{:.0} %", 100.0 * a as f64 / b as f64)
        } else {
            "–".into()
        }
    };
    Ok(page(
        &format!("Report — cohort {name}"),
        Some(&v),
        html! {
            h1 #report-title { "Cohort " (name) " — training report, " (range) }
            p.muted { "Generated " (generated) " UTC by " (v.user.username) ". Scores are final grades (an instructor's override where there is one); dates are upload dates (UTC)." }
            p.noprint {
                button type="button" onclick="window.print()" { "Print" } " "
                a href={ "/api/export/sessions.csv?" (filter_query(&q)) } { "These sessions as CSV" }
            }
            div.cards {
                div.card { div.muted { "Trainees" } div.big { (trainees.len()) } }
                div.card { div.muted { "Sessions (scored)" } div.big { (sessions) " (" (scored) ")" } }
                div.card { div.muted { "Pass rate" } div.big { (pct(passed, scored)) } }
                div.card { div.muted { "Mean score" } div.big { (score_text(mean)) } }
                div.card { div.muted { "Risk-structure hits" } div.big { (risk) } }
            }
            h2 { "Trainees" }
            table #report-trainees {
                thead { tr { th { "Trainee" } th.num { "Sessions" } th.num { "Passed / scored" } th.num { "Pass rate" } th.num { "Mean score" } th { "Latest scores" } } }
                tbody { @for t in &trainees {
                    @let points: Vec<(f64, bool)> = recent.iter().filter(|p| p.trainee == t.username).map(|p| (p.score, p.passed)).collect();
                    tr {
                        td { (t.username) } td.num { (t.sessions) } td.num { (t.passed) " / " (t.scored) }
                        td.num { (pct(t.passed, t.scored)) } td.num { (score_text(t.mean_score)) }
                        td { (PreEscaped(sparkline(&points))) }
                    }
                } }
            }
            h2 { "By trainee and difficulty" }
            @if lines.is_empty() { p.muted { "No sessions in this range." } }
            @else {
                table #report-lines {
                    thead { tr {
                        th { "Trainee" } th { "Difficulty" } th.num { "Sessions" } th.num { "Passed / scored" }
                        th.num { "Mean score" } th.num { "Best score" } th.num { "Mean attempts" } th.num { "Risk hits" } th { "First – last upload" }
                    } }
                    tbody { @for l in &lines { tr {
                        td { (l.trainee) } td { (l.difficulty) } td.num { (l.sessions) } td.num { (l.passed) " / " (l.scored) }
                        td.num { (score_text(l.mean_score)) } td.num { (score_text(l.best_score)) }
                        td.num { (l.mean_attempts.map_or("–".into(), |a| format!("{a:.1}"))) } td.num { (l.risk_hits) }
                        td { (l.first_upload.as_deref().map(short_time).unwrap_or_default()) " – " (l.last_upload.as_deref().map(short_time).unwrap_or_default()) }
                    } } }
                }
            }
            p.noprint { a href={ "/cohorts/" (encode_query(&name)) } { "Cohort view →" } }
        },
    ))
}
