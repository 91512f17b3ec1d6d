//! Stylet's scoring service, `stylet-service` (`stylet serve`; docs/api.md, docs/security.md): a
//! JSON API over axum that takes session files, validates them with the recorder's reader before
//! anything is stored, keeps them by content hash, and scores them by replay on a worker pool whose
//! jobs live in the database (a restart resumes them; a session is never scored twice).
//!
//! [`api`] assembles the router from one module per resource, each with its handlers: [`health`],
//! [`openapi`], [`logins`], [`tokens`], [`users`], [`atlases`], [`upload`] (the whole upload, from
//! the request to the scoring queue), [`sessions`], [`review`], [`experts`], [`reports`] and
//! [`export`]. Layers and the connection loop are [`server`]'s; docs/architecture.md lists the
//! rest.

pub mod access;
pub mod admin;
pub mod api;
pub mod atlases;
pub mod auth;
pub mod backup;
pub mod catalogue;
pub mod disk;
pub mod error;
pub mod experts;
pub mod export;
pub mod extract;
pub mod health;
pub mod housekeeping;
pub mod intake;
pub mod limits;
pub mod list_query;
pub mod local_copies;
pub mod logins;
pub mod lti;
pub mod openapi;
pub mod pairing;
pub mod publish;
pub mod reports;
pub mod review;
pub mod server;
pub mod sessions;
pub mod shared_atlases;
pub mod slots;
pub mod storage;
pub mod store;
pub mod telemetry;
pub mod tokens;
pub mod traces;
pub mod upload;
pub mod upload_hold;
pub mod users;
pub mod worker;
pub mod xapi;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub use limits::Limits;
pub use store::{Store, StoreError};

/// Settings of a running service.
#[derive(Debug, Clone)]
pub struct Config {
    pub bind: String,
    /// Where the admin port listens (`/metrics`, `/livez`, `/readyz`); none by default.
    pub admin_bind: Option<String>,
    pub data_dir: PathBuf,
    /// Default: SQLite `stylet.db` in the data directory.
    pub database_url: Option<String>,
    /// Object storage for session files, traces and published atlases (`s3://bucket/prefix`);
    /// default: the data directory ([`storage::Storage`]).
    pub storage_url: Option<String>,
    /// Directory of atlas directories sessions may use.
    pub atlases_dir: Option<PathBuf>,
    pub workers: usize,
    pub max_upload_bytes: usize,
    /// Mark cookies Secure (behind TLS).
    pub secure_cookies: bool,
    /// Limits and timeouts (docs/security.md).
    pub limits: Limits,
    /// The Learning Record Store the scored sessions' xAPI statements go to; none by default.
    pub lrs: Option<xapi::LrsConfig>,
}

impl Config {
    pub fn database_url(&self) -> String {
        self.database_url.clone().unwrap_or_else(|| sqlite_url(&self.data_dir))
    }
}

/// Shared state of the handlers and workers.
pub struct AppState {
    pub store: Store,
    /// Where session files, traces and published atlases are kept.
    pub storage: storage::Storage,
    pub config: Config,
    /// Every known atlas and its scorer, by content hash (configured and published ones); the
    /// loaded ones in a cache bounded by bytes.
    pub catalogue: Arc<catalogue::Catalogue>,
    /// One atlas publication checked and kept at a time (each loads a whole CT and replays its
    /// smoke test). Archives arrive without it (as uploads: [`AppState::upload_slots`]).
    pub publish_permit: Arc<tokio::sync::Semaphore>,
    pub wake: tokio::sync::Notify,
    /// Password checks, off the async threads, with a bounded queue.
    pub passwords: logins::PasswordPool,
    /// The last health check (it writes; at most once a second).
    pub health: store::health::Health,
    /// Upload verifications running at once (each holds a chunk and a tick block in memory).
    pub verify_permits: Arc<tokio::sync::Semaphore>,
    /// Uploads being received (sessions and atlas archives), in all and per account.
    pub upload_slots: Arc<slots::Slots>,
    /// Requests in flight per account.
    pub request_slots: Arc<slots::Slots>,
    /// Disk space reserved by the uploads arriving now.
    pub disk: Arc<disk::DiskBudget>,
    /// The OpenAPI document (set when the router is built).
    pub openapi: std::sync::OnceLock<serde_json::Value>,
    /// Set once the server is asked to stop: the worker claims no more jobs, `/readyz` says
    /// 503 while the requests in flight finish.
    pub stopping: std::sync::atomic::AtomicBool,
    /// The admin port's address, when it has one.
    pub admin_addr: Option<SocketAddr>,
    /// LTI key sets, grade-service tokens and the tool's key ([`lti`]).
    pub lti: lti::LtiCache,
}

