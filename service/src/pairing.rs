//! Pairing a desktop simulator in seconds (docs/integration.md "Pairing a simulator"): a short
//! code shown on the dashboard, typed into the simulator, yields the upload-scoped API token
//! the simulator already uses — no password on the simulator, no token copied by hand.
//!
//! - `POST /api/pairing/codes` (login cookie and CSRF token): a code for `simulator` (anyone's
//!   own simulator), `lab` (an instructor of the cohort, or an admin: a lab machine of it) or
//!   `sign_in` (a trainee, at a lab machine of their cohort). Valid [`CODE_MINUTES`] minutes,
//!   used once, at most [`MAX_ACTIVE_CODES`] unused per account; audited.
//! - `POST /api/pair` (no credential: the code is one): a simulator code gives an upload token
//!   (90 days); a lab code makes the machine a lab machine and gives it a lab token.
//! - `POST /api/lab/sign-in` (a lab token): a cohort trainee's sign-in code gives an upload token
//!   of that trainee for [`LAB_SIGN_IN_HOURS`] hours; `POST /api/tokens/current/revoke` (the
//!   token itself) signs them out.
//!
//! Codes are [`CODE_LENGTH`] characters of Crockford's base-32 alphabet (50 bits; no I, L, O, U;
//! typed in any case, with or without the dash). Wrong codes are counted in the database, per
//! client address and for all addresses together (see [`PER_ADDRESS_FAILURES`]); past either
//! limit, 429 until the window has passed.

use std::net::IpAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::json;

use super::AppState;
use super::error::{ApiError, err};
use super::extract::{CookieActor, Reader, bearer_token};
use super::store::{
    CheckEnd, CheckReservation, LabMachine, Paired, PairingPlace, PairingPurpose, PairingRefusal, Role, User,
};
use super::tokens::{MAX_ACTIVE_TOKENS, MAX_TOKEN_DAYS, check_label};

/// Characters of a code.
pub const CODE_LENGTH: usize = 10;
/// Minutes a code is valid.
pub const CODE_MINUTES: u64 = 10;
/// Unused codes one account may hold.
pub const MAX_ACTIVE_CODES: usize = 5;
/// Hours a trainee stays signed in at a lab machine (a lab day), unless they sign out.
pub const LAB_SIGN_IN_HOURS: u64 = 12;
/// Wrong codes allowed from one client address per window ([`crate::logins::LOGIN_WINDOW`]).
pub const PER_ADDRESS_FAILURES: u32 = 20;
/// Wrong codes allowed from all addresses together per window: with 2^50 codes and at most a
/// few thousand valid at once, a guesser spread over many addresses hits one with a chance of
/// about 10^-9 a window, at the cost of pairing (only) waiting out the window.
pub const ALL_FAILURES: u32 = 2000;

/// Crockford's base-32 digits.
const ALPHABET: &[u8; 32] = b"0123456789ABCDEFGHJKMNPQRSTVWXYZ";

/// A new random code, normalised (no dash).
pub fn new_code() -> String {
    use argon2::password_hash::rand_core::{OsRng, RngCore};
    let mut code = String::with_capacity(CODE_LENGTH);
    for _ in 0..CODE_LENGTH {
        // 32 divides 2^32: no bias.
        code.push(ALPHABET[(OsRng.next_u32() % 32) as usize] as char);
    }
    code
}

/// A code as shown: two groups of five, `K7QM3-XPD9A`.
pub fn display(code: &str) -> String {
    let (a, b) = code.split_at(code.len() / 2);
    format!("{a}-{b}")
}

/// A typed code, normalised: spaces and dashes dropped, upper case, O read as 0 and I, L as 1
/// (Crockford); None when it is not a code's length and alphabet.
pub fn normalise(typed: &str) -> Option<String> {
    let code: String = typed
        .chars()
        .filter(|c| !c.is_whitespace() && *c != '-')
        .map(|c| match c.to_ascii_uppercase() {
            'O' => '0',
            'I' | 'L' => '1',
            c => c,
        })
        .collect();
    (code.len() == CODE_LENGTH && code.bytes().all(|b| ALPHABET.contains(&b))).then_some(code)
}

