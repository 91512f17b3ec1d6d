//! Uploading a session file, from the request to the scoring queue: `POST /api/sessions`, the
//! dashboard's upload form and the demo's own sessions all go through [`accept_upload`]. Nothing
//! is stored until every check has passed, and the checks run cheapest and most decisive first,
//! in the order of this file:
//! 1. who asks: the route's extractor checks the login or token before the handler runs;
//! 2. before a byte of the body is read: the declared size, a free upload slot (per account and
//!    in all) and room on the disk;
//! 3. the first bytes only, until the session header is complete (a few records, nothing
//!    decompressed): they say who the session belongs to, so the uploader is authorised, and the
//!    header's fields are checked against what this server knows (atlas, difficulty, device,
//!    physics version);
//! 4. the rest, chunk by chunk at no less than the minimum rate ([`crate::intake`]), into a
//!    temporary file (its SHA-256 computed on the way), within the size limit;
//! 5. its ticks verified from that file, block by block;
//! 6. stored: the file by content hash, renamed into place, then the session and its scoring job
//!    in one transaction, and a scoring worker woken.
//!
//! The memory of an upload is one chunk and one tick block, whatever its size, and the number of
//! uploads at once is capped.

use std::sync::Arc;

use axum::Json;
use axum::body::{Body, Bytes};
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use futures_util::Stream;
use serde_json::json;
use stylet_recorder::SessionHeader;
use stylet_recorder::reader::{self, Damage, DamageKind, LimitExceeded, Limits, ReadError, Verified, VerifyError};

use super::AppState;
use super::error::{ApiError, err};
use super::extract::SimulatorActor;
use super::intake::{RatedBody, TempFile};
use super::store::{NewSession, Role, SessionStatus, User};

/// POST /api/sessions: the session file as `application/octet-stream`. Received and checked
/// before anything is stored (see the module doc): who asks, the size, an upload slot and room on
/// the disk before the body; who may upload the header's trainee and the header's fields from
/// its first bytes; then the rest to a temporary file and the recorder's strict reader streaming
/// its ticks within the upload limits.
#[utoipa::path(post, path = "/api/sessions", tag = "sessions",
    summary = "Upload a session file",
    description = "API tokens of either scope may upload (the desktop simulator). Checked before anything is stored: who asks, the size, an upload slot (per account and in all) and room on the disk before the body; who may upload the header's trainee and the header's fields from its first bytes; then the rest, at no less than the minimum rate, verified from disk.",
    request_body(content = Vec<u8>, content_type = "application/octet-stream"),
    responses(
        (status = 201, description = "new bytes: stored and queued for scoring", body = UploadAnswer),
        (status = 200, description = "the same bytes were uploaded before", body = UploadAnswer),
        (status = 400, description = "empty body, or the body broke off", body = super::openapi::ErrorBody),
        (status = 403, description = "may not upload for this trainee, the trainee's account is disabled, or CSRF token missing", body = super::openapi::ErrorBody),
        (status = 413, description = "over the size limit (--max-upload-bytes)", body = super::openapi::ErrorBody),
        (status = 422, description = "not a valid session file, an unknown or withdrawn atlas, an unknown trainee, scenario, difficulty or device, or more than the server replays", body = super::openapi::ErrorBody),
        (status = 429, description = "this account has as many uploads in progress as it may; Retry-After", body = super::openapi::ErrorBody),
        (status = 503, description = "the server takes as many uploads as it can, or its disk is too full; Retry-After", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn upload(
    State(s): State<Arc<AppState>>,
    SimulatorActor(user): SimulatorActor,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let (id, status, created) = accept_upload(&s, &user, body.into_data_stream(), content_length(&headers)).await?;
    let code = if created { StatusCode::CREATED } else { StatusCode::OK };
    Ok((code, Json(json!({ "id": id, "status": status }))).into_response())
}

/// An upload's session: its id and where it is on its way to a score.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct UploadAnswer {
    pub id: String,
    pub status: SessionStatus,
}

/// The request's `Content-Length`, if it sent a valid one.
pub fn content_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
}

