//! `GET/POST /login`, `POST /logout`: the same logins as the JSON API (argon2id, rate limited,
//! HttpOnly SameSite=Strict cookie).

use std::sync::Arc;

use axum::Form;
use axum::extract::{Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use maud::html;
use stylet_service::api::{LOGIN_TTL_S, log_in};
use stylet_service::{AppState, auth};

use crate::auth::{PageError, Viewer, check_csrf, check_same_site, safe_next};
use crate::layout::page;

#[derive(serde::Deserialize)]
pub struct NextQuery {
    next: Option<String>,
}

fn login_page(next: &str, error: Option<&str>, username: &str) -> maud::Markup {
    html! {
        h1 { "Stylet — log in" }
        p.muted { "Needle-puncture training on virtual patients: your sessions, scores and progress." }
        @if let Some(e) = error { p.error role="alert" { (e) } }
        form.login method="post" action="/login" {
            input type="hidden" name="next" value=(next);
            p { label { "Username" input #username name="username" autocomplete="username" required value=(username); } }
            p { label { "Password" input #password name="password" type="password" autocomplete="current-password" required; } }
            p { button.primary type="submit" { "Log in" } }
        }
    }
}

pub async fn form(Query(q): Query<NextQuery>) -> impl IntoResponse {
    let next = safe_next(q.next.as_deref());
    page("Log in", None, login_page(&next, None, ""))
}

#[derive(serde::Deserialize)]
pub struct LoginForm {
    username: String,
    password: String,
    next: Option<String>,
}

pub async fn submit(State(s): State<Arc<AppState>>, headers: HeaderMap, Form(f): Form<LoginForm>) -> Response {
    if let Err(e) = check_same_site(&headers) {
        return e.into_response();
    }
    let next = safe_next(f.next.as_deref());
    match log_in(&s, &f.username, &f.password).await {
        Ok((_, token, _)) => {
            let mut r = Redirect::to(&next).into_response();
            r.headers_mut().insert(
                header::SET_COOKIE,
                auth::login_cookie(&token, s.config.secure_cookies, LOGIN_TTL_S)
                    .parse()
                    .expect("a valid header value"),
            );
            r
        }
        Err(e) => {
            let status = match e.status() {
                StatusCode::TOO_MANY_REQUESTS | StatusCode::SERVICE_UNAVAILABLE => e.status(),
                _ => StatusCode::UNAUTHORIZED,
            };
            let mut r = (
                status,
                page("Log in", None, login_page(&next, Some(&e.message()), &f.username)),
            )
                .into_response();
            if status == StatusCode::SERVICE_UNAVAILABLE {
                r.headers_mut()
                    .insert(header::RETRY_AFTER, axum::http::HeaderValue::from_static("1"));
            }
            r
        }
    }
}

#[derive(serde::Deserialize)]
pub struct LogoutForm {
    csrf: String,
}

pub async fn logout(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    headers: HeaderMap,
    Form(f): Form<LogoutForm>,
) -> Result<Response, PageError> {
    check_csrf(&v, &f.csrf)?;
    if let Some(token) = headers
        .get(header::COOKIE)
        .and_then(|h| h.to_str().ok())
        .and_then(auth::token_from_cookie_header)
    {
        s.store.end_login(token).await?;
    }
    let mut r = Redirect::to("/login").into_response();
    r.headers_mut().insert(
        header::SET_COOKIE,
        auth::logout_cookie(s.config.secure_cookies)
            .parse()
            .expect("a valid header value"),
    );
    Ok(r)
}
