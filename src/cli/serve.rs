//! `stylet serve` and `stylet user add`: the scoring service and its accounts
//! (the crate stylet-service; docs/api.md, docs/security.md).

use std::io::Read;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use stylet_service::{self as service, Config, Store};

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address to listen on (port 0 picks a free port; the address is printed).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub bind: String,
    /// Address of the admin port: `/metrics` (Prometheus), `/livez`, `/readyz` (none by
    /// default; bind it to a private address, port 0 picks a free one).
    #[arg(long)]
    pub admin_bind: Option<String>,
    /// Where the database (SQLite by default) and the session files live.
    #[arg(long)]
    pub data_dir: PathBuf,
    /// Database URL (default: SQLite in the data directory; or postgres://…).
    #[arg(long)]
    pub database: Option<String>,
    /// Object storage for session files, traces and published atlases, shared by several
    /// replicas: `s3://bucket/prefix` (endpoint, region and credentials from the AWS_*
    /// environment variables: AWS_ENDPOINT, AWS_REGION, AWS_ACCESS_KEY_ID,
    /// AWS_SECRET_ACCESS_KEY, AWS_ALLOW_HTTP). Default: the data directory; with a store, the
    /// data directory holds this replica's local copies.
    #[arg(long)]
    pub storage: Option<String>,
    /// Directory of atlas directories that uploaded sessions may use (besides the atlases
    /// published through the API, kept in DATA_DIR/atlases).
    #[arg(long)]
    pub atlases: Option<PathBuf>,
    /// Scoring threads (default: all cores).
    #[arg(long)]
    pub workers: Option<usize>,
    /// Largest accepted upload (bytes).
    #[arg(long, default_value_t = 64 << 20)]
    pub max_upload_bytes: usize,
    /// Mark cookies Secure (when served behind TLS).
    #[arg(long)]
    pub secure_cookies: bool,
    /// How log lines are written to standard error: text for people, json (one object per
    /// line, with the request id and the job's session) for a log collector.
    #[arg(long, value_enum, default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,
    /// A Learning Record Store's xAPI endpoint (e.g. https://lrs.example.org/xAPI): each scored
    /// session's statements go there (docs/integration.md "Learning records (xAPI)"). Needs
    /// --lrs-username, --public-url and the password in $STYLET_LRS_PASSWORD.
    #[arg(long, requires_all = ["lrs_username", "public_url"])]
    pub lrs_url: Option<String>,
    /// The LRS account the statements are sent with (HTTP Basic).
    #[arg(long)]
    pub lrs_username: Option<String>,
    /// The address people reach this service at (https://stylet.example.org): the home of its
    /// accounts and activities in the xAPI statements.
    #[arg(long)]
    pub public_url: Option<String>,
    #[command(flatten)]
    pub limits: LimitArgs,
}

/// The LRS of `--lrs-url`, checked: http(s) addresses, and the password from the environment
/// (never on the command line).
fn lrs_config(a: &ServeArgs) -> anyhow::Result<Option<service::xapi::LrsConfig>> {
    let (Some(url), Some(username), Some(public_url)) = (&a.lrs_url, &a.lrs_username, &a.public_url) else {
        return Ok(None);
    };
    for (flag, value) in [("--lrs-url", url), ("--public-url", public_url)] {
        if !(value.starts_with("https://") || value.starts_with("http://")) {
            anyhow::bail!("{flag} {value}: an http(s) address, such as https://lrs.example.org/xAPI");
        }
    }
    let password = std::env::var("STYLET_LRS_PASSWORD")
        .context("--lrs-url needs the LRS account's password in the environment variable STYLET_LRS_PASSWORD")?;
    Ok(Some(service::xapi::LrsConfig {
        url: url.trim_end_matches('/').to_string(),
        username: username.clone(),
        password,
        public_url: public_url.trim_end_matches('/').to_string(),
    }))
}

/// The form of the service's log lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    Text,
    Json,
}