/// [`accept_upload`] of a file already in memory (the demo's own sessions).
pub async fn accept_upload_bytes(
    s: &AppState,
    user: &User,
    bytes: Vec<u8>,
) -> Result<(String, SessionStatus, bool), ApiError> {
    let len = bytes.len() as u64;
    let body = futures_util::stream::iter([Ok::<_, std::convert::Infallible>(Bytes::from(bytes))]);
    accept_upload(s, user, body, Some(len)).await
}

/// Receives an upload `body` (its chunks), checks it and stores it (the file by content hash,
/// renamed into place, then the session and job rows): returns the session id, its status and
/// whether it is new. Nothing is left behind on refusal.
pub async fn accept_upload<S, E>(
    s: &AppState,
    user: &User,
    body: S,
    declared: Option<u64>,
) -> Result<(String, SessionStatus, bool), ApiError>
where
    S: Stream<Item = Result<Bytes, E>> + Unpin,
    E: std::fmt::Display,
{
    use super::telemetry::{UPLOADS, count};
    let checked = match receive(s, user, body, declared).await {
        Ok(checked) => checked,
        Err(e) => {
            count(UPLOADS, "refused");
            return Err(e);
        }
    };
    let kept = keep(s, user, checked).await;
    count(
        UPLOADS,
        match &kept {
            Ok((_, _, true)) => "stored",
            Ok((_, _, false)) => "duplicate",
            Err(_) => "refused",
        },
    );
    kept
}

/// Most bytes read for the session header before the upload is refused (the writer's header
/// takes about a kilobyte: its fields are bounded by the format).
pub const MAX_HEADER_BYTES: usize = 64 << 10;

/// A received and checked upload: its header, the trainee it belongs to, what verification
/// found, and the file (temporary until stored; removed if dropped).
struct CheckedUpload {
    header: SessionHeader,
    trainee: User,
    verified: Verified,
    file: TempFile,
    sha256: String,
}

/// Receives the upload `body` of `user` (`declared`: its Content-Length, if sent) and runs every
/// check (see the module doc); the error says what was wrong, and nothing is left behind.
async fn receive<S, E>(s: &AppState, user: &User, body: S, declared: Option<u64>) -> Result<CheckedUpload, ApiError>
where
    S: Stream<Item = Result<Bytes, E>> + Unpin,
    E: std::fmt::Display,
{
    let limit = s.config.max_upload_bytes as u64;
    let too_large = || {
        err(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("the upload exceeds the limit of {limit} bytes"),
        )
    };
    if declared.is_some_and(|n| n > limit) {
        return Err(too_large());
    }
    let limits = &s.config.limits;
    let slot = super::upload_hold::take(s, &user.id).await?;
    let room = s.disk.reserve(
        &s.config.data_dir,
        declared.unwrap_or(limit),
        limits.min_free_disk_bytes,
    )?;
    let mut body = RatedBody::new(body, limits.min_upload_bytes_per_s);
    // The first bytes, until the header is complete; then who may send it and what it says.
    let mut head: Vec<u8> = Vec::new();
    let checked = async {
        let header = loop {
            if let Some(h) = reader::read_header_prefix(&head).map_err(invalid)? {
                break h;
            }
            if head.len() >= MAX_HEADER_BYTES {
                return Err(invalid(format_args!(
                    "no session header in its first {MAX_HEADER_BYTES} bytes"
                )));
            }
            match body.next().await? {
                Some(chunk) => head.extend_from_slice(&chunk),
                None if head.is_empty() => {
                    return Err(err(
                        StatusCode::BAD_REQUEST,
                        "the request body is empty: send the session file",
                    ));
                }
                None => return Err(invalid("the file ends before its session header is complete")),
            }
        };
        let trainee = authorise(s, user, &header.trainee).await?;
        // An atlas published at another replica since this one last synced its catalogue.
        if s.catalogue.get(&header.atlas_hash).is_none() {
            super::shared_atlases::adopt(s, &header.atlas_hash).await;
        }
        check_header(s, &header)?;
        Ok((header, trainee))
    }
    .await;
    let (header, trainee) = match checked {
        Ok(pair) => pair,
        Err(refused) => {
            // Refused from the first bytes: the rest is read and dropped (holding no upload slot
            // and no room on the disk; for at most the request timeout) before the answer, so
            // that a client that sends its whole body before reading the answer (most do) reads
            // the refusal, not a broken pipe. A body sent too slowly is not waited for.
            slot.release().await;
            drop(room);
            if refused.status() != StatusCode::REQUEST_TIMEOUT {
                let _ = tokio::time::timeout(limits.request_timeout, discard(&mut body, limit)).await;
            }
            return Err(refused);
        }
    };
    let _room = room;
    // The rest, to a temporary file.
    let mut file = TempFile::create(&incoming_dir(s)).await?;
    if head.len() as u64 > limit {
        return Err(too_large());
    }
    file.write(&head).await?;
    drop(head);
    while let Some(chunk) = body.next().await? {
        if file.bytes + chunk.len() as u64 > limit {
            return Err(too_large());
        }
        file.write(&chunk).await?;
    }
    let sha256 = file.finish().await?;
    let verified = verify(s, &file, &header).await?;
    slot.release().await;
    Ok(CheckedUpload {
        header,
        trainee,
        verified,
        file,
        sha256,
    })
}

