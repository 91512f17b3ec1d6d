//! `GET/POST /admin/users`: admins list accounts and add them (argon2id, audited), with the
//! same checks as `stylet user add` and `POST /api/users`.

use std::sync::Arc;

use axum::Form;
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode, Uri};
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::store::{ROLES, StoreError, UserRow};

use crate::auth::{PageError, Viewer, check_csrf, fail, viewer};
use crate::layout::{csrf_field, page, short_time};

fn require_admin(v: &Viewer) -> Result<(), PageError> {
    if v.role() == "admin" {
        Ok(())
    } else {
        Err(fail(StatusCode::FORBIDDEN, "only admins manage accounts"))
    }
}

fn accounts_page(v: &Viewer, users: &[UserRow], error: Option<&str>) -> Markup {
    html! {
        h1 { "Accounts" }
        h2 { "Add an account" }
        @if let Some(e) = error { p.error role="alert" #add-user-error { (e) } }
        form.inline #add-user method="post" action="/admin/users" {
            (csrf_field(v))
            label { "Username" input name="username" required; }
            label { "Role" select name="role" { @for r in ROLES { option value=(r) { (r) } } } }
            label { "Cohort (optional)" input name="cohort"; }
            label { "Password (8 or more characters)" input name="password" type="password" autocomplete="new-password" required; }
            button.primary type="submit" { "Add" }
        }
        h2 { (users.len()) " accounts" }
        table #users {
            thead { tr { th { "Username" } th { "Role" } th { "Cohorts" } th { "Since (UTC)" } } }
            tbody { @for u in users { tr {
                td { (u.username) } td { (u.role) } td { (u.cohorts.join(", ")) } td { (short_time(&u.created_at)) }
            } } }
        }
    }
}

pub async fn users(State(s): State<Arc<AppState>>, headers: HeaderMap, uri: Uri) -> Result<Response, PageError> {
    let v = viewer(&s, &headers, &uri).await?;
    require_admin(&v)?;
    let users = s.store.users().await?;
    Ok(page("Accounts", Some(&v), accounts_page(&v, &users, None)).into_response())
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
    headers: HeaderMap,
    uri: Uri,
    Form(f): Form<NewUserForm>,
) -> Result<Response, PageError> {
    let v = viewer(&s, &headers, &uri).await?;
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    let cohort = Some(f.cohort.trim()).filter(|c| !c.is_empty());
    match s
        .store
        .add_user(f.username.trim(), &f.role, &f.password, cohort, Some(&v.user.id))
        .await
    {
        Ok(_) => Ok(Redirect::to("/admin/users").into_response()),
        Err(StoreError::Invalid(m)) => {
            let users = s.store.users().await?;
            Ok((
                StatusCode::BAD_REQUEST,
                page("Accounts", Some(&v), accounts_page(&v, &users, Some(&m))),
            )
                .into_response())
        }
        Err(e) => Err(e.into()),
    }
}
