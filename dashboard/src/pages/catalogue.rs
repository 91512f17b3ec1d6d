//! `GET /atlases`: the scenario catalogue, every atlas this service scores sessions on (the
//! configured ones and those published with `stylet atlas publish`), with its scenarios, planned
//! paths and who published it. Everyone logged in may see it: trainees choose their patient
//! from it.

use std::sync::Arc;

use axum::extract::State;
use axum::response::Html;
use maud::html;
use stylet_service::AppState;
use stylet_service::atlases::catalogue;
use stylet_service::store::Role;

use crate::auth::{PageError, Viewer};
use crate::layout::{page, short_time};

pub async fn index(State(s): State<Arc<AppState>>, v: Viewer) -> Result<Html<String>, PageError> {
    let items = catalogue(&s).await?;
    let may_publish = matches!(v.role(), Role::Admin | Role::Instructor);
    let body = html! {
        h1 { "Scenario catalogue" }
        p.muted {
            "The virtual patients this service scores sessions on. A session recorded on any of them is accepted and graded."
        }
        @if may_publish {
            p.muted #publish-help {
                "To add a patient: make it with " code { "stylet atlas new" } " (or check an atlas with "
                code { "stylet atlas validate" } "), have a clinician approve its validation report, then run "
                code { "stylet atlas publish DIR --server URL" } " with a " strong { "full" }
                " API token of yours in " code { "STYLET_TOKEN" } ". The service checks the atlas again and runs its smoke test before it lists it here."
            }
        }
        @if items.is_empty() {
            p.muted { "No atlases yet." }
        } @else {
            table #catalogue {
                thead { tr {
                    th { "Patient" } th { "Scenarios" } th { "Planned paths (guided first)" } th { "Structures" }
                    th { "Grid" } th { "Origin" } th { "Sessions" } th { "Content hash" }
                } }
                tbody { @for a in &items { tr data-hash=(a.content_hash) {
                    td { strong { (a.name) } @if !a.description.is_empty() { br; span.muted { (a.description) } } }
                    td { (a.scenarios.join(", ")) }
                    td { @for (i, p) in a.paths.iter().enumerate() { @if i > 0 { br; } span title=(p.description) { (p.name) } } }
                    td.num { (a.structures) }
                    td { (a.dims[0]) "×" (a.dims[1]) "×" (a.dims[2]) br;
                         span.muted { (format!("{:.2}×{:.2}×{:.2} mm", a.spacing_mm[0], a.spacing_mm[1], a.spacing_mm[2])) } }
                    td { @match (&a.published_by, &a.published_at) {
                        (Some(by), Some(at)) => { "published by " (by) br; span.muted { (short_time(at)) " UTC" } },
                        _ => { (a.origin) },
                    } }
                    td.num { (a.sessions) }
                    td { code title=(a.content_hash) { (a.content_hash.get(..12).unwrap_or_default()) "…" } }
                } } }
            }
        }
    };
    Ok(page("Scenario catalogue", Some(&v), body))
}