/// The client's address: the connection's peer, or — when the peer is a trusted proxy
/// (`--trusted-proxy`) — the nearest address in `X-Forwarded-For` that is not one.
pub fn client_address(peer: Option<IpAddr>, headers: &HeaderMap, trusted: &[ipnet::IpNet]) -> Option<IpAddr> {
    let peer = peer?.to_canonical();
    if !trusted.iter().any(|n| n.contains(&peer)) {
        return Some(peer);
    }
    let forwarded = headers
        .get_all("x-forwarded-for")
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .map(|a| a.trim().parse::<IpAddr>().ok().map(|a| a.to_canonical()))
        .collect::<Vec<_>>();
    for address in forwarded.into_iter().rev() {
        match address {
            Some(a) if trusted.iter().any(|n| n.contains(&a)) => continue,
            Some(a) => return Some(a),
            None => break,
        }
    }
    Some(peer)
}

/// The connection's peer address, put on each request by the server.
#[derive(Debug, Clone, Copy)]
pub struct Peer(pub IpAddr);

/// Counts a code check against the client's address and against all addresses; 429 past
/// either. The check's end is recorded by [`end_check`].
async fn reserve_check(s: &AppState, keys: &[(String, u32)]) -> Result<(), ApiError> {
    let window = super::logins::LOGIN_WINDOW;
    for (i, (key, allowed)) in keys.iter().enumerate() {
        let refused = match s.store.reserve_login_check(key, *allowed, window).await? {
            CheckReservation::Granted => continue,
            CheckReservation::Refused { window_left } => window_left.as_secs() + 1,
            CheckReservation::Wait => 1,
        };
        for (earlier, _) in &keys[..i] {
            s.store.end_login_check(earlier, CheckEnd::Abandoned).await?;
        }
        return Err(ApiError::Throttled {
            message: format!("too many wrong pairing codes; try again in {refused} s"),
            retry_after_s: refused as u32,
        });
    }
    Ok(())
}

/// Records how a reserved check ended: a wrong code counts; a good one forgets nothing (a code
/// of one's own must not wipe the count of one's guesses).
async fn end_check(s: &AppState, keys: &[(String, u32)], wrong: bool) -> Result<(), ApiError> {
    let end = if wrong { CheckEnd::Failed } else { CheckEnd::Abandoned };
    for (key, _) in keys {
        s.store.end_login_check(key, end).await?;
    }
    Ok(())
}

/// The failure counters of a request: its address's and everyone's (named so that no username
/// can collide: usernames have no spaces).
fn check_keys(s: &AppState, headers: &HeaderMap, peer: Option<Peer>) -> Vec<(String, u32)> {
    let address = client_address(peer.map(|p| p.0), headers, &s.config.limits.trusted_proxies)
        .map_or_else(|| "unknown".to_string(), |a| a.to_string());
    vec![
        (format!("pairing from {address}"), PER_ADDRESS_FAILURES),
        ("pairing from all addresses".to_string(), ALL_FAILURES),
    ]
}

/// Uses `typed` at `place`, counted against the request's failure limits.
async fn use_code(
    s: &AppState,
    headers: &HeaderMap,
    peer: Option<Peer>,
    typed: &str,
    place: PairingPlace<'_>,
) -> Result<Paired, ApiError> {
    let keys = check_keys(s, headers, peer);
    reserve_check(s, &keys).await?;
    let used = match normalise(typed) {
        Some(code) => s.store.use_pairing_code(&code, place).await,
        None => Ok(Err(PairingRefusal::Unknown)),
    };
    let wrong = matches!(used, Ok(Err(PairingRefusal::Unknown)));
    end_check(s, &keys, wrong).await?;
    match used? {
        Ok(paired) => Ok(paired),
        Err(PairingRefusal::Unknown) => Err(err(
            StatusCode::NOT_FOUND,
            "no such pairing code: it is mistyped, expired (codes last 10 minutes) or used (once); make a new one on the dashboard",
        )),
        Err(PairingRefusal::WrongPlace(purpose)) => Err(err(
            StatusCode::CONFLICT,
            format!(
                "this code {}: {}",
                purpose.words(),
                match purpose {
                    PairingPurpose::SignIn => "type it into a lab machine's sign-in box",
                    PairingPurpose::Simulator | PairingPurpose::Lab =>
                        "type it where the simulator pairs with the service",
                }
            ),
        )),
        Err(PairingRefusal::NotInCohort) => Err(err(
            StatusCode::FORBIDDEN,
            "this lab machine serves another cohort: sign in at one of your cohort's machines",
        )),
        Err(PairingRefusal::AccountDisabled) => Err(err(
            StatusCode::FORBIDDEN,
            "the code's account is disabled; ask an admin",
        )),
    }
}

