//! Review traces on disk (`DATA/traces/xx/<sha>.json.zst`): derived data, written by the worker
//! when it scores a session and rebuilt by a replay whenever one is missing, unreadable, or of
//! another trace format or physics version. Deleting the folder loses nothing. With object
//! storage, a trace written by one replica is shared with the others through it.

use std::path::{Path, PathBuf};

use stylet_scoring::trace::{ReviewTrace, TRACE_VERSION};

use super::AppState;
use super::catalogue::LoadError;

/// Why a session's review trace cannot be had: the atlas, the file or the replay that rebuilds
/// it failed, or the server could not run the replay. Pages show the message (an error page, or a
/// note where the force curves would be).
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// The session's atlas is not known or cannot be loaded.
    #[error(transparent)]
    Atlas(#[from] LoadError),
    /// The session file cannot be read (not even its intact part).
    #[error("{}: {source}", path.display())]
    Unreadable {
        path: PathBuf,
        source: stylet_recorder::ReadError,
    },
    /// The replay refused the session (another atlas, another physics version, no rubric level).
    #[error(transparent)]
    Replay(#[from] stylet_scoring::ScoreError),
    /// The session file is not in the storage, or the object storage does not answer.
    #[error(transparent)]
    Storage(#[from] super::storage::StorageError),
    /// A blocking task reading or rebuilding the trace panicked or was cancelled.
    #[error("{0}")]
    Task(#[from] tokio::task::JoinError),
    /// No turn to replay: the server is shutting down.
    #[error("{0}")]
    Turn(#[from] tokio::sync::AcquireError),
}

/// Where the trace of the session file `sha` lives.
pub fn trace_path(data_dir: &Path, sha: &str) -> PathBuf {
    data_dir.join(super::storage::trace_key(sha))
}

/// Largest stored trace fetched from the object storage (traces take ~50 Hz of a session).
const MAX_TRACE_BYTES: u64 = 256 << 20;

/// Puts the trace of the session file `sha`, just written to the data directory, into the
/// object storage (when there is one), so that other replicas need not replay the session for
/// it. A cache: a failure is logged and costs a replay later.
pub async fn share_trace(state: &AppState, sha: &str) {
    if state.storage.url().is_none() {
        return;
    }
    if let Err(e) = state.storage.keep(&super::storage::trace_key(sha)).await {
        tracing::warn!(error = %e, "cannot put a review trace into the object storage");
    }
}

/// Writes atomically (a temporary file renamed into place).
pub fn write_trace(path: &Path, trace: &ReviewTrace) -> std::io::Result<()> {
    let json = serde_json::to_vec(trace).map_err(std::io::Error::other)?;
    let packed = zstd::encode_all(&json[..], 3)?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    // A name of its own: the worker and a page may write the same trace at once.
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = path.with_extension(format!("{}-{n}.partial", std::process::id()));
    std::fs::write(&tmp, packed)?;
    std::fs::rename(&tmp, path)
}

/// The stored trace, if it is there, readable and current.
pub fn read_trace(path: &Path) -> Option<ReviewTrace> {
    let packed = std::fs::read(path).ok()?;
    // Traces are small (~50 Hz of a session); a bigger one is not ours.
    let json = zstd::bulk::decompress(&packed, 256 << 20).ok()?;
    let trace: ReviewTrace = serde_json::from_slice(&json).ok()?;
    (trace.version == TRACE_VERSION && trace.physics_version == stylet_physics::PHYSICS_VERSION).then_some(trace)
}

/// Replays for pages (a trace missing from disk) run one at a time, beside the scoring workers:
/// viewers asking for many figures at once must not starve scoring.
static PAGE_REPLAYS: tokio::sync::Semaphore = tokio::sync::Semaphore::const_new(1);

/// The review trace of a stored session: from disk, else by replaying the file (then stored).
pub async fn review_trace(state: &AppState, file_sha256: &str, atlas_hash: &str) -> Result<ReviewTrace, TraceError> {
    let path = trace_path(&state.config.data_dir, file_sha256);
    let cached = || {
        let cached = path.clone();
        async move { tokio::task::spawn_blocking(move || read_trace(&cached)).await }
    };
    if let Some(t) = cached().await? {
        return Ok(t);
    }
    // Another replica may have stored it (a fetch error only costs the replay below).
    if state.storage.url().is_some()
        && state
            .storage
            .fetch(&super::storage::trace_key(file_sha256), MAX_TRACE_BYTES)
            .await
            .is_ok()
        && let Some(t) = cached().await?
    {
        return Ok(t);
    }
    let _turn = PAGE_REPLAYS.acquire().await?;
    // Whoever held the turn before may have replayed this very session.
    if let Some(t) = cached().await? {
        return Ok(t);
    }
    let scorer = super::shared_atlases::loaded(state, atlas_hash).await?.scorer;
    let file = state.session_copy(file_sha256).await?;
    let trace = tokio::task::spawn_blocking(move || {
        let session =
            stylet_recorder::reader::recover(&file).map_err(|source| TraceError::Unreadable { path: file, source })?;
        let (_, trace) = scorer.score_session_traced(&session)?;
        if let Err(e) = write_trace(&path, &trace) {
            tracing::warn!(error = %e, path = %path.display(), "cannot store a review trace");
        }
        Ok::<_, TraceError>(trace)
    })
    .await??;
    share_trace(state, file_sha256).await;
    Ok(trace)
}
