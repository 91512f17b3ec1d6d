//! The review of a session by the trainee's instructors and admins: a grade override with its
//! reason and comments (optionally at a moment of the session), both audited. The checks of
//! their text are shared with the dashboard's review page.

use std::sync::Arc;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::json;

use super::AppState;
use super::access::reviewable;
use super::error::{ApiError, err};
use super::extract::Actor;

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
        (status = 201, description = "stored", body = OverrideAnswer),
        (status = 400, description = "bad body: score in 0…100, a reason", body = super::openapi::ErrorBody),
        (status = 403, description = "not a reviewer of this trainee, CSRF or token scope", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over --max-body-bytes", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn override_grade(
    State(s): State<Arc<AppState>>,
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

/// A grade override as stored.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct OverrideAnswer {
    pub session: String,
    pub score: f64,
    pub passed: bool,
    pub reason: String,
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
        (status = 201, description = "stored", body = CommentAnswer),
        (status = 400, description = "bad body: 1–10000 characters, a moment inside the session", body = super::openapi::ErrorBody),
        (status = 403, description = "not a reviewer of this trainee, CSRF or token scope", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over --max-body-bytes", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn add_comment(
    State(s): State<Arc<AppState>>,
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

/// A comment as stored.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct CommentAnswer {
    pub id: String,
    pub session: String,
}

#[cfg(test)]
mod tests {
    use super::*;

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
