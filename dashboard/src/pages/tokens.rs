//! `GET/POST /tokens`, `POST /tokens/{id}/revoke`: API tokens for the desktop simulator (the same
//! rules as `/api/tokens`: upload scope unless full is chosen, 90 days at most, audited). A new
//! token is shown once, on the answer to the form that made it; lists never show tokens.

use std::sync::Arc;

use axum::Form;
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::store::{Role, TokenRow, TokenScope, TokenStatus};
use stylet_service::tokens::{self, MAX_LABEL_CHARS, MAX_TOKEN_DAYS};

use crate::auth::{PageError, Viewer, check_csrf};
use crate::layout::{csrf_field, page, short_time};

fn status_badge(status: TokenStatus) -> Markup {
    html! {
        @match status {
            TokenStatus::Active => span.badge.ok { "active" },
            TokenStatus::Expired => span.badge.muted { "expired" },
            TokenStatus::Revoked => span.badge.bad { "revoked" },
        }
    }
}

/// The page: a token just made (shown once), an error, the form, the list.
fn tokens_page(v: &Viewer, rows: &[TokenRow], new_token: Option<(&str, &TokenRow)>, error: Option<&str>) -> Markup {
    let admin = v.role() == Role::Admin;
    html! {
        h1 { "API tokens" }
        p.muted {
            "The desktop simulator uploads sessions with an API token. An " strong { "upload" }
            " token may only upload sessions and read their status; a " strong { "full" }
            " token may do through the API what your account may. Tokens expire after at most "
            (MAX_TOKEN_DAYS) " days; revoke one as soon as it is no longer needed."
        }
        @if let Some((token, row)) = new_token {
            div.notice #new-token-box role="status" {
                p { "Token " strong { (row.label) } " (" (row.scope.as_str()) ", expires " (short_time(row.expires_at.as_deref().unwrap_or_default())) " UTC). "
                    strong { "Copy it now: it is shown only once." } }
                p { code #new-token { (token) } }
            }
        }
        h2 { "Create a token" }
        @if let Some(e) = error { p.error role="alert" #token-error { (e) } }
        form.inline #create-token method="post" action="/tokens" {
            (csrf_field(v))
            label { "Label (e.g. the PC it is for)" input name="label" required maxlength=(MAX_LABEL_CHARS); }
            label { "Scope" select name="scope" { @for s in TokenScope::ALL {
                option value=(s.as_str()) selected[s == TokenScope::default()] { (s.as_str()) }
            } } }
            label { "Days valid (1–" (MAX_TOKEN_DAYS) ")" input name="days" type="number" min="1" max=(MAX_TOKEN_DAYS) value=(MAX_TOKEN_DAYS); }
            button.primary type="submit" { "Create" }
        }
        h2 { @if admin { "Everyone's tokens" } @else { "Your tokens" } }
        @if rows.is_empty() {
            p.muted { "No tokens yet." }
        } @else {
            table #tokens {
                thead { tr {
                    th { "Label" } @if admin { th { "User" } } th { "Scope" } th { "Ends with" }
                    th { "Created (UTC)" } th { "Expires (UTC)" } th { "Status" } th {}
                } }
                tbody { @for t in rows { tr data-token-id=(t.id) {
                    td { (t.label) }
                    @if admin { td { (t.username) } }
                    td { (t.scope.as_str()) }
                    td { code { @if let Some(l) = &t.last4 { "…" (l) } @else { "–" } } }
                    td { (short_time(&t.created_at)) }
                    td { (t.expires_at.as_deref().map_or_else(|| "–".into(), short_time)) }
                    td { (status_badge(t.status)) }
                    td { @if t.status == TokenStatus::Active {
                        form method="post" action={ "/tokens/" (t.id) "/revoke" } {
                            (csrf_field(v))
                            button type="submit" { "Revoke" }
                        }
                    } }
                } } }
            }
        }
    }
}

/// A page with a secret on it: not to be kept by the browser or a proxy.
fn no_store(status: StatusCode, body: impl IntoResponse) -> Response {
    (status, [(header::CACHE_CONTROL, "no-store")], body).into_response()
}

