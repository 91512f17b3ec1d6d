//! API tokens (`/api/tokens`; the dashboard's tokens page uses the same functions): made from a
//! login only, never by another token; `upload` scope unless `full` is asked for; expiring
//! (90 days at most); listed without their secret; revocable by their owner or an admin.

use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::json;

use super::AppState;
use super::error::{ApiError, err};
use super::extract::{Actor, CookieActor, Reader};
use super::store::{Role, TokenRow, TokenScope, User};

/// How long a token lasts unless asked for less, and the most it may last: a token forgotten
/// on a training PC stops working on its own.
pub const MAX_TOKEN_DAYS: u32 = 90;

/// Longest label, in characters.
pub const MAX_LABEL_CHARS: usize = 100;
/// Active tokens one account may hold (each desktop installation needs one): a bound on the
/// rows an account can make.
pub const MAX_ACTIVE_TOKENS: usize = 20;

/// A token label is 1–100 characters; returns it trimmed.
pub fn check_label(label: &str) -> Result<&str, ApiError> {
    let label = label.trim();
    if label.is_empty() || label.chars().count() > MAX_LABEL_CHARS {
        return Err(err(
            StatusCode::BAD_REQUEST,
            format!("a token label is 1–{MAX_LABEL_CHARS} characters"),
        ));
    }
    Ok(label)
}

/// Days a token lasts: as asked, 1–90; 90 when not asked.
pub fn check_days(days: Option<u32>) -> Result<u32, ApiError> {
    match days.unwrap_or(MAX_TOKEN_DAYS) {
        d @ 1..=MAX_TOKEN_DAYS => Ok(d),
        d => Err(err(
            StatusCode::BAD_REQUEST,
            format!("a token lasts 1–{MAX_TOKEN_DAYS} days, not {d}"),
        )),
    }
}

/// A new token of `user`: the token (shown once) and its row. Audited.
pub async fn create(
    s: &AppState,
    user: &User,
    label: &str,
    scope: TokenScope,
    days: Option<u32>,
) -> Result<(String, TokenRow), ApiError> {
    let label = check_label(label)?;
    let days = check_days(days)?;
    let ttl = Duration::from_secs(u64::from(days) * 86_400);
    Ok(s.store
        .create_api_token(user, label, scope, ttl, MAX_ACTIVE_TOKENS)
        .await?)
}

/// The tokens `user` may see and revoke: their own; an admin's, everyone's.
pub async fn list(s: &AppState, user: &User) -> Result<Vec<TokenRow>, ApiError> {
    let owner = (user.role != Role::Admin).then_some(user.id.as_str());
    Ok(s.store.api_tokens(owner).await?)
}

/// Revokes token `id` for `user` (their own; an admin, anyone's), or 404: whether another
/// account's token exists is not theirs to know. Revoking a revoked token changes nothing.
pub async fn revoke(s: &AppState, user: &User, id: &str) -> Result<TokenRow, ApiError> {
    let not_found = || err(StatusCode::NOT_FOUND, format!("no API token {id}"));
    let token = s.store.api_token_by_id(id).await?.ok_or_else(not_found)?;
    if token.user_id != user.id && user.role != Role::Admin {
        return Err(not_found());
    }
    s.store.revoke_api_token(id, user).await?.ok_or_else(not_found)
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
struct NewTokenRequest {
    #[schema(min_length = 1, max_length = 100)]
    label: String,
    #[serde(default)]
    scope: TokenScope,
    #[serde(default)]
    #[schema(minimum = 1, maximum = 90)]
    expires_in_days: Option<u32>,
}

/// POST /api/tokens: `{"label", "scope"?, "expires_in_days"?}` → 201 with the token, shown once.
/// Login cookie and CSRF token only: a Bearer token gets 403.
#[utoipa::path(post, path = "/api/tokens", tag = "accounts",
    summary = "Create an API token for the logged-in user (shown once; audited)",
    description = "Login cookie and X-CSRF-Token only: a request authenticated by an API token gets 403. Scope `upload` (default) may only upload sessions and read their status; `full` has the account's rights.",
    request_body(content = NewTokenRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "the token, its secret shown only here", body = NewToken),
        (status = 400, description = "bad label, scope or expiry", body = super::openapi::ErrorBody),
        (status = 403, description = "CSRF token missing, or authenticated by an API token", body = super::openapi::ErrorBody),
        (status = 409, description = "the account has as many active tokens as it may", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over --max-body-bytes", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = [])))]
pub async fn create_token(
    State(s): State<Arc<AppState>>,
    CookieActor(user): CookieActor,
    body: Bytes,
) -> Result<Response, ApiError> {
    let req: NewTokenRequest = serde_json::from_slice(&body).map_err(|e| {
        err(
            StatusCode::BAD_REQUEST,
            format!(
                "expected {{\"label\", \"scope\"?: \"upload\"|\"full\", \"expires_in_days\"?: 1–{MAX_TOKEN_DAYS}}}: {e}"
            ),
        )
    })?;
    let (token, row) = create(&s, &user, &req.label, req.scope, req.expires_in_days).await?;
    let mut body = serde_json::to_value(&row).map_err(|_| err(StatusCode::INTERNAL_SERVER_ERROR, "internal error"))?;
    body["token"] = json!(token);
    Ok((StatusCode::CREATED, Json(body)).into_response())
}

/// A new API token: the row and `token`, the secret, shown only here.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct NewToken {
    #[serde(flatten)]
    pub row: TokenRow,
    pub token: String,
}

/// GET /api/tokens: `{"tokens": [...]}`, newest first, without the tokens themselves.
#[utoipa::path(get, path = "/api/tokens", tag = "accounts",
    summary = "The caller's API tokens (an admin's: everyone's), newest first, never the secret",
    responses(
        (status = 200, description = "the tokens", body = TokenList),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn list_tokens(State(s): State<Arc<AppState>>, Reader(user): Reader) -> Result<Response, ApiError> {
    Ok(Json(json!({ "tokens": list(&s, &user).await? })).into_response())
}

/// The caller's API tokens.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct TokenList {
    pub tokens: Vec<TokenRow>,
}

/// POST /api/tokens/{id}/revoke: the token's row, now revoked. Audited.
#[utoipa::path(post, path = "/api/tokens/{id}/revoke", tag = "accounts",
    summary = "Revoke an API token (own; admins: anyone's); audited; revoking twice changes nothing",
    params(("id" = String, Path, description = "the token's id")),
    responses(
        (status = 200, description = "the token, now revoked", body = super::store::TokenRow),
        (status = 403, description = "CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such token, or not yours", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn revoke_token(
    State(s): State<Arc<AppState>>,
    Actor(user): Actor,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    Ok(Json(revoke(&s, &user, &id).await?).into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_count_characters_and_days_are_capped() {
        let e = |n: usize| "é".repeat(n);
        assert_eq!(check_label(&format!("  {}  ", e(100))).unwrap(), e(100));
        assert_eq!(check_label(&e(101)).unwrap_err().status(), StatusCode::BAD_REQUEST);
        assert_eq!(check_label("   ").unwrap_err().status(), StatusCode::BAD_REQUEST);
        assert_eq!(check_days(None).unwrap(), MAX_TOKEN_DAYS);
        assert_eq!(check_days(Some(7)).unwrap(), 7);
        for bad in [0, MAX_TOKEN_DAYS + 1, u32::MAX] {
            let e = check_days(Some(bad)).unwrap_err();
            assert_eq!(e.status(), StatusCode::BAD_REQUEST);
            assert!(e.message().contains("1–90 days"), "{e}");
        }
    }
}
