//! The service's one error type and its HTTP answer: every module of the service returns
//! [`ApiError`], and [`ApiError::status`] is the one place its kinds become HTTP statuses.

use axum::Json;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::json;

use super::store::{AccountError, ImportLineError};

/// The service's one error type: what went wrong, in words for the person who asked, by kind.
/// [`ApiError::status`] maps the kinds to HTTP statuses, in this one place; the API answers
/// `{"error": "..."}` (and `lines` for an import), the dashboard an error page.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// 400: the request is malformed or a value is out of range.
    #[error("{0}")]
    Invalid(String),
    /// 401: not logged in, or the login or token is no longer valid.
    #[error("{0}")]
    Unauthenticated(String),
    /// 403: logged in, but not allowed.
    #[error("{0}")]
    Forbidden(String),
    /// 404 (also for what exists but is not the caller's to know of).
    #[error("{0}")]
    NotFound(String),
    /// 409: clashes with what is stored (a taken username, too many tokens).
    #[error("{0}")]
    Conflict(String),
    /// 413.
    #[error("{0}")]
    TooLarge(String),
    /// 415.
    #[error("{0}")]
    UnsupportedMediaType(String),
    /// 422: a bulk import with bad lines (every one named); nothing was imported.
    #[error("{}", AccountError::Import(.0.clone()))]
    ImportRejected(Vec<ImportLineError>),
    /// 429: this account (or this client) is over a rate or a cap; try again after
    /// `retry_after_s` (sent as `Retry-After`).
    #[error("{message}")]
    Throttled { message: String, retry_after_s: u32 },
    /// 503: overload or storage that cannot write now; try again shortly.
    #[error("{0}")]
    Unavailable(String),
    /// 500: details are logged, not shown.
    #[error("internal error")]
    Internal,
    /// Any other status (kept for statuses no kind names yet).
    #[error("{1}")]
    Other(StatusCode, String),
}

impl ApiError {
    /// The HTTP status of each kind.
    pub fn status(&self) -> StatusCode {
        match self {
            ApiError::Invalid(_) => StatusCode::BAD_REQUEST,
            ApiError::Unauthenticated(_) => StatusCode::UNAUTHORIZED,
            ApiError::Forbidden(_) => StatusCode::FORBIDDEN,
            ApiError::NotFound(_) => StatusCode::NOT_FOUND,
            ApiError::Conflict(_) => StatusCode::CONFLICT,
            ApiError::TooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            ApiError::UnsupportedMediaType(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ApiError::ImportRejected(_) => StatusCode::UNPROCESSABLE_ENTITY,
            ApiError::Throttled { .. } => StatusCode::TOO_MANY_REQUESTS,
            ApiError::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            ApiError::Internal => StatusCode::INTERNAL_SERVER_ERROR,
            ApiError::Other(status, _) => *status,
        }
    }

    /// The message for people.
    pub fn message(&self) -> String {
        self.to_string()
    }

    /// When the client may try again (s), sent as `Retry-After`: for 429 and 503.
    pub fn retry_after_s(&self) -> Option<u32> {
        match self {
            ApiError::Throttled { retry_after_s, .. } => Some(*retry_after_s),
            // Overload and an unwritable store pass: clients may try again shortly.
            ApiError::Unavailable(_) => Some(1),
            _ => None,
        }
    }
}

/// Longest error message sent (bytes): a message that quotes what a client sent is cut here, so
/// an error body never grows with the input.
pub const MAX_ERROR_MESSAGE_BYTES: usize = 4096;

/// `text` cut to at most `max` bytes at a character boundary, with "…" when cut.
pub fn bounded(text: &str, max: usize) -> String {
    if text.len() <= max {
        return text.to_string();
    }
    let mut end = max.saturating_sub('…'.len_utf8());
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}…", &text[..end])
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        let message = bounded(&self.message(), MAX_ERROR_MESSAGE_BYTES);
        let body = match &self {
            ApiError::ImportRejected(lines) => json!({ "error": message, "lines": lines }),
            _ => json!({ "error": message }),
        };
        let mut r = (status, Json(body)).into_response();
        if let Some(s) = self.retry_after_s() {
            r.headers_mut()
                .insert(header::RETRY_AFTER, axum::http::HeaderValue::from(s));
        }
        r
    }
}

/// How long a client refused for a full cap (429) is asked to wait (s).
pub const RETRY_AFTER_S: u32 = 5;

/// The error of a kind by its status (handlers written before the kinds name the status).
pub fn err(status: StatusCode, msg: impl Into<String>) -> ApiError {
    let msg = msg.into();
    match status {
        StatusCode::BAD_REQUEST => ApiError::Invalid(msg),
        StatusCode::UNAUTHORIZED => ApiError::Unauthenticated(msg),
        StatusCode::FORBIDDEN => ApiError::Forbidden(msg),
        StatusCode::NOT_FOUND => ApiError::NotFound(msg),
        StatusCode::CONFLICT => ApiError::Conflict(msg),
        StatusCode::PAYLOAD_TOO_LARGE => ApiError::TooLarge(msg),
        StatusCode::UNSUPPORTED_MEDIA_TYPE => ApiError::UnsupportedMediaType(msg),
        StatusCode::TOO_MANY_REQUESTS => ApiError::Throttled {
            message: msg,
            retry_after_s: RETRY_AFTER_S,
        },
        StatusCode::SERVICE_UNAVAILABLE => ApiError::Unavailable(msg),
        status => ApiError::Other(status, msg),
    }
}

impl From<super::StoreError> for ApiError {
    fn from(e: super::StoreError) -> Self {
        use super::StoreError;
        if let StoreError::UserExists(_)
        | StoreError::TooManyTokens { .. }
        | StoreError::TooManyPairingCodes { .. }
        | StoreError::LtiPlatformExists { .. } = e
        {
            return ApiError::Conflict(e.to_string());
        }
        if let StoreError::TooManyLaunches = e {
            return ApiError::Throttled {
                message: e.to_string(),
                retry_after_s: RETRY_AFTER_S,
            };
        }
        tracing::error!(error = %e, "store");
        if e.is_transient() {
            return ApiError::Unavailable("the server cannot write its data right now; try again shortly".into());
        }
        ApiError::Internal
    }
}

impl From<AccountError> for ApiError {
    fn from(e: AccountError) -> Self {
        match e {
            AccountError::NoSuchUser(_) => ApiError::NotFound(e.to_string()),
            AccountError::LastAdmin(_) | AccountError::OwnAccount => ApiError::Conflict(e.to_string()),
            AccountError::Invalid(m) => ApiError::Invalid(m),
            AccountError::Import(lines) => ApiError::ImportRejected(lines),
            AccountError::Store(e) => e.into(),
        }
    }
}
