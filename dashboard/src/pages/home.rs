//! `GET /`: the logged-in user's home. Trainees: first their next step (the scenario and the
//! difficulty to practise), then their sessions and progress per difficulty. Instructors: their
//! cohorts and their trainees' latest sessions.
//! Curriculum staff and admins: every cohort, reports, the latest sessions.

use std::sync::Arc;

use axum::extract::State;

use axum::response::Html;
use maud::{Markup, PreEscaped, html};
use stylet_scoring::Exercise;
use stylet_service::AppState;
use stylet_service::store::{CohortLine, Role, SessionFilter};

use crate::auth::{PageError, Viewer};
use crate::charts::{inline_svg, progress_chart};
use crate::layout::{page, score_text, sessions_table};
use crate::pages::upload::upload_form;
use crate::progress::{NextStep, next_step};

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
    let next = next_step(&points, &training_punctures(s));
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
        (next_block(&next))
        div.cards.counts {
            div.card { div.muted { "Sessions" } div.big { (total) } }
            div.card { div.muted { "Scored / passed" } div.big { (points.len()) " / " (passed) } }
            div.card { div.muted { "Mean score" } div.big { (score_text(mean)) } }
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

/// The puncture scenarios offered to trainees on the atlases that take sessions, in the
/// catalogue's order, each once (the same scenario on two atlases is one exercise).
fn training_punctures(s: &AppState) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for (_, entry) in s.catalogue.entries() {
        if entry.withdrawn() {
            continue;
        }
        for sc in &entry.summary.training {
            if entry.summary.exercise_of(sc) == Exercise::Puncture && !out.contains(sc) {
                out.push(sc.clone());
            }
        }
    }
    out
}

/// The trainee's next step, first on the home page: the scenario and the level to practise,
/// how, and why this level.
fn next_block(next: &NextStep) -> Markup {
    html! {
        section.card #suggestion {
            div.muted { "Your next step" }
            p.next {
                "Practise "
                @if let Some(sc) = &next.scenario { strong { (sc) } " " }
                "at " strong { (next.level) } " level"
            }
            p { "In the simulator, choose this scenario and difficulty; then upload the session below." }
            div.muted { (capitalised(&next.reason)) "." }
        }
    }
}

/// `text` with its first letter in upper case.
fn capitalised(text: &str) -> String {
    let mut chars = text.chars();
    match chars.next() {
        Some(first) => first.to_uppercase().chain(chars).collect(),
        None => String::new(),
    }
}

/// The link to the review queue in words, the verb agreeing with the count.
fn review_queue_text(to_review: i64) -> String {
    let waiting = match to_review {
        0 => "No session needs review".to_string(),
        1 => "1 session needs review".to_string(),
        n => format!("{n} sessions need review"),
    };
    format!("{waiting} (not yet commented; risk hits and failures marked) →")
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
            p #home-review-queue { a href="/review-queue" { (review_queue_text(to_review)) } }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_next_step_names_the_scenario_and_the_level() {
        let html = next_block(&NextStep {
            level: stylet_scoring::Difficulty::Beginner,
            scenario: Some("success-intercostal".into()),
            reason: "no scored sessions yet: start at beginner".into(),
        })
        .into_string();
        assert!(
            html.starts_with("<section") && html.contains("id=\"suggestion\""),
            "{html}"
        );
        assert!(
            html.contains("Practise <strong>success-intercostal</strong> at <strong>beginner</strong> level"),
            "{html}"
        );
        assert!(html.contains("No scored sessions yet: start at beginner."), "{html}");
        let any = next_block(&NextStep {
            level: stylet_scoring::Difficulty::Advanced,
            scenario: None,
            reason: "the last 3 beginner sessions all passed".into(),
        })
        .into_string();
        assert!(any.contains("Practise at <strong>advanced</strong> level"), "{any}");
    }

    #[test]
    fn the_review_queue_link_agrees_with_its_count() {
        assert!(review_queue_text(0).starts_with("No session needs review"));
        assert!(review_queue_text(1).starts_with("1 session needs review"));
        assert!(review_queue_text(4).starts_with("4 sessions need review"));
    }
}
