//! JSON API routes. Every route that shows data checks who asks: a trainee sees only their own
//! sessions, an instructor those of their cohorts, curriculum staff and admins all of them.
//! Errors are JSON `{"error": "..."}` with a 4xx status that says what was wrong.

use std::sync::Arc;

use axum::Json;
use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::json;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::AppState;
use super::auth;
use super::store::{NewSession, Role, SessionStatus, User};
use stylet_scoring::Difficulty;

type AppRef = Arc<AppState>;

pub use super::access::{may_review, may_see, reviewable, visible_session};
pub use super::error::{ApiError, MAX_ERROR_MESSAGE_BYTES, bounded, err};
pub use super::extract::{
    Actor, AdminActor, AdminReader, CookieActor, Reader, SimulatorActor, SimulatorReader, TokenUse, Via, authenticate,
    hold_request_slot, require_admin, user_for,
};

/// The API's routes, each registered from its annotated handler: the router and the OpenAPI
/// document's paths come from the same list ([`super::openapi`]).
pub fn routes() -> OpenApiRouter<AppRef> {
    OpenApiRouter::new()
        .routes(routes!(healthz))
        .routes(routes!(openapi))
        .routes(routes!(login))
        .routes(routes!(logout))
        .routes(routes!(super::tokens::create_token, super::tokens::list_tokens))
        .routes(routes!(super::tokens::revoke_token))
        .routes(routes!(super::users::add_or_import, super::users::list))
        .routes(routes!(super::users::get_one, super::users::patch))
        .routes(routes!(super::users::disable))
        .routes(routes!(super::users::enable))
        .routes(routes!(super::users::password))
        .routes(routes!(super::atlases::publish_atlas, super::atlases::list))
        .routes(routes!(super::atlases::unpublish))
        .routes(routes!(upload, list_sessions))
        .routes(routes!(get_session, delete_session))
        .routes(routes!(get_session_file))
        .routes(routes!(override_grade))
        .routes(routes!(add_comment))
        .routes(routes!(super::experts::mark, super::experts::unmark))
        .routes(routes!(super::experts::get))
        .routes(routes!(progress))
        .routes(routes!(cohort_summary))
        .routes(routes!(export_csv))
}

/// The API's router; its OpenAPI document (with `more`, the paths of the routes mounted beside
/// it) is kept in the state for `GET /api/openapi.json`.
pub fn router(state: AppRef, more: Option<utoipa::openapi::OpenApi>) -> Router {
    let (router, mut paths) = routes().split_for_parts();
    if let Some(more) = more {
        paths.merge(more);
    }
    let doc = super::openapi::document(paths);
    let _ = state
        .openapi
        .set(serde_json::to_value(&doc).expect("the OpenAPI document serializes"));
    router.with_state(state)
}

/// Gives every request an id (the client's `X-Request-Id` if sensible, else a new UUID), logs it
/// with method, path, status and duration, and returns it in `X-Request-Id`.
pub async fn request_log(req: axum::extract::Request, next: axum::middleware::Next) -> Response {
    use tracing::Instrument;
    let id = req
        .headers()
        .get("x-request-id")
        .and_then(|v| v.to_str().ok())
        .filter(|v| !v.is_empty() && v.len() <= 64 && v.chars().all(|c| c.is_ascii_alphanumeric() || c == '-'))
        .map_or_else(super::store::new_id, str::to_string);
    let span = tracing::info_span!("request", id = %id, method = %req.method(), path = %req.uri().path());
    let started = std::time::Instant::now();
    let mut resp = next.run(req).instrument(span.clone()).await;
    span.in_scope(|| {
        tracing::info!(
            status = resp.status().as_u16(),
            ms = started.elapsed().as_secs_f64() * 1e3,
            "served"
        )
    });
    if let Ok(v) = id.parse() {
        resp.headers_mut().insert("x-request-id", v);
    }
    resp
}

/// This document.
#[utoipa::path(get, path = "/api/openapi.json", tag = "service",
    responses((status = 200, description = "OpenAPI 3.1", content_type = "application/json", body = Object)))]
async fn openapi(State(s): State<AppRef>) -> Json<serde_json::Value> {
    Json(s.openapi.get().cloned().unwrap_or_default())
}

/// GET /healthz: 200 while the service can read and write its database and data directory,
/// 503 otherwise (checked by writing, at most once a second).
#[utoipa::path(get, path = "/healthz", tag = "service",
    summary = "Health: the database and the data directory can be written",
    responses(
        (status = 200, description = "healthy", body = super::openapi::Health),
        (status = 503, description = "the database or the data directory cannot be written", body = super::openapi::ErrorBody),
    ))]
