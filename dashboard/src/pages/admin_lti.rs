//! `GET/POST /admin/lti`, `POST /admin/lti/{id}/deployments`: the learning management systems
//! that launch Stylet (LTI 1.3). Admins see the values to paste into a platform's tool
//! registration, the platforms registered, register one and add a deployment id to one (a
//! platform such as Canvas gives every installation its own); the same store calls as
//! `stylet lti add-platform` and `add-deployment`; audited.

use std::sync::Arc;

use axum::Form;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::store::{DEFAULT_INSTRUCTOR_ROLES, LtiPlatform, NewLtiPlatform, Role, StoreError};

use crate::auth::{PageError, Viewer, check_csrf, fail};
use crate::layout::{csrf_field, page, short_time};

fn require_admin(v: &Viewer) -> Result<(), PageError> {
    if v.role() == Role::Admin {
        Ok(())
    } else {
        Err(fail(StatusCode::FORBIDDEN, "only admins register learning platforms"))
    }
}

/// This server's address as the browser reached it (https behind TLS: `--secure-cookies`).
fn base_url(s: &AppState, headers: &HeaderMap) -> String {
    let host = headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .filter(|h| !h.is_empty() && h.len() <= 255 && h.bytes().all(|b| b.is_ascii_graphic()))
        .unwrap_or("stylet.example.org");
    format!("{}://{host}", if s.config.secure_cookies { "https" } else { "http" })
}

/// The form's fields, as typed (shown again with the problems when refused).
#[derive(Debug, Default, serde::Deserialize)]
pub struct PlatformForm {
    #[serde(default)]
    csrf: String,
    #[serde(default)]
    issuer: String,
    #[serde(default)]
    client_id: String,
    /// One a line, or separated by commas.
    #[serde(default)]
    deployment_ids: String,
    #[serde(default)]
    keyset_url: String,
    #[serde(default)]
    auth_url: String,
    #[serde(default)]
    token_url: String,
    #[serde(default)]
    instructor_roles: String,
}

fn list(text: &str) -> Vec<String> {
    text.split([',', '\n'])
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(str::to_string)
        .collect()
}

impl PlatformForm {
    fn platform(&self) -> NewLtiPlatform {
        NewLtiPlatform {
            issuer: self.issuer.trim().to_string(),
            client_id: self.client_id.trim().to_string(),
            deployment_ids: list(&self.deployment_ids),
            keyset_url: self.keyset_url.trim().to_string(),
            auth_url: self.auth_url.trim().to_string(),
            token_url: self.token_url.trim().to_string(),
            instructor_roles: list(&self.instructor_roles),
        }
    }
}

