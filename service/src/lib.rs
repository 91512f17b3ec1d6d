//! Stylet's scoring service, `stylet-service` (`stylet serve`; DESIGN.md "Service and security"): a JSON API over axum
//! that takes session files, validates them with the recorder's reader before anything is
//! stored, keeps them by content hash, and scores them by replay on a worker pool whose jobs live
//! in the database (a restart resumes them; a session is never scored twice).

pub mod api;
pub mod auth;
pub mod experts;
pub mod export;
pub mod limits;
pub mod logins;
pub mod openapi;
pub mod server;
pub mod store;
pub mod tokens;
pub mod traces;
pub mod upload;
pub mod users;
pub mod worker;

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

pub use limits::Limits;
pub use store::{Store, StoreError};

/// Settings of a running service.
#[derive(Debug, Clone)]
pub struct Config {
    pub bind: String,
    pub data_dir: PathBuf,
    /// Default: SQLite `stylet.db` in the data directory.
    pub database_url: Option<String>,
    /// Directory of atlas directories sessions may use.
    pub atlases_dir: Option<PathBuf>,
    pub workers: usize,
    pub max_upload_bytes: usize,
    /// Mark cookies Secure (behind TLS).
    pub secure_cookies: bool,
    /// Limits and timeouts (docs/security.md).
    pub limits: Limits,
}

impl Config {
    pub fn database_url(&self) -> String {
        self.database_url
            .clone()
            .unwrap_or_else(|| format!("sqlite://{}?mode=rwc", self.data_dir.join("stylet.db").display()))
    }
}

/// Shared state of the handlers and workers.
pub struct AppState {
    pub store: Store,
    pub config: Config,
    /// One scorer per known atlas, by content hash.
    pub scorers: BTreeMap<String, Arc<stylet_scoring::Scorer>>,
    /// The same atlases with their manifests (presets, scenarios' C-arms), by content hash, for
    /// pictures drawn as `stylet render` draws them; the volumes are shared with the scorers.
    pub atlases: BTreeMap<String, Arc<stylet_atlas::Atlas>>,
    pub wake: tokio::sync::Notify,
    /// Recent failed logins per account (rate limiting), bounded.
    pub login_failures: logins::FailedLogins,
    /// Password checks, off the async threads, with a bounded queue.
    pub passwords: logins::PasswordPool,
    /// The last health check (it writes; at most once a second).
    pub health: store::health::Health,
    /// Upload verifications running at once (each holds a chunk and a tick block in memory).
    pub verify_permits: Arc<tokio::sync::Semaphore>,
}

impl AppState {
    pub fn session_file(&self, sha: &str) -> PathBuf {
        self.config
            .data_dir
            .join("sessions")
            .join(&sha[..2])
            .join(format!("{sha}.mcap"))
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("{0}")]
    Setup(String),
}

/// Routes mounted beside the API (the dashboard's pages), built from the shared state.
pub type Mount = fn(Arc<AppState>) -> axum::Router;

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
    let store = Store::open(&config.database_url()).await?;
    let mut scorers = BTreeMap::new();
    let mut atlases = BTreeMap::new();
    if let Some(dir) = &config.atlases_dir {
        let dir = dir.clone();
        let loaded = tokio::task::spawn_blocking(move || load_atlases(&dir))
            .await
            .map_err(|e| setup(&e))??;
        for (atlas, scorer) in loaded {
            store
                .register_atlas(
                    &atlas.content_hash,
                    &atlas.manifest.name,
                    &atlas.dir.display().to_string(),
                )
                .await?;
            tracing::info!(atlas = %atlas.manifest.name, hash = %atlas.content_hash, "atlas ready");
            scorers.insert(atlas.content_hash.clone(), Arc::new(scorer));
            atlases.insert(atlas.content_hash.clone(), Arc::new(atlas));
        }
    }
    let requeued = store.requeue_running().await?;
    if requeued > 0 {
        tracing::info!(requeued, "resuming scoring jobs a previous run left unfinished");
    }
    let listener = tokio::net::TcpListener::bind(&config.bind)
        .await
        .map_err(|e| setup(&format!("cannot bind {}: {e}", config.bind)))?;
    let addr = listener.local_addr().map_err(|e| setup(&e))?;
    let login_failures = logins::FailedLogins::new(config.limits.login_failure_accounts, api::LOGIN_WINDOW);
    let passwords = logins::PasswordPool::new(config.limits.password_threads, config.limits.password_queue);
    let state = Arc::new(AppState {
        store,
        config,
        scorers,
        atlases,
        wake: tokio::sync::Notify::new(),
        login_failures,
        passwords,
        health: Default::default(),
        verify_permits: Arc::new(tokio::sync::Semaphore::new(
            std::thread::available_parallelism().map_or(1, |n| n.get()),
        )),
    });
    worker::start(state.clone());
    let mut app = api::router(state.clone());
    if let Some(mount) = mount {
        app = app.merge(mount(state.clone()));
    }
    let limits = Arc::new(state.config.limits.clone());
    let max_upload = state.config.max_upload_bytes as u64;
    ready(addr, state);
    let app = app
        .layer(axum::extract::DefaultBodyLimit::max(limits.max_json_body_bytes))
        .layer(axum::middleware::from_fn(server::json_errors))
        .layer(axum::middleware::from_fn_with_state(
            (limits.clone(), max_upload),
            server::deadline,
        ))
        .layer(axum::middleware::from_fn(server::security_headers))
        .layer(axum::middleware::from_fn(api::request_log));
    server::run(listener, app, &limits).await.map_err(|e| setup(&e))
}

fn load_atlases(dir: &std::path::Path) -> Result<Vec<(stylet_atlas::Atlas, stylet_scoring::Scorer)>, ServiceError> {
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
    dirs.iter()
        .map(|d| {
            let atlas = stylet_atlas::load(d).map_err(|e| ServiceError::Setup(e.to_string()))?;
            let scorer = stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None)
                .map_err(ServiceError::Setup)?;
            Ok((atlas, scorer))
        })
        .collect()
}
