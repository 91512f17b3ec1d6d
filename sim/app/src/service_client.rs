//! The simulator's side of the scoring service's HTTP API (docs/api.md): logging in once to get
//! an upload-only API token, and uploading session files with it.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::Value;

use crate::upload::{MAX_SESSION_BYTES, Uploader};

/// What the service said to an upload, also under this module's name.
pub use crate::upload::UploadReply;

/// Longest reply body read from the service (its JSON answers are small).
const MAX_REPLY_BYTES: u64 = 1 << 20;

/// Errors of fetching a session file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FetchError {
    #[error("'{0}' is not a session id (letters, digits and '-')")]
    BadId(String),
    #[error("the service has no session {0} that this login may see")]
    NotFound(String),
    #[error("the service refused ({status}): {reason}")]
    Refused { status: u16, reason: String },
    #[error("the service cannot be reached: {0}")]
    Unavailable(String),
    #[error("the file is larger than {0} bytes")]
    TooLarge(u64),
    #[error("cannot keep the file: {0}")]
    Write(String),
}

/// What pairing by a code gave this simulator.
#[derive(Clone, PartialEq, Eq)]
pub enum Pairing {
    /// An upload token of `username`: log in with it.
    Account { username: String, token: String },
    /// This computer is a lab machine of `cohort`; `lab_token` signs its trainees in.
    Lab { cohort: String, lab_token: String },
}

impl std::fmt::Debug for Pairing {
    /// Never prints a token.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Pairing::Account { username, .. } => write!(f, "Account({username})"),
            Pairing::Lab { cohort, .. } => write!(f, "Lab({cohort})"),
        }
    }
}

/// Errors of logging in.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LoginError {
    #[error("{0}")]
    Address(#[from] AddressError),
    #[error("the server at {url} cannot be reached: {reason}")]
    Unreachable { url: String, reason: String },
    #[error("the server refused: {status} {reason}")]
    Refused { status: u16, reason: String },
    #[error("the server's answer was not understood: {0}")]
    Protocol(String),
}

/// A server address the simulator will not use.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AddressError {
    #[error("'{0}' is not a server address such as https://stylet.example.org")]
    NotUrl(String),
    #[error(
        "'{0}': use https (a password and tokens must not cross the network in clear); plain http is accepted for this computer only (localhost, 127.0.0.1, [::1])"
    )]
    Cleartext(String),
}

/// Checks a server address: `https://HOST[:PORT]`, or `http://` to this computer only.
pub fn check_address(base: &str) -> Result<String, AddressError> {
    let base = base.trim().trim_end_matches('/');
    let (scheme, rest) = base
        .split_once("://")
        .ok_or_else(|| AddressError::NotUrl(base.to_string()))?;
    let host_port = rest.split('/').next().unwrap_or("");
    if host_port.is_empty() || rest.contains(['?', '#', '@', ' ']) {
        return Err(AddressError::NotUrl(base.to_string()));
    }
    let host = if let Some(v6) = host_port.strip_prefix('[') {
        v6.split(']').next().unwrap_or("")
    } else {
        host_port.rsplit_once(':').map_or(host_port, |(h, _)| h)
    };
    match scheme.to_ascii_lowercase().as_str() {
        "https" => Ok(base.to_string()),
        "http" if matches!(host, "localhost" | "127.0.0.1" | "::1") => Ok(base.to_string()),
        "http" => Err(AddressError::Cleartext(base.to_string())),
        _ => Err(AddressError::NotUrl(base.to_string())),
    }
}

/// A client of one scoring service.
#[derive(Clone)]
pub struct ServiceClient {
    base: String,
    agent: ureq::Agent,
}

fn reason_of(resp: ureq::Response) -> String {
    let status = resp.status();
    let body = read_body(resp).unwrap_or_default();
    serde_json::from_str::<Value>(&body)
        .ok()
        .and_then(|v| v["error"].as_str().map(str::to_string))
        .unwrap_or_else(|| format!("HTTP {status}"))
}

fn read_body(resp: ureq::Response) -> std::io::Result<String> {
    use std::io::Read;
    let mut s = String::new();
    resp.into_reader().take(MAX_REPLY_BYTES).read_to_string(&mut s)?;
    Ok(s)
}

