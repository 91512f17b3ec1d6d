//! How a [`PageError`] reaches the browser: a redirect to the login page, or an error page in the
//! page shell that says why (with `Retry-After` when the server is busy).

use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use maud::html;

use crate::auth::{PageError, encode_query};
use crate::layout;

impl IntoResponse for PageError {
    fn into_response(self) -> Response {
        match self {
            PageError::Login { next } => Redirect::to(&format!("/login?next={}", encode_query(&next))).into_response(),
            PageError::Status(status, msg) => {
                let msg = stylet_service::api::bounded(&msg, stylet_service::api::MAX_ERROR_MESSAGE_BYTES);
                let body = html! {
                    h1 { (status.as_u16()) " " (status.canonical_reason().unwrap_or("")) }
                    p.error { (msg) }
                    p { a href="/" { "Home" } }
                };
                let mut r = (
                    status,
                    layout::page(status.canonical_reason().unwrap_or("Error"), None, body),
                )
                    .into_response();
                let retry_after_s = match status {
                    StatusCode::TOO_MANY_REQUESTS => Some(stylet_service::slots::RETRY_AFTER_S),
                    StatusCode::SERVICE_UNAVAILABLE => Some(1),
                    _ => None,
                };
                if let Some(after) = retry_after_s {
                    r.headers_mut()
                        .insert(header::RETRY_AFTER, axum::http::HeaderValue::from(after));
                }
                r
            }
        }
    }
}
