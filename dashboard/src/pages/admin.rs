//! `/admin/users`: admins list accounts (searched, a page at a time), add them, import them from
//! CSV (all lines or none, every bad line named), disable and enable them, reset passwords and
//! change roles and cohorts: the same store calls as `/api/users` and `stylet user`, audited.
//! Every form carries the login's CSRF token.

use std::sync::Arc;

use axum::Form;
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::api::ApiError;
use stylet_service::store::{AccountChange, IMPORT_HEADER, ImportLineError, MAX_IMPORT_LINES, Role, UserRow};
use stylet_service::users::{self, USERS_PAGE_SIZE, UsersQuery};

use crate::auth::{PageError, Viewer, check_csrf, encode_query, fail};
use crate::layout::{count, csrf_field, page, short_time};

fn require_admin(v: &Viewer) -> Result<(), PageError> {
    if v.role() == Role::Admin {
        Ok(())
    } else {
        Err(fail(StatusCode::FORBIDDEN, "only admins manage accounts"))
    }
}

/// What the page says after a refused action.
#[derive(Clone, Copy)]
enum Notice<'a> {
    None,
    /// A refused change of an account (top of the page).
    Error(&'a str),
    /// A refused new account (beside its form).
    AddError(&'a str),
    /// A refused import: every bad line.
    Import(&'a [ImportLineError]),
}

struct Listing {
    users: Vec<UserRow>,
    total: i64,
    page: i64,
    search: String,
}

fn accounts_page(v: &Viewer, l: &Listing, notice: Notice) -> Markup {
    let pages = ((l.total + USERS_PAGE_SIZE - 1) / USERS_PAGE_SIZE).max(1);
    html! {
        h1 { "Accounts" }
        @match notice {
            Notice::None => {},
            Notice::Error(e) => p.error role="alert" #account-error { (e) },
            Notice::AddError(_) => {},
            Notice::Import(lines) => div.error role="alert" #import-error {
                p { "Nothing was imported. Correct these lines and import the file again:" }
                ul { @for l in lines { li { (l.to_string()) } } }
            },
        }
        h2 { "Add an account" }
        @if let Notice::AddError(e) = notice { p.error role="alert" #add-user-error { (e) } }
        form.inline #add-user method="post" action="/admin/users" {
            (csrf_field(v))
            label { "Username" input name="username" required; }
            label { "Role" select name="role" { @for r in Role::ALL { option value=(r) { (r) } } } }
            label { "Cohort (optional)" input name="cohort"; }
            label { "Password (8 or more characters)" input name="password" type="password" autocomplete="new-password" required; }
            button.primary type="submit" { "Add" }
        }
        h2 { "Import accounts" }
        p.muted { "One account per line: " code { (IMPORT_HEADER) } " (cohort may be empty; at most "
            (MAX_IMPORT_LINES) " lines). If any line is wrong, nothing is imported." }
        form #import-users method="post" action="/admin/users/import" {
            (csrf_field(v))
            textarea name="csv" rows="6" cols="60" required placeholder=(format!("{IMPORT_HEADER}\nalice,trainee,2026-spring,a-long-password")) {}
            div { button.primary type="submit" { "Import" } }
        }
        h2 { (count(l.total, "account", "accounts")) }
        form.inline #user-search method="get" action="/admin/users" {
            label { "Username contains" input name="q" value=(l.search); }
            button type="submit" { "Search" }
        }
        div.table-scroll { table #users {
            thead { tr { th { "Username" } th { "Role" } th { "Cohorts" } th { "Status" } th { "Since (UTC)" } th { "Change" } } }
            tbody { @for u in &l.users {
                @let path = format!("/admin/users/{}", encode_query(&u.username));
                tr data-user=(u.username) {
                    td { (u.username) }
                    td { (u.role) }
                    td { (u.cohorts.join(", ")) }
                    td { @if let Some(at) = &u.disabled_at { "disabled since " (short_time(at)) } @else { "active" } }
                    td { (short_time(&u.created_at)) }
                    td {
                        form.inline.set-user method="post" action=(format!("{path}/set")) {
                            (csrf_field(v))
                            select name="role" aria-label="Role" { @for r in Role::ALL {
                                option value=(r) selected[r == u.role] { (r) }
                            } }
                            input name="cohorts" aria-label="Cohorts (comma-separated)" value=(u.cohorts.join(", "));
                            button type="submit" { "Save" }
                        }
                        form.inline.user-status method="post" action=(format!("{path}/status")) {
                            (csrf_field(v))
                            @if u.disabled_at.is_some() {
                                input type="hidden" name="action" value="enable";
                                button type="submit" { "Enable" }
                            } @else {
                                input type="hidden" name="action" value="disable";
                                button type="submit" { "Disable" }
                            }
                        }
                        form.inline.user-password method="post" action=(format!("{path}/password")) {
                            (csrf_field(v))
                            input name="password" type="password" autocomplete="new-password" aria-label="New password" placeholder="new password" required;
                            button type="submit" { "Reset password" }
                        }
                    }
                }
            } }
        } }
        @if pages > 1 {
            nav.pages {
                @if l.page > 1 { a href=(format!("/admin/users?q={}&page={}", encode_query(&l.search), l.page - 1)) { "← Previous" } " " }
                "page " (l.page) " of " (pages)
                @if l.page < pages { " " a href=(format!("/admin/users?q={}&page={}", encode_query(&l.search), l.page + 1)) { "Next →" } }
            }
        }
    }
}

