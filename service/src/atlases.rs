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
use super::catalogue::AtlasOrigin;
use super::error::{ApiError, err};
use super::extract::{Actor, AdminActor, Reader};
use super::publish::{self, Refusal};
use super::store::{Role, User};

/// One atlas of the catalogue, as the API and the catalogue page show it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
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
    /// When an admin withdrew it (only in [`all_atlases`]: the catalogue lists those that take
    /// sessions).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub withdrawn_at: Option<String>,
}

/// A planned insertion path of a catalogue atlas.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct PathItem {
    pub name: String,
    /// In words, e.g. the intercostal space and its clearances.
    pub description: String,
}

/// The catalogue: every atlas of this server that takes sessions, with what the database knows
/// of it.
pub async fn catalogue(s: &AppState) -> Result<Vec<CatalogueItem>, ApiError> {
    Ok(all_atlases(s)
        .await?
        .into_iter()
        .filter(|a| a.withdrawn_at.is_none())
        .collect())
}

/// Every atlas this server knows, withdrawn ones too (the admins' page).
pub async fn all_atlases(s: &AppState) -> Result<Vec<CatalogueItem>, ApiError> {
    let rows = s.store.atlas_rows().await?;
    let mut items: Vec<CatalogueItem> = s
        .catalogue
        .entries()
        .into_iter()
        .map(|(hash, e)| {
            let row = rows.iter().find(|r| r.content_hash == hash);
            let m = &e.summary;
            CatalogueItem {
                content_hash: hash.clone(),
                name: m.name.clone(),
                description: m.description.clone(),
                origin: e.origin.as_str(),
                published_by: row.and_then(|r| r.published_by.clone()),
                published_at: row.and_then(|r| r.published_at.clone()),
                scenarios: m.scenarios.clone(),
                paths: m
                    .paths
                    .iter()
                    .map(|(name, description)| PathItem {
                        name: name.clone(),
                        description: description.clone(),
                    })
                    .collect(),
                structures: m.structures,
                dims: m.dims,
                spacing_mm: m.spacing_mm,
                sessions: row.map_or(0, |r| r.sessions),
                withdrawn_at: e.withdrawn().then(|| {
                    row.and_then(|r| r.withdrawn_at.clone())
                        .unwrap_or_else(|| "withdrawn".into())
                }),
            }
        })
        .collect();
    items.sort_by(|a, b| a.name.cmp(&b.name).then(a.content_hash.cmp(&b.content_hash)));
    Ok(items)
}