pub async fn index(State(s): State<Arc<AppState>>, v: Viewer) -> Result<Response, PageError> {
    let rows = tokens::list(&s, &v.user).await?;
    Ok(page("API tokens", Some(&v), tokens_page(&v, &rows, None, None)).into_response())
}

#[derive(serde::Deserialize)]
pub struct NewTokenForm {
    csrf: String,
    label: String,
    #[serde(default)]
    scope: String,
    #[serde(default)]
    days: String,
}

pub async fn create(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Form(f): Form<NewTokenForm>,
) -> Result<Response, PageError> {
    check_csrf(&v, &f.csrf)?;
    let scope = match f.scope.trim() {
        "" => Ok(TokenScope::default()),
        name => TokenScope::parse(name).ok_or_else(|| format!("unknown scope '{name}' (upload or full)")),
    };
    let days = match f.days.trim() {
        "" => Ok(None),
        d => d
            .parse::<u32>()
            .map(Some)
            .map_err(|_| format!("days valid is a whole number, 1–{MAX_TOKEN_DAYS}")),
    };
    let made = match (scope, days) {
        (Ok(scope), Ok(days)) => tokens::create(&s, &v.user, &f.label, scope, days)
            .await
            .map_err(|e| (e.status(), e.message())),
        (Err(m), _) | (_, Err(m)) => Err((StatusCode::BAD_REQUEST, m)),
    };
    let rows = tokens::list(&s, &v.user).await?;
    match made {
        Ok((token, row)) => Ok(no_store(
            StatusCode::OK,
            page(
                "API tokens",
                Some(&v),
                tokens_page(&v, &rows, Some((&token, &row)), None),
            ),
        )),
        Err((status, m)) if status.is_client_error() => Ok(no_store(
            status,
            page("API tokens", Some(&v), tokens_page(&v, &rows, None, Some(&m))),
        )),
        Err((status, m)) => Err(PageError::Status(status, m)),
    }
}

#[derive(serde::Deserialize)]
pub struct RevokeForm {
    csrf: String,
}

pub async fn revoke(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    Form(f): Form<RevokeForm>,
) -> Result<Response, PageError> {
    check_csrf(&v, &f.csrf)?;
    tokens::revoke(&s, &v.user, &id).await?;
    Ok(Redirect::to("/tokens").into_response())
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_service::store::User;

    fn row(id: &str, status: TokenStatus) -> TokenRow {
        TokenRow {
            id: id.into(),
            username: "tina".into(),
            user_id: "u1".into(),
            label: "sim <PC 3>".into(),
            scope: TokenScope::Upload,
            created_at: "2026-05-01T10:00:00.000000Z".into(),
            expires_at: Some("2026-07-30T10:00:00.000000Z".into()),
            revoked_at: None,
            last4: Some("be3f".into()),
            status,
        }
    }

    #[test]
    fn the_list_shows_no_secret_and_revokes_only_active_tokens() {
        let v = Viewer {
            user: User {
                id: "u1".into(),
                username: "tina".into(),
                role: stylet_service::store::Role::Trainee,
            },
            csrf: "c5rf".into(),
        };
        let rows = [
            row("t-active", TokenStatus::Active),
            row("t-revoked", TokenStatus::Revoked),
        ];
        let html = tokens_page(&v, &rows, None, None).into_string();
        assert!(html.contains("…be3f") && html.contains("sim &lt;PC 3&gt;"), "{html}");
        assert!(html.contains(r#"action="/tokens/t-active/revoke""#), "{html}");
        assert!(!html.contains("/tokens/t-revoked/revoke"), "{html}");
        assert!(!html.contains("new-token"), "{html}");
        assert_eq!(
            html.matches(r#"name="csrf" value="c5rf""#).count(),
            2,
            "create and one revoke"
        );
        let secret = "ab".repeat(32);
        let html = tokens_page(&v, &rows, Some((&secret, &rows[0])), None).into_string();
        assert_eq!(html.matches(&secret).count(), 1, "{html}");
    }
}