impl AppState {
    pub fn session_file(&self, sha: &str) -> PathBuf {
        session_file(&self.config.data_dir, sha)
    }

    /// The local path of the session file `sha`, fetched from the object storage first when
    /// this replica has no copy yet (at most the largest upload).
    pub async fn session_copy(&self, sha: &str) -> Result<PathBuf, storage::StorageError> {
        let path = self
            .storage
            .fetch(&storage::session_key(sha), self.config.max_upload_bytes as u64)
            .await?;
        if self.storage.url().is_some() {
            local_copies::mark_used(&path);
        }
        Ok(path)
    }

    /// Where published atlases live: `DATA/atlases/<content hash>/`.
    pub fn published_dir(&self) -> PathBuf {
        published_dir(&self.config.data_dir)
    }
}

/// This server's name among the replicas on its database: kept in `DATA/replica-id` (made on
/// the first start), so that a restart knows which running jobs were its own. Each replica has a
/// data directory of its own (one server serves a data directory).
fn replica_name(data_dir: &Path) -> Result<String, String> {
    let file = data_dir.join("replica-id");
    match std::fs::read_to_string(&file) {
        Ok(s)
            if !s.trim().is_empty()
                && s.trim().len() <= 64
                && s.trim().bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-') =>
        {
            Ok(s.trim().to_string())
        }
        Ok(_) => Err(format!(
            "{}: not a replica name (letters, digits and -, at most 64)",
            file.display()
        )),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let name = store::new_id();
            let tmp = data_dir.join("replica-id.tmp");
            std::fs::write(&tmp, format!("{name}\n"))
                .and_then(|()| std::fs::rename(&tmp, &file))
                .map_err(|e| format!("{}: {e}", file.display()))?;
            Ok(name)
        }
        Err(e) => Err(format!("{}: {e}", file.display())),
    }
}

/// `DATA/sessions/aa/<sha256>.mcap`: where the service whose data directory is `data_dir` keeps
/// the session file of content hash `sha` (a SHA-256 in hex).
pub fn session_file(data_dir: &Path, sha: &str) -> PathBuf {
    data_dir.join(storage::session_key(sha))
}

/// The default database of the service whose data directory is `data_dir`: SQLite `stylet.db`
/// in it.
pub fn sqlite_url(data_dir: &Path) -> String {
    format!("sqlite://{}?mode=rwc", data_dir.join("stylet.db").display())
}

/// `DATA/atlases`: the published atlases of the service whose data directory is `data_dir`.
pub fn published_dir(data_dir: &std::path::Path) -> PathBuf {
    data_dir.join("atlases")
}

#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Storage(#[from] storage::StorageError),
    #[error("{0}")]
    Setup(String),
}

/// Routes mounted beside the API (the dashboard's pages), built from the shared state, and the
/// part of the OpenAPI document they add (the routes programs call: the player's frames).
#[derive(Clone, Copy)]
pub struct Mount {
    pub router: fn(Arc<AppState>) -> axum::Router,
    pub openapi: fn() -> utoipa::openapi::OpenApi,
}