/// Who may upload a session of `trainee_name`: the trainee themself, an instructor of their
/// cohort, an admin; never for a disabled account. "No such trainee" and "not yours" get the
/// same answer unless the caller may see every account (admins), so an upload cannot probe which
/// accounts exist.
async fn authorise(s: &AppState, user: &User, trainee_name: &str) -> Result<User, ApiError> {
    let refused = || {
        err(
            StatusCode::FORBIDDEN,
            format!("{} may not upload sessions of trainee '{trainee_name}'", user.username),
        )
    };
    let disabled = || {
        err(
            StatusCode::FORBIDDEN,
            format!("the account of trainee '{trainee_name}' is disabled: an admin must enable it first"),
        )
    };
    let trainee = || async {
        Ok::<_, ApiError>(
            s.store
                .account_by_name(trainee_name)
                .await?
                .filter(|(t, _)| t.role == Role::Trainee),
        )
    };
    match user.role {
        Role::Trainee if user.username == trainee_name => Ok(user.clone()),
        Role::Instructor => match trainee().await? {
            Some((t, is_disabled)) if s.store.teaches(&user.id, &t.id).await? => {
                if is_disabled {
                    Err(disabled())
                } else {
                    Ok(t)
                }
            }
            _ => Err(refused()),
        },
        Role::Admin => match trainee().await? {
            Some((_, true)) => Err(disabled()),
            Some((t, false)) => Ok(t),
            None => Err(err(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!("the session's trainee '{trainee_name}' has no trainee account"),
            )),
        },
        _ => Err(refused()),
    }
}

