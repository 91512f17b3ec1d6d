//! Who is looking at a page: the login cookie (the same logins as the JSON API), the CSRF token
//! every form posts, and page errors (a login redirect or an error page that says why, drawn by
//! `error_page.rs`).

use axum::http::{HeaderMap, StatusCode, Uri, header};
use stylet_service::AppState;
use stylet_service::api::{ApiError, hold_request_slot};
use stylet_service::auth::{from_other_site, token_from_cookie_header};
use stylet_service::store::{Role, StoreError, User};

/// The logged-in user of a page and the CSRF token of their login (forms echo it).
pub struct Viewer {
    pub user: User,
    pub csrf: String,
}

impl Viewer {
    pub fn role(&self) -> Role {
        self.user.role
    }
}

/// Why a page is not shown.
#[derive(Debug)]
pub enum PageError {
    /// Not logged in: to the login page, then back to `next`.
    Login { next: String },
    /// An error page with this status and message.
    Status(StatusCode, String),
}

pub fn fail(status: StatusCode, msg: impl Into<String>) -> PageError {
    PageError::Status(status, msg.into())
}

impl From<ApiError> for PageError {
    fn from(e: ApiError) -> Self {
        PageError::Status(e.status(), e.message())
    }
}

impl From<StoreError> for PageError {
    fn from(e: StoreError) -> Self {
        tracing::error!(error = %e, "store");
        PageError::Status(StatusCode::INTERNAL_SERVER_ERROR, "internal error".into())
    }
}

/// Percent-encodes a path for a query value (`/sessions/x?y` → `%2Fsessions%2Fx%3Fy`).
pub fn encode_query(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// The viewer of a page, or a redirect to the login page that comes back to `uri`.
pub async fn viewer(s: &AppState, headers: &HeaderMap, uri: &Uri) -> Result<Viewer, PageError> {
    let login = || PageError::Login {
        next: uri.path_and_query().map_or("/", |p| p.as_str()).to_string(),
    };
    let token = headers
        .get(header::COOKIE)
        .and_then(|v| v.to_str().ok())
        .and_then(token_from_cookie_header)
        .ok_or_else(login)?;
    let (user, csrf) = s.store.user_for_login(token).await?.ok_or_else(login)?;
    Ok(Viewer { user, csrf })
}

/// Pages take the viewer as an argument: a page that needs a login names `Viewer` (not logged
/// in: to the login page, then back), one that may be seen without names `Option<Viewer>`.
impl axum::extract::FromRequestParts<std::sync::Arc<AppState>> for Viewer {
    type Rejection = PageError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        s: &std::sync::Arc<AppState>,
    ) -> Result<Self, PageError> {
        let v = viewer(s, &parts.headers, &parts.uri).await?;
        hold_request_slot(s, parts, &v.user)?;
        Ok(v)
    }
}

impl axum::extract::OptionalFromRequestParts<std::sync::Arc<AppState>> for Viewer {
    type Rejection = PageError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        s: &std::sync::Arc<AppState>,
    ) -> Result<Option<Self>, PageError> {
        match viewer(s, &parts.headers, &parts.uri).await {
            Ok(v) => {
                hold_request_slot(s, parts, &v.user)?;
                Ok(Some(v))
            }
            Err(PageError::Login { .. }) => Ok(None),
            Err(e) => Err(e),
        }
    }
}

/// A form's CSRF field must carry the login's token (another site's page cannot read it).
pub fn check_csrf(v: &Viewer, sent: &str) -> Result<(), PageError> {
    if sent == v.csrf {
        Ok(())
    } else {
        Err(fail(
            StatusCode::FORBIDDEN,
            "the form's security token does not match your login; reload the page and try again",
        ))
    }
}

/// Refuses a form posted from another site (see [`from_other_site`]: login CSRF).
pub fn check_same_site(headers: &HeaderMap) -> Result<(), PageError> {
    if from_other_site(headers) {
        Err(fail(
            StatusCode::FORBIDDEN,
            "this form was sent from another site; log in from Stylet's own login page",
        ))
    } else {
        Ok(())
    }
}

/// Where a login may send the browser back to: a local path only (no other sites).
pub fn safe_next(next: Option<&str>) -> String {
    match next {
        // Browsers drop tabs and newlines from URLs (`/\t/x` becomes `//x`, another site), so
        // only visible ASCII is allowed.
        Some(n)
            if n.starts_with('/')
                && !n.starts_with("//")
                && !n.contains('\\')
                && n.bytes().all(|b| b.is_ascii_graphic()) =>
        {
            n.to_string()
        }
        _ => "/".to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn login_only_returns_to_local_paths() {
        assert_eq!(safe_next(Some("/sessions/abc")), "/sessions/abc");
        assert_eq!(safe_next(Some("//evil.example/")), "/");
        assert_eq!(safe_next(Some("https://evil.example/")), "/");
        assert_eq!(safe_next(Some("/\\evil.example")), "/");
        assert_eq!(safe_next(None), "/");
        assert_eq!(safe_next(Some("/\t/evil.example")), "/");
        assert_eq!(safe_next(Some("/\n/evil.example")), "/");
        assert_eq!(safe_next(Some("/ /evil.example")), "/");
        assert_eq!(
            safe_next(Some("/sessions?page=2&to=2026-01-01")),
            "/sessions?page=2&to=2026-01-01"
        );
        assert_eq!(encode_query("/a b?c=1&d"), "%2Fa%20b%3Fc%3D1%26d");
    }

    #[test]
    fn forms_from_other_sites_are_refused() {
        let with = |v: &str| {
            let mut h = HeaderMap::new();
            h.insert("sec-fetch-site", v.parse().unwrap());
            h
        };
        assert!(check_same_site(&with("same-origin")).is_ok());
        assert!(check_same_site(&with("none")).is_ok());
        assert!(check_same_site(&HeaderMap::new()).is_ok());
        for v in ["cross-site", "same-site"] {
            match check_same_site(&with(v)) {
                Err(PageError::Status(status, msg)) => {
                    assert_eq!(status, StatusCode::FORBIDDEN);
                    assert!(msg.contains("another site"), "{msg}");
                }
                _ => panic!("{v} was let through"),
            }
        }
    }
}
