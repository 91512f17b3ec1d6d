//! `stylet backup` and `stylet restore`: the service's database and the files it names, with a
//! manifest of hashes (stylet-service's `backup` module; docs/operations.md "Backing up").

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use stylet_service::backup;
use stylet_service::storage::Storage;

#[derive(Debug, Args)]
pub struct BackupArgs {
    /// The service's data directory.
    #[arg(long)]
    pub data_dir: PathBuf,
    /// Its database URL (default: SQLite in the data directory).
    #[arg(long)]
    pub database: Option<String>,
    /// Its object storage (`stylet serve --storage`), if it has one: session files this data
    /// directory has no copy of are fetched from it.
    #[arg(long)]
    pub storage: Option<String>,
    /// A new folder for the backup, or a new object-store prefix (`s3://bucket/prefix`,
    /// credentials from the AWS_* environment variables; staged in the data directory first).
    #[arg(long)]
    pub to: String,
}

#[derive(Debug, Args)]
pub struct RestoreArgs {
    /// The backup folder, or its object-store prefix (`s3://bucket/prefix`; fetched into the
    /// data directory's `.restore-staging` first, removed after).
    #[arg(long)]
    pub from: String,
    /// An empty data directory to restore into.
    #[arg(long)]
    pub data_dir: PathBuf,
    /// An empty database to restore into (default: SQLite in the data directory).
    #[arg(long)]
    pub database: Option<String>,
    /// The object storage the restored service will use (`stylet serve --storage`): the
    /// session files are put into it as well.
    #[arg(long)]
    pub storage: Option<String>,
    /// The configured atlas directory the service runs with (`stylet serve --atlases`): the
    /// sample of sessions replayed after the restore finds their atlases there or among the
    /// published ones.
    #[arg(long)]
    pub atlases: Option<PathBuf>,
}

fn database_url(data_dir: &std::path::Path, database: Option<String>) -> String {
    database.unwrap_or_else(|| stylet_service::sqlite_url(data_dir))
}

fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

pub fn backup(a: BackupArgs) -> anyhow::Result<()> {
    let url = database_url(&a.data_dir, a.database);
    let storage = Storage::open(&a.data_dir, a.storage.as_deref())?;
    let rt = runtime()?;
    let manifest = if a.to.starts_with("s3://") {
        let staging = a.data_dir.join(format!(".backup-staging-{}", std::process::id()));
        rt.block_on(backup::backup_to_store(&storage, &url, &a.to, &staging))?
    } else {
        rt.block_on(backup::backup(&storage, &url, std::path::Path::new(&a.to)))?
    };
    let bytes: u64 = manifest.files.iter().map(|f| f.bytes).sum();
    sayf!(
        "backed up {} sessions ({} scored) in {} files, {:.1} MB, to {}",
        manifest.sessions,
        manifest.scores,
        manifest.files.len(),
        bytes as f64 / 1e6,
        a.to
    );
    Ok(())
}

pub fn restore(a: RestoreArgs) -> anyhow::Result<()> {
    let url = database_url(&a.data_dir, a.database);
    let rt = runtime()?;
    let storage = Storage::open(&a.data_dir, a.storage.as_deref())?;
    let manifest = if a.from.starts_with("s3://") {
        let staging = a.data_dir.join(".restore-staging");
        rt.block_on(backup::restore_from_store(
            &storage,
            &a.from,
            &staging,
            &a.data_dir,
            &url,
        ))?
    } else {
        rt.block_on(backup::restore(
            &storage,
            std::path::Path::new(&a.from),
            &a.data_dir,
            &url,
        ))?
    };
    sayf!(
        "restored {} sessions ({} scored), every file checked against the manifest, into {}",
        manifest.sessions,
        manifest.scores,
        a.data_dir.display()
    );
    let sample = rt.block_on(backup::reverify_sample(
        &a.data_dir,
        &url,
        a.atlases.as_deref(),
        backup::REVERIFY_SAMPLE,
    ))?;
    let mut differing = Vec::new();
    for r in &sample {
        match &r.problem {
            None => sayf!("  session {}: replayed, identical to its restored score", r.session),
            Some(p) => differing.push(format!("session {}: {p}", r.session)),
        }
    }
    if !differing.is_empty() {
        anyhow::bail!(
            "{} of {} sessions replayed after the restore do not match their scores:\n  {}",
            differing.len(),
            sample.len(),
            differing.join("\n  ")
        );
    }
    Ok(())
}