/// The header's fields against what this server knows; 422 with the reason.
fn check_header(s: &AppState, h: &SessionHeader) -> Result<(), ApiError> {
    let bad = |m: String| err(StatusCode::UNPROCESSABLE_ENTITY, m);
    let Some(atlas) = s.catalogue.get(&h.atlas_hash) else {
        return Err(bad(format!(
            "the session was recorded on atlas '{}' ({}), which this server does not know",
            h.atlas_id, h.atlas_hash
        )));
    };
    if atlas.withdrawn() {
        return Err(bad(format!(
            "the session was recorded on atlas '{}' ({}), which was withdrawn from this server: it takes no new sessions",
            h.atlas_id, h.atlas_hash
        )));
    }
    // The limits on an upload's ticks follow from its rate: only the rate the simulator runs at.
    if h.tick_rate_hz != stylet_physics::DEFAULT_TICK_RATE_HZ {
        return Err(bad(format!(
            "the session ticks at {} Hz; this server accepts {} Hz",
            h.tick_rate_hz,
            stylet_physics::DEFAULT_TICK_RATE_HZ
        )));
    }
    if let Err(e) = h.difficulty.parse::<stylet_scoring::Difficulty>() {
        return Err(bad(e.to_string()));
    }
    if stylet_physics::DeviceProfile::by_name(&h.device).is_none() {
        let known: Vec<&str> = stylet_physics::DeviceProfile::ALL.iter().map(|d| d.name).collect();
        return Err(bad(format!("unknown device '{}' ({})", h.device, known.join(", "))));
    }
    if h.physics_version != stylet_physics::PHYSICS_VERSION {
        return Err(bad(format!(
            "the session was recorded with physics version {}; this server replays version {}",
            h.physics_version,
            stylet_physics::PHYSICS_VERSION
        )));
    }
    // A scoring worker replays the deformation the header asks for: no more than the
    // simulator's default costs, in memory and in work per tick.
    let (asked, budget) = (h.deformation.cost(), stylet_physics::DeformCost::replay_budget());
    if !asked.within(&budget) {
        return Err(bad(format!(
            "the session's tissue deformation ({} cells, a solve every {} ticks) costs {:.1}× the work per tick \
             and {:.1}× the memory this server allows (the simulator's default, with a quarter's headroom for work)",
            h.deformation.cells,
            h.deformation.every_ticks,
            asked.node_updates_per_tick / budget.node_updates_per_tick,
            asked.nodes as f64 / budget.nodes as f64,
        )));
    }
    // Likewise the contrast agent's diffusion: no more steps over the duct network per tick.
    let contrast = stylet_physics::ContrastSettings::default();
    if h.contrast.steps_per_tick() > contrast.steps_per_tick() {
        return Err(bad(format!(
            "the session's contrast agent ({} diffusion steps every {} ticks) costs {:.1}× the work per tick \
             of the simulator's default ({} every {}); this server replays at most the default",
            h.contrast.steps_per_update,
            h.contrast.update_every_ticks,
            h.contrast.steps_per_tick() / contrast.steps_per_tick(),
            contrast.steps_per_update,
            contrast.update_every_ticks,
        )));
    }
    if !atlas.summary.knows_scenario(&h.scenario) {
        return Err(bad(format!(
            "unknown scenario '{}' for atlas '{}' (its scenarios: {})",
            h.scenario,
            h.atlas_id,
            atlas.summary.scenarios.join(", ")
        )));
    }
    Ok(())
}

/// Reads and drops what is left of `body`, at most `limit` bytes in all, at no less than the
/// minimum rate; stops at the first error.
async fn discard<S, E>(body: &mut RatedBody<S>, limit: u64)
where
    S: Stream<Item = Result<Bytes, E>> + Unpin,
    E: std::fmt::Display,
{
    while body.received <= limit {
        match body.next().await {
            Ok(Some(_)) => {}
            Ok(None) | Err(_) => break,
        }
    }
}

/// Verifies the received file's ticks, streaming from disk within the upload limits.
async fn verify(s: &AppState, file: &TempFile, header: &SessionHeader) -> Result<Verified, ApiError> {
    let limits = Limits::for_upload(file.bytes, header.tick_rate_hz, s.config.limits.max_session_s);
    let path = file.path.clone();
    // At most a few verifications at once: each holds a chunk and a block in memory.
    // The permit goes with the thread: a request dropped meanwhile still counts until it ends.
    let permit = s.verify_permits.clone().acquire_owned().await.map_err(|_| busy())?;
    let verified = tokio::task::spawn_blocking(move || {
        let _permit = permit;
        let f = std::fs::File::open(&path).map_err(|e| VerifyError::Read(ReadError::Io(e.to_string())))?;
        reader::verify_file_streaming(std::io::BufReader::with_capacity(64 << 10, f), &limits)
    })
    .await
    .map_err(|_| err(StatusCode::INTERNAL_SERVER_ERROR, "validation failed"))?
    .map_err(|e| {
        let too_long = matches!(
            &e,
            VerifyError::Read(ReadError::Damaged(Damage {
                what: DamageKind::OverLimit(LimitExceeded::Ticks(_)),
                ..
            }))
        );
        let hint = if too_long {
            format!(
                " (this server accepts sessions of up to {} minutes)",
                s.config.limits.max_session_s / 60
            )
        } else {
            // A cut or damaged recording: what was saved can still be kept (and reviewed; it is
            // not gradeable).
            " — if the recording was cut off or damaged, run `stylet session recover FILE --out FIXED.mcap` \
             and upload the recovered file: it keeps what was saved and is shown as not gradeable"
                .to_string()
        };
        invalid(format_args!("{e}{hint}"))
    })?;
    if &verified.session.header != header {
        return Err(invalid("it holds more than one session header"));
    }
    Ok(verified)
}