async fn healthz(State(s): State<AppRef>) -> Response {
    let probe = async {
        if let Err(e) = s.store.probe_write().await {
            tracing::warn!(error = %e, "health check: the database cannot write");
            return false;
        }
        let file = s.config.data_dir.join("sessions").join(".health-check");
        let written = tokio::fs::write(&file, b"ok").await;
        let _ = tokio::fs::remove_file(&file).await;
        if let Err(e) = written {
            tracing::warn!(error = %e, "health check: the data directory cannot write");
            return false;
        }
        true
    };
    if s.health.check(probe).await {
        Json(json!({ "status": "ok" })).into_response()
    } else {
        err(
            StatusCode::SERVICE_UNAVAILABLE,
            "unhealthy: the database or the data directory cannot be written",
        )
        .into_response()
    }
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
struct LoginRequest {
    #[schema(max_length = 64)]
    username: String,
    #[schema(max_length = 4096)]
    password: String,
}

/// How long a login lasts (s).
pub const LOGIN_TTL_S: u64 = 12 * 3600;

/// Failed logins allowed per account within [`LOGIN_WINDOW`] before 429.
pub const LOGIN_FAILURES_ALLOWED: usize = 5;
pub const LOGIN_WINDOW: std::time::Duration = std::time::Duration::from_secs(300);

#[utoipa::path(post, path = "/api/login", tag = "accounts",
    summary = "Log in; sets the stylet_session cookie",
    request_body(content = LoginRequest, content_type = "application/json"),
    responses(
        (status = 200, description = "logged in", body = super::openapi::LoginAnswer),
        (status = 400, description = "malformed body", body = super::openapi::ErrorBody),
        (status = 401, description = "wrong username or password", body = super::openapi::ErrorBody),
        (status = 403, description = "sent from another site (Sec-Fetch-Site, or an Origin or Referer that is not this server), or the account is disabled", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over the limit of other requests (--max-body-bytes)", body = super::openapi::ErrorBody),
        (status = 415, description = "not application/json", body = super::openapi::ErrorBody),
        (status = 429, description = "too many failed logins for this account; Retry-After says when to try again", body = super::openapi::ErrorBody),
    ))]
async fn login(State(s): State<AppRef>, headers: HeaderMap, body: Bytes) -> Result<Response, ApiError> {
    if auth::from_other_site(&headers) {
        return Err(err(StatusCode::FORBIDDEN, "logins sent from other sites are refused"));
    }
    // Only JSON: an HTML form on another site can send text/plain that happens to parse as JSON.
    let json_body = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|v| v.trim().eq_ignore_ascii_case("application/json"));
    if !json_body {
        return Err(err(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "send the login as Content-Type: application/json",
        ));
    }
    let req: LoginRequest = serde_json::from_slice(&body).map_err(|e| {
        err(
            StatusCode::BAD_REQUEST,
            format!("expected {{\"username\", \"password\"}}: {e}"),
        )
    })?;
    let (user, token, csrf) = log_in(&s, &req.username, &req.password).await?;
    let mut r = Json(json!({ "username": user.username, "role": user.role, "csrf_token": csrf })).into_response();
    r.headers_mut().insert(
        header::SET_COOKIE,
        auth::login_cookie(&token, s.config.secure_cookies, LOGIN_TTL_S)
            .parse()
            .expect("a valid header value"),
    );
    Ok(r)
}

/// Longest username a login may name: no account has a longer one (checked before anything else,
/// so that no memory or work is spent on longer ones).
pub const MAX_USERNAME_BYTES: usize = 64;
/// Longest password a login may send (characters, as for accounts; 4 bytes each at most).
pub const MAX_PASSWORD_BYTES: usize = 4 * 1024;

/// Checks a password (with per-account rate limiting, on the password threads) and starts a
/// login: the user, the cookie token and the login's CSRF token. Used by the JSON API and the
/// dashboard's login form.
pub async fn log_in(s: &AppState, username: &str, password: &str) -> Result<(User, String, String), ApiError> {
    if username.len() > MAX_USERNAME_BYTES || password.len() > MAX_PASSWORD_BYTES {
        return Err(err(StatusCode::UNAUTHORIZED, "wrong username or password"));
    }
    let account = s.login_failures.of(&username.to_lowercase());
    let mut recent = account.lock().await;
    let now = std::time::Instant::now();
    recent.retain(|t| now.duration_since(*t) < LOGIN_WINDOW);
    if recent.len() >= LOGIN_FAILURES_ALLOWED {
        let wait = LOGIN_WINDOW.saturating_sub(now.duration_since(recent[0])).as_secs() + 1;
        return Err(ApiError::Throttled {
            message: format!("too many failed logins for this account; try again in {wait} s"),
            retry_after_s: wait as u32,
        });
    }
    let candidate = s.store.login_candidate(username).await?;
    // Same work whether or not the account exists, so timing does not reveal which do.
    let hash = candidate.as_ref().map_or(auth::DUMMY_HASH, |(_, h, _)| h.as_str());
    let matched = s
        .passwords
        .verify(password, hash)
        .await
        .map_err(|e| err(StatusCode::SERVICE_UNAVAILABLE, e.to_string()))?;
    let user = match candidate {
        // Told only to whoever knows the password.
        Some((_, _, true)) if matched => {
            recent.clear();
            return Err(err(StatusCode::FORBIDDEN, "this account is disabled; ask an admin"));
        }
        Some((user, _, _)) if matched => user,
        _ => {
            recent.push(now);
            return Err(err(StatusCode::UNAUTHORIZED, "wrong username or password"));
        }
    };
    recent.clear();
    drop(recent);
    let (token, csrf) = s.store.create_login(&user, LOGIN_TTL_S).await?;
    Ok((user, token, csrf))
}