fn lti_page(v: &Viewer, base: &str, platforms: &[LtiPlatform], typed: &PlatformForm, errors: &[String]) -> Markup {
    html! {
        h1 { "LTI platforms" }
        p.muted {
            "Learning management systems (Moodle, Canvas, Blackboard, Open edX) launch Stylet as an LTI 1.3 tool: learners open an exercise "
            "from their course and their grades go to its gradebook. Register Stylet in the platform with these values, then register the platform here."
        }
        h2 { "Stylet's values for the platform" }
        (super::lti::tool_values_table(base))
        h2 { "Registered platforms" }
        @if platforms.is_empty() { p.muted #lti-none { "None yet." } }
        @else {
            div.table-scroll { table #lti-platforms {
                thead { tr { th { "Issuer" } th { "Client id" } th { "Deployments" } th { "Instructor roles" } th { "Registered" } } }
                tbody { @for p in platforms {
                    tr { td { code { (p.issuer) } } td { code { (p.client_id) } }
                         td { (p.deployment_ids.join(", "))
                              form.inline.add-deployment method="post" action=(format!("/admin/lti/{}/deployments", p.id)) {
                                  (csrf_field(v))
                                  input name="deployment_id" required size="12" aria-label="Deployment ID to add";
                                  button type="submit" { "Add deployment" }
                              } }
                         td { (p.instructor_roles.join(", ")) } td { (short_time(&p.created_at)) " UTC" } }
                } }
            } }
        }
        h2 { "Register a platform" }
        @for e in errors { p.error role="alert" .lti-error { (e) } }
        form #lti-register method="post" action="/admin/lti" {
            (csrf_field(v))
            p { label { "Issuer (platform ID) " input #lti-issuer name="issuer" required size="60" value=(typed.issuer) placeholder="https://moodle.example.org"; } }
            p { label { "Client ID " input #lti-client-id name="client_id" required size="40" value=(typed.client_id); } }
            p { label { "Deployment IDs (one a line) " textarea #lti-deployments name="deployment_ids" rows="2" cols="40" required { (typed.deployment_ids) } } }
            p { label { "Public keyset URL " input #lti-keyset name="keyset_url" required size="60" value=(typed.keyset_url); } }
            p { label { "Authentication request URL " input #lti-auth name="auth_url" required size="60" value=(typed.auth_url); } }
            p { label { "Access token URL " input #lti-token name="token_url" required size="60" value=(typed.token_url); } }
            p { label { "Roles that make an instructor (one a line; empty: " (DEFAULT_INSTRUCTOR_ROLES.join(", ")) ") "
                textarea #lti-roles name="instructor_roles" rows="2" cols="40" { (typed.instructor_roles) } } }
            p.muted { "Learner makes a trainee; other roles get no access. Each course becomes a cohort." }
            p { button.primary type="submit" { "Register" } }
        }
    }
}

/// `GET /admin/lti`.
pub async fn index(State(s): State<Arc<AppState>>, v: Viewer, headers: HeaderMap) -> Result<Response, PageError> {
    require_admin(&v)?;
    let platforms = s.store.lti_platforms().await?;
    let body = lti_page(&v, &base_url(&s, &headers), &platforms, &PlatformForm::default(), &[]);
    Ok(page("LTI platforms", Some(&v), body).into_response())
}

#[derive(Debug, serde::Deserialize)]
pub struct DeploymentForm {
    #[serde(default)]
    csrf: String,
    #[serde(default)]
    deployment_id: String,
}

/// `POST /admin/lti/{id}/deployments`: adds a deployment id; back to the list, or the page with
/// the problem.
pub async fn add_deployment(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    headers: HeaderMap,
    Path(id): Path<String>,
    Form(f): Form<DeploymentForm>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    let problem = match s
        .store
        .add_lti_deployment(&id, f.deployment_id.trim(), Some(&v.user.id))
        .await
    {
        Ok(Some(_)) => return Ok(Redirect::to("/admin/lti").into_response()),
        Ok(None) => return Err(fail(StatusCode::NOT_FOUND, "no such platform")),
        Err(StoreError::Invalid(why)) => why,
        Err(e) => return Err(e.into()),
    };
    let platforms = s.store.lti_platforms().await?;
    let body = lti_page(
        &v,
        &base_url(&s, &headers),
        &platforms,
        &PlatformForm::default(),
        &[problem],
    );
    Ok((StatusCode::BAD_REQUEST, page("LTI platforms", Some(&v), body)).into_response())
}

/// `POST /admin/lti`: registers a platform; back to the list, or the form with its problems.
pub async fn register(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    headers: HeaderMap,
    Form(f): Form<PlatformForm>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    let new = f.platform();
    let mut problems = new.check();
    if problems.is_empty() {
        match s.store.add_lti_platform(&new, Some(&v.user.id)).await {
            Ok(_) => return Ok(Redirect::to("/admin/lti").into_response()),
            Err(e @ StoreError::LtiPlatformExists { .. }) => problems.push(e.to_string()),
            Err(e) => return Err(e.into()),
        }
    }
    let platforms = s.store.lti_platforms().await?;
    let body = lti_page(&v, &base_url(&s, &headers), &platforms, &f, &problems);
    Ok((StatusCode::BAD_REQUEST, page("LTI platforms", Some(&v), body)).into_response())
}
