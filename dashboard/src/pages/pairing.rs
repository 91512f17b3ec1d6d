//! `GET/POST /pair`, `POST /pair/machines/{id}/revoke`: pairing codes for the desktop
//! simulator (the rules of `/api/pairing/codes`: 10 minutes, used once, audited), and the lab
//! machines an instructor or admin may revoke. A new code is shown once, large, with the steps
//! to type it in; the page is not kept by the browser.

use std::sync::Arc;

use axum::Form;
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::pairing::{self, CODE_MINUTES, LAB_SIGN_IN_HOURS};
use stylet_service::store::{CohortLine, LabMachine, PairingPurpose, Role};

use crate::auth::{PageError, Viewer, check_csrf};
use crate::layout::{csrf_field, page, short_time};

/// A code just made, to show.
struct Shown<'a> {
    code: &'a str,
    purpose: PairingPurpose,
    cohort: Option<&'a str>,
    expires_at: &'a str,
}

fn steps(purpose: PairingPurpose) -> Markup {
    html! {
        ol.steps {
            @match purpose {
                PairingPurpose::Simulator => {
                    li { "Start the Stylet simulator on the computer you train on." }
                    li { "On its start screen, under " strong { "Scoring service" } ", type this server's address and the code into " strong { "Pairing code" } ", then press " strong { "Pair" } "." }
                    li { "Your sessions upload from that computer from now on (an upload-only token, 90 days; revoke it on " a href="/tokens" { "API tokens" } ")." }
                }
                PairingPurpose::Lab => {
                    li { "On the lab computer, start the simulator and type this server's address and the code into " strong { "Pairing code" } ", then press " strong { "Pair" } "." }
                    li { "It becomes a lab machine of the cohort for a year: its trainees sign in on it with their own sign-in codes, one after another." }
                }
                PairingPurpose::SignIn => {
                    li { "At a lab machine of your cohort, type the code into " strong { "Sign in with your code" } "." }
                    li { "Your sessions on it upload as yours until you sign out, or for " (LAB_SIGN_IN_HOURS) " hours." }
                }
            }
        }
    }
}

fn pairing_page(
    v: &Viewer,
    cohorts: &[CohortLine],
    machines: &[LabMachine],
    shown: Option<Shown<'_>>,
    error: Option<&str>,
) -> Markup {
    let role = v.role();
    html! {
        h1 { "Pair a simulator" }
        p.muted {
            "A pairing code links a desktop simulator with your account in seconds: no password or token to type on it. "
            "A code lasts " (CODE_MINUTES) " minutes and works once."
        }
        @if let Some(s) = &shown {
            div.notice #pairing-box role="status" {
                p { "This code " (s.purpose.words())
                    @if let Some(c) = s.cohort { " " strong { (c) } }
                    ". Valid until " (short_time(s.expires_at)) " UTC." }
                p #pairing-code { (s.code) }
                (steps(s.purpose))
            }
        }
        @if let Some(e) = error { p.error role="alert" #pairing-error { (e) } }
        h2 { "Your simulator" }
        form.inline #pair-simulator method="post" action="/pair" {
            (csrf_field(v))
            input type="hidden" name="purpose" value="simulator";
            button.primary type="submit" { "Show a pairing code" }
        }
        @if role == Role::Trainee {
            h2 { "A lab machine" }
            p.muted { "At a lab machine of your cohort, sign in with a code of your own." }
            form.inline #pair-sign-in method="post" action="/pair" {
                (csrf_field(v))
                input type="hidden" name="purpose" value="sign_in";
                button.primary type="submit" { "Show a sign-in code" }
            }
        }
        @if matches!(role, Role::Instructor | Role::Admin) {
            h2 { "Lab machines" }
            p.muted { "A lab machine serves one cohort: its trainees sign in on it in turn with their own codes." }
            @if cohorts.is_empty() {
                p.muted { "You teach no cohort yet." }
            } @else {
                form.inline #pair-lab method="post" action="/pair" {
                    (csrf_field(v))
                    input type="hidden" name="purpose" value="lab";
                    label { "Cohort" select name="cohort" { @for c in cohorts { option value=(c.name) { (c.name) } } } }
                    button.primary type="submit" { "Pair a lab machine" }
                }
            }
            @if machines.is_empty() {
                p.muted { "No lab machines yet." }
            } @else {
                table #lab-machines {
                    thead { tr { th { "Machine" } th { "Cohort" } th { "Paired by" } th { "Paired (UTC)" } th { "Until (UTC)" } th { "Status" } th {} } }
                    tbody { @for m in machines { tr data-machine-id=(m.id) {
                        td { (m.label) } td { (m.cohort) } td { (m.paired_by) }
                        td { (short_time(&m.created_at)) } td { (short_time(&m.expires_at)) }
                        td { @if m.active { span.badge.ok { "active" } } @else if m.revoked_at.is_some() { span.badge.bad { "revoked" } } @else { span.badge.muted { "expired" } } }
                        td { @if m.active {
                            form method="post" action={ "/pair/machines/" (m.id) "/revoke" } {
                                (csrf_field(v))
                                button type="submit" { "Revoke" }
                            }
                        } }
                    } } }
                }
            }
        }
    }
}

