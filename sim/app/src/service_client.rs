//! The simulator's side of the scoring service's HTTP API (docs/api.md): logging in once to get
//! an upload-only API token, and uploading session files with it.

use std::time::Duration;

use serde_json::Value;

/// Longest reply body read from the service (its JSON answers are small).
const MAX_REPLY_BYTES: u64 = 1 << 20;

/// What the service said to an upload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum UploadReply {
    /// Stored (201) or already stored before (200): the session's id on the service.
    Accepted { id: String, new: bool },
    /// The service refused the file itself (400, 403, 413, 415, 422): uploading it again will
    /// not help. The service's reason.
    Refused { status: u16, reason: String },
    /// The token is missing, expired or revoked (401): log in again.
    Unauthorized { reason: String },
    /// The service is down, overloaded or unreachable: try again later.
    Unavailable { reason: String },
}

/// Errors of logging in.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LoginError {
    #[error("the server at {url} cannot be reached: {reason}")]
    Unreachable { url: String, reason: String },
    #[error("the server refused: {status} {reason}")]
    Refused { status: u16, reason: String },
    #[error("the server's answer was not understood: {0}")]
    Protocol(String),
}

/// A client of one scoring service.
#[derive(Debug, Clone)]
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
    /// A client of the service at `base` (e.g. `https://stylet.example.org`), with time limits so
    /// that a dead server never hangs the caller.
    pub fn new(base: &str) -> ServiceClient {
        let agent = ureq::AgentBuilder::new()
            .timeout_connect(Duration::from_secs(5))
            .timeout(Duration::from_secs(120))
            .build();
        ServiceClient {
            base: base.trim_end_matches('/').to_string(),
            agent,
        }
    }

    pub fn base(&self) -> &str {
        &self.base
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

    /// Uploads one session file with an API token.
    pub fn upload(&self, token: &str, session: &[u8]) -> UploadReply {
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
            Err(ureq::Error::Status(status @ (400 | 403 | 413 | 415 | 422), r)) => UploadReply::Refused {
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

/// A client and an API token: what the outbox uploads with.
#[derive(Debug, Clone)]
pub struct TokenUploader {
    pub client: ServiceClient,
    pub token: String,
}

impl crate::outbox::Uploader for TokenUploader {
    fn upload(&self, session: &[u8]) -> UploadReply {
        self.client.upload(&self.token, session)
    }
}