async fn listing(s: &AppState, q: &UsersQuery) -> Result<Listing, PageError> {
    let page = q.page.unwrap_or(1).max(1);
    let search = q.q.as_deref().map(str::trim).unwrap_or_default().to_string();
    let (users, total) = s
        .store
        .users_page(
            Some(search.as_str()).filter(|q| !q.is_empty()),
            (page - 1).saturating_mul(USERS_PAGE_SIZE),
            USERS_PAGE_SIZE,
        )
        .await?;
    Ok(Listing {
        users,
        total,
        page,
        search,
    })
}

/// The page again with what was refused (4xx), or the error page for anything else.
async fn refused(s: &AppState, v: &Viewer, e: ApiError) -> Result<Response, PageError> {
    refused_at(s, v, e, false).await
}

/// [`refused`], the message beside the add form (`add`) or at the top.
async fn refused_at(s: &AppState, v: &Viewer, e: ApiError, add: bool) -> Result<Response, PageError> {
    let status = e.status();
    if !status.is_client_error() {
        return Err(e.into());
    }
    let l = listing(s, &UsersQuery::default()).await?;
    let message = e.message();
    let body = match &e {
        ApiError::ImportRejected(lines) => accounts_page(v, &l, Notice::Import(lines)),
        _ if add => accounts_page(v, &l, Notice::AddError(&message)),
        _ => accounts_page(v, &l, Notice::Error(&message)),
    };
    Ok((status, page("Accounts", Some(v), body)).into_response())
}

pub async fn users(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Query(q): Query<UsersQuery>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    let l = listing(&s, &q).await?;
    Ok(page("Accounts", Some(&v), accounts_page(&v, &l, Notice::None)).into_response())
}

#[derive(serde::Deserialize)]
pub struct NewUserForm {
    csrf: String,
    username: String,
    role: String,
    #[serde(default)]
    cohort: String,
    password: String,
}

pub async fn add_user(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Form(f): Form<NewUserForm>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    let cohort = Some(f.cohort.trim()).filter(|c| !c.is_empty());
    match users::add(&s, &v.user, f.username.trim(), &f.role, &f.password, cohort).await {
        Ok(()) => Ok(Redirect::to("/admin/users").into_response()),
        Err(e) => refused_at(&s, &v, e, true).await,
    }
}

#[derive(serde::Deserialize)]
pub struct ImportForm {
    csrf: String,
    csv: String,
}

pub async fn import(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Form(f): Form<ImportForm>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    match users::import(&s, &v.user, &f.csv).await {
        Ok(_) => Ok(Redirect::to("/admin/users").into_response()),
        Err(e) => refused(&s, &v, e).await,
    }
}

#[derive(serde::Deserialize)]
pub struct StatusForm {
    csrf: String,
    action: String,
}

pub async fn set_status(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(username): Path<String>,
    Form(f): Form<StatusForm>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    let disabled = match f.action.as_str() {
        "disable" => true,
        "enable" => false,
        other => {
            return Err(fail(
                StatusCode::BAD_REQUEST,
                format!("unknown action '{other}' (disable, enable)"),
            ));
        }
    };
    let change = AccountChange {
        disabled: Some(disabled),
        ..Default::default()
    };
    apply(&s, &v, &username, &change).await
}

#[derive(serde::Deserialize)]
pub struct PasswordForm {
    csrf: String,
    password: String,
}

pub async fn set_password(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(username): Path<String>,
    Form(f): Form<PasswordForm>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    let change = AccountChange {
        password: Some(f.password),
        ..Default::default()
    };
    apply(&s, &v, &username, &change).await
}

#[derive(serde::Deserialize)]
pub struct SetForm {
    csrf: String,
    role: String,
    #[serde(default)]
    cohorts: String,
}

pub async fn set_user(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(username): Path<String>,
    Form(f): Form<SetForm>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    let role = match Role::parse(&f.role) {
        Ok(r) => r,
        Err(e) => return refused(&s, &v, ApiError::Invalid(e.to_string())).await,
    };
    let cohorts = f
        .cohorts
        .split(',')
        .map(str::trim)
        .filter(|c| !c.is_empty())
        .map(str::to_string)
        .collect();
    let change = AccountChange {
        role: Some(role),
        cohorts: Some(cohorts),
        ..Default::default()
    };
    apply(&s, &v, &username, &change).await
}

async fn apply(s: &AppState, v: &Viewer, username: &str, change: &AccountChange) -> Result<Response, PageError> {
    match users::change(s, &v.user, username, change).await {
        Ok(_) => Ok(Redirect::to(&format!("/admin/users?q={}", encode_query(username))).into_response()),
        Err(e) => refused(s, v, e).await,
    }
}
