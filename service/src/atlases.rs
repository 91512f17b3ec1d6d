//! `POST /api/atlases` (publish an atlas, [`super::publish`]) and `GET /api/atlases` (the scenario
//! catalogue); docs/api.md "Atlases".

use std::sync::Arc;

use axum::Json;
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use serde_json::json;

use super::AppState;
use super::api::{Actor, ApiError, Reader, err};
use super::catalogue::AtlasOrigin;
use super::publish::{self, Refusal};
use super::store::{Role, User};

/// One atlas of the catalogue, as the API and the catalogue page show it.
#[derive(Debug, Clone, Serialize)]
pub struct CatalogueItem {
    pub content_hash: String,
    pub name: String,
    pub description: String,
    /// `configured` or `published`.
    pub origin: &'static str,
    pub published_by: Option<String>,
    pub published_at: Option<String>,
    /// Scenarios sessions may be recorded in.
    pub scenarios: Vec<String>,
    /// Planned insertion paths, the beginner's guided one first.
    pub paths: Vec<PathItem>,
    /// Labelled structures.
    pub structures: usize,
    /// Grid in voxels and spacing in mm.
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    /// Sessions stored on it.
    pub sessions: i64,
}

/// A planned insertion path of a catalogue atlas.
#[derive(Debug, Clone, Serialize)]
pub struct PathItem {
    pub name: String,
    /// In words, e.g. the intercostal space and its clearances.
    pub description: String,
}

/// The catalogue: every atlas loaded on this server, with what the database knows of it.
pub async fn catalogue(s: &AppState) -> Result<Vec<CatalogueItem>, ApiError> {
    let rows = s.store.atlas_rows().await?;
    let mut items: Vec<CatalogueItem> = s
        .catalogue
        .entries()
        .into_iter()
        .map(|(hash, e)| {
            let row = rows.iter().find(|r| r.content_hash == hash);
            let m = &e.atlas.manifest;
            let guided = e.atlas.guided_path().map(|p| p.name.as_str());
            let mut paths: Vec<&stylet_atlas::manifest::InsertionPath> = m.paths.iter().collect();
            paths.sort_by_key(|p| Some(p.name.as_str()) != guided);
            let paths = paths
                .into_iter()
                .map(|p| PathItem {
                    name: p.name.clone(),
                    description: p.description.clone(),
                })
                .collect();
            let grid = e.atlas.model.ct().grid();
            let sp = grid.spacing_mm();
            CatalogueItem {
                content_hash: hash.clone(),
                name: m.name.clone(),
                description: m.description.clone(),
                origin: e.origin.as_str(),
                published_by: row.and_then(|r| r.published_by.clone()),
                published_at: row.and_then(|r| r.published_at.clone()),
                scenarios: e.scorer.scenario_names().to_vec(),
                paths,
                structures: m.labels.len(),
                dims: grid.dims(),
                spacing_mm: sp,
                sessions: row.map_or(0, |r| r.sessions),
            }
        })
        .collect();
    items.sort_by(|a, b| a.name.cmp(&b.name).then(a.content_hash.cmp(&b.content_hash)));
    Ok(items)
}

/// `GET /api/atlases`: any logged-in account (trainees choose their scenario from it).
pub async fn list(State(s): State<Arc<AppState>>, Reader(_): Reader) -> Result<Response, ApiError> {
    Ok(Json(json!({ "atlases": catalogue(&s).await? })).into_response())
}

/// Who may publish: admins and instructors.
pub fn may_publish(user: &User) -> Result<(), ApiError> {
    match user.role {
        Role::Admin | Role::Instructor => Ok(()),
        _ => Err(err(
            StatusCode::FORBIDDEN,
            format!(
                "{} is a {} account: only admins and instructors may publish atlases",
                user.username,
                user.role.as_str()
            ),
        )),
    }
}