impl ServiceClient {
    /// A client of the service at `base` (e.g. `https://stylet.example.org`; see
    /// [`check_address`]), with time limits so that a dead server never hangs the caller: 5 s to
    /// connect, 60 s for any one read or write (a large upload on a slow line may take longer in
    /// all, as long as it moves).
    pub fn new(base: &str) -> Result<ServiceClient, AddressError> {
        let base = check_address(base)?;
        let agent = ureq::AgentBuilder::new()
            .timeout_connect(Duration::from_secs(5))
            .timeout_read(Duration::from_secs(60))
            .timeout_write(Duration::from_secs(60))
            .build();
        Ok(ServiceClient { base, agent })
    }

    pub fn base(&self) -> &str {
        &self.base
    }

    /// Fetches the file of session `id` (one the token's account may see) and writes it to
    /// `dir/fetched-ID.mcap` completely or not at all; refuses ids that are not the service's
    /// (letters, digits, `-`) and files over the upload limit.
    pub fn fetch_session(&self, token: &str, id: &str, dir: &Path) -> Result<PathBuf, FetchError> {
        use std::io::Read;
        if id.is_empty() || id.len() > 64 || !id.chars().all(|c| c.is_ascii_alphanumeric() || c == '-') {
            return Err(FetchError::BadId(id.to_string()));
        }
        let resp = match self
            .agent
            .get(&format!("{}/api/sessions/{id}/file", self.base))
            .set("Authorization", &format!("Bearer {token}"))
            .call()
        {
            Ok(r) => r,
            Err(ureq::Error::Status(404, _)) => return Err(FetchError::NotFound(id.to_string())),
            Err(ureq::Error::Status(status, r)) => {
                return Err(FetchError::Refused {
                    status,
                    reason: reason_of(r),
                });
            }
            Err(ureq::Error::Transport(t)) => return Err(FetchError::Unavailable(t.to_string())),
        };
        let limit = MAX_SESSION_BYTES;
        let mut bytes = Vec::new();
        resp.into_reader()
            .take(limit + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| FetchError::Unavailable(e.to_string()))?;
        if bytes.len() as u64 > limit {
            return Err(FetchError::TooLarge(limit));
        }
        let io = |e: std::io::Error| FetchError::Write(e.to_string());
        std::fs::create_dir_all(dir).map_err(io)?;
        let path = dir.join(format!("fetched-{id}.mcap"));
        let part = dir.join(format!(".fetching-{id}.mcap"));
        std::fs::write(&part, &bytes).map_err(io)?;
        std::fs::rename(&part, &path).map_err(io)?;
        Ok(path)
    }

    /// Logs in with a username and password, makes an upload-only API token labelled `label`,
    /// logs out again and returns the token (the password is not kept).
    pub fn upload_token(&self, username: &str, password: &str, label: &str) -> Result<String, LoginError> {
        let url = format!("{}/api/login", self.base);
        let unreachable = |e: ureq::Transport| LoginError::Unreachable {
            url: self.base.clone(),
            reason: e.to_string(),
        };
        let refused = |resp: ureq::Response| LoginError::Refused {
            status: resp.status(),
            reason: reason_of(resp),
        };
        let resp = match self
            .agent
            .post(&url)
            .send_json(serde_json::json!({ "username": username, "password": password }))
        {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => return Err(refused(r)),
            Err(ureq::Error::Transport(t)) => return Err(unreachable(t)),
        };
        let cookie = resp
            .all("set-cookie")
            .into_iter()
            .find_map(|c| c.split(';').next().filter(|kv| kv.starts_with("stylet_session=")))
            .map(str::to_string)
            .ok_or_else(|| LoginError::Protocol("the login set no session cookie".into()))?;
        let body: Value = serde_json::from_str(&read_body(resp).map_err(|e| LoginError::Protocol(e.to_string()))?)
            .map_err(|e| LoginError::Protocol(e.to_string()))?;
        let csrf = body["csrf_token"]
            .as_str()
            .ok_or_else(|| LoginError::Protocol("the login returned no csrf_token".into()))?
            .to_string();
        let made = self
            .agent
            .post(&format!("{}/api/tokens", self.base))
            .set("Cookie", &cookie)
            .set("X-CSRF-Token", &csrf)
            .send_json(serde_json::json!({ "label": label, "scope": "upload" }));
        let token = match made {
            Ok(r) => {
                let v: Value = serde_json::from_str(&read_body(r).map_err(|e| LoginError::Protocol(e.to_string()))?)
                    .map_err(|e| LoginError::Protocol(e.to_string()))?;
                v["token"]
                    .as_str()
                    .ok_or_else(|| LoginError::Protocol("no token in the answer".into()))?
                    .to_string()
            }
            Err(ureq::Error::Status(_, r)) => return Err(refused(r)),
            Err(ureq::Error::Transport(t)) => return Err(unreachable(t)),
        };
        // The login is not needed any more; the token stays valid (docs/api.md "API tokens").
        let _ = self
            .agent
            .post(&format!("{}/api/logout", self.base))
            .set("Cookie", &cookie)
            .set("X-CSRF-Token", &csrf)
            .call();
        Ok(token)
    }

