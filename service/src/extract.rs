//! Who is asking: the logged-in user of a request (API token or login cookie with its CSRF
//! token), checked for token scope, disabled account and role before a handler runs, as
//! extractors a handler names in its arguments.

use std::sync::Arc;

use axum::http::{HeaderMap, StatusCode, header};

use super::AppState;
use super::auth;
use super::error::{ApiError, err};
use super::store::{Role, TokenScope, TokenStatus, User};

type AppRef = Arc<AppState>;

/// Only admins manage accounts.
pub fn require_admin(user: &User) -> Result<(), ApiError> {
    if user.role == Role::Admin {
        Ok(())
    } else {
        Err(err(
            StatusCode::FORBIDDEN,
            format!("{} ({}) may not manage accounts", user.username, user.role),
        ))
    }
}

/// How a request authenticated.
pub enum Via {
    /// The login cookie: state-changing requests must echo the login's CSRF token.
    Cookie { csrf: String },
    /// `Authorization: Bearer <API token>` (the desktop app): not sent by browsers on their own.
    Token { scope: TokenScope },
}

/// What a route takes from API tokens. Decided here, for every route, so that a route cannot
/// forget to refuse a token that may not use it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TokenUse {
    /// Any token, `upload` scope too: what the desktop simulator does (upload a session, read
    /// its status).
    Upload,
    /// `full` tokens only: every other route.
    Full,
    /// No token: the login cookie only (making tokens: a stolen token must not mint more).
    None,
}

/// The token of an `Authorization: Bearer <token>` header, trimmed; None without one or in
/// another form.
pub fn bearer_token(headers: &HeaderMap) -> Option<&str> {
    headers
        .get(header::AUTHORIZATION)?
        .to_str()
        .ok()?
        .strip_prefix("Bearer ")
        .map(str::trim)
}

/// The authenticated user (API token or login cookie), or 401 (also for an expired or revoked
/// token).
pub async fn authenticate(s: &AppState, headers: &HeaderMap) -> Result<(User, Via), ApiError> {
    if headers.contains_key(header::AUTHORIZATION) {
        let token = bearer_token(headers)
            .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "Authorization must be 'Bearer <API token>'"))?;
        let found = s
            .store
            .api_token(token)
            .await?
            .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "unknown API token"))?;
        if found.account_disabled {
            return Err(err(StatusCode::UNAUTHORIZED, "this account is disabled; ask an admin"));
        }
        return match found.status {
            TokenStatus::Active => Ok((found.user, Via::Token { scope: found.scope })),
            TokenStatus::Expired => Err(err(
                StatusCode::UNAUTHORIZED,
                "the API token has expired; create a new one",
            )),
            TokenStatus::Revoked => Err(err(StatusCode::UNAUTHORIZED, "the API token has been revoked")),
        };
    }
    let token = headers
        .get(header::COOKIE)
        .and_then(|v| v.to_str().ok())
        .and_then(auth::token_from_cookie_header)
        .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "log in first (POST /api/login)"))?;
    let (user, csrf) = s
        .store
        .user_for_login(token)
        .await?
        .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "the login has expired; log in again"))?;
    Ok((user, Via::Cookie { csrf }))
}

/// The user of a request to a route that takes `tokens`; `writes`: a state-changing request,
/// for which the login cookie must come with the `X-CSRF-Token` header carrying the token the
/// login returned (a page of another site cannot read it). 403 with the reason otherwise.
pub async fn user_for(s: &AppState, headers: &HeaderMap, tokens: TokenUse, writes: bool) -> Result<User, ApiError> {
    let (user, via) = authenticate(s, headers).await?;
    match via {
        Via::Cookie { csrf } if writes => {
            let sent = headers
                .get("x-csrf-token")
                .and_then(|v| v.to_str().ok())
                .unwrap_or_default();
            if sent != csrf {
                return Err(err(
                    StatusCode::FORBIDDEN,
                    "missing or wrong X-CSRF-Token header (the csrf_token of your login)",
                ));
            }
        }
        Via::Cookie { .. } => {}
        Via::Token { scope } => match (tokens, scope) {
            (TokenUse::None, _) => {
                return Err(err(
                    StatusCode::FORBIDDEN,
                    "API tokens cannot create API tokens: log in (cookie and X-CSRF-Token) to create one",
                ));
            }
            (TokenUse::Full, TokenScope::Upload) => {
                return Err(err(
                    StatusCode::FORBIDDEN,
                    "this API token has scope 'upload': it may only upload sessions (POST /api/sessions), \
                     read their status (GET /api/sessions/{id}) and fetch their files (GET /api/sessions/{id}/file); \
                     use a 'full' token for this",
                ));
            }
            (TokenUse::Upload, _) | (TokenUse::Full, TokenScope::Full) => {}
        },
    }
    Ok(user)
}

/// Counts the request against its account's requests in flight
/// ([`super::Limits::max_requests_per_account`]; 429 past it) until it has been answered.
pub fn hold_request_slot(s: &AppState, parts: &axum::http::request::Parts, user: &User) -> Result<(), ApiError> {
    match parts.extensions.get::<super::slots::InFlight>() {
        Some(slot) => slot.hold(&s.request_slots, &user.id),
        None => Ok(()),
    }
}

/// Extractors of the logged-in user (`FromRequestParts`): a handler names who may call it in its
/// arguments instead of looking the user up itself. Each applies [`user_for`] with its token use
/// and whether the request writes (CSRF for cookies); the `Admin…` ones also require an admin.
macro_rules! user_extractor {
    ($(#[$doc:meta])* $name:ident, $tokens:expr, $writes:expr, $admin:expr) => {
        $(#[$doc])*
        pub struct $name(pub User);

        impl axum::extract::FromRequestParts<AppRef> for $name {
            type Rejection = ApiError;

            async fn from_request_parts(parts: &mut axum::http::request::Parts, s: &AppRef) -> Result<Self, ApiError> {
                let user = user_for(s, &parts.headers, $tokens, $writes).await?;
                hold_request_slot(s, parts, &user)?;
                if $admin {
                    require_admin(&user)?;
                }
                Ok($name(user))
            }
        }
    };
}

user_extractor!(
    /// A read request: the login cookie or a `full` API token.
    Reader, TokenUse::Full, false, false
);
user_extractor!(
    /// A state-changing request: the login cookie with its `X-CSRF-Token`, or a `full` API token.
    Actor, TokenUse::Full, true, false
);
user_extractor!(
    /// An admin's read request.
    AdminReader, TokenUse::Full, false, true
);
user_extractor!(
    /// An admin's state-changing request.
    AdminActor, TokenUse::Full, true, true
);
user_extractor!(
    /// What the desktop simulator reads, which `upload` tokens may (a session's status).
    SimulatorReader, TokenUse::Upload, false, false
);
user_extractor!(
    /// What the desktop simulator writes, which `upload` tokens may (an upload).
    SimulatorActor, TokenUse::Upload, true, false
);
user_extractor!(
    /// Making API tokens: the login cookie with its CSRF token only (a token cannot mint more).
    CookieActor, TokenUse::None, true, false
);