/// A new code of `user` for `purpose` (for a lab code, `cohort` by name): the code (shown) and
/// its expiry. Who may make which: anyone a simulator code; trainees sign-in codes; instructors
/// of the cohort and admins lab codes.
pub async fn create(
    s: &AppState,
    user: &User,
    purpose: PairingPurpose,
    cohort: Option<&str>,
) -> Result<(String, String), ApiError> {
    let cohort_id = match purpose {
        PairingPurpose::Simulator => None,
        PairingPurpose::SignIn if user.role == Role::Trainee => None,
        PairingPurpose::SignIn => {
            return Err(err(
                StatusCode::FORBIDDEN,
                "sign-in codes are for trainees (a lab machine signs in its cohort's trainees)",
            ));
        }
        PairingPurpose::Lab => {
            let name = cohort.map(str::trim).filter(|c| !c.is_empty()).ok_or_else(|| {
                err(
                    StatusCode::BAD_REQUEST,
                    "a lab machine is paired to a cohort: name it (\"cohort\")",
                )
            })?;
            let not_yours = || {
                err(
                    StatusCode::FORBIDDEN,
                    format!("you may not pair lab machines of cohort '{name}'"),
                )
            };
            let id = s.store.cohort_id(name).await?;
            match (user.role, id) {
                (Role::Admin, Some(id)) => Some(id),
                (Role::Admin, None) => return Err(err(StatusCode::NOT_FOUND, format!("no cohort '{name}'"))),
                (Role::Instructor, Some(id)) if s.store.in_cohort(&user.id, &id).await? => Some(id),
                _ => return Err(not_yours()),
            }
        }
    };
    let code = new_code();
    let expires_at = s
        .store
        .create_pairing_code(
            user,
            &code,
            purpose,
            cohort_id.as_deref(),
            Duration::from_secs(CODE_MINUTES * 60),
            MAX_ACTIVE_CODES,
        )
        .await?;
    Ok((display(&code), expires_at))
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
struct NewCodeRequest {
    purpose: PairingPurpose,
    /// For a `lab` code: the cohort the machine will serve.
    #[serde(default)]
    cohort: Option<String>,
}

/// A new pairing code, shown once.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct NewCode {
    /// `K7QM3-XPD9A`: type it into the simulator.
    pub code: String,
    pub purpose: PairingPurpose,
    pub cohort: Option<String>,
    pub expires_at: String,
}

/// POST /api/pairing/codes
#[utoipa::path(post, path = "/api/pairing/codes", tag = "pairing",
    summary = "Make a pairing code (10 minutes, used once; audited)",
    description = "Login cookie and X-CSRF-Token only. `simulator`: pairs a simulator with your account (an upload token). `lab` (instructors of the cohort, admins): makes a simulator a lab machine of `cohort`. `sign_in` (trainees): signs you in at a lab machine of your cohort.",
    request_body(content = NewCodeRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "the code", body = NewCode),
        (status = 400, description = "bad purpose, or a lab code without a cohort", body = super::openapi::ErrorBody),
        (status = 403, description = "CSRF token missing, a token instead of the login, or not allowed this purpose or cohort", body = super::openapi::ErrorBody),
        (status = 404, description = "no such cohort (admins)", body = super::openapi::ErrorBody),
        (status = 409, description = "as many unused codes as allowed", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = [])))]
