//! Logging in and out: `POST /api/login` and `POST /api/logout`, and [`log_in`], the password
//! check the dashboard's login form shares. And what keeps logins from taking the service down:
//! password checks (argon2id, tens of milliseconds of CPU each) run on a few threads of their own
//! with a bounded queue, so a flood of logins waits or gets 503 while every other route keeps its
//! latency; failed logins are rate-limited per account, and the memory of recent failures per
//! account is bounded in entries and in time.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

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
use super::store::{Role, User};

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
pub const LOGIN_FAILURES_ALLOWED: usize = 5;
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
    if username.len() > MAX_USERNAME_BYTES || password.len() > MAX_PASSWORD_BYTES {
        return Err(err(StatusCode::UNAUTHORIZED, "wrong username or password"));
    }
    let account = s.login_failures.of(&username.to_lowercase());
    let mut recent = account.lock().await;
    let now = Instant::now();
    recent.retain(|t| now.duration_since(*t) < LOGIN_WINDOW);
    if recent.len() >= LOGIN_FAILURES_ALLOWED {
        let wait = LOGIN_WINDOW.saturating_sub(now.duration_since(recent[0])).as_secs() + 1;
        return Err(ApiError::Throttled {
            message: format!("too many failed logins for this account; try again in {wait} s"),
            retry_after_s: wait as u32,
        });
    }
    let candidate = s.store.login_candidate(username).await?;
    // Same work whether or not the account exists, so timing does not reveal which do.
    let hash = candidate.as_ref().map_or(auth::DUMMY_HASH, |(_, h, _)| h.as_str());
    let matched = s
        .passwords
        .verify(password, hash)
        .await
        .map_err(|e| err(StatusCode::SERVICE_UNAVAILABLE, e.to_string()))?;
    let user = match candidate {
        // Told only to whoever knows the password.
        Some((_, _, true)) if matched => {
            recent.clear();
            return Err(err(StatusCode::FORBIDDEN, "this account is disabled; ask an admin"));
        }
        Some((user, _, _)) if matched => user,
        _ => {
            recent.push(now);
            return Err(err(StatusCode::UNAUTHORIZED, "wrong username or password"));
        }
    };
    recent.clear();
    drop(recent);
    let (token, csrf) = s.store.create_login(&user, LOGIN_TTL_S).await?;
    Ok((user, token, csrf))
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

/// Gives an admission back when a check ends (or its request is dropped).
struct Admission(Arc<AtomicUsize>);

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

    /// Whether `password` matches the argon2id `hash`; [`Busy`] at once when the queue is full.
    pub async fn verify(&self, password: &str, hash: &str) -> Result<bool, Busy> {
        if self.admitted.fetch_add(1, Ordering::AcqRel) >= self.capacity {
            self.admitted.fetch_sub(1, Ordering::AcqRel);
            return Err(Busy);
        }
        let admission = Admission(self.admitted.clone());
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
}

/// One account's recent failed logins. Its lock is held while a password is checked, so that
/// guesses sent in parallel are checked one after another, each seeing the failures before it.
pub type AccountFailures = Arc<tokio::sync::Mutex<Vec<Instant>>>;

/// Recent failed logins per account name, bounded: entries whose failures are all older than
/// the window are dropped, and past `max_accounts` the entries least recently failed go first.
pub struct FailedLogins {
    accounts: std::sync::Mutex<BTreeMap<String, AccountFailures>>,
    max_accounts: usize,
    window: Duration,
}

impl FailedLogins {
    pub fn new(max_accounts: usize, window: Duration) -> FailedLogins {
        FailedLogins {
            accounts: Default::default(),
            max_accounts: max_accounts.max(1),
            window,
        }
    }

    /// The failures of `account` (lower-cased by the caller), created if new.
    pub fn of(&self, account: &str) -> AccountFailures {
        let mut map = self.accounts.lock().expect("not poisoned");
        if let Some(f) = map.get(account) {
            return f.clone();
        }
        if map.len() >= self.max_accounts {
            self.prune(&mut map);
        }
        let f = AccountFailures::default();
        map.insert(account.to_string(), f.clone());
        f
    }

    /// How many accounts are remembered (tests, metrics).
    pub fn len(&self) -> usize {
        self.accounts.lock().expect("not poisoned").len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Drops the entries nobody is using whose failures have expired; if that is not enough to
    /// get below three quarters of the cap, the least recently failed ones too.
    fn prune(&self, map: &mut BTreeMap<String, AccountFailures>) {
        let now = Instant::now();
        // An entry in use (a login is checking it) has another handle and is kept.
        let last_failure = |f: &AccountFailures| -> Option<Option<Instant>> {
            if Arc::strong_count(f) > 1 {
                return None;
            }
            f.try_lock().ok().map(|v| v.last().copied())
        };
        map.retain(|_, f| match last_failure(f) {
            Some(last) => last.is_some_and(|t| now.duration_since(t) < self.window),
            None => true,
        });
        let target = self.max_accounts * 3 / 4;
        if map.len() <= target {
            return;
        }
        let mut by_age: Vec<(Instant, String)> = map
            .iter()
            .filter_map(|(k, f)| Some((last_failure(f)??, k.clone())))
            .collect();
        by_age.sort();
        for (_, k) in by_age.into_iter().take(map.len() - target) {
            map.remove(&k);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn failed_logins_stay_bounded() {
        let f = FailedLogins::new(100, Duration::from_secs(300));
        for i in 0..10_000 {
            let a = f.of(&format!("user{i}"));
            a.lock().await.push(Instant::now());
        }
        assert!(f.len() <= 100, "{}", f.len());
        // The newest failures are remembered.
        assert_eq!(f.of("user9999").lock().await.len(), 1);
    }

    #[tokio::test]
    async fn expired_failures_are_forgotten_first() {
        let f = FailedLogins::new(10, Duration::from_millis(1));
        for i in 0..10 {
            f.of(&format!("old{i}")).lock().await.push(Instant::now());
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
        f.of("new");
        assert_eq!(f.len(), 1);
    }

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