    /// Pairs this simulator with the service by a code shown on the dashboard
    /// (`POST /api/pair`): an upload token of the code's account, or — for a lab code — this
    /// computer becomes a lab machine of a cohort.
    pub fn pair(&self, code: &str, label: &str) -> Result<Pairing, LoginError> {
        let v = self.post_json("/api/pair", None, &serde_json::json!({ "code": code, "label": label }))?;
        let field = |name: &str| {
            v[name]
                .as_str()
                .map(str::to_string)
                .ok_or_else(|| LoginError::Protocol(format!("no {name} in the answer")))
        };
        match v["kind"].as_str() {
            Some("simulator") => Ok(Pairing::Account {
                username: field("username")?,
                token: field("token")?,
            }),
            Some("lab") => Ok(Pairing::Lab {
                cohort: field("cohort")?,
                lab_token: field("lab_token")?,
            }),
            other => Err(LoginError::Protocol(format!("an unknown pairing kind {other:?}"))),
        }
    }

    /// Signs a trainee in at this lab machine with their sign-in code (`POST /api/lab/sign-in`):
    /// their username and an upload token for the lab day.
    pub fn lab_sign_in(&self, lab_token: &str, code: &str) -> Result<(String, String), LoginError> {
        let v = self.post_json(
            "/api/lab/sign-in",
            Some(lab_token),
            &serde_json::json!({ "code": code }),
        )?;
        match (v["username"].as_str(), v["token"].as_str()) {
            (Some(u), Some(t)) => Ok((u.to_string(), t.to_string())),
            _ => Err(LoginError::Protocol("no username and token in the answer".into())),
        }
    }

    /// Revokes `token` itself (`POST /api/tokens/current/revoke`): a trainee signing out of a
    /// lab machine.
    pub fn sign_out(&self, token: &str) -> Result<(), LoginError> {
        self.post_json("/api/tokens/current/revoke", Some(token), &serde_json::json!({}))
            .map(|_| ())
    }

    /// POSTs `body` to `path` (with `Authorization: Bearer token` when given): the JSON answer,
    /// or why not.
    fn post_json(&self, path: &str, token: Option<&str>, body: &Value) -> Result<Value, LoginError> {
        let mut req = self.agent.post(&format!("{}{path}", self.base));
        if let Some(t) = token {
            req = req.set("Authorization", &format!("Bearer {t}"));
        }
        let resp = match req.send_json(body) {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => {
                return Err(LoginError::Refused {
                    status: r.status(),
                    reason: reason_of(r),
                });
            }
            Err(ureq::Error::Transport(t)) => {
                return Err(LoginError::Unreachable {
                    url: self.base.clone(),
                    reason: t.to_string(),
                });
            }
        };
        serde_json::from_str(&read_body(resp).map_err(|e| LoginError::Protocol(e.to_string()))?)
            .map_err(|e| LoginError::Protocol(e.to_string()))
    }

