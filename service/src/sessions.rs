//! The session routes: the list of sessions a caller may see, one session with its score and
//! review, its file as uploaded, and its deletion (admins). Uploads are [`super::upload`]'s;
//! who may see which session is [`super::access`]'s.

use std::sync::Arc;

use axum::Json;
use axum::body::{Body, Bytes};
use axum::extract::{Path, Query, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::json;

use super::AppState;
use super::access::visible_session;
use super::error::{ApiError, err};
use super::extract::{Actor, Reader, SimulatorReader};
use super::list_query::{ListQuery, PAGE_SIZE};
use super::store::{Role, SessionLine, User};

/// GET /api/sessions: the sessions the caller may see, newest first, filtered, a page of
/// [`PAGE_SIZE`] at a time (`total` says how many match).
#[utoipa::path(get, path = "/api/sessions", tag = "sessions",
    summary = "Sessions the caller may see, newest first, a page at a time",
    params(ListQuery),
    responses(
        (status = 200, description = "a page of sessions", body = SessionPage),
        (status = 400, description = "a bad filter", body = super::openapi::ErrorBody),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn list_sessions(
    State(s): State<Arc<AppState>>,
    Reader(user): Reader,
    Query(q): Query<ListQuery>,
) -> Result<Response, ApiError> {
    let filter = q.filter(&s).await?;
    let rows = s.store.sessions(&user, &filter).await?;
    let total = s.store.count_sessions(&user, &filter).await?;
    Ok(
        Json(json!({ "sessions": rows, "total": total, "page": q.page.unwrap_or(1).max(1), "page_size": PAGE_SIZE }))
            .into_response(),
    )
}

/// A page of sessions, newest first.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct SessionPage {
    pub sessions: Vec<SessionLine>,
    pub total: i64,
    pub page: i64,
    pub page_size: i64,
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
pub async fn get_session(
    State(s): State<Arc<AppState>>,
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
pub async fn get_session_file(
    State(s): State<Arc<AppState>>,
    SimulatorReader(user): SimulatorReader,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let row = visible_session(&s, &user, &id).await?;
    let gone = || err(StatusCode::NOT_FOUND, format!("the file of session {id} is gone"));
    let path = s.session_copy(&row.file_sha256).await.map_err(|e| {
        if e.is_missing() {
            gone()
        } else {
            tracing::error!(session = %id, error = %e, "cannot fetch a session file");
            err(
                StatusCode::SERVICE_UNAVAILABLE,
                "the session file cannot be read now; try again shortly",
            )
        }
    })?;
    let file = tokio::fs::File::open(&path).await.map_err(|_| gone())?;
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
        (status = 200, description = "deleted", body = Deleted),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn delete_session(
    State(s): State<Arc<AppState>>,
    Actor(user): Actor,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    remove_session(&s, &user, &id).await?;
    Ok(Json(json!({ "deleted": id })).into_response())
}

/// `{"deleted": id}`.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct Deleted {
    pub deleted: String,
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
    for key in [super::storage::session_key(sha), super::storage::trace_key(sha)] {
        if let Err(e) = s.storage.remove(&key).await {
            tracing::warn!(error = %e, "cannot remove a deleted session's object");
        }
    }
    if let Err(e) = s
        .storage
        .remove_shared_folder(&super::storage::frames_prefix(sha))
        .await
    {
        tracing::warn!(error = %e, "cannot remove a deleted session's shared player frames");
    }
    let frames = s.config.data_dir.join("frames").join(prefix).join(sha);
    if let Err(e) = tokio::fs::remove_dir_all(&frames).await
        && e.kind() != std::io::ErrorKind::NotFound
    {
        tracing::warn!(error = %e, dir = %frames.display(), "cannot remove a deleted session's player frames");
    }
}
