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
    /// The account may not upload (403 without a file problem: a disabled account, a token of
    /// the wrong scope): nothing is moved aside; the next round tries again.
    Forbidden { reason: String },
    /// The service is down, overloaded or unreachable: try again later.
    Unavailable { reason: String },
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

impl crate::outbox::Uploader for TokenUploader {
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