/// Limits and timeouts (docs/security.md); defaults in `stylet_service::Limits`.
#[derive(Debug, Args)]
pub struct LimitArgs {
    /// Longest session accepted for upload (minutes).
    #[arg(long)]
    pub max_session_minutes: Option<u64>,
    /// Largest request body other than a session upload (bytes).
    #[arg(long)]
    pub max_body_bytes: Option<usize>,
    /// Seconds a client has to send a request's headers (and a keep-alive connection to start
    /// its next request).
    #[arg(long)]
    pub header_timeout_s: Option<u64>,
    /// Seconds a request other than an upload may take, body included.
    #[arg(long)]
    pub request_timeout_s: Option<u64>,
    /// Slowest upload rate accepted (bytes per second, over every 10 s of the body; an upload may
    /// take the request timeout plus its size at this rate).
    #[arg(long)]
    pub min_upload_rate: Option<u64>,
    /// Connections open at once, whatever they are doing.
    #[arg(long)]
    pub max_connections: Option<usize>,
    /// Connections open at once from one address.
    #[arg(long)]
    pub max_connections_per_address: Option<usize>,
    /// Requests being served at once (/healthz is never refused).
    #[arg(long)]
    pub max_requests: Option<usize>,
    /// Requests one account may have in flight at once.
    #[arg(long)]
    pub max_requests_per_account: Option<usize>,
    /// Uploads (sessions and atlas archives) received at once, in all.
    #[arg(long)]
    pub max_uploads: Option<usize>,
    /// Uploads one account may send at once.
    #[arg(long)]
    pub max_uploads_per_account: Option<usize>,
    /// Free disk space an upload must leave in the data directory (bytes).
    #[arg(long)]
    pub min_free_disk_bytes: Option<u64>,
    /// Password checks run at once.
    #[arg(long)]
    pub password_threads: Option<usize>,
    /// Password checks that may wait; more get 503.
    #[arg(long)]
    pub password_queue: Option<usize>,
    /// Largest atlas publication accepted (bytes of its archive).
    #[arg(long)]
    pub max_atlas_bytes: Option<u64>,
    /// Most atlases the catalogue offers (withdrawn ones do not count).
    #[arg(long)]
    pub max_atlases: Option<usize>,
    /// Memory the loaded atlases may take (bytes); the least recently used are let go past it.
    #[arg(long)]
    pub atlas_cache_bytes: Option<u64>,
    /// Most voxels a published atlas may hold (its CT and measured breathing fields).
    #[arg(long)]
    pub max_atlas_voxels: Option<u64>,
    /// Seconds a publication may take for its checks (loading the atlas, its smoke test), beyond
    /// its upload time.
    #[arg(long)]
    pub atlas_check_timeout_s: Option<u64>,
    /// With --storage: bytes of session files kept as local copies in the data directory; the
    /// least recently used are deleted past it (the store has them all).
    #[arg(long)]
    pub local_copies_bytes: Option<u64>,
    /// A reverse proxy (address or network, e.g. 10.0.0.0/8; repeatable) whose X-Forwarded-For
    /// header names the client, for the limits counted per client address.
    #[arg(long = "trusted-proxy", value_name = "NETWORK")]
    pub trusted_proxies: Vec<ipnet::IpNet>,
}

impl LimitArgs {
    pub fn limits(&self) -> service::Limits {
        let d = service::Limits::default();
        let secs = std::time::Duration::from_secs;
        service::Limits {
            max_session_s: self
                .max_session_minutes
                .map_or(d.max_session_s, |m| m.saturating_mul(60)),
            max_json_body_bytes: self.max_body_bytes.unwrap_or(d.max_json_body_bytes),
            header_timeout: self.header_timeout_s.map_or(d.header_timeout, secs),
            request_timeout: self.request_timeout_s.map_or(d.request_timeout, secs),
            min_upload_bytes_per_s: self.min_upload_rate.unwrap_or(d.min_upload_bytes_per_s),
            max_connections: self.max_connections.unwrap_or(d.max_connections).max(1),
            max_connections_per_address: self
                .max_connections_per_address
                .unwrap_or(d.max_connections_per_address)
                .max(1),
            max_requests: self.max_requests.unwrap_or(d.max_requests).max(1),
            max_requests_per_account: self
                .max_requests_per_account
                .unwrap_or(d.max_requests_per_account)
                .max(1),
            max_uploads: self.max_uploads.unwrap_or(d.max_uploads).max(1),
            max_uploads_per_account: self.max_uploads_per_account.unwrap_or(d.max_uploads_per_account).max(1),
            min_free_disk_bytes: self.min_free_disk_bytes.unwrap_or(d.min_free_disk_bytes),
            password_threads: self.password_threads.unwrap_or(d.password_threads).max(1),
            password_queue: self.password_queue.unwrap_or(d.password_queue),
            max_atlas_bytes: self.max_atlas_bytes.unwrap_or(d.max_atlas_bytes),
            max_atlases: self.max_atlases.unwrap_or(d.max_atlases),
            atlas_cache_bytes: self.atlas_cache_bytes.unwrap_or(d.atlas_cache_bytes),
            max_atlas_voxels: self.max_atlas_voxels.unwrap_or(d.max_atlas_voxels),
            atlas_check_timeout: self.atlas_check_timeout_s.map_or(d.atlas_check_timeout, secs),
            local_copies_bytes: self.local_copies_bytes.unwrap_or(d.local_copies_bytes),
            trusted_proxies: self.trusted_proxies.clone(),
        }
    }
}