pub async fn create_code(
    State(s): State<Arc<AppState>>,
    CookieActor(user): CookieActor,
    body: Bytes,
) -> Result<Response, ApiError> {
    let req: NewCodeRequest = serde_json::from_slice(&body).map_err(|e| {
        err(
            StatusCode::BAD_REQUEST,
            format!("expected {{\"purpose\": \"simulator\"|\"lab\"|\"sign_in\", \"cohort\"?}}: {e}"),
        )
    })?;
    let (code, expires_at) = create(&s, &user, req.purpose, req.cohort.as_deref()).await?;
    let body = NewCode {
        code,
        purpose: req.purpose,
        cohort: req.cohort.filter(|_| req.purpose == PairingPurpose::Lab),
        expires_at,
    };
    Ok((StatusCode::CREATED, [(header::CACHE_CONTROL, "no-store")], Json(body)).into_response())
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
struct PairRequest {
    /// The code shown on the dashboard.
    code: String,
    /// What the simulator is called (its computer): the token's or the lab machine's label.
    #[schema(min_length = 1, max_length = 100)]
    label: String,
}

/// What a pairing gave the simulator.
#[derive(serde::Serialize, utoipa::ToSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PairResult {
    /// An upload token of `username`.
    Simulator {
        username: String,
        token: String,
        expires_at: String,
    },
    /// A lab machine of `cohort`, with its lab token.
    Lab {
        cohort: String,
        lab_token: String,
        machine_id: String,
        expires_at: String,
    },
}

/// POST /api/pair
#[utoipa::path(post, path = "/api/pair", tag = "pairing",
    summary = "Pair a simulator with a code: an upload token, or a lab machine's token",
    description = "No credential: the code is one. Wrong codes are counted per client address and for all addresses (429 past the limits).",
    request_body(content = PairRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "paired", body = PairResult),
        (status = 400, description = "a malformed request or label", body = super::openapi::ErrorBody),
        (status = 403, description = "the code's account is disabled", body = super::openapi::ErrorBody),
        (status = 404, description = "no such code (mistyped, expired or used)", body = super::openapi::ErrorBody),
        (status = 409, description = "a sign-in code (for a lab machine), or the account has as many tokens as allowed", body = super::openapi::ErrorBody),
        (status = 429, description = "too many wrong codes", body = super::openapi::ErrorBody),
    ),
    security(()))]
pub async fn pair(
    State(s): State<Arc<AppState>>,
    peer: Option<axum::Extension<Peer>>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    let req: PairRequest = serde_json::from_slice(&body).map_err(|e| {
        err(
            StatusCode::BAD_REQUEST,
            format!("expected {{\"code\", \"label\"}}: {e}"),
        )
    })?;
    let label = check_label(&req.label)?;
    let place = PairingPlace::Simulator {
        label,
        token_days: MAX_TOKEN_DAYS,
        max_tokens: MAX_ACTIVE_TOKENS,
    };
    let result = match use_code(&s, &headers, peer.map(|p| p.0), &req.code, place).await? {
        Paired::Token { token, row } => PairResult::Simulator {
            username: row.username,
            token,
            expires_at: row.expires_at.unwrap_or_default(),
        },
        Paired::Lab { token, machine } => PairResult::Lab {
            cohort: machine.cohort,
            lab_token: token,
            machine_id: machine.id,
            expires_at: machine.expires_at,
        },
    };
    Ok((StatusCode::CREATED, [(header::CACHE_CONTROL, "no-store")], Json(result)).into_response())
}

/// The active lab machine whose token the request bears, or 401.
async fn lab_machine(s: &AppState, headers: &HeaderMap) -> Result<LabMachine, ApiError> {
    let token = bearer_token(headers)
        .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "Authorization must be 'Bearer <lab token>'"))?;
    match s.store.lab_machine(token).await? {
        Some(m) if m.active => Ok(m),
        Some(_) => Err(err(
            StatusCode::UNAUTHORIZED,
            "this lab machine's pairing has expired or was revoked; an instructor pairs it again",
        )),
        None => Err(err(StatusCode::UNAUTHORIZED, "unknown lab token")),
    }
}

