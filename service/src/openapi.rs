//! The OpenAPI 3.1 document of the JSON API (`GET /api/openapi.json`), derived from the code:
//! - each handler's `#[utoipa::path]` annotation, next to it, gives its path, parameters, body,
//!   security and the statuses the handler answers itself, with the schemas of its answers
//!   (derived from the types it serializes, or the shapes below for answers built in place);
//! - the router is built from the same annotated handlers ([`crate::api::router`], utoipa-axum),
//!   so a route cannot be served without being in the document;
//! - [`add_layer_statuses`] adds what the layers around every route can answer
//!   (docs/security.md): 408 past its deadline, 503 past the cap on requests being served (not
//!   `/healthz`), and on every route that needs a login 401 and 429 (the account's requests in
//!   flight).
//!
//! The service tests validate the server's real answers against this document.

use serde::Serialize;
use utoipa::openapi::path::Operation;
use utoipa::openapi::security::{ApiKey, ApiKeyValue, HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::openapi::{ContentBuilder, OpenApi, Ref, RefOr, ResponseBuilder};
use utoipa::{Modify, ToSchema};

use super::store::{Role, SessionStatus};

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
    pub lines: Vec<super::store::ImportLineError>,
}

/// `GET /healthz`.
#[derive(Serialize, ToSchema)]
pub struct Health {
    /// "ok".
    pub status: String,
}

/// A login: who, and the CSRF token state-changing requests send in `X-CSRF-Token`.
#[derive(Serialize, ToSchema)]
pub struct LoginAnswer {
    pub username: String,
    pub role: Role,
    pub csrf_token: String,
}

/// `{"status": "logged out"}`.
#[derive(Serialize, ToSchema)]
pub struct LogoutAnswer {
    pub status: String,
}

/// An upload's session: its id and where it is on its way to a score.
#[derive(Serialize, ToSchema)]
pub struct UploadAnswer {
    pub id: String,
    pub status: SessionStatus,
}

/// A page of sessions, newest first.
#[derive(Serialize, ToSchema)]
pub struct SessionPage {
    pub sessions: Vec<super::store::SessionLine>,
    pub total: i64,
    pub page: i64,
    pub page_size: i64,
}

/// `{"deleted": id}`.
#[derive(Serialize, ToSchema)]
pub struct Deleted {
    pub deleted: String,
}

/// A grade override as stored.
#[derive(Serialize, ToSchema)]
pub struct OverrideAnswer {
    pub session: String,
    pub score: f64,
    pub passed: bool,
    pub reason: String,
}

/// A comment as stored.
#[derive(Serialize, ToSchema)]
pub struct CommentAnswer {
    pub id: String,
    pub session: String,
}

/// A trainee's scored sessions per difficulty (`beginner`, `advanced`, `expert`), each a list of
/// `{id, uploaded_at, score, passed, …}` in upload order.
#[derive(Serialize, ToSchema)]
pub struct Progress {
    pub trainee: String,
    #[schema(value_type = Object)]
    pub progress: serde_json::Value,
}

/// Per trainee of a cohort: sessions, scored, passed, mean score, last upload.
#[derive(Serialize, ToSchema)]
pub struct CohortSummary {
    pub cohort: String,
    #[schema(value_type = Vec<Object>)]
    pub trainees: Vec<serde_json::Value>,
}

/// A page of accounts, by username.
#[derive(Serialize, ToSchema)]
pub struct AccountPage {
    pub users: Vec<super::store::UserRow>,
    pub total: i64,
    pub page: i64,
    pub page_size: i64,
}

/// A new account (JSON), or the accounts a CSV import added (`imported`).
#[derive(Serialize, ToSchema)]
pub struct AccountAdded {
    pub username: Option<String>,
    pub role: Option<Role>,
    pub cohort: Option<String>,
    pub imported: Option<Vec<String>>,
}

/// The caller's API tokens.
#[derive(Serialize, ToSchema)]
pub struct TokenList {
    pub tokens: Vec<super::store::TokenRow>,
}

/// A new API token: the row and `token`, the secret, shown only here.
#[derive(Serialize, ToSchema)]
pub struct NewToken {
    #[serde(flatten)]
    pub row: super::store::TokenRow,
    pub token: String,
}

/// The scenario catalogue.
#[derive(Serialize, ToSchema)]
pub struct Catalogue {
    pub atlases: Vec<super::atlases::CatalogueItem>,
}

/// What became of a publication or a withdrawal: `published` (201), `already_published` (200),
/// `withdrawn`.
#[derive(Serialize, ToSchema)]
pub struct AtlasAnswer {
    pub content_hash: String,
    pub name: String,
    pub status: String,
    /// The service's smoke test, one line per script (a new publication).
    pub smoke: Option<Vec<String>>,
    /// The atlas as the catalogue lists it (a new publication).
    pub atlas: Option<super::atlases::CatalogueItem>,
}

/// Whether a session is an expert reference now.
#[derive(Serialize, ToSchema)]
pub struct ExpertAnswer {
    pub session: String,
    pub expert: bool,
}

/// The expert benchmark of a session's scenario and the session's metrics against it.
#[derive(Serialize, ToSchema)]
pub struct BenchmarkAnswer {
    pub scenario: String,
    pub exercise: String,
    pub experts: i64,
    #[schema(value_type = Vec<Object>)]
    pub metrics: Vec<serde_json::Value>,
    pub expert: bool,
    #[schema(value_type = Vec<Object>)]
    pub comparison: Vec<serde_json::Value>,
    /// Staff only.
    #[schema(value_type = Option<Vec<Object>>)]
    pub references: Option<Vec<serde_json::Value>>,
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
