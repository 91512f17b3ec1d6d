//! `POST /upload`: a session file from a browser form (multipart). Checked exactly like the
//! API's uploads (`accept_upload`: size, the recorder's strict reader, known atlas, who may
//! upload for whom); on success the browser goes to the session's page, which shows its score
//! as soon as the replay is done.

use std::sync::Arc;

use axum::extract::{Multipart, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::api::accept_upload;

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

pub async fn upload(State(s): State<Arc<AppState>>, v: Viewer, mut form: Multipart) -> Result<Response, PageError> {
    let bad = |m: String| fail(StatusCode::BAD_REQUEST, m);
    let mut csrf = None;
    let mut file = None;
    while let Some(field) = form
        .next_field()
        .await
        .map_err(|e| bad(format!("the form could not be read: {e}")))?
    {
        match field.name() {
            Some("csrf") => csrf = Some(field.text().await.map_err(|e| bad(e.to_string()))?),
            Some("session") => {
                // The body limit of this route (the service's upload limit) bounds this read.
                let bytes = field.bytes().await.map_err(|e| {
                    fail(
                        StatusCode::PAYLOAD_TOO_LARGE,
                        format!(
                            "the upload could not be read (over {} bytes?): {e}",
                            s.config.max_upload_bytes
                        ),
                    )
                })?;
                file = Some(bytes);
            }
            _ => {}
        }
    }
    check_csrf(&v, csrf.as_deref().unwrap_or_default())?;
    let bytes = file.ok_or_else(|| bad("choose a session file to upload".into()))?;
    match accept_upload(&s, &v.user, bytes).await {
        Ok((id, _, _)) => Ok(Redirect::to(&format!("/sessions/{id}")).into_response()),
        Err(e) => Ok((
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
            .into_response()),
    }
}