#[derive(serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
struct SignInRequest {
    /// The trainee's sign-in code.
    code: String,
}

/// A trainee signed in at a lab machine.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct SignedIn {
    pub username: String,
    /// An upload token of the trainee, until `expires_at` or sign-out.
    pub token: String,
    pub expires_at: String,
}

/// POST /api/lab/sign-in
#[utoipa::path(post, path = "/api/lab/sign-in", tag = "pairing",
    summary = "Sign a trainee in at a lab machine with their sign-in code: an upload token for 12 hours",
    description = "Authorization: Bearer <lab token>. The code's trainee must be in the machine's cohort.",
    request_body(content = SignInRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "signed in", body = SignedIn),
        (status = 401, description = "no lab token, or one expired or revoked", body = super::openapi::ErrorBody),
        (status = 403, description = "the trainee is not in the machine's cohort, or disabled", body = super::openapi::ErrorBody),
        (status = 404, description = "no such code (mistyped, expired or used)", body = super::openapi::ErrorBody),
        (status = 409, description = "not a sign-in code, or the trainee has as many tokens as allowed", body = super::openapi::ErrorBody),
        (status = 429, description = "too many wrong codes", body = super::openapi::ErrorBody),
    ),
    security(("lab_token" = [])))]
pub async fn lab_sign_in(
    State(s): State<Arc<AppState>>,
    peer: Option<axum::Extension<Peer>>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    let machine = lab_machine(&s, &headers).await?;
    let req: SignInRequest = serde_json::from_slice(&body)
        .map_err(|e| err(StatusCode::BAD_REQUEST, format!("expected {{\"code\"}}: {e}")))?;
    let place = PairingPlace::Lab {
        machine: &machine,
        sign_in: Duration::from_secs(LAB_SIGN_IN_HOURS * 3600),
        max_tokens: MAX_ACTIVE_TOKENS,
    };
    match use_code(&s, &headers, peer.map(|p| p.0), &req.code, place).await? {
        Paired::Token { token, row } => {
            let body = SignedIn {
                username: row.username,
                token,
                expires_at: row.expires_at.unwrap_or_default(),
            };
            Ok((StatusCode::CREATED, [(header::CACHE_CONTROL, "no-store")], Json(body)).into_response())
        }
        Paired::Lab { .. } => Err(ApiError::Internal),
    }
}

/// POST /api/tokens/current/revoke
#[utoipa::path(post, path = "/api/tokens/current/revoke", tag = "accounts",
    summary = "Revoke the API token the request bears (a simulator signing out)",
    responses(
        (status = 200, description = "revoked (or already)", body = Object),
        (status = 401, description = "no API token, or an unknown one", body = super::openapi::ErrorBody),
    ),
    security(("token" = [])))]
pub async fn revoke_current_token(State(s): State<Arc<AppState>>, headers: HeaderMap) -> Result<Response, ApiError> {
    let token = bearer_token(&headers)
        .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "Authorization must be 'Bearer <API token>'"))?;
    let id = s
        .store
        .revoke_presented_token(token)
        .await?
        .ok_or_else(|| err(StatusCode::UNAUTHORIZED, "unknown API token"))?;
    Ok(Json(json!({ "revoked": id })).into_response())
}

/// Lab machines an instructor or admin may see.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct LabMachineList {
    pub machines: Vec<LabMachine>,
}