/// `POST /api/atlases`: see [`super::publish`]. 201 with the atlas when it is new to the
/// catalogue, 200 when it was there already.
pub async fn publish_atlas(
    State(s): State<Arc<AppState>>,
    Actor(user): Actor,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    may_publish(&user)?;
    let media = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default();
    if media.split(';').next().map(str::trim) != Some(publish::CONTENT_TYPE) {
        return Err(err(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            format!(
                "send the atlas as a tar archive with Content-Type {} (stylet atlas publish does)",
                publish::CONTENT_TYPE
            ),
        ));
    }
    let limit = s.config.limits.max_atlas_bytes;
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
        .ok_or_else(|| {
            err(
                StatusCode::LENGTH_REQUIRED,
                "send the archive with its Content-Length (its time limit follows from its size)",
            )
        })?;
    if declared > limit {
        return Err(err(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("the atlas upload exceeds the limit of {limit} bytes"),
        ));
    }
    // At most two archives on disk at once (each until its publication ends), one checked at a
    // time: the permits live in the publication's own task, so a client that goes away
    // releases them only when the work it started has ended.
    let arriving = s.publish_uploads.clone().try_acquire_owned().map_err(|_| {
        err(
            StatusCode::SERVICE_UNAVAILABLE,
            "other atlases are being published; try again when they are done",
        )
    })?;
    let max = s.config.limits.max_atlases;
    if s.catalogue.len() >= max {
        return Err(err(
            StatusCode::CONFLICT,
            format!("the catalogue holds {max} atlases, the most this server keeps loaded"),
        ));
    }
    let incoming = Incoming::create(&s.published_dir()).map_err(ApiError::from)?;
    let received = publish::receive(body, &incoming.path.join("upload.tar"), declared).await?;
    if received != declared {
        return Err(err(
            StatusCode::BAD_REQUEST,
            format!("the upload ended after {received} of the {declared} bytes it declared"),
        ));
    }
    // From here the publication runs to its end in a task of its own: the rename, the row and
    // the catalogue entry happen together or not at all, whatever the client does.
    let state = s.clone();
    let task = tokio::spawn(async move {
        let _arriving = arriving;
        let checking = state.publish_permit.clone().acquire_owned().await.map_err(|_| busy())?;
        let work = incoming.path.clone();
        let max_voxels = state.config.limits.max_atlas_voxels;
        let checked = tokio::task::spawn_blocking(move || {
            let _checking = checking;
            publish::unpack(&work.join("upload.tar"), &work.join("atlas"))?;
            let _ = std::fs::remove_file(work.join("upload.tar"));
            publish::check(&work.join("atlas"), &work.join("smoke"), max_voxels)
        })
        .await
        .map_err(|_| ApiError::Internal)??;
        keep(&state, &user, checked, &incoming).await
    });
    task.await.map_err(|_| ApiError::Internal)?
}

fn busy() -> ApiError {
    err(StatusCode::SERVICE_UNAVAILABLE, "the server is shutting down")
}

/// Keeps a checked atlas: renamed to `DATA/atlases/<hash>/`, its row and audit record, then the
/// catalogue. A folder of that hash that is not in the catalogue (left by a failure, or no longer
/// of its hash) is moved aside first; the folder is removed again when the row cannot be written.
async fn keep(s: &AppState, user: &User, checked: publish::Checked, incoming: &Incoming) -> Result<Response, ApiError> {
    let hash = checked.atlas.content_hash.clone();
    let name = checked.atlas.manifest.name.clone();
    let smoke: Vec<String> = checked
        .smoke
        .iter()
        .map(|o| format!("{} {}", o.script, if o.passed { "ok" } else { "failed" }))
        .collect();
    if s.catalogue.contains(&hash) {
        return Ok((
            StatusCode::OK,
            Json(json!({ "content_hash": hash, "name": name, "status": "already_published" })),
        )
            .into_response());
    }
    let root = s.published_dir();
    let dest = root.join(&hash);
    let storage = |e: std::io::Error| ApiError::from(Refusal::Storage(format!("{}: {e}", dest.display())));
    if dest.exists() {
        let aside = root.join(format!(".replaced-{hash}-{}", super::store::new_id()));
        tracing::warn!(dir = %dest.display(), aside = %aside.display(), "a folder of this hash was not in the catalogue; moved aside");
        std::fs::rename(&dest, &aside).map_err(storage)?;
    }
    std::fs::rename(incoming.path.join("atlas"), &dest).map_err(storage)?;
    let dir = dest.display().to_string();
    let detail = format!("{name}: smoke test {}", smoke.join(", "));
    if let Err(e) = s.store.publish_atlas(&hash, &name, &dir, user, &detail).await {
        let _ = std::fs::remove_dir_all(&dest);
        return Err(e.into());
    }
    let mut atlas = checked.atlas;
    atlas.dir = dest;
    s.catalogue.insert(atlas, checked.scorer, AtlasOrigin::Published);
    tracing::info!(atlas = %name, hash = %hash, by = %user.username, "atlas published");
    let item = catalogue(s).await?.into_iter().find(|i| i.content_hash == hash);
    Ok((
        StatusCode::CREATED,
        Json(json!({ "content_hash": hash, "name": name, "status": "published", "smoke": smoke, "atlas": item })),
    )
        .into_response())
}

/// A publication's working folder `DATA/atlases/.incoming-<id>/`, removed when the request ends
/// however it ends (a refusal, an error, a client that went away).
struct Incoming {
    path: std::path::PathBuf,
}

impl Incoming {
    fn create(root: &std::path::Path) -> Result<Incoming, Refusal> {
        let path = root.join(format!(".incoming-{}", super::store::new_id()));
        std::fs::create_dir_all(&path).map_err(|e| Refusal::Storage(format!("{}: {e}", path.display())))?;
        Ok(Incoming { path })
    }
}

impl Drop for Incoming {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}
