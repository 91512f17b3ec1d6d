//! `GET /sessions`: every session the viewer may see, newest first, with filters (dates,
//! scenario, difficulty, trainee) and pages of 100.

use std::sync::Arc;

use axum::extract::{Query, State};

use axum::response::Html;
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::api::{ListQuery, PAGE_SIZE};
use stylet_service::store::Role;

use crate::auth::{PageError, Viewer};
use crate::layout::{page, pager, sessions_table};

/// The filter form, keeping what was chosen.
pub fn filter_form(action: &str, q: &ListQuery, scenarios: &[String], with_trainee: bool) -> Markup {
    let v = |o: &Option<String>| o.clone().unwrap_or_default();
    html! {
        form.inline.filters method="get" action=(action) {
            label { "From" input type="date" name="from" value=(v(&q.from)); }
            label { "To" input type="date" name="to" value=(v(&q.to)); }
            label { "Scenario"
                select name="scenario" {
                    option value="" { "all" }
                    @for sc in scenarios { option value=(sc) selected[q.scenario.as_deref() == Some(sc.as_str())] { (sc) } }
                }
            }
            label { "Difficulty"
                select name="difficulty" {
                    option value="" { "all" }
                    @for d in stylet_scoring::Difficulty::ALL.map(stylet_scoring::Difficulty::as_str) { option value=(d) selected[q.difficulty.as_deref() == Some(d)] { (d) } }
                }
            }
            @if with_trainee { label { "Trainee" input type="text" name="trainee" value=(v(&q.trainee)) size="12"; } }
            button type="submit" { "Filter" }
        }
    }
}

/// The query string of the filters (for pager and export links), without the page.
pub fn filter_query(q: &ListQuery) -> String {
    let mut parts = Vec::new();
    for (k, v) in [
        ("from", &q.from),
        ("to", &q.to),
        ("scenario", &q.scenario),
        ("difficulty", &q.difficulty),
        ("cohort", &q.cohort),
        ("trainee", &q.trainee),
    ] {
        if let Some(v) = v.as_deref().filter(|v| !v.is_empty()) {
            parts.push(format!("{k}={}", crate::auth::encode_query(v)));
        }
    }
    parts.join("&")
}

pub async fn list(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Query(q): Query<ListQuery>,
) -> Result<Html<String>, PageError> {
    let filter = q.filter(&s).await?;
    let lines = s.store.sessions(&v.user, &filter).await?;
    let total = s.store.count_sessions(&v.user, &filter).await?;
    let scenarios = s.store.scenarios(&v.user, None).await?;
    let staff = v.role() != Role::Trainee;
    Ok(page(
        "Sessions",
        Some(&v),
        html! {
            h1 { @if staff { "Sessions" } @else { "My sessions" } }
            (filter_form("/sessions", &q, &scenarios, staff))
            (sessions_table(&lines, staff))
            (pager(&filter_query(&q), q.page.unwrap_or(1).max(1), total, PAGE_SIZE))
            @if staff {
                p.noprint { a #export-csv href={ "/api/export/sessions.csv?" (filter_query(&q)) } { "Export these sessions as CSV" } }
            }
        },
    ))
}
