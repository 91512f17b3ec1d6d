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
use super::error::{ApiError, err};
use super::extract::{AdminActor, AdminReader};
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

#[derive(Debug, Default, serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct UsersQuery {
    /// Part of a username.
    pub q: Option<String>,
    /// 1 = the first page.
    #[param(minimum = 1)]
    pub page: Option<i64>,
}

/// GET /api/users (admin): `?q=part-of-name&page=N` → `{users, total, page, page_size}`.
#[utoipa::path(get, path = "/api/users", tag = "accounts",
    summary = "Accounts with role, cohorts and status, by username, 100 a page (admin)",
    params(UsersQuery),
    responses(
        (status = 200, description = "a page of accounts", body = AccountPage),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn list(
    State(s): State<AppRef>,
    AdminReader(_admin): AdminReader,
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

/// A page of accounts, by username.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct AccountPage {
    pub users: Vec<UserRow>,
    pub total: i64,
    pub page: i64,
    pub page_size: i64,
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
struct NewUserRequest {
    #[schema(min_length = 1, max_length = 64)]
    username: String,
    #[schema(value_type = Role)]
    role: String,
    #[schema(min_length = 8, max_length = 1024)]
    password: String,
    #[serde(default)]
    cohort: Option<String>,
}

/// POST /api/users (admin): JSON `{"username","role","password","cohort"?}` → 201; or a CSV
/// import (`Content-Type: text/csv`, `username,role,cohort,password` per line) → 201
/// `{"imported": [...]}`, or 422 `{"error", "lines": [{line, reason}]}` with nothing imported.
#[utoipa::path(post, path = "/api/users", tag = "accounts",
    summary = "Add an account, or import accounts from CSV (admin; audited)",
    description = "JSON adds one account. `Content-Type: text/csv` imports one account per line, `username,role,cohort,password` (optional header line; cohort may be empty; the password is the rest of the line; at most 200 lines): every account or none; 422 names every bad line.",
    request_body(content(
        (NewUserRequest = "application/json"),
        (String = "text/csv"),
    )),
    responses(
        (status = 201, description = "the account added, or the accounts imported", body = AccountAdded),
        (status = 400, description = "invalid username, role, password or cohort", body = super::openapi::ErrorBody),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 409, description = "the username exists", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over --max-body-bytes", body = super::openapi::ErrorBody),
        (status = 422, description = "an import with bad lines; nothing was imported", body = super::openapi::ImportRefused),
    ),
    security(("cookie" = []), ("token" = [])))]
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

/// A new account (JSON), or the accounts a CSV import added (`imported`).
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct AccountAdded {
    pub username: Option<String>,
    pub role: Option<Role>,
    pub cohort: Option<String>,
    pub imported: Option<Vec<String>>,
}

/// GET /api/users/{username} (admin).
#[utoipa::path(get, path = "/api/users/{username}", tag = "accounts",
    summary = "One account (admin)",
    params(("username" = String, Path)),
    responses(
        (status = 200, description = "the account", body = super::store::UserRow),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such account", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn get_one(
    State(s): State<AppRef>,
    AdminReader(_admin): AdminReader,
    Path(username): Path<String>,
) -> Result<Response, ApiError> {
    let row = s
        .store
        .user_row(&username)
        .await?
        .ok_or_else(|| ApiError::from(AccountError::NoSuchUser(username.clone())))?;
    Ok(Json(row).into_response())
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
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
#[utoipa::path(patch, path = "/api/users/{username}", tag = "accounts",
    summary = "Change an account's role, cohorts or status (admin; audited per change)",
    description = "`cohorts` replaces the account's cohorts (created if new; [] for none). Takes effect on the account's next request.",
    params(("username" = String, Path)),
    request_body(content = ChangeRequest, content_type = "application/json"),
    responses(
        (status = 200, description = "the account", body = super::store::UserRow),
        (status = 400, description = "bad role or cohort name", body = super::openapi::ErrorBody),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such account", body = super::openapi::ErrorBody),
        (status = 409, description = "it would leave no active admin, or an admin disabling or demoting their own account", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over --max-body-bytes", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
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
#[utoipa::path(post, path = "/api/users/{username}/disable", tag = "accounts",
    summary = "Disable an account (admin; audited): its logins and API tokens are refused from its next request; its sessions stay",
    params(("username" = String, Path)),
    responses(
        (status = 200, description = "the account", body = super::store::UserRow),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such account", body = super::openapi::ErrorBody),
        (status = 409, description = "the last active admin, or one's own account", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
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
#[utoipa::path(post, path = "/api/users/{username}/enable", tag = "accounts",
    summary = "Enable a disabled account (admin; audited): its unexpired logins and tokens work again",
    params(("username" = String, Path)),
    responses(
        (status = 200, description = "the account", body = super::store::UserRow),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such account", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
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

#[derive(serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
struct PasswordRequest {
    #[schema(min_length = 8, max_length = 1024)]
    password: String,
}

/// POST /api/users/{username}/password (admin): `{"password"}` sets a new password and ends the
/// account's logins.
#[utoipa::path(post, path = "/api/users/{username}/password", tag = "accounts",
    summary = "Reset an account's password (admin; audited); its logins end",
    params(("username" = String, Path)),
    request_body(content = PasswordRequest, content_type = "application/json"),
    responses(
        (status = 200, description = "the account", body = super::store::UserRow),
        (status = 400, description = "a password has 8–1024 characters", body = super::openapi::ErrorBody),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such account", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over --max-body-bytes", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
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
