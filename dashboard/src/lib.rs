//! The Stylet dashboard (docs/dashboard.md; its security rules: docs/security.md): server-rendered
//! pages for trainees, instructors, curriculum staff and admins, mounted by `stylet serve` beside
//! the JSON API and sharing its logins, store and authorization rules. Charts are drawn on the
//! server with plotters as inline SVG ([`charts`], on [`plot`]); the tip path over CT slices is a PNG drawn by
//! the CPU renderer ([`figures`]). Pages work without JavaScript; every form carries the login's
//! CSRF token.

pub mod auth;
pub mod charts;
mod error_page;
pub mod figures;
pub mod layout;
pub mod pages;
pub mod pdf;
pub mod player;
pub mod plot;
pub mod progress;
pub mod session_access;
pub mod trends;

use std::sync::Arc;

use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::routing::{get, post};
use stylet_service::AppState;

/// The dashboard, as `stylet serve` mounts it beside the API.
pub const MOUNT: stylet_service::Mount = stylet_service::Mount { router, openapi };

/// The part of the OpenAPI document for the dashboard's routes that programs call (the player's
/// frames); the pages themselves are for browsers.
#[derive(utoipa::OpenApi)]
#[openapi(paths(player::frame, player::overview::frame, pages::lti::jwks))]
struct PlayerApi;

/// `PlayerApi`'s document.
pub fn openapi() -> utoipa::openapi::OpenApi {
    <PlayerApi as utoipa::OpenApi>::openapi()
}

/// The dashboard's routes (`stylet serve` merges them with the API's).
pub fn router(state: Arc<AppState>) -> Router {
    // A multipart upload carries the file plus a little form overhead.
    let upload_limit = state.config.max_upload_bytes.saturating_add(64 << 10);
    Router::new()
        .route("/", get(pages::home::home))
        .route("/login", get(pages::login::form).post(pages::login::submit))
        .route("/logout", post(pages::login::logout))
        .route("/sessions", get(pages::sessions::list))
        .route("/sessions/{id}", get(pages::review::review))
        .route("/sessions/{id}/file", get(pages::review::file))
        .route("/sessions/{id}/slices.png", get(pages::review::slices))
        .route("/sessions/{id}/frame", get(player::frame))
        .route("/sessions/{id}/overview", get(player::overview::frame))
        .route("/assets/player.js", get(player::script))
        .route("/assets/dashboard.js", get(layout::script))
        .route("/assets/favicon.svg", get(layout::favicon))
        .route("/sessions/{id}/hits/{n}/slices.png", get(pages::review::hit_slices))
        .route("/sessions/{id}/comment", post(pages::review::comment))
        .route("/sessions/{id}/override", post(pages::review::override_grade))
        .route("/sessions/{id}/delete", post(pages::review::delete))
        .route("/sessions/{id}/expert", post(pages::benchmark::mark))
        .route(
            "/upload",
            post(pages::upload::upload).layer(DefaultBodyLimit::max(upload_limit)),
        )
        .route("/atlases", get(pages::catalogue::index))
        .route("/cohorts", get(pages::home::cohorts))
        .route("/cohorts/{name}", get(pages::cohort::cohort))
        .route("/compare", get(pages::compare::compare))
        .route("/review-queue", get(pages::instructors::review_queue))
        .route("/trainees/{username}", get(pages::instructors::trainee_progress))
        .route("/reports", get(pages::reports::index))
        .route("/reports/cohort", get(pages::reports::cohort_report))
        .route("/reports/cohort.pdf", get(pages::reports::cohort_report_pdf))
        .route("/admin/users", get(pages::admin::users).post(pages::admin::add_user))
        .route("/admin/users/import", post(pages::admin::import))
        .route("/admin/atlases", get(pages::admin_atlases::index))
        .route(
            "/admin/atlases/{hash}/withdraw",
            post(pages::admin_atlases::withdraw_form),
        )
        .route("/admin/users/{username}/status", post(pages::admin::set_status))
        .route("/admin/users/{username}/password", post(pages::admin::set_password))
        .route("/admin/users/{username}/set", post(pages::admin::set_user))
        .route("/tokens", get(pages::tokens::index).post(pages::tokens::create))
        .route("/tokens/{id}/revoke", post(pages::tokens::revoke))
        .route("/pair", get(pages::pairing::index).post(pages::pairing::create))
        .route("/pair/machines/{id}/revoke", post(pages::pairing::revoke))
        .route(
            "/admin/lti",
            get(pages::admin_lti::index).post(pages::admin_lti::register),
        )
        .route("/admin/lti/{id}/deployments", post(pages::admin_lti::add_deployment))
        .route("/lti/login", get(pages::lti::login_get).post(pages::lti::login_post))
        .route("/lti/launch", post(pages::lti::launch))
        .route("/lti/deep-link", post(pages::lti::pick))
        .route("/lti/submit.js", get(pages::lti::submit_js))
        .route("/lti/jwks", get(pages::lti::jwks))
        .with_state(state)
}