/// POST /api/logout: ends the login of the cookie sent (none: nothing to end). API tokens do
/// not log in, so they cannot log out either: a request with one is refused (403), whatever its
/// scope, so that a token (an upload-scoped one on a lab's simulator) cannot end its account's
/// logins.
#[utoipa::path(post, path = "/api/logout", tag = "accounts",
    summary = "Log out: ends the login of the cookie sent",
    responses(
        (status = 200, description = "logged out", body = super::openapi::LogoutAnswer),
        (status = 403, description = "sent with an API token: tokens do not log in or out", body = super::openapi::ErrorBody),
    ))]
async fn logout(State(s): State<AppRef>, headers: HeaderMap) -> Result<Response, ApiError> {
    if headers.contains_key(header::AUTHORIZATION) {
        return Err(err(
            StatusCode::FORBIDDEN,
            "API tokens cannot log out: a token stays valid until it expires or is revoked (POST /api/tokens/{id}/revoke)",
        ));
    }
    if let Some(token) = headers
        .get(header::COOKIE)
        .and_then(|v| v.to_str().ok())
        .and_then(auth::token_from_cookie_header)
    {
        s.store.end_login(token).await?;
    }
    let mut r = Json(json!({ "status": "logged out" })).into_response();
    r.headers_mut().insert(
        header::SET_COOKIE,
        auth::logout_cookie(s.config.secure_cookies)
            .parse()
            .expect("a valid header value"),
    );
    Ok(r)
}