/// `GET /api/atlases`: any logged-in account (trainees choose their scenario from it).
#[utoipa::path(get, path = "/api/atlases", tag = "atlases",
    summary = "The scenario catalogue: every atlas this server takes sessions on",
    responses(
        (status = 200, description = "the catalogue", body = Catalogue),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn list(State(s): State<Arc<AppState>>, Reader(_reader): Reader) -> Result<Response, ApiError> {
    Ok(Json(json!({ "atlases": catalogue(&s).await? })).into_response())
}

/// The scenario catalogue.
#[derive(Serialize, utoipa::ToSchema)]
pub struct Catalogue {
    pub atlases: Vec<CatalogueItem>,
}

/// Who may publish: admins and instructors.
pub fn may_publish(user: &User) -> Result<(), ApiError> {
    match user.role {
        Role::Admin | Role::Instructor => Ok(()),
        Role::Trainee | Role::Curriculum => Err(err(
            StatusCode::FORBIDDEN,
            format!(
                "{} is a {} account: only admins and instructors may publish atlases",
                user.username, user.role
            ),
        )),
    }
}

/// `POST /api/atlases`: see [`super::publish`]. 201 with the atlas when it is new to the
/// catalogue, 200 when it was there already.
#[utoipa::path(post, path = "/api/atlases", tag = "atlases",
    summary = "Publish an atlas (admins and instructors; audited)",
    description = "A tar archive of atlas.toml, validation.toml, the two volumes, the record's scripts/*.txt and any measured breathing motion under motion/ (stylet atlas publish makes it). It arrives like an upload (a slot, room on the disk, the minimum rate); then, one publication at a time, the service checks the validation record against the content hash, loads the atlas and runs the smoke test before it keeps it by content hash and lists it. An atlas this server has checked before is taken back without checking it again.",
    request_body(content = Vec<u8>, content_type = "application/x-tar"),
    responses(
        (status = 201, description = "published (or published again after it was withdrawn)", body = AtlasAnswer),
        (status = 200, description = "it was in the catalogue already", body = AtlasAnswer),
        (status = 400, description = "empty body, or it ended before its Content-Length", body = super::openapi::ErrorBody),
        (status = 403, description = "not an admin or instructor, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 409, description = "the catalogue holds the most atlases this server takes", body = super::openapi::ErrorBody),
        (status = 411, description = "no Content-Length", body = super::openapi::ErrorBody),
        (status = 413, description = "over the atlas size or voxel limit", body = super::openapi::ErrorBody),
        (status = 415, description = "not application/x-tar", body = super::openapi::ErrorBody),
        (status = 422, description = "not a valid archive, a damaged atlas, not validated, or its smoke test failed", body = super::openapi::ErrorBody),
        (status = 429, description = "this account has as many uploads in progress as it may; Retry-After", body = super::openapi::ErrorBody),
        (status = 503, description = "the server takes as many uploads as it can, or its disk is too full; Retry-After", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
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
    let max = s.config.limits.max_atlases;
    if s.catalogue.active_len() >= max {
        return Err(err(
            StatusCode::CONFLICT,
            format!("the catalogue holds {max} atlases, the most this server takes (withdraw one first)"),
        ));
    }
    // The archive arrives like an upload: a slot of the uploads (per account and in all), room
    // on the disk for it and its unpacked copy, no slower than the minimum rate. Publications
    // are not held up by one another while their archives arrive.
    let _slot = super::upload_hold::take(&s, &user.id).await?;
    let _room = s.disk.reserve(
        &s.config.data_dir,
        declared.saturating_mul(2),
        s.config.limits.min_free_disk_bytes,
    )?;
    let incoming = Incoming::create(&s.published_dir()).map_err(ApiError::from)?;
    let received = publish::receive(
        body,
        &incoming.path.join("upload.tar"),
        declared,
        s.config.limits.min_upload_bytes_per_s,
    )
    .await?;
    if received != declared {
        return Err(err(
            StatusCode::BAD_REQUEST,
            format!("the upload ended after {received} of the {declared} bytes it declared"),
        ));
    }
    // From here the publication runs to its end in a task of its own: the rename, the row and
    // the catalogue entry happen together or not at all, whatever the client does. One at a
    // time: the checks, the rename and the catalogue update hold the permit.
    let state = s.clone();
    let task = tokio::spawn(async move {
        let checking = state.publish_permit.clone().acquire_owned().await.map_err(|_| busy())?;
        let work = incoming.path.clone();
        let catalogue = state.catalogue.clone();
        let max_voxels = state.config.limits.max_atlas_voxels;
        let outcome = tokio::task::spawn_blocking(move || {
            publish::unpack(&work.join("upload.tar"), &work.join("atlas"))?;
            let _ = std::fs::remove_file(work.join("upload.tar"));
            // An atlas this server has already checked is not checked again.
            let hash = publish::content_of(&work.join("atlas"))?;
            if catalogue.contains(&hash) {
                return Ok(Outcome::Known(hash));
            }
            publish::check(&work.join("atlas"), &work.join("smoke"), max_voxels).map(|c| Outcome::Checked(Box::new(c)))
        })
        .await
        .map_err(|_| ApiError::Internal)??;
        let answer = match outcome {
            Outcome::Known(hash) => republish(&state, &user, &hash).await,
            Outcome::Checked(checked) => keep(&state, &user, *checked, &incoming).await,
        };
        drop(checking);
        answer
    });
    task.await.map_err(|_| ApiError::Internal)?
}

/// What the checks of an arrived archive found.
enum Outcome {
    /// An atlas of the catalogue already (withdrawn or not): the content hash.
    Known(String),
    Checked(Box<publish::Checked>),
}

/// The answer to an archive of an atlas the catalogue holds: 200 `already_published`; when it
/// had been withdrawn, it is reinstated (audited as a publication) and answered 201.
async fn republish(s: &AppState, user: &User, hash: &str) -> Result<Response, ApiError> {
    let entry = s.catalogue.get(hash).ok_or(ApiError::Internal)?;
    let name = entry.summary.name.clone();
    if !entry.withdrawn() {
        return Ok((
            StatusCode::OK,
            Json(json!({ "content_hash": hash, "name": name, "status": "already_published" })),
        )
            .into_response());
    }
    let detail = format!("{name}: published again after it was withdrawn (checked when first published)");
    s.store
        .publish_atlas(hash, &name, &entry.dir.display().to_string(), user, &detail)
        .await?;
    s.catalogue.set_withdrawn(hash, false);
    tracing::info!(atlas = %name, hash = %hash, by = %user.username, "atlas published again");
    let item = catalogue(s).await?.into_iter().find(|i| i.content_hash == hash);
    Ok((
        StatusCode::CREATED,
        Json(json!({ "content_hash": hash, "name": name, "status": "published", "smoke": [], "atlas": item })),
    )
        .into_response())
}

/// `DELETE /api/atlases/{content hash}` (admins): withdraws the atlas from the catalogue (see
/// [`withdraw`]).
#[utoipa::path(delete, path = "/api/atlases/{hash}", tag = "atlases",
    summary = "Withdraw an atlas from the catalogue (admins; audited)",
    description = "It takes no new sessions; the sessions recorded on it stay readable, replayable and scored. Publishing it again reinstates it.",
    params(("hash" = String, Path, description = "the atlas' content hash")),
    responses(
        (status = 200, description = "withdrawn", body = AtlasAnswer),
        (status = 403, description = "not an admin, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no atlas with this content hash on this server", body = super::openapi::ErrorBody),
        (status = 409, description = "withdrawn already", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn unpublish(
    State(s): State<Arc<AppState>>,
    AdminActor(user): AdminActor,
    axum::extract::Path(hash): axum::extract::Path<String>,
) -> Result<Response, ApiError> {
    let name = withdraw(&s, &user, &hash).await?;
    Ok(Json(json!({ "content_hash": hash, "name": name, "status": "withdrawn" })).into_response())
}

/// What became of a publication or a withdrawal: `published` (201), `already_published` (200),
/// `withdrawn`.
#[derive(Serialize, utoipa::ToSchema)]
pub struct AtlasAnswer {
    pub content_hash: String,
    pub name: String,
    pub status: String,
    /// The service's smoke test, one line per script (a new publication).
    pub smoke: Option<Vec<String>>,
    /// The atlas as the catalogue lists it (a new publication).
    pub atlas: Option<CatalogueItem>,
}

/// Withdraws the atlas `hash` for the admin `user`: no new sessions are accepted on it and it
/// leaves the catalogue; the sessions recorded on it stay readable, replayable and scored (its
/// folder stays). Audited (`atlas.withdraw`). 404 for an atlas this server does not know, 409
/// for one withdrawn already. Returns the atlas' name.
pub async fn withdraw(s: &AppState, user: &User, hash: &str) -> Result<String, ApiError> {
    let entry = s
        .catalogue
        .get(hash)
        .ok_or_else(|| err(StatusCode::NOT_FOUND, "no atlas with this content hash on this server"))?;
    let name = entry.summary.name.clone();
    if entry.withdrawn() {
        return Err(err(
            StatusCode::CONFLICT,
            format!("the atlas {name} is withdrawn already"),
        ));
    }
    let detail = format!("{name} ({})", entry.origin.as_str());
    if !s.store.withdraw_atlas(hash, user, &detail).await? {
        return Err(err(
            StatusCode::CONFLICT,
            format!("the atlas {name} is withdrawn already"),
        ));
    }
    s.catalogue.set_withdrawn(hash, true);
    tracing::info!(atlas = %name, hash = %hash, by = %user.username, "atlas withdrawn");
    Ok(name)
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
    let root = s.published_dir();
    let dest = root.join(&hash);
    let storage = |e: std::io::Error| ApiError::from(Refusal::Storage(format!("{}: {e}", dest.display())));
    if dest.exists() {
        let aside = root.join(format!(".replaced-{hash}-{}", super::store::new_id()));
        tracing::warn!(dir = %dest.display(), aside = %aside.display(), "a folder of this hash was not in the catalogue; moved aside");
        std::fs::rename(&dest, &aside).map_err(storage)?;
    }
    std::fs::rename(incoming.path.join("atlas"), &dest).map_err(storage)?;
    // In the object storage before the row: every replica can fetch what the row publishes.
    if let Err(e) = s.storage.keep_folder(&format!("atlases/{hash}")).await {
        tracing::error!(atlas = %name, error = %e, "cannot put a published atlas into the object storage");
        let _ = std::fs::remove_dir_all(&dest);
        return Err(err(
            StatusCode::SERVICE_UNAVAILABLE,
            "the object storage cannot take the atlas now; try again shortly",
        ));
    }
    let dir = dest.display().to_string();
    let detail = format!("{name}: smoke test {}", smoke.join(", "));
    if let Err(e) = s.store.publish_atlas(&hash, &name, &dir, user, &detail).await {
        let _ = std::fs::remove_dir_all(&dest);
        return Err(e.into());
    }
    let mut atlas = checked.atlas;
    atlas.dir = dest;
    s.catalogue.insert(atlas, checked.scorer, AtlasOrigin::Published, false);
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
