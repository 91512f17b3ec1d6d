//! `POST /upload`: a session file from a browser form (multipart). Checked exactly like the
//! API's uploads (`accept_upload`: size, the recorder's strict reader, known atlas, who may
//! upload for whom); on success the browser goes to the session's page, which shows its score
//! as soon as the replay is done.

use std::sync::Arc;

use axum::extract::{Multipart, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::api::{ApiError, accept_upload, content_length};

use crate::auth::{PageError, Viewer, check_csrf, fail};
use crate::layout::{csrf_field, page};

/// The upload form (trainees upload their own sessions, instructors those of their trainees).
pub fn upload_form(v: &Viewer) -> Markup {
    html! {
        form.inline #upload method="post" action="/upload" enctype="multipart/form-data" {
            (csrf_field(v))
            label { "Session file (.mcap)" input #session-file type="file" name="session" accept=".mcap" required; }
            button.primary type="submit" { "Upload and score" }
        }
    }
}

/// Receives the form: its CSRF token must come first (the form puts it before the file), so the
/// login is checked before a byte of the file is read; the file is then received and checked
/// exactly as the API's uploads are (streamed, never held whole in memory).
pub async fn upload(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    headers: HeaderMap,
    mut form: Multipart,
) -> Result<Response, PageError> {
    let bad = |m: String| fail(StatusCode::BAD_REQUEST, m);
    let mut csrf_checked = false;
    let mut stored: Option<Result<_, ApiError>> = None;
    while let Some(field) = form
        .next_field()
        .await
        .map_err(|e| bad(format!("the form could not be read: {e}")))?
    {
        match field.name() {
            Some("csrf") if !csrf_checked => {
                // A token is a few dozen characters: a longer field is not one.
                let sent = field.text().await.map_err(|e| bad(e.to_string()))?;
                check_csrf(&v, &sent)?;
                csrf_checked = true;
            }
            Some("session") if csrf_checked && stored.is_none() => {
                let chunks = Box::pin(futures_util::stream::unfold(field, |mut f| async move {
                    match f.chunk().await {
                        Ok(Some(chunk)) => Some((Ok(chunk), f)),
                        Ok(None) => None,
                        Err(e) => Some((Err(e), f)),
                    }
                }));
                stored = Some(accept_upload(&s, &v.user, chunks, content_length(&headers)).await);
                // Whatever follows the file is not read (a refused file's rest neither).
                break;
            }
            Some("session") if !csrf_checked => {
                return Err(bad(
                    "the form's security token must come before the file; reload the page and try again".into(),
                ));
            }
            _ => {}
        }
    }
    if !csrf_checked {
        check_csrf(&v, "")?;
    }
    let stored = stored.ok_or_else(|| bad("choose a session file to upload".into()))?;
    match stored {
        Ok((id, _, _)) => Ok(Redirect::to(&format!("/sessions/{id}")).into_response()),
        Err(e) => {
            let mut r = (
                e.status(),
                page(
                    "Upload refused",
                    Some(&v),
                    html! {
                        h1 { "Upload refused" }
                        p.error role="alert" #upload-error { (e.message()) }
                        p { "Nothing was stored." }
                        (upload_form(&v))
                    },
                ),
            )
                .into_response();
            if let Some(after) = e.retry_after_s() {
                r.headers_mut().insert(header::RETRY_AFTER, HeaderValue::from(after));
            }
            Ok(r)
        }
    }
}
