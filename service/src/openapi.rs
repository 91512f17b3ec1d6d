//! The OpenAPI 3.1 document of the JSON API and its route (`GET /api/openapi.json`), derived from
//! the code:
//! - each handler's `#[utoipa::path]` annotation, next to it, gives its path, parameters, body,
//!   security and the statuses the handler answers itself, with the schemas of its answers
//!   (derived from the types it serializes, or, for answers built in place, shapes declared
//!   beside the handler); every error answer is [`ErrorBody`];
//! - the router is built from the same annotated handlers (the API's router, utoipa-axum), so a
//!   route cannot be served without being in the document;
//! - [`add_layer_statuses`] adds what the layers around every route can answer
//!   (docs/security.md): 408 past its deadline, 503 past the cap on requests being served (not
//!   `/healthz`), and on every route that needs a login 401 and 429 (the account's requests in
//!   flight).
//!
//! The service tests validate the server's real answers against this document.

use std::sync::Arc;

use axum::Json;
use axum::extract::State;
use serde::Serialize;
use utoipa::openapi::path::Operation;
use utoipa::openapi::security::{ApiKey, ApiKeyValue, HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::openapi::{ContentBuilder, OpenApi, Ref, RefOr, ResponseBuilder};
use utoipa::{Modify, ToSchema};

use super::AppState;
use super::store::ImportLineError;

/// The document's frame: title, description, security schemes.
#[derive(utoipa::OpenApi)]
#[openapi(
    info(
        title = "Stylet scoring service",
        description = "Uploads of session files, scoring by deterministic replay, scores by role. See docs/api.md; limits and the statuses they answer in docs/security.md."
    ),
    components(schemas(ErrorBody)),
    modifiers(&SecuritySchemes)
)]
pub struct ApiDoc;

struct SecuritySchemes;

impl Modify for SecuritySchemes {
    fn modify(&self, doc: &mut OpenApi) {
        let components = doc.components.get_or_insert_with(Default::default);
        let mut cookie = ApiKeyValue::new("stylet_session");
        cookie.description = Some("From POST /api/login. State-changing requests also send X-CSRF-Token.".into());
        components.add_security_scheme("cookie", SecurityScheme::ApiKey(ApiKey::Cookie(cookie)));
        components.add_security_scheme(
            "token",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some(
                        "From POST /api/tokens. Scope `upload` (the desktop simulator): POST /api/sessions, GET /api/sessions/{id} \
                         and GET /api/sessions/{id}/file only, 403 elsewhere; scope `full`: the account's rights. Expired or revoked: 401.",
                    ))
                    .build(),
            ),
        );
        components.add_security_scheme(
            "lab_token",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some(
                        "A lab machine's token, from POST /api/pair with a lab code: POST /api/lab/sign-in only.",
                    ))
                    .build(),
            ),
        );
    }
}

/// Every error: `{"error": "..."}` (at most 4 KiB; a bulk import's also names its bad lines).
#[derive(Serialize, ToSchema)]
#[schema(as = Error)]
pub struct ErrorBody {
    pub error: String,
}

/// A refused bulk import: every bad line, nothing imported.
#[derive(Serialize, ToSchema)]
pub struct ImportRefused {
    pub error: String,
    pub lines: Vec<ImportLineError>,
}

/// An error answer described by `why`: the Error body for the API, an error page for the
/// dashboard's routes.
fn error_response(why: &str, api: bool) -> RefOr<utoipa::openapi::Response> {
    let content = if api {
        ("application/json", Ref::from_schema_name("Error").into())
    } else {
        (
            "text/html",
            utoipa::openapi::schema::Object::with_type(utoipa::openapi::Type::String).into(),
        )
    };
    ResponseBuilder::new()
        .description(why)
        .content(
            content.0,
            ContentBuilder::new().schema(Some::<RefOr<_>>(content.1)).build(),
        )
        .build()
        .into()
}

/// Adds `status` to `op` unless the handler documents it itself.
fn add_status(op: &mut Operation, api: bool, status: &str, why: &str) {
    op.responses
        .responses
        .entry(status.to_string())
        .or_insert_with(|| error_response(why, api));
}

/// Whether an operation needs a login (it names a security requirement).
fn needs_login(op: &Operation) -> bool {
    op.security.as_ref().is_some_and(|s| !s.is_empty())
}

/// Adds the statuses the layers around every route can answer (see the module doc).
pub fn add_layer_statuses(doc: &mut OpenApi) {
    for (path, item) in doc.paths.paths.iter_mut() {
        let ops = [
            item.get.as_mut(),
            item.post.as_mut(),
            item.put.as_mut(),
            item.patch.as_mut(),
            item.delete.as_mut(),
        ];
        // The API answers JSON errors; the dashboard's routes error pages, and a login
        // redirect instead of 401.
        let api = path.starts_with("/api/") || path == "/healthz";
        for op in ops.into_iter().flatten() {
            add_status(
                op,
                api,
                "408",
                "the request took too long (its body sent too slowly?); the connection is closed",
            );
            if path != "/healthz" {
                add_status(
                    op,
                    api,
                    "503",
                    "the server is serving as many requests as it can, or cannot write its data now; try again after Retry-After",
                );
            }
            if needs_login(op) {
                if api {
                    add_status(
                        op,
                        api,
                        "401",
                        "not logged in, or the login or token expired, was revoked or its account disabled",
                    );
                }
                add_status(
                    op,
                    api,
                    "429",
                    "this account has as many requests in flight as it may; try again after Retry-After",
                );
            }
        }
    }
}

/// The whole document: [`ApiDoc`] with the routes' paths (`routes`, from the router) and the
/// layers' statuses.
pub fn document(routes: OpenApi) -> OpenApi {
    let mut doc = <ApiDoc as utoipa::OpenApi>::openapi();
    doc.merge(routes);
    doc.info.version = env!("CARGO_PKG_VERSION").to_string();
    add_layer_statuses(&mut doc);
    doc
}

/// This document.
#[utoipa::path(get, path = "/api/openapi.json", tag = "service",
    responses((status = 200, description = "OpenAPI 3.1", content_type = "application/json", body = Object)))]
pub async fn openapi(State(s): State<Arc<AppState>>) -> Json<serde_json::Value> {
    Json(s.openapi.get().cloned().unwrap_or_default())
}
