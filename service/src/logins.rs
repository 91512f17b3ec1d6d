//! Logging in and out: `POST /api/login` and `POST /api/logout`, and [`log_in`], the password
//! check the dashboard's login form shares. And what keeps logins from taking the service down:
//! password checks (argon2id, tens of milliseconds of CPU each) run on a few threads of their own
//! with a bounded queue, so a flood of logins waits or gets 503 while every other route keeps its
//! latency; login attempts are counted per account in the database (so the limit holds across
//! replicas and restarts), before the password is checked.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use axum::Json;
use axum::body::Bytes;
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::json;
use tokio::sync::Semaphore;

use super::AppState;
use super::auth;
use super::error::{ApiError, err};
use super::store::{CheckEnd, CheckReservation, Role, Store, StoreError, User};

#[derive(serde::Deserialize, utoipa::ToSchema)]
struct LoginRequest {
    #[schema(max_length = 64)]
    username: String,
    #[schema(max_length = 4096)]
    password: String,
}

/// How long a login lasts (s).
pub const LOGIN_TTL_S: u64 = 12 * 3600;

/// Failed logins allowed per account within [`LOGIN_WINDOW`] before 429.
pub const LOGIN_FAILURES_ALLOWED: u32 = 5;
pub const LOGIN_WINDOW: Duration = Duration::from_secs(300);

#[utoipa::path(post, path = "/api/login", tag = "accounts",
    summary = "Log in; sets the stylet_session cookie",
    request_body(content = LoginRequest, content_type = "application/json"),
    responses(
        (status = 200, description = "logged in", body = LoginAnswer),
        (status = 400, description = "malformed body", body = super::openapi::ErrorBody),
        (status = 401, description = "wrong username or password", body = super::openapi::ErrorBody),
        (status = 403, description = "sent from another site (Sec-Fetch-Site, or an Origin or Referer that is not this server), or the account is disabled", body = super::openapi::ErrorBody),
        (status = 413, description = "a body over the limit of other requests (--max-body-bytes)", body = super::openapi::ErrorBody),
        (status = 415, description = "not application/json", body = super::openapi::ErrorBody),
        (status = 429, description = "too many failed logins for this account; Retry-After says when to try again", body = super::openapi::ErrorBody),
    ))]
pub async fn login(State(s): State<Arc<AppState>>, headers: HeaderMap, body: Bytes) -> Result<Response, ApiError> {
    if auth::from_other_site(&headers) {
        return Err(err(StatusCode::FORBIDDEN, "logins sent from other sites are refused"));
    }
    // Only JSON: an HTML form on another site can send text/plain that happens to parse as JSON.
    let json_body = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|v| v.trim().eq_ignore_ascii_case("application/json"));
    if !json_body {
        return Err(err(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "send the login as Content-Type: application/json",
        ));
    }
    let req: LoginRequest = serde_json::from_slice(&body).map_err(|e| {
        err(
            StatusCode::BAD_REQUEST,
            format!("expected {{\"username\", \"password\"}}: {e}"),
        )
    })?;
    let (user, token, csrf) = log_in(&s, &req.username, &req.password).await?;
    let mut r = Json(json!({ "username": user.username, "role": user.role, "csrf_token": csrf })).into_response();
    r.headers_mut().insert(
        header::SET_COOKIE,
        auth::login_cookie(&token, s.config.secure_cookies, LOGIN_TTL_S)
            .parse()
            .expect("a valid header value"),
    );
    Ok(r)
}

/// A login: who, and the CSRF token state-changing requests send in `X-CSRF-Token`.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct LoginAnswer {
    pub username: String,
    pub role: Role,
    pub csrf_token: String,
}

/// Longest username a login may name: no account has a longer one (checked before anything else,
/// so that no memory or work is spent on longer ones).
pub const MAX_USERNAME_BYTES: usize = 64;
/// Longest password a login may send (characters, as for accounts; 4 bytes each at most).
pub const MAX_PASSWORD_BYTES: usize = 4 * 1024;

