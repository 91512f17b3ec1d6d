//! The HTTP server around the routes: connections capped and timed out, every request given a
//! deadline, every answer the security headers, every API error JSON (docs/security.md), and
//! every request logged under an id.
//!
//! Connections are served by hyper directly (not `axum::serve`) for its header-read timer: a
//! client gets [`Limits::header_timeout`] to send each request's headers, and the same timer
//! closes keep-alive connections that stay idle that long. Two different things are bounded:
//! - open connections, whatever they do ([`Limits::max_connections`], at most
//!   [`Limits::max_connections_per_address`] from one address): a socket and a small task each,
//!   with a read buffer of at most [`MAX_CONNECTION_BUFFER_BYTES`];
//! - requests being served ([`Limits::max_requests`], [`serving`]; per account
//!   [`Limits::max_requests_per_account`], [`in_flight`]): a connection holds such a slot only
//!   from its request's complete headers to its answer, so connections that are still sending
//!   their headers (slowloris) or idle cannot take the serving capacity, and `/healthz` is never
//!   refused.

use std::net::IpAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::Request;
use axum::http::{HeaderValue, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::net::TcpListener;
use tokio::sync::Semaphore;

use super::Limits;
use super::error::err;
use super::slots::{InFlight, Slots};

/// Largest read buffer of a connection (bytes): bounds what a client's headers can make the
/// server hold per connection (hyper's default is about 400 KB).
pub const MAX_CONNECTION_BUFFER_BYTES: usize = 64 << 10;

/// File descriptors kept for everything but connections (database, session and atlas files).
const OTHER_FILE_DESCRIPTORS: u64 = 512;

/// Raises the process's soft limit of open files to its hard limit and returns how many
/// connections fit under it: `wanted`, or fewer (logged) when the limit is lower.
pub fn connection_cap(wanted: usize) -> usize {
    use rustix::process::{Resource, getrlimit, setrlimit};
    let mut limit = getrlimit(Resource::Nofile);
    if limit.current < limit.maximum {
        limit.current = limit.maximum;
        if let Err(e) = setrlimit(Resource::Nofile, limit) {
            tracing::warn!(error = %e, "cannot raise the open-file limit");
        }
        limit = getrlimit(Resource::Nofile);
    }
    let fit = limit
        .current
        .map_or(usize::MAX, |n| n.saturating_sub(OTHER_FILE_DESCRIPTORS) as usize)
        .max(1);
    if fit < wanted {
        tracing::warn!(
            wanted,
            fit,
            "the open-file limit allows fewer connections than --max-connections; serving at most {fit}"
        );
    }
    wanted.min(fit).max(1)
}

/// How long requests in flight may take to finish once the server is asked to stop.
pub const SHUTDOWN_GRACE: std::time::Duration = std::time::Duration::from_secs(20);

/// Serves `app` on `listener` until `stop` completes; then accepts no more connections, lets the
/// requests in flight finish (closing idle keep-alive connections) for up to [`SHUTDOWN_GRACE`],
/// and returns.
pub async fn run(
    listener: TcpListener,
    app: Router,
    limits: &Limits,
    stop: impl std::future::Future<Output = ()>,
) -> std::io::Result<()> {
    let graceful = hyper_util::server::graceful::GracefulShutdown::new();
    tokio::pin!(stop);
    let sockets = Arc::new(Semaphore::new(connection_cap(limits.max_connections)));
    let addresses = Slots::new("connections", usize::MAX, limits.max_connections_per_address);
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout)
        .max_buf_size(MAX_CONNECTION_BUFFER_BYTES)
        .keep_alive(true);
    loop {
        let next = async {
            let permit = sockets
                .clone()
                .acquire_owned()
                .await
                .expect("the semaphore is never closed");
            (permit, listener.accept().await)
        };
        let (permit, accepted) = tokio::select! {
            biased;
            () = &mut stop => break,
            next = next => next,
        };
        let (socket, peer) = match accepted {
            Ok(accepted) => accepted,
            Err(e) => {
                // Out of file descriptors and the like: wait instead of spinning.
                tracing::warn!(error = %e, "cannot accept a connection");
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                continue;
            }
        };
        let Ok(from) = addresses.try_take(&address_key(peer.ip())) else {
            tracing::debug!(peer = %peer.ip(), "too many connections from one address; closed");
            continue;
        };
        let _ = socket.set_nodelay(true);
        // The peer's address, for the limits counted per client (crate::pairing).
        let peer_ip = crate::pairing::Peer(peer.ip());
        let with_peer = tower::util::MapRequest::new(
            app.clone(),
            move |mut req: axum::http::Request<hyper::body::Incoming>| {
                req.extensions_mut().insert(peer_ip);
                req
            },
        );
        let service = hyper_util::service::TowerToHyperService::new(with_peer);
        let connection = graceful.watch(http.serve_connection(TokioIo::new(socket), service));
        tokio::spawn(async move {
            let _held = (permit, from);
            if let Err(e) = connection.await {
                tracing::debug!(error = %e, "connection closed");
            }
        });
    }
    drop(listener);
    tracing::info!("stopping: no new connections; finishing the requests in flight");
    if tokio::time::timeout(SHUTDOWN_GRACE, graceful.shutdown()).await.is_err() {
        tracing::warn!(
            grace_s = SHUTDOWN_GRACE.as_secs(),
            "requests still in flight after the grace period; closing them"
        );
    }
    Ok(())
}

