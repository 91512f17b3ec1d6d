//! `stylet serve` and `stylet user add`: the scoring service and its accounts
//! (scoring::service; DESIGN.md "Service and security").

use std::io::Read;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use stylet_scoring::service::{self, Config, Store};

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address to listen on (port 0 picks a free port; the address is printed).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub bind: String,
    /// Where the database (SQLite by default) and the session files live.
    #[arg(long)]
    pub data_dir: PathBuf,
    /// Database URL (default: SQLite in the data directory; or postgres://…).
    #[arg(long)]
    pub database: Option<String>,
    /// Directory of atlas directories that uploaded sessions may use.
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
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    let config = Config {
        bind: a.bind,
        data_dir: a.data_dir,
        database_url: a.database,
        atlases_dir: a.atlases,
        workers: a
            .workers
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
        max_upload_bytes: a.max_upload_bytes,
        secure_cookies: a.secure_cookies,
    };
    runtime()?.block_on(service::serve(config, Some(stylet_dashboard::router), |addr, _| {
        sayf!("listening on http://{addr}")
    }))?;
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
                data_dir: a.data_dir.clone(),
                database_url: a.database.clone(),
                atlases_dir: None,
                workers: 1,
                max_upload_bytes: 0,
                secure_cookies: false,
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