/// Checks a password (with per-account rate limiting, on the password threads) and starts a
/// login: the user, the cookie token and the login's CSRF token. Used by the JSON API and the
/// dashboard's login form.
pub async fn log_in(s: &AppState, username: &str, password: &str) -> Result<(User, String, String), ApiError> {
    use super::telemetry::{LOGINS, count};
    if username.len() > MAX_USERNAME_BYTES || password.len() > MAX_PASSWORD_BYTES {
        count(LOGINS, "wrong");
        return Err(err(StatusCode::UNAUTHORIZED, "wrong username or password"));
    }
    // A place among the password checks first: a flood of logins is refused (503) before it
    // costs a database write.
    let busy = |e: Busy| {
        count(LOGINS, "busy");
        err(StatusCode::SERVICE_UNAVAILABLE, e.to_string())
    };
    let admission = s.passwords.admit().map_err(busy)?;
    // A check of the account reserved in the database, so that guesses sent at once (to any
    // replica) get no more checks than the limit; a login of the account in progress elsewhere
    // only makes this one wait for it.
    let account = username.to_lowercase();
    let waiting_since = std::time::Instant::now();
    loop {
        match s
            .store
            .reserve_login_check(&account, LOGIN_FAILURES_ALLOWED, LOGIN_WINDOW)
            .await?
        {
            CheckReservation::Granted => break,
            CheckReservation::Refused { window_left } => {
                let wait = window_left.as_secs() + 1;
                count(LOGINS, "throttled");
                return Err(ApiError::Throttled {
                    message: format!("too many failed logins for this account; try again in {wait} s"),
                    retry_after_s: wait as u32,
                });
            }
            CheckReservation::Wait if waiting_since.elapsed() < LOGIN_CHECK_WAIT => {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            CheckReservation::Wait => return Err(busy(Busy)),
        }
    }
    let check = ReservedCheck {
        store: s.store.clone(),
        account: Some(account),
    };
    let candidate = s.store.login_candidate(username).await?;
    // Same work whether or not the account exists, so timing does not reveal which do.
    let hash = candidate.as_ref().map_or(auth::DUMMY_HASH, |(_, h, _)| h.as_str());
    let matched = s.passwords.check(admission, password, hash).await.map_err(busy)?;
    check
        .end(if matched { CheckEnd::Matched } else { CheckEnd::Failed })
        .await?;
    let user = match candidate {
        // Told only to whoever knows the password.
        Some((_, _, true)) if matched => {
            count(LOGINS, "disabled");
            return Err(err(StatusCode::FORBIDDEN, "this account is disabled; ask an admin"));
        }
        Some((user, _, _)) if matched => user,
        _ => {
            count(LOGINS, "wrong");
            return Err(err(StatusCode::UNAUTHORIZED, "wrong username or password"));
        }
    };
    count(LOGINS, "success");
    let (token, csrf) = s.store.create_login(&user, LOGIN_TTL_S).await?;
    Ok((user, token, csrf))
}

/// How long a login waits for the account's other checks in progress before it gets 503.
pub const LOGIN_CHECK_WAIT: Duration = Duration::from_secs(10);

/// A password check reserved in the database; given back (abandoned) if its request goes away
/// before [`ReservedCheck::end`].
struct ReservedCheck {
    store: Store,
    account: Option<String>,
}

impl ReservedCheck {
    async fn end(mut self, end: CheckEnd) -> Result<(), StoreError> {
        match self.account.take() {
            Some(account) => self.store.end_login_check(&account, end).await,
            None => Ok(()),
        }
    }
}

impl Drop for ReservedCheck {
    fn drop(&mut self) {
        if let Some(account) = self.account.take()
            && let Ok(runtime) = tokio::runtime::Handle::try_current()
        {
            let store = self.store.clone();
            runtime.spawn(async move {
                if let Err(e) = store.end_login_check(&account, CheckEnd::Abandoned).await {
                    tracing::warn!(error = %e, "cannot give back an abandoned login check");
                }
            });
        }
    }
}

/// POST /api/logout: ends the login of the cookie sent (none: nothing to end). API tokens do
/// not log in, so they cannot log out either: a request with one is refused (403), whatever its
/// scope, so that a token (an upload-scoped one on a lab's simulator) cannot end its account's
/// logins.
#[utoipa::path(post, path = "/api/logout", tag = "accounts",
    summary = "Log out: ends the login of the cookie sent",
    responses(
        (status = 200, description = "logged out", body = LogoutAnswer),
        (status = 403, description = "sent with an API token: tokens do not log in or out", body = super::openapi::ErrorBody),
    ))]