/// Stores a checked upload of `user` and queues it for scoring: the file by content hash (renamed
/// into place), then the session and its scoring job in one transaction, and a worker woken.
/// Bytes uploaded before give the session they were stored as.
async fn keep(s: &AppState, user: &User, checked: CheckedUpload) -> Result<(String, SessionStatus, bool), ApiError> {
    let (h, trainee) = (&checked.header, &checked.trainee);
    let sha = checked.sha256.clone();
    let existing = |id: String| async move {
        let status = s
            .store
            .session(&id)
            .await?
            .map_or(SessionStatus::Queued, |(r, _)| r.status);
        Ok::<_, ApiError>((id, status, false))
    };
    if let Some(id) = s.store.session_by_file(&sha).await? {
        return existing(id).await;
    }
    // The file first (renamed into place by content hash: two uploads of the same bytes may
    // race here, and either rename leaves the same bytes), then the rows in one transaction.
    let new = NewSession {
        file_sha256: sha.clone(),
        size_bytes: checked.file.bytes as i64,
        session_uuid: h.session_id.clone(),
        trainee_id: trainee.id.clone(),
        uploaded_by: user.id.clone(),
        scenario: h.scenario.clone(),
        difficulty: h.difficulty.clone(),
        atlas_hash: h.atlas_hash.clone(),
        physics_version: h.physics_version as i64,
        duration_s: checked.verified.duration_s(),
        recorded_at: h.wall_clock_start.clone(),
        request_id: super::server::current_request_id(),
    };
    checked.file.persist(&s.session_file(&sha)).await?;
    // In the object storage before the row names it: a row never points at a missing object.
    s.storage.keep(&super::storage::session_key(&sha)).await.map_err(|e| {
        tracing::error!(sha256 = %sha, error = %e, "cannot put an upload into the object storage");
        err(
            StatusCode::SERVICE_UNAVAILABLE,
            "the object storage cannot take the file now; try again shortly",
        )
    })?;
    let id = match s.store.insert_session(&new).await {
        Ok(id) => id,
        Err(e) => {
            // Lost a race with an upload of the same bytes: that row owns the file now.
            if let Some(id) = s.store.session_by_file(&new.file_sha256).await? {
                return existing(id).await;
            }
            // The file stays: a concurrent upload of the same bytes whose row is not committed
            // yet may own it. Unreferenced, it is only reused by the next upload of these bytes.
            tracing::error!(sha256 = %new.file_sha256, "upload stored but its row was not written");
            return Err(e.into());
        }
    };
    metrics::counter!(super::telemetry::UPLOAD_BYTES).increment(new.size_bytes.max(0) as u64);
    s.wake.notify_one();
    Ok((id, SessionStatus::Queued, true))
}

/// The folder uploads arrive in, on the data directory's file system (a rename stores them).
fn incoming_dir(s: &AppState) -> std::path::PathBuf {
    s.config.data_dir.join("sessions").join(".incoming")
}

fn invalid(e: impl std::fmt::Display) -> ApiError {
    err(
        StatusCode::UNPROCESSABLE_ENTITY,
        format!("not a valid session file: {e}"),
    )
}

fn busy() -> ApiError {
    err(StatusCode::SERVICE_UNAVAILABLE, "the server is shutting down")
}
