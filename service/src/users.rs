//! Account management for admins (`/api/users…`; the dashboard's accounts page and `stylet user`
//! use the same store calls): add, bulk import from CSV (all lines or none), disable and enable,
//! reset a password, change role and cohorts. Every change is audited in the store, in the
//! transaction that makes it.

use std::sync::Arc;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::json;

use super::AppState;
use super::api::{AdminActor, AdminReader, ApiError, err};
use super::store::{AccountChange, AccountError, Role, StoreError, User, UserRow};

type AppRef = Arc<AppState>;

/// Accounts per page of `GET /api/users` and the accounts page.
pub const USERS_PAGE_SIZE: i64 = 100;

/// Adds one account for `admin` (409 if the name is taken, 400 for a bad value).
pub async fn add(
    s: &AppState,
    admin: &User,
    username: &str,
    role: &str,
    password: &str,
    cohort: Option<&str>,
) -> Result<(), ApiError> {
    match s
        .store
        .add_user(username, role, password, cohort, Some(&admin.id))
        .await
    {
        Ok(_) => Ok(()),
        Err(StoreError::Invalid(m)) if m.contains("already exists") => Err(ApiError::Conflict(m)),
        Err(StoreError::Invalid(m)) => Err(ApiError::Invalid(m)),
        Err(e) => Err(e.into()),
    }
}

/// Imports the accounts of a CSV text for `admin`: all of them, or none with every bad line
/// named (422). Returns the usernames added.
pub async fn import(s: &AppState, admin: &User, csv: &str) -> Result<Vec<String>, ApiError> {
    Ok(s.store.import_csv(csv, Some(&admin.id)).await?)
}

/// Changes an account for `admin` (see [`super::Store::update_user`] for what is refused).
pub async fn change(s: &AppState, admin: &User, username: &str, change: &AccountChange) -> Result<UserRow, ApiError> {
    Ok(s.store.update_user(username, change, Some(admin)).await?)
}

#[derive(Debug, Default, serde::Deserialize)]
pub struct UsersQuery {
    /// Part of a username.
    pub q: Option<String>,
    pub page: Option<i64>,
}

/// GET /api/users (admin): `?q=part-of-name&page=N` → `{users, total, page, page_size}`.
pub async fn list(
    State(s): State<AppRef>,
    AdminReader(_): AdminReader,
    Query(q): Query<UsersQuery>,
) -> Result<Response, ApiError> {
    let page = q.page.unwrap_or(1).max(1);
    let search = q.q.as_deref().map(str::trim).filter(|q| !q.is_empty());
    let (users, total) = s
        .store
        .users_page(search, (page - 1).saturating_mul(USERS_PAGE_SIZE), USERS_PAGE_SIZE)
        .await?;
    Ok(Json(json!({ "users": users, "total": total, "page": page, "page_size": USERS_PAGE_SIZE })).into_response())
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct NewUserRequest {
    username: String,
    role: String,
    password: String,
    #[serde(default)]
    cohort: Option<String>,
}

/// POST /api/users (admin): JSON `{"username","role","password","cohort"?}` → 201; or a CSV
/// import (`Content-Type: text/csv`, `username,role,cohort,password` per line) → 201
/// `{"imported": [...]}`, or 422 `{"error", "lines": [{line, reason}]}` with nothing imported.
pub async fn add_or_import(
    State(s): State<AppRef>,
    AdminActor(admin): AdminActor,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    let csv = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|v| v.trim().eq_ignore_ascii_case("text/csv"));
    if csv {
        let text = std::str::from_utf8(&body).map_err(|_| ApiError::Invalid("the CSV is not UTF-8".into()))?;
        let imported = import(&s, &admin, text).await?;
        return Ok((StatusCode::CREATED, Json(json!({ "imported": imported }))).into_response());
    }
    let req: NewUserRequest = serde_json::from_slice(&body).map_err(|e| {
        err(
            StatusCode::BAD_REQUEST,
            format!("expected {{\"username\", \"role\", \"password\", \"cohort\"?}} (or a text/csv import): {e}"),
        )
    })?;
    let cohort = req.cohort.as_deref().map(str::trim).filter(|c| !c.is_empty());
    add(&s, &admin, &req.username, &req.role, &req.password, cohort).await?;
    Ok((
        StatusCode::CREATED,
        Json(json!({ "username": req.username, "role": req.role, "cohort": cohort })),
    )
        .into_response())
}

/// GET /api/users/{username} (admin).
pub async fn get_one(
    State(s): State<AppRef>,
    AdminReader(_): AdminReader,
    Path(username): Path<String>,
) -> Result<Response, ApiError> {
    let row = s
        .store
        .user_row(&username)
        .await?
        .ok_or_else(|| ApiError::from(AccountError::NoSuchUser(username.clone())))?;
    Ok(Json(row).into_response())
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ChangeRequest {
    #[serde(default)]
    role: Option<Role>,
    #[serde(default)]
    cohorts: Option<Vec<String>>,
    #[serde(default)]
    disabled: Option<bool>,
}

/// PATCH /api/users/{username} (admin): `{"role"?, "cohorts"?: [names], "disabled"?}` → the
/// account. 409 for the last active admin or one's own account, 404 for an unknown one.
pub async fn patch(
    State(s): State<AppRef>,
    AdminActor(admin): AdminActor,
    Path(username): Path<String>,
    body: Bytes,
) -> Result<Response, ApiError> {
    let req: ChangeRequest = serde_json::from_slice(&body).map_err(|e| {
        ApiError::Invalid(format!(
            "expected {{\"role\"?: trainee|instructor|curriculum|admin, \"cohorts\"?: [names], \"disabled\"?: bool}}: {e}"
        ))
    })?;
    let c = AccountChange {
        role: req.role,
        cohorts: req.cohorts.map(|cs| cs.iter().map(|c| c.trim().to_string()).collect()),
        disabled: req.disabled,
        password: None,
    };
    Ok(Json(change(&s, &admin, &username, &c).await?).into_response())
}

/// POST /api/users/{username}/disable (admin): its logins and tokens are refused from now on.
pub async fn disable(
    State(s): State<AppRef>,
    AdminActor(admin): AdminActor,
    Path(username): Path<String>,
) -> Result<Response, ApiError> {
    let c = AccountChange {
        disabled: Some(true),
        ..Default::default()
    };
    Ok(Json(change(&s, &admin, &username, &c).await?).into_response())
}

/// POST /api/users/{username}/enable (admin).
pub async fn enable(
    State(s): State<AppRef>,
    AdminActor(admin): AdminActor,
    Path(username): Path<String>,
) -> Result<Response, ApiError> {
    let c = AccountChange {
        disabled: Some(false),
        ..Default::default()
    };
    Ok(Json(change(&s, &admin, &username, &c).await?).into_response())
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PasswordRequest {
    password: String,
}

/// POST /api/users/{username}/password (admin): `{"password"}` sets a new password and ends the
/// account's logins.
pub async fn password(
    State(s): State<AppRef>,
    AdminActor(admin): AdminActor,
    Path(username): Path<String>,
    body: Bytes,
) -> Result<Response, ApiError> {
    let req: PasswordRequest =
        serde_json::from_slice(&body).map_err(|e| ApiError::Invalid(format!("expected {{\"password\"}}: {e}")))?;
    let c = AccountChange {
        password: Some(req.password),
        ..Default::default()
    };
    Ok(Json(change(&s, &admin, &username, &c).await?).into_response())
}
