//! `/admin/atlases`: admins see every atlas the service knows, withdrawn ones too, and withdraw
//! one from the catalogue (`POST /admin/atlases/{hash}/withdraw`: the same call as
//! `DELETE /api/atlases/{hash}` and `stylet atlas unpublish`, audited). A withdrawn atlas takes
//! no new sessions; the sessions recorded on it stay readable and replayable. Publishing it
//! again reinstates it.

use std::sync::Arc;

use axum::Form;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Redirect, Response};
use maud::{Markup, html};
use stylet_service::AppState;
use stylet_service::atlases::{CatalogueItem, all_atlases, withdraw};
use stylet_service::store::Role;

use crate::auth::{PageError, Viewer, check_csrf, fail};
use crate::layout::{csrf_field, page, short_time};

fn require_admin(v: &Viewer) -> Result<(), PageError> {
    if v.role() == Role::Admin {
        Ok(())
    } else {
        Err(fail(StatusCode::FORBIDDEN, "only admins manage atlases"))
    }
}

fn atlases_page(v: &Viewer, items: &[CatalogueItem], error: Option<&str>) -> Markup {
    html! {
        h1 { "Atlases" }
        p.muted {
            "Every virtual patient this service knows. Withdrawing one takes it out of the catalogue: no new sessions are accepted on it, "
            "while the sessions already recorded on it stay readable, replayable and scored. To offer it again, publish it again ("
            code { "stylet atlas publish" } ")."
        }
        @if let Some(e) = error { p.error role="alert" #atlas-error { (e) } }
        div.table-scroll { table #atlases {
            thead { tr { th { "Patient" } th { "Origin" } th { "Sessions" } th { "Status" } th { "Content hash" } th { "Change" } } }
            tbody { @for a in items {
                tr data-hash=(a.content_hash) {
                    td { strong { (a.name) } }
                    td { @match (&a.published_by, &a.published_at) {
                        (Some(by), Some(at)) => { "published by " (by) br; span.muted { (short_time(at)) " UTC" } },
                        _ => { (a.origin) },
                    } }
                    td.num { (a.sessions) }
                    td.status { @match &a.withdrawn_at {
                        Some(at) => { "withdrawn " (short_time(at)) " UTC" },
                        None => { "in the catalogue" },
                    } }
                    td { code title=(a.content_hash) { (a.content_hash.get(..12).unwrap_or_default()) "…" } }
                    td { @if a.withdrawn_at.is_none() {
                        form.inline.withdraw method="post" action=(format!("/admin/atlases/{}/withdraw", a.content_hash)) {
                            (csrf_field(v))
                            label { input type="checkbox" name="confirm" value="yes" required; " no new sessions on " (a.name) }
                            button type="submit" { "Withdraw" }
                        }
                    } }
                }
            } }
        } }
    }
}

/// `GET /admin/atlases`.
pub async fn index(State(s): State<Arc<AppState>>, v: Viewer) -> Result<Response, PageError> {
    require_admin(&v)?;
    let items = all_atlases(&s).await?;
    Ok(page("Atlases", Some(&v), atlases_page(&v, &items, None)).into_response())
}

#[derive(serde::Deserialize)]
pub struct WithdrawForm {
    csrf: String,
    #[serde(default)]
    confirm: String,
}

/// `POST /admin/atlases/{hash}/withdraw`: with its box ticked; back to the list.
pub async fn withdraw_form(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(hash): Path<String>,
    Form(f): Form<WithdrawForm>,
) -> Result<Response, PageError> {
    require_admin(&v)?;
    check_csrf(&v, &f.csrf)?;
    if f.confirm != "yes" {
        return Err(fail(
            StatusCode::BAD_REQUEST,
            "tick the box to confirm that the atlas takes no new sessions",
        ));
    }
    match withdraw(&s, &v.user, &hash).await {
        Ok(_) => Ok(Redirect::to("/admin/atlases").into_response()),
        Err(e) => {
            let items = all_atlases(&s).await?;
            Ok((
                e.status(),
                page("Atlases", Some(&v), atlases_page(&v, &items, Some(&e.message()))),
            )
                .into_response())
        }
    }
}