/// The cohorts `v` may pair lab machines of, and the machines they may see.
async fn lists(s: &AppState, v: &Viewer) -> Result<(Vec<CohortLine>, Vec<LabMachine>), PageError> {
    if !matches!(v.role(), Role::Instructor | Role::Admin) {
        return Ok((Vec::new(), Vec::new()));
    }
    Ok((
        s.store.cohorts_for(&v.user).await?,
        s.store.lab_machines(&v.user).await?,
    ))
}

pub async fn index(State(s): State<Arc<AppState>>, v: Viewer) -> Result<Response, PageError> {
    let (cohorts, machines) = lists(&s, &v).await?;
    Ok(page(
        "Pair a simulator",
        Some(&v),
        pairing_page(&v, &cohorts, &machines, None, None),
    )
    .into_response())
}

#[derive(serde::Deserialize)]
pub struct NewCodeForm {
    csrf: String,
    purpose: String,
    #[serde(default)]
    cohort: String,
}

pub async fn create(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Form(f): Form<NewCodeForm>,
) -> Result<Response, PageError> {
    check_csrf(&v, &f.csrf)?;
    let purpose = PairingPurpose::parse(f.purpose.trim());
    let made = match purpose {
        Some(p) => pairing::create(&s, &v.user, p, Some(f.cohort.as_str()).filter(|c| !c.is_empty()))
            .await
            .map_err(|e| (e.status(), e.message())),
        None => Err((StatusCode::BAD_REQUEST, format!("unknown purpose '{}'", f.purpose))),
    };
    let (cohorts, machines) = lists(&s, &v).await?;
    let body = match (&made, purpose) {
        (Ok((code, expires_at)), Some(purpose)) => {
            let shown = Shown {
                code,
                purpose,
                cohort: (purpose == PairingPurpose::Lab).then_some(f.cohort.as_str()),
                expires_at,
            };
            pairing_page(&v, &cohorts, &machines, Some(shown), None)
        }
        (Err((status, m)), _) if status.is_client_error() => pairing_page(&v, &cohorts, &machines, None, Some(m)),
        (Err((status, m)), _) => return Err(PageError::Status(*status, m.clone())),
        (Ok(_), None) => {
            return Err(PageError::Status(
                StatusCode::INTERNAL_SERVER_ERROR,
                "internal error".into(),
            ));
        }
    };
    let status = made.as_ref().err().map_or(StatusCode::OK, |(status, _)| *status);
    Ok((
        status,
        [(header::CACHE_CONTROL, "no-store")],
        page("Pair a simulator", Some(&v), body),
    )
        .into_response())
}

#[derive(serde::Deserialize)]
pub struct RevokeForm {
    csrf: String,
}

pub async fn revoke(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    Form(f): Form<RevokeForm>,
) -> Result<Response, PageError> {
    check_csrf(&v, &f.csrf)?;
    pairing::revoke_lab_machine(&s, &v.user, &id).await?;
    Ok(Redirect::to("/pair").into_response())
}
