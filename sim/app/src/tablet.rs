//! The tablet page (thesis §6.2.2): a small web page the simulator serves on the local network,
//! with large buttons for tools, modes and events, for a tablet beside the workbench so the hand
//! on the device never has to let go.
//!
//! Off by default. When started it shows a six-digit pairing code in the window; a browser that
//! enters it gets a cookie (HttpOnly, SameSite=Strict, 12 h) and the buttons, and the code
//! changes (each code pairs one tablet; at most [`MAX_TABLETS`]). Five wrong codes lock pairing for
//! a minute and change the code. Requests must name this machine by address (or `localhost`) in
//! `Host`, and must not come from another site (`Origin`, `Sec-Fetch-Site`): a web page elsewhere
//! cannot drive the page through DNS rebinding or a cross-site form. Buttons post a [`Command`]
//! to the simulator, which the live device resolves into events in the loop exactly as for the
//! numeric keypad, so the session records them like any other event. No script, no external
//! asset; bodies are limited to 1 KiB.

use std::net::SocketAddr;
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::{DefaultBodyLimit, Form, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{Html, IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use stylet_physics::needle::spec::Gauge;
use stylet_physics::{ProbeKind, ToolSpec};

use stylet_devices::command::Command;

/// Wrong pairing codes allowed before pairing locks.
pub const MAX_WRONG_CODES: u32 = 5;
/// How long pairing stays locked after too many wrong codes.
pub const LOCKOUT: Duration = Duration::from_secs(60);
/// Most tablets paired at once.
pub const MAX_TABLETS: usize = 8;
/// Time a stopping page waits for open connections.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(2);
const COOKIE: &str = "stylet_tablet";

/// The buttons, in page order: form value, label, command.
pub const BUTTONS: [(&str, &str, Command); 12] = [
    ("finger", "Finger", Command::Tool(ToolSpec::Finger)),
    (
        "linear",
        "Linear probe",
        Command::Tool(ToolSpec::Probe(ProbeKind::Linear)),
    ),
    (
        "convex",
        "Convex probe",
        Command::Tool(ToolSpec::Probe(ProbeKind::Convex)),
    ),
    (
        "needle",
        "Needle 18 G",
        Command::Tool(ToolSpec::Needle {
            gauge: Gauge::G18,
            length_mm: 150.0,
            stylet_in: true,
        }),
    ),
    ("stylet", "Stylet out / in", Command::ToggleStylet),
    ("contrast", "Contrast 1 ml", Command::Contrast { ml: 1.0 }),
    // The window gives the wire the needle in hand takes.
    (
        "next",
        "Drainage: next step",
        Command::NextStep {
            wire: stylet_physics::wire::WireDiameter::In035,
        },
    ),
    ("fluoro", "Fluoroscopy on / off", Command::ToggleFluoroscopy),
    ("shot", "X-ray shot", Command::XrayShot),
    ("breath", "Breath hold / release", Command::ToggleBreathHold),
    ("layout", "Next layout", Command::NextLayout),
    ("finish", "Finish", Command::Finish),
];

/// Errors starting the page.
#[derive(Debug, thiserror::Error)]
pub enum TabletError {
    #[error("cannot listen on {addr}: {source}")]
    Bind { addr: SocketAddr, source: std::io::Error },
    #[error("cannot start the tablet page's thread: {0}")]
    Thread(std::io::Error),
    #[error("no random numbers from the system: {0}")]
    Random(String),
}

struct Pairing {
    code: String,
    /// Cookies of paired browsers.
    paired: Vec<String>,
    wrong: u32,
    locked_until: Option<Instant>,
}

#[derive(Clone)]
struct AppState {
    pairing: Arc<Mutex<Pairing>>,
    commands: Sender<Command>,
}

/// A running tablet page.
pub struct TabletPage {
    pub addr: SocketAddr,
    pairing: Arc<Mutex<Pairing>>,
    stop: Option<tokio::sync::watch::Sender<bool>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

fn random_hex(bytes: usize) -> Result<String, TabletError> {
    let mut b = vec![0u8; bytes];
    getrandom::fill(&mut b).map_err(|e| TabletError::Random(e.to_string()))?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

fn pairing_code() -> Result<String, TabletError> {
    let mut b = [0u8; 4];
    getrandom::fill(&mut b).map_err(|e| TabletError::Random(e.to_string()))?;
    Ok(format!("{:06}", u32::from_le_bytes(b) % 1_000_000))
}

/// Equal strings compared in time independent of where they differ.
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

impl TabletPage {
    /// Serves the page on `addr` (e.g. `0.0.0.0:8765` for the local network); button presses
    /// arrive on `commands`.
    pub fn start(addr: SocketAddr, commands: Sender<Command>) -> Result<TabletPage, TabletError> {
        let code = pairing_code()?;
        let state = AppState {
            pairing: Arc::new(Mutex::new(Pairing {
                code: code.clone(),
                paired: Vec::new(),
                wrong: 0,
                locked_until: None,
            })),
            commands,
        };
        let listener = std::net::TcpListener::bind(addr).map_err(|source| TabletError::Bind { addr, source })?;
        let local = listener
            .local_addr()
            .map_err(|source| TabletError::Bind { addr, source })?;
        listener
            .set_nonblocking(true)
            .map_err(|source| TabletError::Bind { addr, source })?;
        let (stop, stopped) = tokio::sync::watch::channel(false);
        let pairing = Arc::clone(&state.pairing);
        let app = Router::new()
            .route("/", get(page))
            .route("/pair", post(pair))
            .route("/command", post(command))
            .layer(axum::middleware::from_fn(same_site_only))
            .layer(DefaultBodyLimit::max(1024))
            .with_state(state);
        let thread = std::thread::Builder::new()
            .name("stylet-tablet".into())
            .spawn(move || {
                let Ok(rt) = tokio::runtime::Builder::new_current_thread().enable_all().build() else {
                    return;
                };
                rt.block_on(async move {
                    let Ok(listener) = tokio::net::TcpListener::from_std(listener) else {
                        return;
                    };
                    let mut graceful = stopped.clone();
                    let mut deadline = stopped;
                    let serve = axum::serve(listener, app).with_graceful_shutdown(async move {
                        let _ = graceful.changed().await;
                    });
                    // Open connections get a short grace, then the page stops regardless.
                    tokio::select! {
                        _ = serve => {}
                        _ = async move {
                            let _ = deadline.changed().await;
                            tokio::time::sleep(SHUTDOWN_GRACE).await;
                        } => {}
                    }
                });
            })
            .map_err(TabletError::Thread)?;
        let _ = code;
        Ok(TabletPage {
            addr: local,
            pairing,
            stop: Some(stop),
            thread: Some(thread),
        })
    }

    /// The pairing code to show in the window now (it changes after each pairing and lockout).
    pub fn code(&self) -> String {
        self.pairing.lock().map(|p| p.code.clone()).unwrap_or_default()
    }
}

/// Whether a `Host` header names this machine by address (or `localhost`), with any port.
fn host_is_address(host: &str) -> bool {
    let name = if let Some(v6) = host.strip_prefix('[') {
        v6.split(']').next().unwrap_or("")
    } else {
        host.rsplit_once(':').map_or(host, |(h, _)| h)
    };
    name == "localhost" || name.parse::<std::net::IpAddr>().is_ok()
}

/// Refuses requests that name this page by a domain (DNS rebinding) or come from another site.
async fn same_site_only(request: axum::extract::Request, next: axum::middleware::Next) -> Response {
    let headers = request.headers();
    let host = headers.get(header::HOST).and_then(|v| v.to_str().ok()).unwrap_or("");
    let cross_site = headers
        .get("sec-fetch-site")
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v == "cross-site");
    let foreign_origin = headers
        .get(header::ORIGIN)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|o| o.split_once("://").map(|(_, h)| h) != Some(host));
    if !host_is_address(host) || cross_site || foreign_origin {
        return html(
            StatusCode::FORBIDDEN,
            shell("<p>Open this page by the simulator's address.</p>"),
        );
    }
    next.run(request).await
}

impl Drop for TabletPage {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(true);
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn paired(state: &AppState, headers: &HeaderMap) -> bool {
    let Some(cookies) = headers.get(header::COOKIE).and_then(|v| v.to_str().ok()) else {
        return false;
    };
    let Ok(p) = state.pairing.lock() else { return false };
    cookies
        .split(';')
        .filter_map(|c| c.trim().strip_prefix(&format!("{COOKIE}=")).map(str::to_string))
        .any(|v| p.paired.iter().any(|k| same(k, &v)))
}

fn html(status: StatusCode, body: String) -> Response {
    let mut r = (status, Html(body)).into_response();
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'none'; style-src 'unsafe-inline'; form-action 'self'; frame-ancestors 'none'",
        ),
    );
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

const STYLE: &str = "body{font-family:sans-serif;margin:1em;background:#111;color:#eee}\
button{font-size:1.4em;width:100%;padding:.9em;margin:.25em 0;border-radius:.4em;border:0;background:#2d5d8a;color:#fff}\
input{font-size:2em;width:8em;letter-spacing:.2em}.grid{display:grid;grid-template-columns:1fr 1fr;gap:0 .5em}\
h2{font-size:1em;color:#9ab;margin:.8em 0 .2em}button.end{background:#8a2d2d}";

fn shell(content: &str) -> String {
    format!(
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width\">\
         <title>Stylet tablet</title><style>{STYLE}</style></head><body><h1>Stylet</h1>{content}</body></html>"
    )
}

async fn page(State(state): State<AppState>, headers: HeaderMap) -> Response {
    if !paired(&state, &headers) {
        return html(
            StatusCode::OK,
            shell(
                "<p>Enter the pairing code shown in the simulator's window.</p>\
                 <form method=\"post\" action=\"/pair\"><input name=\"code\" inputmode=\"numeric\" autocomplete=\"off\" maxlength=\"6\">\
                 <button>Pair</button></form>",
            ),
        );
    }
    // Groups of buttons: (heading, first index, end index) into BUTTONS.
    let groups = [
        ("Tool", 0, 4),
        ("Needle", 4, 6),
        ("Drainage", 6, 7),
        ("Imaging and patient", 7, 10),
        ("Session", 10, 12),
    ];
    let mut body = String::new();
    for (heading, from, to) in groups {
        body.push_str(&format!("<h2>{heading}</h2><div class=\"grid\">"));
        for (name, label, _) in &BUTTONS[from..to] {
            let class = if *name == "finish" { " class=\"end\"" } else { "" };
            body.push_str(&format!(
                "<form method=\"post\" action=\"/command\"><button{class} name=\"cmd\" value=\"{name}\">{label}</button></form>"
            ));
        }
        body.push_str("</div>");
    }
    html(StatusCode::OK, shell(&body))
}

#[derive(serde::Deserialize)]
struct PairForm {
    code: String,
}

async fn pair(State(state): State<AppState>, Form(form): Form<PairForm>) -> Response {
    let cookie = {
        let Ok(mut p) = state.pairing.lock() else {
            return html(StatusCode::INTERNAL_SERVER_ERROR, shell("<p>Pairing failed.</p>"));
        };
        if p.locked_until.is_some_and(|t| Instant::now() < t) {
            return html(
                StatusCode::TOO_MANY_REQUESTS,
                shell("<p>Too many wrong codes: try again in a minute.</p>"),
            );
        }
        if !same(form.code.trim(), &p.code) {
            p.wrong += 1;
            if p.wrong >= MAX_WRONG_CODES {
                p.wrong = 0;
                p.locked_until = Some(Instant::now() + LOCKOUT);
                if let Ok(c) = pairing_code() {
                    p.code = c;
                }
            }
            return html(
                StatusCode::FORBIDDEN,
                shell("<p>Wrong code.</p><p><a href=\"/\">Try again</a></p>"),
            );
        }
        if p.paired.len() >= MAX_TABLETS {
            return html(
                StatusCode::CONFLICT,
                shell("<p>Enough tablets are paired with this simulator.</p>"),
            );
        }
        let (Ok(cookie), Ok(next_code)) = (random_hex(16), pairing_code()) else {
            return html(StatusCode::INTERNAL_SERVER_ERROR, shell("<p>Pairing failed.</p>"));
        };
        p.wrong = 0;
        p.paired.push(cookie.clone());
        // Each code pairs one tablet.
        p.code = next_code;
        cookie
    };
    let mut r = Redirect::to("/").into_response();
    if let Ok(v) = HeaderValue::from_str(&format!(
        "{COOKIE}={cookie}; HttpOnly; SameSite=Strict; Path=/; Max-Age=43200"
    )) {
        r.headers_mut().insert(header::SET_COOKIE, v);
    }
    r
}

#[derive(serde::Deserialize)]
struct CommandForm {
    cmd: String,
}

async fn command(State(state): State<AppState>, headers: HeaderMap, Form(form): Form<CommandForm>) -> Response {
    if !paired(&state, &headers) {
        return html(
            StatusCode::FORBIDDEN,
            shell("<p>Not paired. <a href=\"/\">Pair</a></p>"),
        );
    }
    let Some((_, _, cmd)) = BUTTONS.iter().find(|(name, _, _)| *name == form.cmd) else {
        return html(StatusCode::BAD_REQUEST, shell("<p>Unknown button.</p>"));
    };
    if state.commands.send(*cmd).is_err() {
        return html(StatusCode::SERVICE_UNAVAILABLE, shell("<p>The session has ended.</p>"));
    }
    Redirect::to("/").into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn agent() -> ureq::Agent {
        ureq::AgentBuilder::new().redirects(0).build()
    }

    /// (status, body, Set-Cookie) of a form POST.
    fn post(base: &str, path: &str, body: &str, cookie: Option<&str>) -> (u16, String, Option<String>) {
        let mut req = agent()
            .post(&format!("{base}{path}"))
            .set("Content-Type", "application/x-www-form-urlencoded");
        if let Some(c) = cookie {
            req = req.set("Cookie", c);
        }
        let resp = match req.send_string(body) {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => r,
            Err(e) => panic!("{e}"),
        };
        let set = resp
            .header("set-cookie")
            .map(|c| c.split(';').next().unwrap().to_string());
        (resp.status(), resp.into_string().unwrap(), set)
    }

    fn get(base: &str, cookie: Option<&str>) -> String {
        let mut req = agent().get(&format!("{base}/"));
        if let Some(c) = cookie {
            req = req.set("Cookie", c);
        }
        req.call().unwrap().into_string().unwrap()
    }

    #[test]
    fn a_paired_tablet_sends_commands_and_strangers_cannot() {
        let (tx, rx) = std::sync::mpsc::channel();
        let page = TabletPage::start("127.0.0.1:0".parse().unwrap(), tx).unwrap();
        let base = format!("http://{}", page.addr);
        let code = page.code();
        assert_eq!(code.len(), 6);
        // Unpaired: the pairing form, and commands are refused.
        assert!(get(&base, None).contains("pairing code"));
        assert_eq!(post(&base, "/command", "cmd=stylet", None).0, 403);
        assert_eq!(post(&base, "/command", "cmd=stylet", Some("stylet_tablet=00")).0, 403);
        // Pairing with the code shown in the window.
        let (status, _, cookie) = post(&base, "/pair", &format!("code={code}"), None);
        assert_eq!(status, 303);
        let cookie = cookie.expect("a pairing cookie");
        // The code pairs one tablet only.
        assert_eq!(post(&base, "/pair", &format!("code={code}"), None).0, 403);
        assert_ne!(page.code(), code);
        let buttons = get(&base, Some(&cookie));
        assert!(
            buttons.contains("Stylet out / in") && buttons.contains("Finish"),
            "{buttons}"
        );
        assert_eq!(post(&base, "/command", "cmd=stylet", Some(&cookie)).0, 303);
        assert_eq!(post(&base, "/command", "cmd=contrast", Some(&cookie)).0, 303);
        assert_eq!(rx.try_recv().unwrap(), Command::ToggleStylet);
        assert_eq!(rx.try_recv().unwrap(), Command::Contrast { ml: 1.0 });
        assert!(buttons.contains("Drainage: next step"), "{buttons}");
        assert_eq!(post(&base, "/command", "cmd=next", Some(&cookie)).0, 303);
        assert!(matches!(rx.try_recv().unwrap(), Command::NextStep { .. }));
        assert_eq!(post(&base, "/command", "cmd=selfdestruct", Some(&cookie)).0, 400);
        assert!(rx.try_recv().is_err(), "nothing sent for an unknown button");
        // Bodies over 1 KiB are refused.
        let big = format!("cmd={}", "x".repeat(2000));
        assert_eq!(post(&base, "/command", &big, Some(&cookie)).0, 413);
        // Guessing: five wrong codes lock pairing, even for the right code; paired tablets go on.
        // (One wrong code was spent above.)
        let wrong = if page.code() == "000000" { "111111" } else { "000000" };
        for _ in 1..MAX_WRONG_CODES {
            assert_eq!(post(&base, "/pair", &format!("code={wrong}"), None).0, 403);
        }
        assert_eq!(post(&base, "/pair", &format!("code={}", page.code()), None).0, 429);
        assert_eq!(post(&base, "/command", "cmd=finish", Some(&cookie)).0, 303);
        assert_eq!(rx.try_recv().unwrap(), Command::Finish);
        // Named by a domain (DNS rebinding) or posted from another site: refused.
        let raw = |head: &str| {
            use std::io::{Read, Write};
            let mut sock = std::net::TcpStream::connect(page.addr).unwrap();
            let body = "cmd=stylet";
            write!(
                sock,
                "POST /command HTTP/1.1\r\n{head}\r\nCookie: {cookie}\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
                body.len()
            )
            .unwrap();
            let mut out = String::new();
            let _ = sock.read_to_string(&mut out);
            out.split_whitespace().nth(1).unwrap_or("").to_string()
        };
        assert_eq!(raw("Host: evil.example.org"), "403");
        let here = format!("Host: {}", page.addr);
        assert_eq!(raw(&format!("{here}\r\nOrigin: http://evil.example.org")), "403");
        assert_eq!(raw(&format!("{here}\r\nSec-Fetch-Site: cross-site")), "403");
        assert_eq!(raw(&format!("{here}\r\nOrigin: http://{}", page.addr)), "303");
        assert_eq!(rx.try_recv().unwrap(), Command::ToggleStylet);
        assert!(rx.try_recv().is_err());
        drop(page);
    }

    #[test]
    fn hosts_must_be_addresses() {
        assert!(host_is_address("192.168.1.20:8765"));
        assert!(host_is_address("[fe80::1]:8765"));
        assert!(host_is_address("localhost:8765"));
        assert!(!host_is_address("evil.example.org"));
        assert!(!host_is_address("192.168.1.20.nip.io:8765"));
        assert!(!host_is_address(""));
    }
}