    /// Uploads one session file with an API token.
    ///
    /// The service checks the token before it reads a byte of the body, and a refusal closes the
    /// connection while the file is still being sent: the client then sees a broken pipe or a
    /// reset instead of the 401/403 the server wrote. So a failure in transit is followed by an
    /// empty upload with the same token, which has no body to lose the answer under: 401/403
    /// there is the real reason; 400 (the empty body) means the token is good and the network or
    /// the server failed, so the file waits for the next round.
    pub fn upload(&self, token: &str, session: &[u8]) -> UploadReply {
        match self.upload_reply(token, session) {
            UploadReply::Unavailable { reason } if !session.is_empty() => match self.upload_reply(token, &[]) {
                refused @ (UploadReply::Unauthorized { .. } | UploadReply::Forbidden { .. }) => refused,
                _ => UploadReply::Unavailable { reason },
            },
            reply => reply,
        }
    }

    /// One POST /api/sessions and what it means.
    fn upload_reply(&self, token: &str, session: &[u8]) -> UploadReply {
        let resp = self
            .agent
            .post(&format!("{}/api/sessions", self.base))
            .set("Authorization", &format!("Bearer {token}"))
            .set("Content-Type", "application/octet-stream")
            .send_bytes(session);
        match resp {
            Ok(r) => {
                let new = r.status() == 201;
                match read_body(r)
                    .ok()
                    .and_then(|b| serde_json::from_str::<Value>(&b).ok())
                    .and_then(|v| v["id"].as_str().map(str::to_string))
                {
                    Some(id) => UploadReply::Accepted { id, new },
                    None => UploadReply::Unavailable {
                        reason: "the server accepted the upload but sent no session id".into(),
                    },
                }
            }
            Err(ureq::Error::Status(401, r)) => UploadReply::Unauthorized { reason: reason_of(r) },
            Err(ureq::Error::Status(403, r)) => UploadReply::Forbidden { reason: reason_of(r) },
            Err(ureq::Error::Status(status @ (400 | 413 | 415 | 422), r)) => UploadReply::Refused {
                status,
                reason: reason_of(r),
            },
            Err(ureq::Error::Status(status, r)) => UploadReply::Unavailable {
                reason: format!("{status}: {}", reason_of(r)),
            },
            Err(ureq::Error::Transport(t)) => UploadReply::Unavailable { reason: t.to_string() },
        }
    }
}

impl std::fmt::Debug for ServiceClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServiceClient").field("base", &self.base).finish()
    }
}

/// A client and an API token: what the outbox uploads with.
#[derive(Clone)]
pub struct TokenUploader {
    pub client: ServiceClient,
    pub token: String,
}

impl std::fmt::Debug for TokenUploader {
    /// Never prints the token.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TokenUploader")
            .field("client", &self.client)
            .field("token", &"…")
            .finish()
    }
}

impl Uploader for TokenUploader {
    fn upload(&self, session: &[u8]) -> UploadReply {
        self.client.upload(&self.token, session)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passwords_and_tokens_never_cross_the_network_in_clear() {
        assert_eq!(
            check_address("https://stylet.example.org/").unwrap(),
            "https://stylet.example.org"
        );
        assert!(check_address("https://stylet.example.org:8443").is_ok());
        assert!(check_address("http://127.0.0.1:8080").is_ok());
        assert!(check_address("http://localhost:8080").is_ok());
        assert!(check_address("http://[::1]:8080").is_ok());
        let e = check_address("http://stylet.example.org").unwrap_err();
        assert!(e.to_string().contains("use https"), "{e}");
        assert!(matches!(
            check_address("http://127.0.0.1.evil.org"),
            Err(AddressError::Cleartext(_))
        ));
        assert!(matches!(
            check_address("http://localhost@evil.org"),
            Err(AddressError::NotUrl(_))
        ));
        assert!(matches!(check_address("ftp://x"), Err(AddressError::NotUrl(_))));
        assert!(matches!(
            check_address("stylet.example.org"),
            Err(AddressError::NotUrl(_))
        ));
        let t = TokenUploader {
            client: ServiceClient::new("https://stylet.example.org").unwrap(),
            token: "secret-token".into(),
        };
        assert!(!format!("{t:?}").contains("secret-token"));
    }
}