/// POST /api/sessions: the session file as `application/octet-stream`. Received and checked
/// before anything is stored ([`super::upload`]): who asks, the size, an upload slot and room on
/// the disk before the body; who may upload the header's trainee and the header's fields from
/// its first bytes; then the rest to a temporary file and the recorder's strict reader streaming
/// its ticks within the upload limits.
#[utoipa::path(post, path = "/api/sessions", tag = "sessions",
    summary = "Upload a session file",
    description = "API tokens of either scope may upload (the desktop simulator). Checked before anything is stored: who asks, the size, an upload slot (per account and in all) and room on the disk before the body; who may upload the header's trainee and the header's fields from its first bytes; then the rest, at no less than the minimum rate, verified from disk.",
    request_body(content = Vec<u8>, content_type = "application/octet-stream"),
    responses(
        (status = 201, description = "new bytes: stored and queued for scoring", body = super::openapi::UploadAnswer),
        (status = 200, description = "the same bytes were uploaded before", body = super::openapi::UploadAnswer),
        (status = 400, description = "empty body, or the body broke off", body = super::openapi::ErrorBody),
        (status = 403, description = "may not upload for this trainee, the trainee's account is disabled, or CSRF token missing", body = super::openapi::ErrorBody),
        (status = 413, description = "over the size limit (--max-upload-bytes)", body = super::openapi::ErrorBody),
        (status = 422, description = "not a valid session file, an unknown or withdrawn atlas, an unknown trainee, scenario, difficulty or device, or more than the server replays", body = super::openapi::ErrorBody),
        (status = 429, description = "this account has as many uploads in progress as it may; Retry-After", body = super::openapi::ErrorBody),
        (status = 503, description = "the server takes as many uploads as it can, or its disk is too full; Retry-After", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn upload(
    State(s): State<AppRef>,
    SimulatorActor(user): SimulatorActor,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let (id, status, created) = accept_upload(&s, &user, body.into_data_stream(), content_length(&headers)).await?;
    let code = if created { StatusCode::CREATED } else { StatusCode::OK };
    Ok((code, Json(json!({ "id": id, "status": status }))).into_response())
}

/// The request's `Content-Length`, if it sent a valid one.
pub fn content_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
}

/// [`accept_upload`] of a file already in memory (the demo's own sessions).
pub async fn accept_upload_bytes(
    s: &AppState,
    user: &User,
    bytes: Vec<u8>,
) -> Result<(String, SessionStatus, bool), ApiError> {
    let len = bytes.len() as u64;
    let body = futures_util::stream::iter([Ok::<_, std::convert::Infallible>(Bytes::from(bytes))]);
    accept_upload(s, user, body, Some(len)).await
}

/// Receives an upload `body` (its chunks), checks it and stores it (the file by content hash,
/// renamed into place, then the session and job rows): returns the session id, its status and
/// whether it is new. Nothing is left behind on refusal.
pub async fn accept_upload<S, E>(
    s: &AppState,
    user: &User,
    body: S,
    declared: Option<u64>,
) -> Result<(String, SessionStatus, bool), ApiError>
where
    S: futures_util::Stream<Item = Result<Bytes, E>> + Unpin,
    E: std::fmt::Display,
{
    let checked = super::upload::receive(s, user, body, declared).await?;
    let (h, trainee) = (&checked.header, &checked.trainee);
    let sha = checked.sha256.clone();
    let existing = |id: String| async move {
        let status = s
            .store
            .session(&id)
            .await?
            .map_or(SessionStatus::Queued, |(r, _)| r.status);
        Ok::<_, ApiError>((id, status, false))
    };
    if let Some(id) = s.store.session_by_file(&sha).await? {
        return existing(id).await;
    }
    // The file first (renamed into place by content hash: two uploads of the same bytes may
    // race here, and either rename leaves the same bytes), then the rows in one transaction.
    let new = NewSession {
        file_sha256: sha.clone(),
        size_bytes: checked.file.bytes as i64,
        session_uuid: h.session_id.clone(),
        trainee_id: trainee.id.clone(),
        uploaded_by: user.id.clone(),
        scenario: h.scenario.clone(),
        difficulty: h.difficulty.clone(),
        atlas_hash: h.atlas_hash.clone(),
        physics_version: h.physics_version as i64,
        duration_s: checked.verified.duration_s(),
        recorded_at: h.wall_clock_start.clone(),
    };
    checked.file.persist(&s.session_file(&sha)).await?;
    let id = match s.store.insert_session(&new).await {
        Ok(id) => id,
        Err(e) => {
            // Lost a race with an upload of the same bytes: that row owns the file now.
            if let Some(id) = s.store.session_by_file(&new.file_sha256).await? {
                return existing(id).await;
            }
            // The file stays: a concurrent upload of the same bytes whose row is not committed
            // yet may own it. Unreferenced, it is only reused by the next upload of these bytes.
            tracing::error!(sha256 = %new.file_sha256, "upload stored but its row was not written");
            return Err(e.into());
        }
    };
    s.wake.notify_one();
    Ok((id, SessionStatus::Queued, true))
}

#[utoipa::path(get, path = "/api/sessions/{id}", tag = "sessions",
    summary = "One session, its score and its review",
    description = "API tokens of either scope may read it (the simulator polls the status of its upload).",
    params(("id" = String, Path, description = "session id")),
    responses(
        (status = 200, description = "the session", body = super::store::SessionRow),
        (status = 404, description = "no such session, or not yours to see", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn get_session(
    State(s): State<AppRef>,
    SimulatorReader(user): SimulatorReader,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let row = visible_session(&s, &user, &id).await?;
    let mut v = serde_json::to_value(&row).map_err(|_| err(StatusCode::INTERNAL_SERVER_ERROR, "internal error"))?;
    v["review"] = s.store.annotations(&id).await?;
    Ok(Json(v).into_response())
}

/// GET /api/sessions/{id}/file: the session file as uploaded, for whoever may see the session
/// (upload-scoped tokens too: the simulator's replay viewer fetches it). Streamed in 64 KiB
/// chunks, so a download holds no more than that in memory.
#[utoipa::path(get, path = "/api/sessions/{id}/file", tag = "sessions",
    summary = "The session file as uploaded (streamed)",
    description = "For whoever may see the session; API tokens of either scope (the simulator's replay viewer).",
    params(("id" = String, Path, description = "session id")),
    responses(
        (status = 200, description = "the session file (docs/session-format.md)", content_type = "application/octet-stream", body = Vec<u8>),
        (status = 404, description = "no such session, or not yours to see, or its file is gone", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn get_session_file(
    State(s): State<AppRef>,
    SimulatorReader(user): SimulatorReader,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let row = visible_session(&s, &user, &id).await?;
    let path = s.session_file(&row.file_sha256);
    let file = tokio::fs::File::open(&path)
        .await
        .map_err(|_| err(StatusCode::NOT_FOUND, format!("the file of session {id} is gone")))?;
    let len = file.metadata().await.map(|m| m.len()).ok();
    let chunks = futures_util::stream::unfold(Some(file), |file| async move {
        use tokio::io::AsyncReadExt;
        let mut file = file?;
        let mut buf = vec![0u8; 64 * 1024];
        match file.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((Ok::<_, std::io::Error>(Bytes::from(buf)), Some(file)))
            }
            Err(e) => Some((Err(e), None)),
        }
    });
    let mut resp = Body::from_stream(chunks).into_response();
    let h = resp.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        header::HeaderValue::from_static("application/octet-stream"),
    );
    if let Some(len) = len {
        h.insert(header::CONTENT_LENGTH, header::HeaderValue::from(len));
    }
    if let Ok(v) = header::HeaderValue::from_str(&format!("attachment; filename=\"{}.mcap\"", row.id)) {
        h.insert(header::CONTENT_DISPOSITION, v);
    }
    Ok(resp)
}

/// DELETE /api/sessions/{id} (admins): the session, its file, score, job, comments, overrides and
/// derived data go; audited.
#[utoipa::path(delete, path = "/api/sessions/{id}", tag = "sessions",
    summary = "Delete a session (admins): rows, file, trace, figures and player frames; audited",
    description = "Works on a full disk: the session's files go first to make room for the database's journal.",
    params(("id" = String, Path, description = "session id")),
    responses(
        (status = 200, description = "deleted", body = super::openapi::Deleted),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn delete_session(
    State(s): State<AppRef>,
    Actor(user): Actor,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    remove_session(&s, &user, &id).await?;
    Ok(Json(json!({ "deleted": id })).into_response())
}

/// Deletes a session for an admin (API and dashboard): the rows in one transaction, then the
/// stored file and what was derived from it (review trace, figures, player frames). On a full
/// disk (SQLite needs room for its journal even to delete) the session's files go first, to
/// make that room, and the rows after them.
pub async fn remove_session(s: &AppState, user: &User, id: &str) -> Result<(), ApiError> {
    if user.role != Role::Admin {
        return Err(err(
            StatusCode::FORBIDDEN,
            format!("{} ({}) may not delete sessions", user.username, user.role),
        ));
    }
    let not_found = || err(StatusCode::NOT_FOUND, format!("no session {id}"));
    let sha = match s.store.delete_session(id, user).await {
        Ok(sha) => sha.ok_or_else(not_found)?,
        Err(e) if e.is_disk_full() => {
            tracing::warn!(session = %id, "the disk is full: the session's files are removed first to make room");
            let (row, _) = s.store.session(id).await?.ok_or_else(not_found)?;
            remove_session_files(s, &row.file_sha256).await;
            s.store.delete_session(id, user).await?.ok_or_else(not_found)?
        }
        Err(e) => return Err(e.into()),
    };
    remove_session_files(s, &sha).await;
    tracing::info!(session = %id, by = %user.username, "session deleted");
    Ok(())
}

/// Removes what is stored of the session file `sha`: the file, its review trace and figures
/// (`DATA/<kind>/<first two hex digits>/<sha>…`) and its player frames (a folder,
/// `DATA/frames/<first two>/<sha>/`). What cannot be removed is logged.
async fn remove_session_files(s: &AppState, sha: &str) {
    let prefix = &sha[..2.min(sha.len())];
    for kind in ["sessions", "traces", "figures"] {
        let dir = s.config.data_dir.join(kind).join(prefix);
        let Ok(mut entries) = tokio::fs::read_dir(&dir).await else {
            continue;
        };
        while let Ok(Some(e)) = entries.next_entry().await {
            if e.file_name().to_string_lossy().starts_with(sha)
                && let Err(err) = tokio::fs::remove_file(e.path()).await
            {
                tracing::warn!(error = %err, file = %e.path().display(), "cannot remove a deleted session's file");
            }
        }
    }
    let frames = s.config.data_dir.join("frames").join(prefix).join(sha);
    if let Err(e) = tokio::fs::remove_dir_all(&frames).await
        && e.kind() != std::io::ErrorKind::NotFound
    {
        tracing::warn!(error = %e, dir = %frames.display(), "cannot remove a deleted session's player frames");
    }
}

/// An override's score must lie in 0…100 and it needs a reason; returns the trimmed reason.
pub fn check_override(score: f64, reason: &str) -> Result<&str, ApiError> {
    if !(score.is_finite() && (0.0..=100.0).contains(&score)) {
        return Err(err(StatusCode::BAD_REQUEST, "score must lie in 0…100"));
    }
    let reason = reason.trim();
    if reason.is_empty() || reason.chars().count() > 2000 {
        return Err(err(
            StatusCode::BAD_REQUEST,
            "an override needs a reason (1–2000 characters)",
        ));
    }
    Ok(reason)
}

/// A comment's moment lies within the session: 0 ≤ at_s ≤ its duration (s), to the millisecond.
pub fn check_comment_time(at_s: Option<f64>, duration_s: f64) -> Result<Option<f64>, ApiError> {
    let Some(t) = at_s else { return Ok(None) };
    let end = (duration_s.max(0.0) * 1000.0).ceil() / 1000.0;
    if !(t.is_finite() && (0.0..=end).contains(&t)) {
        return Err(err(
            StatusCode::BAD_REQUEST,
            format!("a comment's moment must lie within the session, 0–{end:.1} s"),
        ));
    }
    Ok(Some((t * 1000.0).round() / 1000.0))
}

/// A comment is 1–10000 characters; returns it trimmed.
pub fn check_comment(text: &str) -> Result<&str, ApiError> {
    let text = text.trim();
    if text.is_empty() || text.chars().count() > 10_000 {
        return Err(err(StatusCode::BAD_REQUEST, "a comment is 1–10000 characters"));
    }
    Ok(text)
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
struct OverrideRequest {
    #[schema(minimum = 0, maximum = 100)]
    score: f64,
    passed: bool,
    #[schema(min_length = 1, max_length = 2000)]
    reason: String,
}

/// POST /api/sessions/{id}/override: a new grade with a reason (audited); the computed score stays.
#[utoipa::path(post, path = "/api/sessions/{id}/override", tag = "review",
    summary = "Override the grade with a reason (the trainee's instructors, admins; audited)",
    params(("id" = String, Path, description = "session id")),
    request_body(content = OverrideRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "stored", body = super::openapi::OverrideAnswer),
        (status = 400, description = "bad body: score in 0…100, a reason", body = super::openapi::ErrorBody),
        (status = 403, description = "not a reviewer of this trainee, CSRF or token scope", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over --max-body-bytes", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn override_grade(
    State(s): State<AppRef>,
    Actor(user): Actor,
    Path(id): Path<String>,
    body: Bytes,
) -> Result<Response, ApiError> {
    let req: OverrideRequest = serde_json::from_slice(&body).map_err(|e| {
        err(
            StatusCode::BAD_REQUEST,
            format!("expected {{\"score\", \"passed\", \"reason\"}}: {e}"),
        )
    })?;
    let reason = check_override(req.score, &req.reason)?;
    reviewable(&s, &user, &id).await?;
    s.store
        .override_grade(&id, &user, req.score, req.passed, reason)
        .await?;
    Ok((
        StatusCode::CREATED,
        Json(json!({ "session": id, "score": req.score, "passed": req.passed, "reason": reason })),
    )
        .into_response())
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
struct CommentRequest {
    #[schema(min_length = 1, max_length = 10000)]
    body: String,
    /// The moment of the session the comment points at (s from its start), if any.
    #[serde(default)]
    at_s: Option<f64>,
}

#[utoipa::path(post, path = "/api/sessions/{id}/comments", tag = "review",
    summary = "Comment on a session (the trainee's instructors, admins)",
    params(("id" = String, Path, description = "session id")),
    request_body(content = CommentRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "stored", body = super::openapi::CommentAnswer),
        (status = 400, description = "bad body: 1–10000 characters, a moment inside the session", body = super::openapi::ErrorBody),
        (status = 403, description = "not a reviewer of this trainee, CSRF or token scope", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over --max-body-bytes", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn add_comment(
    State(s): State<AppRef>,
    Actor(user): Actor,
    Path(id): Path<String>,
    body: Bytes,
) -> Result<Response, ApiError> {
    let req: CommentRequest = serde_json::from_slice(&body)
        .map_err(|e| err(StatusCode::BAD_REQUEST, format!("expected {{\"body\"}}: {e}")))?;
    let text = check_comment(&req.body)?;
    reviewable(&s, &user, &id).await?;
    let at_s = match req.at_s {
        Some(t) => {
            let gone = || err(StatusCode::NOT_FOUND, format!("no session {id}"));
            let (row, _) = s.store.session(&id).await?.ok_or_else(gone)?;
            check_comment_time(Some(t), row.duration_s)?
        }
        None => None,
    };
    let cid = s.store.add_comment(&id, &user, text, at_s).await?;
    Ok((StatusCode::CREATED, Json(json!({ "id": cid, "session": id }))).into_response())
}

/// GET /api/trainees/{username}/progress: scored sessions in upload order, grouped by difficulty.
#[utoipa::path(get, path = "/api/trainees/{username}/progress", tag = "review",
    summary = "A trainee's scored sessions per difficulty, in upload order (overrides applied)",
    params(("username" = String, Path)),
    responses(
        (status = 200, description = "progress", body = super::openapi::Progress),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such trainee, or not yours to see", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn progress(
    State(s): State<AppRef>,
    Reader(user): Reader,
    Path(username): Path<String>,
) -> Result<Response, ApiError> {
    let not_found = || err(StatusCode::NOT_FOUND, format!("no trainee {username}"));
    let trainee = s
        .store
        .user_by_name(&username)
        .await?
        .filter(|t| t.role == Role::Trainee)
        .ok_or_else(not_found)?;
    if !may_see(&s, &user, &trainee.id).await? {
        return Err(not_found());
    }
    let points = s.store.progress(&trainee.id).await?;
    let mut by_level = serde_json::Map::new();
    for level in Difficulty::ALL {
        let series: Vec<&super::store::ProgressPoint> =
            points.iter().filter(|p| p.difficulty == level.as_str()).collect();
        by_level.insert(level.to_string(), json!(series));
    }
    Ok(Json(json!({ "trainee": trainee.username, "progress": by_level })).into_response())
}

/// GET /api/cohorts/{name}/summary: per trainee counts, pass rate and mean score.
#[utoipa::path(get, path = "/api/cohorts/{name}/summary", tag = "review",
    summary = "Per trainee of a cohort: sessions, scored, passed, mean score, last upload",
    params(("name" = String, Path), ListQuery),
    responses(
        (status = 200, description = "the summary", body = super::openapi::CohortSummary),
        (status = 400, description = "a bad filter", body = super::openapi::ErrorBody),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such cohort, or not yours", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn cohort_summary(
    State(s): State<AppRef>,
    Reader(user): Reader,
    Path(name): Path<String>,
    axum::extract::Query(q): axum::extract::Query<ListQuery>,
) -> Result<Response, ApiError> {
    // "No such cohort" and "not yours" get the same 404: which cohorts exist is not for everyone.
    let not_found = || err(StatusCode::NOT_FOUND, format!("no cohort {name}"));
    let cohort = s.store.cohort_id(&name).await?.ok_or_else(not_found)?;
    let allowed = match user.role {
        Role::Instructor => s.store.in_cohort(&user.id, &cohort).await?,
        Role::Curriculum | Role::Admin => true,
        Role::Trainee => false,
    };
    if !allowed {
        return Err(not_found());
    }
    let filter = q.filter(&s).await?;
    let trainees = s.store.cohort_summary(&cohort, &filter).await?;
    Ok(Json(json!({ "cohort": name, "trainees": trainees })).into_response())
}

/// The query of list, summary and export routes: `?from=YYYY-MM-DD&to=YYYY-MM-DD&scenario=…&
/// difficulty=…&cohort=…&trainee=…&page=N` (all optional; `to` inclusive).
#[derive(Debug, Default, serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListQuery {
    pub from: Option<String>,
    pub to: Option<String>,
    pub scenario: Option<String>,
    pub difficulty: Option<String>,
    pub cohort: Option<String>,
    pub trainee: Option<String>,
    pub page: Option<i64>,
}

impl ListQuery {
    /// The store filter, or 400 with what is wrong. Unknown cohorts and trainees match nothing.
    pub async fn filter(&self, s: &AppState) -> Result<super::store::SessionFilter, ApiError> {
        let blank = |v: &Option<String>| {
            v.as_deref()
                .map(str::trim)
                .filter(|v| !v.is_empty())
                .map(str::to_string)
        };
        let mut f = super::store::SessionFilter {
            scenario: blank(&self.scenario),
            difficulty: None,
            uploaded_from: blank(&self.from).map(|d| day_start(&d, 0)).transpose()?,
            uploaded_before: blank(&self.to).map(|d| day_start(&d, 1)).transpose()?,
            offset: (self.page.unwrap_or(1).max(1) - 1).saturating_mul(PAGE_SIZE),
            limit: PAGE_SIZE,
            ..Default::default()
        };
        f.difficulty = blank(&self.difficulty)
            .map(|d| d.parse::<Difficulty>())
            .transpose()
            .map_err(|e| ApiError::Invalid(e.to_string()))?;
        // A cohort or trainee that does not exist filters out everything, exactly like one the
        // caller may not see (the lists are narrowed to what the caller may see): the answer
        // does not tell which names exist.
        if let Some(c) = blank(&self.cohort) {
            f.cohort_id = Some(s.store.cohort_id(&c).await?.unwrap_or_default());
        }
        if let Some(t) = blank(&self.trainee) {
            f.trainee_id = Some(s.store.user_by_name(&t).await?.map(|u| u.id).unwrap_or_default());
        }
        Ok(f)
    }
}

/// Sessions per page of a list.
pub const PAGE_SIZE: i64 = 100;

/// `YYYY-MM-DD` (+ `days`) as the RFC 3339 start of that UTC day, or 400.
fn day_start(date: &str, days: u64) -> Result<String, ApiError> {
    let bad = || err(StatusCode::BAD_REQUEST, format!("'{date}' is not a date (YYYY-MM-DD)"));
    if date.len() != 10 {
        return Err(bad());
    }
    let t = humantime::parse_rfc3339(&format!("{date}T00:00:00Z")).map_err(|_| bad())?;
    let day = t + std::time::Duration::from_secs(86_400 * days);
    // humantime cannot write years past 9999 (the day after 9999-12-31).
    let mut out = String::new();
    std::fmt::write(&mut out, format_args!("{}", humantime::format_rfc3339_micros(day)))
        .map_err(|_| err(StatusCode::BAD_REQUEST, format!("'{date}' is out of range")))?;
    Ok(out)
}

/// GET /api/export/sessions.csv: one row per session the caller may see (curriculum staff and
/// admins: all; instructors: their cohorts'), oldest first, filtered like the lists. Trainees use
/// their progress instead.
#[utoipa::path(get, path = "/api/export/sessions.csv", tag = "review",
    summary = "One CSV row per visible session (columns in docs/api.md)",
    params(ListQuery),
    responses(
        (status = 200, description = "the sessions", content_type = "text/csv", body = String),
        (status = 400, description = "a bad filter", body = super::openapi::ErrorBody),
        (status = 403, description = "trainees have no export, or an upload-scoped token", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn export_csv(
    State(s): State<AppRef>,
    Reader(user): Reader,
    axum::extract::Query(q): axum::extract::Query<ListQuery>,
) -> Result<Response, ApiError> {
    if user.role == Role::Trainee {
        return Err(err(
            StatusCode::FORBIDDEN,
            "the export is for instructors and curriculum staff",
        ));
    }
    let filter = q.filter(&s).await?;
    let rows = s.store.export_rows(&user, &filter).await?;
    Ok((
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8"),
            (
                header::CONTENT_DISPOSITION,
                "attachment; filename=\"stylet-sessions.csv\"",
            ),
        ],
        super::export::sessions_csv(&rows),
    )
        .into_response())
}

/// GET /api/sessions: the sessions the caller may see, newest first, filtered, a page of
/// [`PAGE_SIZE`] at a time (`total` says how many match).
#[utoipa::path(get, path = "/api/sessions", tag = "sessions",
    summary = "Sessions the caller may see, newest first, a page at a time",
    params(ListQuery),
    responses(
        (status = 200, description = "a page of sessions", body = super::openapi::SessionPage),
        (status = 400, description = "a bad filter", body = super::openapi::ErrorBody),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
async fn list_sessions(
    State(s): State<AppRef>,
    Reader(user): Reader,
    axum::extract::Query(q): axum::extract::Query<ListQuery>,
) -> Result<Response, ApiError> {
    let filter = q.filter(&s).await?;
    let rows = s.store.sessions(&user, &filter).await?;
    let total = s.store.count_sessions(&user, &filter).await?;
    Ok(
        Json(json!({ "sessions": rows, "total": total, "page": q.page.unwrap_or(1).max(1), "page_size": PAGE_SIZE }))
            .into_response(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_in_filters_are_days_or_400() {
        assert_eq!(day_start("2026-11-23", 0).unwrap(), "2026-11-23T00:00:00.000000Z");
        assert_eq!(day_start("2026-12-31", 1).unwrap(), "2027-01-01T00:00:00.000000Z");
        for bad in ["2026-13-01", "23.11.2026", "2026-11-23T00", ""] {
            assert_eq!(
                day_start(bad, 0).unwrap_err().status(),
                StatusCode::BAD_REQUEST,
                "{bad}"
            );
        }
        // The day after the last day humantime can write: a 400, not a panic.
        let e = day_start("9999-12-31", 1).unwrap_err();
        assert_eq!(e.status(), StatusCode::BAD_REQUEST);
        assert!(e.message().contains("out of range"), "{e}");
    }

    /// Lengths are documented in characters: 1 500 'é' (3 000 bytes) are a valid reason.
    #[test]
    fn text_lengths_count_characters() {
        let e = |n: usize| "é".repeat(n);
        assert_eq!(check_override(50.0, &e(1500)).unwrap(), e(1500));
        assert_eq!(check_override(50.0, &e(2000)).unwrap(), e(2000));
        assert_eq!(
            check_override(50.0, &e(2001)).unwrap_err().status(),
            StatusCode::BAD_REQUEST
        );
        assert_eq!(check_comment(&e(10_000)).unwrap(), e(10_000));
        assert_eq!(check_comment(&e(10_001)).unwrap_err().status(), StatusCode::BAD_REQUEST);
    }
}
