//! `GET /cohorts/{name}`: an instructor's view of a cohort. Trainees with their totals and a
//! sparkline of their latest scores, filters (dates, scenario, difficulty), the cohort's
//! sessions, and a form that opens two of them in the comparison (`GET /compare`, compare.rs).

use std::sync::Arc;

use axum::extract::{Path, Query, State};
use axum::http::{StatusCode, Uri};
use axum::response::Html;
use maud::{Markup, PreEscaped, html};
use stylet_service::AppState;
use stylet_service::api::{ListQuery, PAGE_SIZE};
use stylet_service::store::{Role, ScorePoint, SessionLine, SessionStatus, TraineeSummary};

use crate::auth::{PageError, Viewer, fail};
use crate::charts::sparkline;
use crate::layout::{page, pager, score_text, sessions_table, short_time};
use crate::pages::sessions::{filter_form, filter_query};

/// Scores per trainee in a sparkline.
pub const SPARK_POINTS: i64 = 20;

/// The cohort's id if the viewer may look at it: its instructors, curriculum staff, admins.
pub async fn visible_cohort(s: &AppState, v: &Viewer, name: &str) -> Result<String, PageError> {
    let id = s
        .store
        .cohort_id(name)
        .await?
        .ok_or_else(|| fail(StatusCode::NOT_FOUND, format!("no cohort {name}")))?;
    let allowed = match v.role() {
        Role::Instructor => s.store.in_cohort(&v.user.id, &id).await?,
        Role::Curriculum | Role::Admin => true,
        Role::Trainee => false,
    };
    if !allowed {
        // The same answer as for a cohort that does not exist.
        return Err(fail(StatusCode::NOT_FOUND, format!("no cohort {name}")));
    }
    Ok(id)
}

pub fn trainee_table(trainees: &[TraineeSummary], recent: &[ScorePoint], query: &str) -> Markup {
    html! {
        table #trainees {
            thead { tr {
                th { "Trainee" } th.num { "Sessions" } th.num { "Scored" } th.num { "Passed" } th.num { "Pass rate" }
                th.num { "Mean score" } th { "Latest scores" } th { "Last upload (UTC)" }
            } }
            tbody {
                @for t in trainees {
                    @let points: Vec<(f64, bool)> = recent.iter().filter(|p| p.trainee == t.username).map(|p| (p.score, p.passed)).collect();
                    tr {
                        td { a href={ "/sessions?trainee=" (t.username) @if !query.is_empty() { "&" (query) } } { (t.username) } }
                        td.num { (t.sessions) } td.num { (t.scored) } td.num { (t.passed) }
                        td.num { @if t.scored > 0 { (format!("{:.0} %", 100.0 * t.passed as f64 / t.scored as f64)) } @else { "–" } }
                        td.num { (score_text(t.mean_score)) }
                        td { (PreEscaped(sparkline(&points))) }
                        td { (t.last_upload.as_deref().map(short_time).unwrap_or_else(|| "–".into())) }
                    }
                }
            }
        }
    }
}

fn compare_form(lines: &[SessionLine]) -> Markup {
    let option = |l: &SessionLine| {
        format!(
            "{} · {} · {} · {}",
            l.trainee,
            l.scenario,
            short_time(&l.uploaded_at),
            score_text(l.score)
        )
    };
    html! {
        form.inline #compare method="get" action="/compare" {
            label { "Session A" select name="a" { @for l in lines { option value=(l.id) { (option(l)) } } } }
            label { "Session B" select name="b" { @for (k, l) in lines.iter().enumerate() { option value=(l.id) selected[k == 1] { (option(l)) } } } }
            button type="submit" { "Compare force curves" }
        }
    }
}

pub async fn cohort(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    uri: Uri,
    Path(name): Path<String>,
    Query(mut q): Query<ListQuery>,
) -> Result<Html<String>, PageError> {
    let cohort_id = visible_cohort(&s, &v, &name).await?;
    q.cohort = Some(name.clone());
    let mut filter = q.filter(&s).await?;
    filter.cohort_id = Some(cohort_id.clone());
    let trainees = s.store.cohort_summary(&cohort_id, &filter).await?;
    let recent = s.store.recent_scores(&cohort_id, &filter, SPARK_POINTS).await?;
    let lines = s.store.sessions(&v.user, &filter).await?;
    let total = s.store.count_sessions(&v.user, &filter).await?;
    let scenarios = s.store.scenarios(&v.user, Some(&cohort_id)).await?;
    let mut without_cohort = ListQuery { cohort: None, ..q };
    without_cohort.page = None;
    let query = filter_query(&without_cohort);
    let scored: Vec<SessionLine> = lines
        .iter()
        .filter(|l| l.status == SessionStatus::Scored)
        .cloned()
        .collect();
    Ok(page(
        &format!("Cohort {name}"),
        Some(&v),
        html! {
            h1 { "Cohort " (name) }
            (filter_form(&format!("/cohorts/{name}"), &without_cohort, &scenarios, false))
            h2 { "Trainees" }
            @if trainees.is_empty() { p.muted { "No trainees in this cohort." } }
            @else { (trainee_table(&trainees, &recent, &query)) }
            h2 { "Compare two sessions" }
            @if scored.len() >= 2 { (compare_form(&scored)) }
            @else { p.muted { "Two scored sessions are needed." } }
            h2 { "Sessions" }
            (sessions_table(&lines, true))
            (pager(&query, without_cohort_page(&uri), total, PAGE_SIZE))
            p.noprint {
                a #export-csv href={ "/api/export/sessions.csv?cohort=" (crate::auth::encode_query(&name)) @if !query.is_empty() { "&" (query) } } { "Export these sessions as CSV" }
                " · "
                a href={ "/reports/cohort?cohort=" (crate::auth::encode_query(&name)) @if !query.is_empty() { "&" (query) } } { "Report with trends and failure reasons" }
                " · "
                a #report-pdf href={ "/reports/cohort.pdf?cohort=" (crate::auth::encode_query(&name)) @if !query.is_empty() { "&" (query) } } { "Report as PDF" }
            }
        },
    ))
}

/// The page number in a URI's query (1 if none).
fn without_cohort_page(uri: &Uri) -> i64 {
    uri.query()
        .unwrap_or_default()
        .split('&')
        .find_map(|kv| kv.strip_prefix("page=")?.parse().ok())
        .unwrap_or(1i64)
        .max(1)
}
