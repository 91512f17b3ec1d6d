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
use axum::routing::{get, post};
use serde_json::json;

use super::AppState;
use super::auth;
use super::store::{NewSession, User};

type AppRef = Arc<AppState>;

/// A JSON error response.
pub struct ApiError(StatusCode, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.0, Json(json!({ "error": self.1 }))).into_response()
    }
}

fn err(status: StatusCode, msg: impl Into<String>) -> ApiError {
    ApiError(status, msg.into())
}

impl From<super::StoreError> for ApiError {
    fn from(e: super::StoreError) -> Self {
        tracing::error!(error = %e, "store");
        err(StatusCode::INTERNAL_SERVER_ERROR, "internal error")
    }
}

pub fn router(state: AppRef) -> Router {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/api/login", post(login))
        .route("/api/logout", post(logout))
        .route("/api/sessions", post(upload).get(list_sessions))
        .route("/api/sessions/{id}", get(get_session))
        .with_state(state)
}

async fn healthz(State(s): State<AppRef>) -> Result<Json<serde_json::Value>, ApiError> {
    sqlx::query("SELECT 1")
        .execute(&s.store.pool)
        .await
        .map_err(super::StoreError::Db)?;
    Ok(Json(json!({ "status": "ok" })))
}

/// The logged-in user (login cookie), or 401.
async fn current_user(s: &AppState, headers: &HeaderMap) -> Result<User, ApiError> {
    let token = headers
        .get(header::COOKIE)
        .and_then(|v| v.to_str().ok())
        .and_then(auth::token_from_cookie_header)
        .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "log in first (POST /api/login)"))?;
    s.store
        .user_for_login(token)
        .await?
        .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "the login has expired; log in again"))
}

#[derive(serde::Deserialize)]
struct LoginRequest {
    username: String,
    password: String,
}

const LOGIN_TTL_S: u64 = 12 * 3600;

async fn login(State(s): State<AppRef>, body: Bytes) -> Result<Response, ApiError> {
    let req: LoginRequest = serde_json::from_slice(&body).map_err(|e| {
        err(
            StatusCode::BAD_REQUEST,
            format!("expected {{\"username\", \"password\"}}: {e}"),
        )
    })?;
    let user = s
        .store
        .check_login(&req.username, &req.password)
        .await?
        .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "wrong username or password"))?;
    let (token, csrf) = s.store.create_login(&user, LOGIN_TTL_S).await?;
    let mut r = Json(json!({ "username": user.username, "role": user.role, "csrf_token": csrf })).into_response();
    r.headers_mut().insert(
        header::SET_COOKIE,
        auth::login_cookie(&token, s.config.secure_cookies, LOGIN_TTL_S)
            .parse()
            .expect("a valid header value"),
    );
    Ok(r)
}

async fn logout(State(s): State<AppRef>, headers: HeaderMap) -> Result<Response, ApiError> {
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

/// POST /api/sessions: the session file as `application/octet-stream`. Checked before anything
/// is stored: size, the recorder's strict reader (limits on records and decompression), a known
/// atlas, and that the trainee in the file is the uploader or a trainee the instructor teaches.
async fn upload(State(s): State<AppRef>, headers: HeaderMap, body: Body) -> Result<Response, ApiError> {
    let user = current_user(&s, &headers).await?;
    let limit = s.config.max_upload_bytes;
    let bytes = axum::body::to_bytes(body, limit).await.map_err(|_| {
        err(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("the upload exceeds the limit of {limit} bytes"),
        )
    })?;
    if bytes.is_empty() {
        return Err(err(
            StatusCode::BAD_REQUEST,
            "the request body is empty: send the session file",
        ));
    }
    let data = bytes.clone();
    let session = tokio::task::spawn_blocking(move || stylet_recorder::reader::verify_bytes(&data))
        .await
        .map_err(|_| err(StatusCode::INTERNAL_SERVER_ERROR, "validation failed"))?
        .map_err(|e| {
            err(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!("not a valid session file: {e}"),
            )
        })?;
    let h = &session.header;
    if !s.scorers.contains_key(&h.atlas_hash) {
        return Err(err(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!(
                "the session was recorded on atlas '{}' ({}), which this server does not know",
                h.atlas_id, h.atlas_hash
            ),
        ));
    }
    let trainee = s
        .store
        .user_by_name(&h.trainee)
        .await?
        .filter(|t| t.role == "trainee")
        .ok_or_else(|| {
            err(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!("the session's trainee '{}' has no trainee account", h.trainee),
            )
        })?;
    let allowed = match user.role.as_str() {
        "trainee" => trainee.id == user.id,
        "instructor" => s.store.teaches(&user.id, &trainee.id).await?,
        "admin" => true,
        _ => false,
    };
    if !allowed {
        return Err(err(
            StatusCode::FORBIDDEN,
            format!("{} may not upload sessions of trainee '{}'", user.username, h.trainee),
        ));
    }
    let sha = auth::sha256_hex(&bytes);
    if let Some(id) = s.store.session_by_file(&sha).await? {
        let status = s
            .store
            .session(&id)
            .await?
            .map_or_else(|| "queued".to_string(), |(r, _)| r.status);
        return Ok((StatusCode::OK, Json(json!({ "id": id, "status": status }))).into_response());
    }
    // The file first (atomically, by content hash), then the rows; on failure neither stays.
    let path = s.session_file(&sha);
    let tmp = path.with_extension("partial");
    let write = async {
        tokio::fs::create_dir_all(path.parent().expect("has a parent")).await?;
        tokio::fs::write(&tmp, &bytes).await?;
        tokio::fs::rename(&tmp, &path).await
    };
    if let Err(e) = write.await {
        let _ = tokio::fs::remove_file(&tmp).await;
        tracing::error!(error = %e, "cannot store an upload");
        return Err(err(StatusCode::INTERNAL_SERVER_ERROR, "cannot store the file"));
    }
    let new = NewSession {
        file_sha256: sha,
        size_bytes: bytes.len() as i64,
        session_uuid: h.session_id.clone(),
        trainee_id: trainee.id.clone(),
        uploaded_by: user.id.clone(),
        scenario: h.scenario.clone(),
        difficulty: h.difficulty.clone(),
        atlas_hash: h.atlas_hash.clone(),
        physics_version: h.physics_version as i64,
        duration_s: session.duration_s(),
        recorded_at: h.wall_clock_start.clone(),
    };
    let id = match s.store.insert_session(&new).await {
        Ok(id) => id,
        Err(e) => {
            let _ = tokio::fs::remove_file(&path).await;
            return Err(e.into());
        }
    };
    s.wake.notify_one();
    Ok((StatusCode::CREATED, Json(json!({ "id": id, "status": "queued" }))).into_response())
}

async fn get_session(
    State(s): State<AppRef>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let user = current_user(&s, &headers).await?;
    let not_found = || err(StatusCode::NOT_FOUND, format!("no session {id}"));
    let (row, trainee_id) = s.store.session(&id).await?.ok_or_else(not_found)?;
    let allowed = match user.role.as_str() {
        "trainee" => trainee_id == user.id,
        "instructor" => s.store.teaches(&user.id, &trainee_id).await?,
        _ => true,
    };
    if !allowed {
        // Not 403: whether a session exists is itself private.
        return Err(not_found());
    }
    Ok(Json(row).into_response())
}

async fn list_sessions(State(s): State<AppRef>, headers: HeaderMap) -> Result<Response, ApiError> {
    let user = current_user(&s, &headers).await?;
    let rows = s.store.sessions_for(&user, 1000).await?;
    Ok(Json(json!({ "sessions": rows })).into_response())
}
