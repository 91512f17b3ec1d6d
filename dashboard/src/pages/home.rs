//! `GET /`: the logged-in user's home. Trainees: their sessions, progress per difficulty and the
//! suggested next difficulty. Instructors: their cohorts and their trainees' latest sessions.
//! Curriculum staff and admins: every cohort, reports, the latest sessions.

use std::sync::Arc;

use axum::extract::State;

use axum::response::Html;
use maud::{Markup, PreEscaped, html};
use stylet_service::AppState;
use stylet_service::store::{CohortLine, Role, SessionFilter};

use crate::auth::{PageError, Viewer};
use crate::charts::{inline_svg, progress_chart};
use crate::layout::{page, score_text, sessions_table};
use crate::pages::upload::upload_form;
use crate::progress::suggest_next;

pub async fn home(State(s): State<Arc<AppState>>, v: Viewer) -> Result<Html<String>, PageError> {
    let body = match v.role() {
        Role::Trainee => trainee_home(&s, &v).await?,
        Role::Instructor | Role::Curriculum | Role::Admin => staff_home(&s, &v).await?,
    };
    Ok(page("Home", Some(&v), body))
}

async fn trainee_home(s: &AppState, v: &Viewer) -> Result<Markup, PageError> {
    let points = s.store.progress(&v.user.id).await?;
    let recent = s
        .store
        .sessions(
            &v.user,
            &SessionFilter {
                limit: 20,
                ..Default::default()
            },
        )
        .await?;
    let total = s.store.count_sessions(&v.user, &SessionFilter::default()).await?;
    let suggestion = suggest_next(&points);
    let passed = points.iter().filter(|p| p.passed).count();
    let mean = (!points.is_empty()).then(|| points.iter().map(|p| p.score).sum::<f64>() / points.len() as f64);
    let chart = if points.is_empty() {
        None
    } else {
        Some(
            inline_svg(&progress_chart(
                &points,
                &format!("Scores of {} by difficulty", v.user.username),
            ))
            .map_err(|e| crate::auth::fail(axum::http::StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?,
        )
    };
    Ok(html! {
        h1 { "My training — " (v.user.username) }
        div.cards {
            div.card { div.muted { "Sessions" } div.big { (total) } }
            div.card { div.muted { "Scored / passed" } div.big { (points.len()) " / " (passed) } }
            div.card { div.muted { "Mean score" } div.big { (score_text(mean)) } }
            div.card #suggestion {
                div.muted { "Suggested next difficulty" }
                div.big { (suggestion.level) }
                div.muted { (suggestion.reason) }
            }
        }
        h2 { "My progress" }
        @match &chart {
            Some(svg) => div.chart-box #home-progress { (PreEscaped(svg)) },
            None => p.muted { "Your scores appear here once a session is scored." },
        }
        h2 { "Upload a session" }
        (upload_form(v))
        h2 { "My sessions" }
        (sessions_table(&recent, false))
        @if total > recent.len() as i64 { p { a href="/sessions" { "All " (total) " sessions →" } } }
    })
}

/// The cohorts table (instructor, curriculum, admin homes and `/cohorts`).
pub fn cohorts_table(cohorts: &[CohortLine]) -> Markup {
    html! {
        @if cohorts.is_empty() {
            p.muted { "No cohorts." }
        } @else {
            table.cohorts {
                thead { tr {
                    th { "Cohort" } th.num { "Trainees" } th.num { "Sessions" } th.num { "Scored" }
                    th.num { "Pass rate" } th.num { "Mean score" }
                } }
                tbody {
                    @for c in cohorts {
                        tr {
                            td { a href={ "/cohorts/" (c.name) } { (c.name) } }
                            td.num { (c.trainees) } td.num { (c.sessions) } td.num { (c.scored) }
                            td.num { @if c.scored > 0 { (format!("{:.0} %", 100.0 * c.passed as f64 / c.scored as f64)) } @else { "–" } }
                            td.num { (score_text(c.mean_score)) }
                        }
                    }
                }
            }
        }
    }
}

async fn staff_home(s: &AppState, v: &Viewer) -> Result<Markup, PageError> {
    let cohorts = s.store.cohorts_for(&v.user).await?;
    let recent = s
        .store
        .sessions(
            &v.user,
            &SessionFilter {
                limit: 20,
                ..Default::default()
            },
        )
        .await?;
    let role = v.role();
    // Instructors' and admins' review queue: how many sessions wait (one count; the page lists them).
    let (_, to_review) = s
        .store
        .review_queue(&v.user, stylet_service::store::QueueScope::All, 0, 0)
        .await?;
    Ok(html! {
        h1 {
            @match role {
                Role::Instructor => "Instructor",
                Role::Curriculum => "Curriculum",
                Role::Trainee | Role::Admin => "Administration",
            }
            " — " (v.user.username)
        }
        h2 { @if role == Role::Instructor { "My cohorts" } @else { "Cohorts" } }
        (cohorts_table(&cohorts))
        @if matches!(role, Role::Instructor | Role::Admin) {
            p #home-review-queue { a href="/review-queue" { (to_review) " sessions need review (not yet commented; risk hits and failures marked) →" } }
        }
        @if matches!(role, Role::Curriculum | Role::Admin) {
            p { a href="/reports" { "Cohort reports and the sessions CSV export →" } }
        }
        @if role == Role::Admin { p { a href="/admin/users" { "Accounts →" } } }
        @if matches!(role, Role::Instructor | Role::Admin) {
            h2 { "Upload a session for a trainee" }
            (upload_form(v))
        }
        h2 { "Latest sessions" }
        (sessions_table(&recent, true))
        p { a href="/sessions" { "All sessions, with filters →" } }
    })
}

/// `GET /cohorts`: the cohorts the viewer may look at.
pub async fn cohorts(State(s): State<Arc<AppState>>, v: Viewer) -> Result<Html<String>, PageError> {
    if v.role() == Role::Trainee {
        return Err(crate::auth::fail(
            axum::http::StatusCode::FORBIDDEN,
            "cohort views are for instructors and curriculum staff",
        ));
    }
    let cohorts = s.store.cohorts_for(&v.user).await?;
    Ok(page(
        "Cohorts",
        Some(&v),
        html! { h1 { "Cohorts" } (cohorts_table(&cohorts)) },
    ))
}