pub async fn logout(State(s): State<Arc<AppState>>, headers: HeaderMap) -> Result<Response, ApiError> {
    if headers.contains_key(header::AUTHORIZATION) {
        return Err(err(
            StatusCode::FORBIDDEN,
            "API tokens cannot log out: a token stays valid until it expires or is revoked (POST /api/tokens/{id}/revoke)",
        ));
    }
    if let Some(token) = headers
        .get(header::COOKIE)
        .and_then(|v| v.to_str().ok())
        .and_then(auth::token_from_cookie_header)
    {
        s.store.end_login(token).await?;
    }
    let mut r = Json(json!({ "status": "logged out" })).into_response();
    r.headers_mut().insert(
        header::SET_COOKIE,
        auth::logout_cookie(s.config.secure_cookies)
            .parse()
            .expect("a valid header value"),
    );
    Ok(r)
}

/// `{"status": "logged out"}`.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct LogoutAnswer {
    pub status: String,
}

/// The queue of password checks is full: answer 503 with Retry-After.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("too many logins at once; try again in a second")]
pub struct Busy;

/// Runs password checks on at most `threads` blocking threads, with at most `queue` waiting.
pub struct PasswordPool {
    run: Arc<Semaphore>,
    admitted: Arc<AtomicUsize>,
    capacity: usize,
}

/// A place among the password checks (running or queued), given back when the check ends or
/// its request is dropped.
pub struct Admission(Arc<AtomicUsize>);

impl Drop for Admission {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

impl PasswordPool {
    pub fn new(threads: usize, queue: usize) -> PasswordPool {
        let threads = threads.max(1);
        PasswordPool {
            run: Arc::new(Semaphore::new(threads)),
            admitted: Arc::new(AtomicUsize::new(0)),
            capacity: threads + queue,
        }
    }

    /// A place among the password checks; [`Busy`] at once when the queue is full.
    pub fn admit(&self) -> Result<Admission, Busy> {
        if self.admitted.fetch_add(1, Ordering::AcqRel) >= self.capacity {
            self.admitted.fetch_sub(1, Ordering::AcqRel);
            return Err(Busy);
        }
        Ok(Admission(self.admitted.clone()))
    }

    /// Whether `password` matches the argon2id `hash`, checked in the place `admission` holds.
    pub async fn check(&self, admission: Admission, password: &str, hash: &str) -> Result<bool, Busy> {
        let permit = self.run.clone().acquire_owned().await.map_err(|_| Busy)?;
        let (password, hash) = (password.to_string(), hash.to_string());
        // The permit and the admission go with the thread: a request dropped while its hash runs
        // still counts until the hash ends, so the threads are never oversubscribed.
        tokio::task::spawn_blocking(move || {
            let _held = (permit, admission);
            auth::verify_password(&password, &hash)
        })
        .await
        .map_err(|_| Busy)
    }

    /// [`PasswordPool::admit`], then [`PasswordPool::check`].
    pub async fn verify(&self, password: &str, hash: &str) -> Result<bool, Busy> {
        let admission = self.admit()?;
        self.check(admission, password, hash).await
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_full_password_queue_answers_busy_at_once() {
        let hash = super::super::auth::hash_password("right password").unwrap();
        let pool = Arc::new(PasswordPool::new(1, 2));
        let tasks: Vec<_> = (0..12)
            .map(|_| {
                let (pool, hash) = (pool.clone(), hash.clone());
                tokio::spawn(async move { pool.verify("wrong password", &hash).await })
            })
            .collect();
        let mut busy = 0;
        for t in tasks {
            match t.await.unwrap() {
                Ok(matched) => assert!(!matched),
                Err(Busy) => busy += 1,
            }
        }
        assert!(busy >= 9, "{busy} of 12 refused with a queue of 2 behind 1 thread");
        assert_eq!(pool.verify("right password", &hash).await, Ok(true));
    }
}