/// Opens the store (migrations), loads the atlases, resumes unfinished jobs and serves the API
/// and whatever `mount` adds until the process ends. `ready` gets the bound address (port 0
/// picks a free one) and the shared state, once the server accepts connections.
pub async fn serve(
    config: Config,
    mount: Option<Mount>,
    ready: impl FnOnce(SocketAddr, Arc<AppState>),
) -> Result<(), ServiceError> {
    let setup = |e: &dyn std::fmt::Display| ServiceError::Setup(e.to_string());
    std::fs::create_dir_all(config.data_dir.join("sessions"))
        .map_err(|e| setup(&format!("{}: {e}", config.data_dir.display())))?;
    let replica = replica_name(&config.data_dir).map_err(|e| setup(&e))?;
    let storage = storage::Storage::open(&config.data_dir, config.storage_url.as_deref())?;
    let store = Store::open(&config.database_url()).await?.with_replica(&replica);
    let catalogue = Arc::new(catalogue::Catalogue::new(config.limits.atlas_cache_bytes));
    // The configured directory's atlases, then the published ones the database records (a
    // folder of the atlas store without its publication record is not served). Loaded one at
    // a time: the catalogue's cache keeps what fits its budget.
    let configured = match config.atlases_dir.clone() {
        Some(dir) => atlas_dirs(&dir)?,
        None => Vec::new(),
    };
    let rows = store.atlas_rows().await?;
    let published_root = published_dir(&config.data_dir);
    let published = publish::published_dirs(&published_root, |hash| {
        rows.iter().any(|r| r.content_hash == hash && r.published_at.is_some())
    })
    .map_err(|e| setup(&e))?;
    let all = configured
        .into_iter()
        .map(|d| (d, catalogue::AtlasOrigin::Configured))
        .chain(published.into_iter().map(|d| (d, catalogue::AtlasOrigin::Published)));
    for (dir, origin) in all {
        let shown = dir.display().to_string();
        let loaded = tokio::task::spawn_blocking(move || load_atlas(&dir))
            .await
            .map_err(|e| setup(&e))?;
        let (atlas, scorer) = match (loaded, origin) {
            (Ok(pair), _) => pair,
            // The operator's own directory must load; a published atlas that no longer does is
            // logged and left out (its sessions say the atlas is not loaded).
            (Err(e), catalogue::AtlasOrigin::Configured) => return Err(e),
            (Err(e), catalogue::AtlasOrigin::Published) => {
                tracing::error!(dir = %shown, error = %e, "a published atlas cannot be loaded; not served");
                continue;
            }
        };
        if origin == catalogue::AtlasOrigin::Published
            && Some(atlas.content_hash.as_str()) != atlas.dir.file_name().and_then(|n| n.to_str())
        {
            tracing::error!(dir = %shown, hash = %atlas.content_hash, "a published atlas no longer has the content hash it was published with; not served");
            continue;
        }
        store
            .register_atlas(
                &atlas.content_hash,
                &atlas.manifest.name,
                &atlas.dir.display().to_string(),
            )
            .await?;
        let withdrawn = rows
            .iter()
            .any(|r| r.content_hash == atlas.content_hash && r.withdrawn_at.is_some());
        tracing::info!(atlas = %atlas.manifest.name, hash = %atlas.content_hash, origin = origin.as_str(), withdrawn, "atlas ready");
        catalogue.insert(atlas, scorer, origin, withdrawn);
    }
    let requeued = store.release_own_leases().await?;
    if requeued > 0 {
        tracing::info!(requeued, %replica, "resuming scoring jobs this replica's previous run left unfinished");
    }
    // Its previous run's uploads ended with it.
    store.release_own_upload_slots().await?;
    let listener = tokio::net::TcpListener::bind(&config.bind)
        .await
        .map_err(|e| setup(&format!("cannot bind {}: {e}", config.bind)))?;
    let addr = listener.local_addr().map_err(|e| setup(&e))?;
    let admin = match &config.admin_bind {
        Some(bind) => {
            let metrics = telemetry::install().map_err(|e| setup(&format!("metrics: {e}")))?;
            let admin_listener = tokio::net::TcpListener::bind(bind)
                .await
                .map_err(|e| setup(&format!("cannot bind the admin port {bind}: {e}")))?;
            Some((admin_listener, metrics))
        }
        None => None,
    };
    let admin_addr = match &admin {
        Some((l, _)) => Some(l.local_addr().map_err(|e| setup(&e))?),
        None => None,
    };
    let passwords = logins::PasswordPool::new(config.limits.password_threads, config.limits.password_queue);
    let upload_slots = slots::Slots::new(
        "uploads",
        config.limits.max_uploads,
        config.limits.max_uploads_per_account,
    );
    let request_slots = slots::Slots::new("requests", usize::MAX, config.limits.max_requests_per_account);
    // Uploads cut short by a crash or a kill leave their temporary files here.
    let incoming = config.data_dir.join("sessions").join(".incoming");
    let _ = std::fs::remove_dir_all(&incoming);
    std::fs::create_dir_all(&incoming).map_err(|e| setup(&format!("{}: {e}", incoming.display())))?;
    let state = Arc::new(AppState {
        store,
        storage,
        config,
        catalogue,
        publish_permit: Arc::new(tokio::sync::Semaphore::new(1)),
        wake: tokio::sync::Notify::new(),
        passwords,
        health: Default::default(),
        verify_permits: Arc::new(tokio::sync::Semaphore::new(
            std::thread::available_parallelism().map_or(1, |n| n.get()),
        )),
        upload_slots,
        request_slots,
        disk: Default::default(),
        openapi: Default::default(),
        stopping: Default::default(),
        admin_addr,
        lti: Default::default(),
    });
    // Atlases published at other replicas (fetched from the object storage).
    shared_atlases::sync(&state).await;
    worker::start(state.clone());
    housekeeping::start(state.clone());
    if let Some(lrs) = state.config.lrs.clone() {
        xapi::run(state.clone(), lrs);
    }
    lti::grades::run(state.clone());
    let mut app = api::router(state.clone(), mount.map(|m| (m.openapi)()));
    if let Some(mount) = mount {
        app = app.merge((mount.router)(state.clone()));
    }
    let limits = Arc::new(state.config.limits.clone());
    let max_upload = state.config.max_upload_bytes as u64;
    ready(addr, state.clone());
    let serving = Arc::new(tokio::sync::Semaphore::new(limits.max_requests.max(1)));
    let app = app
        .layer(axum::extract::DefaultBodyLimit::max(limits.max_json_body_bytes))
        .layer(axum::middleware::from_fn(server::in_flight))
        .layer(axum::middleware::from_fn(server::json_errors))
        .layer(axum::middleware::from_fn_with_state(
            (limits.clone(), max_upload),
            server::deadline,
        ))
        .layer(axum::middleware::from_fn_with_state(serving, server::serving))
        .layer(axum::middleware::from_fn_with_state(
            slots::Slots::new("requests", usize::MAX, limits.max_requests_per_account),
            server::per_credential,
        ))
        .layer(axum::middleware::from_fn(server::security_headers))
        .layer(axum::middleware::from_fn(server::request_log));
    // The admin port serves until the API has finished its requests in flight, saying "not
    // ready" meanwhile, so that a load balancer stops sending traffic first.
    let (admin_done, admin_stop) = tokio::sync::oneshot::channel::<()>();
    let admin_task = admin.map(|(admin_listener, metrics)| {
        let (app, limits) = (admin::router(state.clone(), metrics), limits.clone());
        tokio::spawn(async move {
            let stop = async {
                let _ = admin_stop.await;
            };
            if let Err(e) = server::run(admin_listener, app, &limits, stop).await {
                tracing::error!(error = %e, "the admin port failed");
            }
        })
    });
    let stopping = state.clone();
    let stop = async move {
        server::stop_signal().await;
        // From now on: no more jobs claimed, and `/readyz` says 503.
        stopping.stopping.store(true, std::sync::atomic::Ordering::SeqCst);
    };
    server::run(listener, app, &limits, stop).await.map_err(|e| setup(&e))?;
    let _ = admin_done.send(());
    if let Some(task) = admin_task {
        let _ = task.await;
    }
    // Stopped: the running jobs go back to the queue for the other replicas (or this one
    // restarted) rather than waiting out their leases.
    state.stopping.store(true, std::sync::atomic::Ordering::SeqCst);
    let released = state.store.release_own_leases().await?;
    state.store.release_own_upload_slots().await?;
    tracing::info!(released, "stopped");
    Ok(())
}

/// The atlas directories (with an `atlas.toml`) in `dir`, sorted; at least one.
fn atlas_dirs(dir: &std::path::Path) -> Result<Vec<PathBuf>, ServiceError> {
    let err = |e: &dyn std::fmt::Display| ServiceError::Setup(format!("{}: {e}", dir.display()));
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| err(&e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("atlas.toml").is_file())
        .collect();
    dirs.sort();
    if dirs.is_empty() {
        return Err(err(&"no atlas directories (with atlas.toml) in it"));
    }
    Ok(dirs)
}

/// Loads the atlas in `dir` and its scorer.
pub(crate) fn load_atlas(dir: &std::path::Path) -> Result<(stylet_atlas::Atlas, stylet_scoring::Scorer), ServiceError> {
    let atlas = stylet_atlas::load(dir).map_err(|e| ServiceError::Setup(e.to_string()))?;
    let scorer = stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None)
        .map_err(|e| ServiceError::Setup(e.to_string()))?;
    Ok((atlas, scorer))
}
