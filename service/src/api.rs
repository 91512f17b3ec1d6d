//! The JSON API's router: every route, each registered from its annotated handler in the module
//! of its resource, so that the router and the OpenAPI document's paths come from the same list
//! ([`super::openapi`]). Every route that shows data checks who asks: a trainee sees only their
//! own sessions, an instructor those of their cohorts, curriculum staff and admins all of them.
//! Errors are JSON `{"error": "..."}` with a 4xx status that says what was wrong.

use std::sync::Arc;

use axum::Router;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{
    AppState, atlases, experts, export, health, logins, openapi, pairing, reports, review, sessions, tokens, upload,
    users,
};

// What the dashboard and the command line call from the API's modules, under one path.
pub use super::access::{may_review, may_see, reviewable};
pub use super::error::{ApiError, MAX_ERROR_MESSAGE_BYTES, bounded};
pub use super::extract::hold_request_slot;
pub use super::list_query::{ListQuery, PAGE_SIZE};
pub use super::logins::{LOGIN_TTL_S, log_in};
pub use super::review::{check_comment, check_comment_time, check_override};
pub use super::sessions::remove_session;
pub use super::upload::{accept_upload, accept_upload_bytes, content_length};

/// The API's routes, each registered from its annotated handler: the router and the OpenAPI
/// document's paths come from the same list.
pub fn routes() -> OpenApiRouter<Arc<AppState>> {
    OpenApiRouter::new()
        .routes(routes!(health::healthz))
        .routes(routes!(openapi::openapi))
        .routes(routes!(logins::login))
        .routes(routes!(logins::logout))
        .routes(routes!(tokens::create_token, tokens::list_tokens))
        .routes(routes!(tokens::revoke_token))
        .routes(routes!(pairing::revoke_current_token))
        .routes(routes!(pairing::create_code))
        .routes(routes!(pairing::pair))
        .routes(routes!(pairing::lab_sign_in))
        .routes(routes!(pairing::list_lab_machines))
        .routes(routes!(pairing::revoke_machine))
        .routes(routes!(users::add_or_import, users::list))
        .routes(routes!(users::get_one, users::patch))
        .routes(routes!(users::disable))
        .routes(routes!(users::enable))
        .routes(routes!(users::password))
        .routes(routes!(atlases::publish_atlas, atlases::list))
        .routes(routes!(atlases::unpublish))
        .routes(routes!(upload::upload, sessions::list_sessions))
        .routes(routes!(sessions::get_session, sessions::delete_session))
        .routes(routes!(sessions::get_session_file))
        .routes(routes!(review::override_grade))
        .routes(routes!(review::add_comment))
        .routes(routes!(experts::mark, experts::unmark))
        .routes(routes!(experts::get))
        .routes(routes!(reports::progress))
        .routes(routes!(reports::cohort_summary))
        .routes(routes!(export::export_csv))
}

/// The API's router; its OpenAPI document (with `more`, the paths of the routes mounted beside
/// it) is kept in the state for `GET /api/openapi.json`.
pub fn router(state: Arc<AppState>, more: Option<utoipa::openapi::OpenApi>) -> Router {
    let (router, mut paths) = routes().split_for_parts();
    if let Some(more) = more {
        paths.merge(more);
    }
    let doc = openapi::document(paths);
    let _ = state
        .openapi
        .set(serde_json::to_value(&doc).expect("the OpenAPI document serializes"));
    router.with_state(state)
}