/// GET /api/lab/machines
#[utoipa::path(get, path = "/api/lab/machines", tag = "pairing",
    summary = "Lab machines of the caller's cohorts (admins: all), newest first",
    responses(
        (status = 200, description = "the machines", body = LabMachineList),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn list_lab_machines(State(s): State<Arc<AppState>>, Reader(user): Reader) -> Result<Response, ApiError> {
    let machines = s.store.lab_machines(&user).await?;
    Ok(Json(LabMachineList { machines }).into_response())
}

/// Revokes lab machine `id` for `user` (an instructor of its cohort, or an admin), or 404.
pub async fn revoke_lab_machine(s: &AppState, user: &User, id: &str) -> Result<LabMachine, ApiError> {
    let not_found = || err(StatusCode::NOT_FOUND, format!("no lab machine {id}"));
    let machine = s.store.lab_machine_by_id(id).await?.ok_or_else(not_found)?;
    let allowed = match user.role {
        Role::Admin => true,
        Role::Instructor => s.store.in_cohort(&user.id, &machine.cohort_id).await?,
        Role::Trainee | Role::Curriculum => false,
    };
    if !allowed {
        return Err(not_found());
    }
    s.store.revoke_lab_machine(id, user).await?.ok_or_else(not_found)
}

/// POST /api/lab/machines/{id}/revoke
#[utoipa::path(post, path = "/api/lab/machines/{id}/revoke", tag = "pairing",
    summary = "Revoke a lab machine (instructors of its cohort, admins); audited",
    params(("id" = String, Path, description = "the machine's id")),
    responses(
        (status = 200, description = "the machine, now revoked", body = LabMachine),
        (status = 403, description = "CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such machine, or not yours", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn revoke_machine(
    State(s): State<Arc<AppState>>,
    super::extract::Actor(user): super::extract::Actor,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    Ok(Json(revoke_lab_machine(&s, &user, &id).await?).into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_are_typed_forgivingly_and_checked() {
        for _ in 0..100 {
            let code = new_code();
            assert_eq!(code.len(), CODE_LENGTH);
            assert_eq!(normalise(&display(&code)).as_deref(), Some(code.as_str()));
            assert_eq!(
                normalise(&display(&code).to_lowercase()).as_deref(),
                Some(code.as_str())
            );
        }
        assert_eq!(normalise(" k7qm3 - xpd9a ").as_deref(), Some("K7QM3XPD9A"));
        assert_eq!(normalise("O1LI0-ABCDE").as_deref(), Some("01110ABCDE"));
        assert_eq!(normalise("K7QM3-XPD9"), None, "too short");
        assert_eq!(normalise("K7QM3-XPD9AA"), None, "too long");
        assert_eq!(normalise("K7QM3-XPD9U"), None, "U is not a digit");
        assert_eq!(normalise("K7QM3-XPD9é"), None);
        assert_eq!(display("K7QM3XPD9A"), "K7QM3-XPD9A");
    }

    #[test]
    fn the_client_is_the_peer_unless_the_peer_is_a_trusted_proxy() {
        let proxy: IpAddr = "10.0.0.5".parse().unwrap();
        let trusted: Vec<ipnet::IpNet> = vec!["10.0.0.0/24".parse().unwrap()];
        let mut h = HeaderMap::new();
        h.insert("x-forwarded-for", "203.0.113.7, 10.0.0.9".parse().unwrap());
        // A peer that is not a proxy: its own address, whatever it claims.
        let stranger: IpAddr = "198.51.100.1".parse().unwrap();
        assert_eq!(client_address(Some(stranger), &h, &trusted), Some(stranger));
        // Through the proxies: the nearest address that is not one.
        assert_eq!(client_address(Some(proxy), &h, &trusted), "203.0.113.7".parse().ok());
        // No proxies trusted: the header is ignored.
        assert_eq!(client_address(Some(proxy), &h, &[]), Some(proxy));
        // A proxy without the header, or with garbage: the proxy.
        assert_eq!(client_address(Some(proxy), &HeaderMap::new(), &trusted), Some(proxy));
        let mut bad = HeaderMap::new();
        bad.insert("x-forwarded-for", "not an address".parse().unwrap());
        assert_eq!(client_address(Some(proxy), &bad, &trusted), Some(proxy));
        // IPv4 mapped into IPv6 is IPv4.
        let mapped: IpAddr = "::ffff:198.51.100.1".parse().unwrap();
        assert_eq!(client_address(Some(mapped), &h, &[]), Some(stranger));
    }
}
