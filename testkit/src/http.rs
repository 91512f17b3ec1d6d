//! HTTP calls of a test client to the service: logins, JSON and raw requests. Every answer to a
//! URL of the service is checked against its OpenAPI document ([`crate::contract`]).

use std::io::{Read, Write};

use serde_json::Value;

use crate::contract;

/// How a test client authenticates.
pub enum Auth {
    /// The login cookie and the login's CSRF token (sent with POSTs).
    Cookie {
        token: String,
        csrf: String,
    },
    Bearer(String),
}

/// (status, JSON body, Set-Cookie token) of a request; a body that is not JSON comes back as a
/// JSON string.
pub fn call(
    method: &str,
    url: &str,
    auth: Option<&Auth>,
    body: Option<&[u8]>,
    json: bool,
) -> (u16, Value, Option<String>) {
    let mut req = ureq::request(method, url);
    match auth {
        Some(Auth::Cookie { token, csrf }) => {
            req = req.set("Cookie", &format!("stylet_session={token}"));
            if method != "GET" {
                req = req.set("X-CSRF-Token", csrf);
            }
        }
        Some(Auth::Bearer(t)) => req = req.set("Authorization", &format!("Bearer {t}")),
        None => {}
    }
    let res = match body {
        Some(b) => req
            .set(
                "Content-Type",
                if json {
                    "application/json"
                } else {
                    "application/octet-stream"
                },
            )
            .send_bytes(b),
        None => req.call(),
    };
    let resp = match res {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("{method} {url}: {e}"),
    };
    let status = resp.status();
    let token = resp
        .header("Set-Cookie")
        .and_then(|c| c.strip_prefix("stylet_session="))
        .and_then(|c| c.split(';').next())
        .map(str::to_string);
    let content_type = resp.header("Content-Type").map(str::to_string);
    let text = resp.into_string().unwrap();
    if let Some(base) = base_of(url) {
        contract::check(base, method, url, status, content_type.as_deref(), &text);
    }
    (
        status,
        serde_json::from_str(&text).unwrap_or(Value::String(text)),
        token,
    )
}

/// `http://host:port` of a URL.
fn base_of(url: &str) -> Option<&str> {
    let after = url.strip_prefix("http://")?;
    let end = after.find('/').map_or(url.len(), |i| i + "http://".len());
    Some(&url[..end])
}

/// Logs `user` in with the password `<user>-password` (as [`crate::Stylet::add_user`] sets it).
/// Like any client, it tries again after a second when the server answers that too many logins
/// are being checked at once (503: a class logging in together can fill the password queue).
pub fn login(base: &str, user: &str) -> Auth {
    let body = format!(r#"{{"username":"{user}","password":"{user}-password"}}"#);
    let mut tries = 0;
    let (status, json, token) = loop {
        let answer = call("POST", &format!("{base}/api/login"), None, Some(body.as_bytes()), true);
        tries += 1;
        if answer.0 != 503 || tries == 30 {
            break answer;
        }
        std::thread::sleep(std::time::Duration::from_secs(1));
    };
    assert_eq!(status, 200, "{json}");
    Auth::Cookie {
        token: token.unwrap(),
        csrf: json["csrf_token"].as_str().unwrap().to_string(),
    }
}

/// A dashboard page as a browser with the login cookie gets it, redirects not followed.
pub struct Page {
    pub status: u16,
    pub cache_control: String,
    pub location: String,
    pub body: String,
}

/// GETs a dashboard page, or POSTs `form` to it, with `who`'s login cookie.
pub fn page(base: &str, path: &str, who: &Auth, form: Option<&[(&str, &str)]>) -> Page {
    let Auth::Cookie { token, .. } = who else {
        panic!("a login cookie")
    };
    let agent = ureq::AgentBuilder::new().redirects(0).build();
    let url = format!("{base}{path}");
    let req = match form {
        Some(_) => agent.post(&url),
        None => agent.get(&url),
    }
    .set("Cookie", &format!("stylet_session={token}"));
    let res = match form {
        Some(fields) => req.send_form(fields),
        None => req.call(),
    };
    let resp = match res {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("{path}: {e}"),
    };
    let header = |h: &str| resp.header(h).unwrap_or_default().to_string();
    let (status, cache_control, location) = (resp.status(), header("Cache-Control"), header("Location"));
    Page {
        status,
        cache_control,
        location,
        body: resp.into_string().unwrap(),
    }
}

/// A GET with a login cookie: status and body bytes (images, PDFs, CSV).
pub fn get_bytes(url: &str, auth: &Auth) -> (u16, Vec<u8>) {
    let Auth::Cookie { token, .. } = auth else {
        panic!("a login cookie")
    };
    let resp = match ureq::get(url).set("Cookie", &format!("stylet_session={token}")).call() {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("GET {url}: {e}"),
    };
    let status = resp.status();
    let mut body = Vec::new();
    resp.into_reader().read_to_end(&mut body).unwrap();
    (status, body)
}

/// A POST over a raw socket that ignores write errors (the server may answer and close before
/// the whole body is sent); returns status and JSON body.
pub fn raw_post(base: &str, path: &str, auth: Option<&Auth>, body: &[u8]) -> (u16, Value) {
    raw_post_as(base, path, auth, "application/octet-stream", body)
}

/// [`raw_post`] with another `Content-Type`.
pub fn raw_post_as(base: &str, path: &str, auth: Option<&Auth>, content_type: &str, body: &[u8]) -> (u16, Value) {
    let addr = base.strip_prefix("http://").unwrap();
    let mut sock = std::net::TcpStream::connect(addr).unwrap();
    let credentials = match auth {
        Some(Auth::Cookie { token, csrf }) => format!("Cookie: stylet_session={token}\r\nX-CSRF-Token: {csrf}\r\n"),
        Some(Auth::Bearer(t)) => format!("Authorization: Bearer {t}\r\n"),
        None => String::new(),
    };
    let head = format!(
        "POST {path} HTTP/1.1\r\nHost: {addr}\r\n{credentials}\
         Content-Type: {content_type}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    sock.write_all(head.as_bytes()).unwrap();
    let _ = sock.write_all(body);
    let mut resp = Vec::new();
    let _ = sock.read_to_end(&mut resp);
    let text = String::from_utf8_lossy(&resp).to_string();
    let status = text.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    if status != 0 {
        let content_type = head
            .lines()
            .find_map(|l| {
                l.split_once(':')
                    .filter(|(k, _)| k.eq_ignore_ascii_case("content-type"))
            })
            .map(|(_, v)| v.trim().to_string());
        contract::check(
            base,
            "POST",
            &format!("{base}{path}"),
            status,
            content_type.as_deref(),
            body,
        );
    }
    let json = serde_json::from_str(body).unwrap_or(Value::String(text.clone()));
    (status, json)
}