/// Completes when the process is asked to stop: SIGTERM (a service manager, a container
/// runtime) or Ctrl-C.
pub async fn stop_signal() {
    let ctrl_c = async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {}
        () = term => {}
    }
}

/// The address a connection is counted under: IPv4 as itself (also when mapped into IPv6).
fn address_key(ip: IpAddr) -> String {
    ip.to_canonical().to_string()
}

/// The cap on requests being served ([`Limits::max_requests`]): past it, 503 with
/// `Retry-After` at once. `/healthz` is never refused, so a load balancer sees a busy server as
/// alive.
pub async fn serving(
    axum::extract::State(permits): axum::extract::State<Arc<Semaphore>>,
    req: Request,
    next: Next,
) -> Response {
    if req.uri().path() == "/healthz" {
        return next.run(req).await;
    }
    match permits.try_acquire() {
        Ok(_serving) => next.run(req).await,
        Err(_) => {
            tracing::warn!("refused: as many requests are being served as --max-requests allows");
            err(
                StatusCode::SERVICE_UNAVAILABLE,
                "the server is serving as many requests as it can; try again shortly",
            )
            .into_response()
        }
    }
}

/// Requests in flight per credential — the login cookie's or the API token's value, as sent —
/// counted before the login is looked up, with the account's cap
/// ([`Limits::max_requests_per_account`]; 429 past it, at once). A burst of one account's
/// requests is refused without a database lookup each and cannot fill the server's
/// [`Limits::max_requests`] for the others meanwhile. (The account's own count, over all its
/// credentials, is taken after the lookup: [`in_flight`].) The key is a hash of the credential,
/// never the credential.
pub async fn per_credential(
    axum::extract::State(slots): axum::extract::State<Arc<super::slots::Slots>>,
    req: Request,
    next: Next,
) -> Response {
    let Some(key) = credential_key(req.headers()) else {
        return next.run(req).await;
    };
    match slots.take(&key) {
        Ok(_in_flight) => next.run(req).await,
        Err(e) => e.into_response(),
    }
}

/// A hash of the request's credential (`Authorization` if sent, else the login cookie).
fn credential_key(headers: &axum::http::HeaderMap) -> Option<String> {
    use sha2::Digest;
    let credential = match headers.get(header::AUTHORIZATION) {
        Some(v) => v.as_bytes(),
        None => headers
            .get_all(header::COOKIE)
            .iter()
            .filter_map(|v| v.to_str().ok())
            .find_map(super::auth::token_from_cookie_header)?
            .as_bytes(),
    };
    Some(format!("{:x}", sha2::Sha256::digest(credential)))
}

/// Gives the request a place for its account's in-flight slot ([`InFlight`]), filled by the
/// extractor that authenticates it, and given back once the request is answered.
pub async fn in_flight(mut req: Request, next: Next) -> Response {
    let slot = InFlight::default();
    req.extensions_mut().insert(slot.clone());
    let r = next.run(req).await;
    drop(slot);
    r
}

/// The deadline of a request, body included: [`Limits::request_timeout`], plus, for a session
/// upload (`POST /api/sessions`, the dashboard's `POST /upload`), its declared size (or the
/// largest upload) at the slowest accepted rate; an atlas publication (`POST /api/atlases`) the
/// same for its size and [`Limits::atlas_check_timeout`] for its checks. Other bodies are small (at most
/// [`Limits::max_json_body_bytes`]) and get no allowance. A request past its deadline gets 408
/// and its connection is closed. (Uploads are also cut off as soon as they arrive more slowly than
/// the minimum rate over a window: [`crate::intake`].)
pub async fn deadline(
    axum::extract::State((limits, max_upload)): axum::extract::State<(Arc<Limits>, u64)>,
    req: Request,
    next: Next,
) -> Response {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let post = req.method() == Method::POST;
    let upload = post && matches!(req.uri().path(), "/api/sessions" | "/upload");
    let publication = post && req.uri().path() == "/api/atlases";
    let bytes = match (upload, publication, declared) {
        (true, _, Some(n)) => n.min(max_upload),
        (true, _, None) => max_upload,
        (_, true, Some(n)) => n.min(limits.max_atlas_bytes),
        (_, true, None) => limits.max_atlas_bytes,
        (false, false, _) => 0,
    };
    let checks = if publication {
        limits.atlas_check_timeout
    } else {
        Duration::ZERO
    };
    match tokio::time::timeout(limits.upload_timeout(bytes) + checks, next.run(req)).await {
        // A refused upload's body may not have been read: the connection cannot carry another
        // request, so it is closed.
        Ok(mut r) if (upload || publication) && !r.status().is_success() => {
            r.headers_mut()
                .insert(header::CONNECTION, HeaderValue::from_static("close"));
            r
        }
        Ok(r) => r,
        Err(_) => {
            let mut r = err(
                StatusCode::REQUEST_TIMEOUT,
                "the request took too long (body sent too slowly?)",
            )
            .into_response();
            r.headers_mut()
                .insert(header::CONNECTION, HeaderValue::from_static("close"));
            r
        }
    }
}