#[derive(Debug, Subcommand)]
pub enum UserCommand {
    /// Add an account; the password is read from standard input.
    Add(UserAddArgs),
}

#[derive(Debug, Args)]
pub struct UserAddArgs {
    #[arg(long)]
    pub data_dir: PathBuf,
    #[arg(long)]
    pub database: Option<String>,
    #[arg(long)]
    pub username: String,
    /// trainee, instructor, curriculum or admin.
    #[arg(long)]
    pub role: String,
    /// Cohort to join (created if new): trainees learn in it, instructors teach it.
    #[arg(long)]
    pub cohort: Option<String>,
    /// Read the password from standard input (required: passwords never go on the command line).
    #[arg(long, required = true)]
    pub password_stdin: bool,
}

fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

pub fn serve(a: ServeArgs) -> anyhow::Result<()> {
    // A log line that cannot be written (stderr on a full disk) is lost, never reported: the
    // logger's report goes to the same stderr with `eprintln!`, which panics on that failure and
    // would take the request being served with it.
    let logs = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .log_internal_errors(false);
    match a.log_format {
        // Colours only on a terminal: a log file gets plain text.
        LogFormat::Text => logs
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .init(),
        // The spans (request id, method, path; a job's session and request) as fields of
        // each line.
        LogFormat::Json => logs.json().with_current_span(true).with_span_list(true).init(),
    }
    let lrs = lrs_config(&a)?;
    let config = Config {
        bind: a.bind,
        admin_bind: a.admin_bind,
        data_dir: a.data_dir,
        database_url: a.database,
        storage_url: a.storage,
        atlases_dir: a.atlases,
        workers: a
            .workers
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
        max_upload_bytes: a.max_upload_bytes,
        secure_cookies: a.secure_cookies,
        limits: a.limits.limits(),
        lrs,
    };
    runtime()?.block_on(service::serve(
        config,
        Some(stylet_dashboard::MOUNT),
        |addr, state| match state.admin_addr {
            Some(admin) => sayf!("listening on http://{addr} (admin: http://{admin})"),
            None => sayf!("listening on http://{addr}"),
        },
    ))?;
    Ok(())
}

pub fn user(cmd: UserCommand) -> anyhow::Result<()> {
    match cmd {
        UserCommand::Add(a) => {
            let mut password = String::new();
            std::io::stdin()
                .read_to_string(&mut password)
                .context("reading the password from standard input")?;
            let password = password.trim_end_matches(['\n', '\r']);
            let config = Config {
                bind: String::new(),
                admin_bind: None,
                data_dir: a.data_dir.clone(),
                database_url: a.database.clone(),
                storage_url: None,
                atlases_dir: None,
                workers: 1,
                max_upload_bytes: 0,
                secure_cookies: false,
                limits: Default::default(),
                lrs: None,
            };
            std::fs::create_dir_all(&a.data_dir).with_context(|| format!("cannot create {}", a.data_dir.display()))?;
            runtime()?.block_on(async {
                let store = Store::open(&config.database_url()).await?;
                store
                    .add_user(&a.username, &a.role, password, a.cohort.as_deref(), None)
                    .await?;
                anyhow::Ok(())
            })?;
            sayf!(
                "user {} added as {}{}",
                a.username,
                a.role,
                a.cohort
                    .as_ref()
                    .map_or_else(String::new, |c| format!(" in cohort {c}"))
            );
            Ok(())
        }
    }
}