/// The security headers of every answer: no framing, no content sniffing, scripts and other
/// resources from this site only, no referrer to other sites.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'; \
     script-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'";

pub async fn security_headers(req: Request, next: Next) -> Response {
    let mut r = next.run(req).await;
    let h = r.headers_mut();
    // The LTI pages set their own policy (a platform may frame them; one posts its form to the
    // platform); every other response gets this one, and no frame at all.
    if !h.contains_key(header::CONTENT_SECURITY_POLICY) {
        h.insert(
            header::CONTENT_SECURITY_POLICY,
            HeaderValue::from_static(CONTENT_SECURITY_POLICY),
        );
        h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    }
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(header::REFERRER_POLICY, HeaderValue::from_static("same-origin"));
    r
}

/// Longest error text taken over from a framework rejection.
const MAX_ERROR_TEXT: usize = 4096;

/// API errors are JSON `{"error": ...}` (docs/api.md), including the ones the framework writes
/// itself as plain text: bad query strings, bodies over the limit, unknown routes and methods.
pub async fn json_errors(req: Request, next: Next) -> Response {
    let path = req.uri().path();
    let api = path.starts_with("/api/") || path == "/healthz";
    let r = next.run(req).await;
    let status = r.status();
    let is_json = r
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !api || is_json || !(status.is_client_error() || status.is_server_error()) {
        return r;
    }
    let (parts, body) = r.into_parts();
    let text = match axum::body::to_bytes(body, MAX_ERROR_TEXT).await {
        Ok(b) if !b.is_empty() => String::from_utf8_lossy(&b).trim().to_string(),
        _ => status.canonical_reason().unwrap_or("error").to_lowercase(),
    };
    let mut out = err(status, text).into_response();
    for (name, value) in &parts.headers {
        if name != header::CONTENT_TYPE && name != header::CONTENT_LENGTH {
            out.headers_mut().insert(name, value.clone());
        }
    }
    out
}

tokio::task_local! {
    /// The id of the request being served, for the work it causes (a session's scoring job
    /// keeps it, so that the job's log lines carry it too).
    static REQUEST_ID: String;
}

/// The id of the request this task serves, if it serves one.
pub fn current_request_id() -> Option<String> {
    REQUEST_ID.try_with(String::clone).ok()
}

/// Gives every request an id (the client's `X-Request-Id` if sensible, else a new UUID), logs it
/// with method, path, status and duration, records its duration by route
/// ([`super::telemetry::HTTP_REQUEST_DURATION`]), and returns it in `X-Request-Id`.
pub async fn request_log(req: Request, next: Next) -> Response {
    use tracing::Instrument;
    let id = req
        .headers()
        .get("x-request-id")
        .and_then(|v| v.to_str().ok())
        .filter(|v| !v.is_empty() && v.len() <= 64 && v.chars().all(|c| c.is_ascii_alphanumeric() || c == '-'))
        .map_or_else(super::store::new_id, str::to_string);
    let span = tracing::info_span!("request", id = %id, method = %req.method(), path = %req.uri().path());
    let method = req.method().clone();
    // The route's template (`/api/sessions/{id}`), not the path: a bounded label set.
    let route = req
        .extensions()
        .get::<axum::extract::MatchedPath>()
        .map_or_else(String::new, |p| p.as_str().to_string());
    let started = std::time::Instant::now();
    let mut resp = REQUEST_ID
        .scope(id.clone(), next.run(req))
        .instrument(span.clone())
        .await;
    let elapsed = started.elapsed();
    super::telemetry::record_request(&method, &route, resp.status().as_u16(), elapsed);
    span.in_scope(|| {
        tracing::info!(
            status = resp.status().as_u16(),
            ms = elapsed.as_secs_f64() * 1e3,
            "served"
        )
    });
    if let Ok(v) = id.parse() {
        resp.headers_mut().insert("x-request-id", v);
    }
    resp
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_credential_is_counted_by_its_hash_the_token_before_the_cookie() {
        let mut h = axum::http::HeaderMap::new();
        assert_eq!(credential_key(&h), None);
        h.insert(
            header::COOKIE,
            HeaderValue::from_static("theme=dark; stylet_session=abc"),
        );
        let cookie = credential_key(&h).unwrap();
        assert!(!cookie.contains("abc") && cookie.len() == 64, "{cookie}");
        h.insert(header::AUTHORIZATION, HeaderValue::from_static("Bearer tok"));
        let token = credential_key(&h).unwrap();
        assert_ne!(token, cookie);
        h.remove(header::AUTHORIZATION);
        h.insert(header::COOKIE, HeaderValue::from_static("stylet_session=abd"));
        assert_ne!(credential_key(&h).unwrap(), cookie);
    }
}
