//! `stylet backup` and `stylet restore`: a consistent snapshot of the database and of the files it
//! names, with a manifest of their SHA-256, and its restoration into an empty data directory.
//!
//! A backup is a folder: `manifest.json`; the database (`database.sqlite`, written by SQLite's
//! `VACUUM INTO` from the live database — consistent while the server runs — or
//! `database.pgdump`, PostgreSQL's `pg_dump --format=custom`); `sessions/aa/<sha256>.mcap`, the
//! session files the database names; `atlases/<content hash>/…`, the published atlases. It is
//! written under `<DIR>.partial` and renamed into place at the end, so a folder named `DIR` is a
//! whole backup. Caches (traces, figures, frames) are left out: they are recomputed.
//!
//! `restore` first checks every file of the backup against the manifest (and the session files
//! against their names) and refuses, naming the file, before anything is written; it restores
//! only into an empty data directory and an empty database. Then it replays a sample of the
//! scored sessions through the scorer and compares their metrics with the restored scores.

use std::path::{Path, PathBuf};

use sha2::Digest;
use sqlx::Row;

use super::Store;
use super::storage::Storage;
use super::store::StoreError;

/// The manifest's format.
pub const MANIFEST_FORMAT: u32 = 1;
/// The manifest's name in a backup.
const MANIFEST: &str = "manifest.json";
/// Scored sessions `restore` replays to check the restored scores.
pub const REVERIFY_SAMPLE: usize = 3;

#[derive(Debug, thiserror::Error)]
pub enum BackupError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Storage(#[from] super::storage::StorageError),
    #[error("{0} exists already: back up into a new folder (or a new prefix)")]
    TargetExists(PathBuf),
    #[error("{tool} failed: {detail}")]
    Tool { tool: &'static str, detail: String },
    #[error("{0}: not a backup manifest: {1}")]
    Manifest(PathBuf, String),
    #[error(
        "{path}: its SHA-256 is {found}, the manifest says {expected}: the backup is damaged; nothing was restored"
    )]
    Damaged {
        path: PathBuf,
        expected: String,
        found: String,
    },
    #[error("{0}: restore into an empty data directory (this one holds {1})")]
    NotEmpty(PathBuf, String),
    #[error("the target database is not empty (it has the service's tables): restore into a new database")]
    DatabaseNotEmpty,
    #[error(
        "session {session} of the database has no file {sha256} in the data directory (deleted during the backup?): run the backup again"
    )]
    Missing { session: String, sha256: String },
    #[error("a path with a quote cannot be given to SQLite's VACUUM INTO: {0}")]
    Quote(PathBuf),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> BackupError + '_ {
    move |source| BackupError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// One file of a backup.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ManifestFile {
    /// Relative to the backup folder, `/`-separated.
    pub path: String,
    pub sha256: String,
    pub bytes: u64,
}

/// What a backup holds.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Manifest {
    pub format: u32,
    pub created_at: String,
    /// `sqlite` or `postgres`.
    pub database: String,
    pub sessions: u64,
    pub scores: u64,
    pub files: Vec<ManifestFile>,
}

/// SHA-256 (hex) and size of a file, streamed.
fn sha256_of(path: &Path) -> Result<(String, u64), BackupError> {
    let mut f = std::fs::File::open(path).map_err(io(path))?;
    let mut hasher = sha2::Sha256::new();
    let bytes = std::io::copy(&mut f, &mut hasher).map_err(io(path))?;
    Ok((format!("{:x}", hasher.finalize()), bytes))
}

/// Every file under `dir`, relative, sorted.
fn files_under(dir: &Path) -> Result<Vec<PathBuf>, BackupError> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).map_err(io(&d))? {
            let entry = entry.map_err(io(&d))?;
            let path = entry.path();
            if entry.file_type().map_err(io(&path))?.is_dir() {
                stack.push(path);
            } else {
                out.push(path.strip_prefix(dir).expect("under dir").to_path_buf());
            }
        }
    }
    out.sort();
    Ok(out)
}

fn run_tool(tool: &'static str, args: &[&std::ffi::OsStr]) -> Result<(), BackupError> {
    let out = std::process::Command::new(tool)
        .args(args)
        .output()
        .map_err(|e| BackupError::Tool {
            tool,
            detail: format!("cannot run it ({e}); install PostgreSQL's client programs"),
        })?;
    if out.status.success() {
        Ok(())
    } else {
        Err(BackupError::Tool {
            tool,
            detail: String::from_utf8_lossy(&out.stderr).trim().to_string(),
        })
    }
}

/// Backs up the service whose storage (data directory, object store) is `storage` and database
/// `database_url` into the new folder `to`.
pub async fn backup(storage: &Storage, database_url: &str, to: &Path) -> Result<Manifest, BackupError> {
    if to.exists() {
        return Err(BackupError::TargetExists(to.to_path_buf()));
    }
    let partial = to.with_extension("partial");
    if partial.exists() {
        std::fs::remove_dir_all(&partial).map_err(io(&partial))?;
    }
    std::fs::create_dir_all(&partial).map_err(io(&partial))?;
    let sqlite = database_url.starts_with("sqlite:");
    let store = Store::open(database_url).await?;
    // The database first: the files it names are never changed once written, so copying them
    // after the snapshot gives every file it names.
    let (database_file, kind) = if sqlite {
        let file = partial.join("database.sqlite");
        let shown = file.display().to_string();
        if shown.contains('\'') {
            return Err(BackupError::Quote(file));
        }
        sqlx::query(sqlx::AssertSqlSafe(format!("VACUUM INTO '{shown}'")))
            .execute(&store.pool)
            .await
            .map_err(StoreError::from)?;
        (file, "sqlite")
    } else {
        let file = partial.join("database.pgdump");
        run_tool(
            "pg_dump",
            &[
                "--format=custom".as_ref(),
                "--no-owner".as_ref(),
                "--file".as_ref(),
                file.as_os_str(),
                database_url.as_ref(),
            ],
        )?;
        (file, "postgres")
    };
    // What the snapshot names: for SQLite read from the snapshot itself; PostgreSQL's dump is
    // read from the live database just after it (a session added meanwhile only adds a file).
    let listing = if sqlite {
        sqlx::AnyPool::connect(&format!("sqlite://{}?mode=ro", database_file.display()))
            .await
            .map_err(StoreError::from)?
    } else {
        store.pool.clone()
    };
    let sessions: Vec<(String, String)> = sqlx::query("SELECT id, file_sha256 FROM sessions ORDER BY id")
        .fetch_all(&listing)
        .await
        .map_err(StoreError::from)?
        .iter()
        .map(|r| Ok((r.try_get("id")?, r.try_get("file_sha256")?)))
        .collect::<Result<_, sqlx::Error>>()
        .map_err(StoreError::from)?;
    let scores: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM scores")
        .fetch_one(&listing)
        .await
        .map_err(StoreError::from)?;
    let published: Vec<String> =
        sqlx::query_scalar("SELECT content_hash FROM atlases WHERE published_at IS NOT NULL ORDER BY content_hash")
            .fetch_all(&listing)
            .await
            .map_err(StoreError::from)?;
    if sqlite {
        listing.close().await;
    }
    store.pool.close().await;
    let mut files = Vec::new();
    let (db_sha, db_bytes) = sha256_of(&database_file)?;
    files.push(ManifestFile {
        path: database_file
            .file_name()
            .expect("a file")
            .to_string_lossy()
            .into_owned(),
        sha256: db_sha,
        bytes: db_bytes,
    });
    for (session, sha) in &sessions {
        // From the object storage when this data directory has no copy.
        let rel = super::storage::session_key(sha);
        let from = match storage.fetch(&rel, u64::MAX).await {
            Ok(from) => from,
            Err(e) if e.is_missing() => {
                return Err(BackupError::Missing {
                    session: session.clone(),
                    sha256: sha.clone(),
                });
            }
            Err(e) => return Err(e.into()),
        };
        files.push(copy_file(&from, &partial.join(&rel), rel)?);
    }
    for hash in &published {
        let dir = storage.fetch_folder(&format!("atlases/{hash}"), u64::MAX).await?;
        for rel in files_under(&dir)? {
            let rel_text = format!("atlases/{hash}/{}", rel.to_string_lossy().replace('\\', "/"));
            files.push(copy_file(&dir.join(&rel), &partial.join(&rel_text), rel_text)?);
        }
    }
    let manifest = Manifest {
        format: MANIFEST_FORMAT,
        created_at: super::store::now(),
        database: kind.to_string(),
        sessions: sessions.len() as u64,
        scores: scores.max(0) as u64,
        files,
    };
    let text = serde_json::to_vec_pretty(&manifest).expect("a manifest serialises");
    let manifest_path = partial.join(MANIFEST);
    std::fs::write(&manifest_path, text).map_err(io(&manifest_path))?;
    std::fs::rename(&partial, to).map_err(io(to))?;
    Ok(manifest)
}

/// Copies `from` to `to` (folders made) and returns its manifest line.
fn copy_file(from: &Path, to: &Path, rel: String) -> Result<ManifestFile, BackupError> {
    if let Some(parent) = to.parent() {
        std::fs::create_dir_all(parent).map_err(io(parent))?;
    }
    std::fs::copy(from, to).map_err(io(from))?;
    let (sha256, bytes) = sha256_of(to)?;
    Ok(ManifestFile {
        path: rel,
        sha256,
        bytes,
    })
}

/// Reads a backup's manifest and checks every file it lists (and that session files hash to
/// their names); nothing is written.
pub fn check(from: &Path) -> Result<Manifest, BackupError> {
    check_within(from, MAX_MANIFEST_BYTES)
}

/// Largest manifest read (about 6 M files at ≈ 150 bytes a line).
pub const MAX_MANIFEST_BYTES: u64 = 1 << 30;

fn check_within(from: &Path, max_manifest_bytes: u64) -> Result<Manifest, BackupError> {
    let manifest = read_manifest(&from.join(MANIFEST), max_manifest_bytes)?;
    for f in &manifest.files {
        let file = from.join(&f.path);
        let (found, _) = sha256_of(&file)?;
        let named = f
            .path
            .strip_prefix("sessions/")
            .and_then(|p| p.rsplit('/').next())
            .and_then(|n| n.strip_suffix(".mcap"));
        for expected in [Some(f.sha256.as_str()), named].into_iter().flatten() {
            if found != expected {
                return Err(BackupError::Damaged {
                    path: file,
                    expected: expected.to_string(),
                    found,
                });
            }
        }
    }
    Ok(manifest)
}

/// Reads the manifest at `path` (at most `max_bytes`, checked before it is read): its format, and
/// every file it lists inside the backup (relative, no `..`). Nothing listed is read.
fn read_manifest(path: &Path, max_bytes: u64) -> Result<Manifest, BackupError> {
    let size = std::fs::metadata(path).map_err(io(path))?.len();
    if size > max_bytes {
        return Err(BackupError::Manifest(
            path.to_path_buf(),
            format!("{size} bytes, more than the {max_bytes} a manifest may have"),
        ));
    }
    let text = std::fs::read(path).map_err(io(path))?;
    let manifest: Manifest =
        serde_json::from_slice(&text).map_err(|e| BackupError::Manifest(path.to_path_buf(), e.to_string()))?;
    if manifest.format != MANIFEST_FORMAT {
        return Err(BackupError::Manifest(
            path.to_path_buf(),
            format!("format {} (this build reads {MANIFEST_FORMAT})", manifest.format),
        ));
    }
    for f in &manifest.files {
        let safe = Path::new(&f.path)
            .components()
            .all(|c| matches!(c, std::path::Component::Normal(_)));
        if !safe {
            return Err(BackupError::Manifest(
                path.to_path_buf(),
                format!("a path outside the backup: {:?}", f.path),
            ));
        }
    }
    Ok(manifest)
}

/// Restores the backup in `from` into the empty data directory `data_dir` and the empty database
/// `database_url` (SQLite: `data_dir/stylet.db`). Every file is checked first.
pub async fn restore(
    storage: &Storage,
    from: &Path,
    data_dir: &Path,
    database_url: &str,
) -> Result<Manifest, BackupError> {
    let manifest = check(from)?;
    if data_dir.exists() {
        let mut held: Vec<String> = std::fs::read_dir(data_dir)
            .map_err(io(data_dir))?
            .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
            .filter(|n| !n.starts_with('.') && n != "server.log")
            .collect();
        held.sort();
        if !held.is_empty() {
            return Err(BackupError::NotEmpty(data_dir.to_path_buf(), held.join(", ")));
        }
    }
    let sqlite = database_url.starts_with("sqlite:");
    if (manifest.database == "sqlite") != sqlite {
        return Err(BackupError::Manifest(
            from.join(MANIFEST),
            format!(
                "a backup of a {} database cannot be restored into {}",
                manifest.database,
                if sqlite { "SQLite" } else { "PostgreSQL" }
            ),
        ));
    }
    if !sqlite {
        sqlx::any::install_default_drivers();
        let pool = sqlx::AnyPool::connect(database_url).await.map_err(StoreError::from)?;
        let tables: i64 =
            sqlx::query_scalar("SELECT COUNT(*) FROM information_schema.tables WHERE table_name = '_sqlx_migrations'")
                .fetch_one(&pool)
                .await
                .map_err(StoreError::from)?;
        pool.close().await;
        if tables > 0 {
            return Err(BackupError::DatabaseNotEmpty);
        }
    }
    std::fs::create_dir_all(data_dir).map_err(io(data_dir))?;
    for f in &manifest.files {
        if f.path.starts_with("sessions/") || f.path.starts_with("atlases/") {
            let to = data_dir.join(&f.path);
            if let Some(parent) = to.parent() {
                std::fs::create_dir_all(parent).map_err(io(parent))?;
            }
            std::fs::copy(from.join(&f.path), &to).map_err(io(&to))?;
            if f.path.starts_with("sessions/") {
                // Into the object storage too, before the database that names it.
                storage.keep(&f.path).await?;
            }
        }
    }
    for hash in manifest
        .files
        .iter()
        .filter_map(|f| f.path.strip_prefix("atlases/")?.split('/').next())
        .collect::<std::collections::BTreeSet<_>>()
    {
        storage.keep_folder(&format!("atlases/{hash}")).await?;
    }
    if sqlite {
        let to = data_dir.join("stylet.db");
        std::fs::copy(from.join("database.sqlite"), &to).map_err(io(&to))?;
    } else {
        run_tool(
            "pg_restore",
            &[
                "--no-owner".as_ref(),
                "--dbname".as_ref(),
                database_url.as_ref(),
                from.join("database.pgdump").as_os_str(),
            ],
        )?;
    }
    Ok(manifest)
}

/// How a restored session's replay compared with its restored score.
#[derive(Debug, Clone, PartialEq)]
pub struct Reverified {
    pub session: String,
    /// `None`: replayed and identical; else what differed or why it could not be replayed.
    pub problem: Option<String>,
}

/// Replays up to `n` scored sessions of the restored service (spread over them in id order)
/// and compares the replay check, the ticks and the metrics with the stored score. Atlases are
/// looked for among the published ones and in `atlases_dir` (the configured directory).
pub async fn reverify_sample(
    data_dir: &Path,
    database_url: &str,
    atlases_dir: Option<&Path>,
    n: usize,
) -> Result<Vec<Reverified>, BackupError> {
    let store = Store::open(database_url).await?;
    let rows = sqlx::query(
        "SELECT s.id, s.file_sha256, s.atlas_hash, sc.report_json FROM sessions s JOIN scores sc ON sc.session_id = s.id ORDER BY s.id",
    )
    .fetch_all(&store.pool)
    .await
    .map_err(StoreError::from)?;
    store.pool.close().await;
    let step = rows.len().div_ceil(n.max(1)).max(1);
    let mut atlas_dirs: Vec<PathBuf> = Vec::new();
    if let Some(dir) = atlases_dir
        && let Ok(entries) = std::fs::read_dir(dir)
    {
        atlas_dirs.extend(
            entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.join("atlas.toml").is_file()),
        );
    }
    let mut out = Vec::new();
    for r in rows.iter().step_by(step).take(n) {
        let get = |c: &str| r.try_get::<String, _>(c).map_err(StoreError::from);
        let (id, sha, atlas_hash, stored) = (get("id")?, get("file_sha256")?, get("atlas_hash")?, get("report_json")?);
        let file = super::session_file(data_dir, &sha);
        let published = super::published_dir(data_dir).join(&atlas_hash);
        let candidates: Vec<PathBuf> = std::iter::once(published).chain(atlas_dirs.iter().cloned()).collect();
        let problem = tokio::task::spawn_blocking(move || replay_and_compare(&file, &atlas_hash, &candidates, &stored))
            .await
            .unwrap_or_else(|e| Some(format!("the replay panicked: {e}")));
        out.push(Reverified { session: id, problem });
    }
    Ok(out)
}

fn replay_and_compare(file: &Path, atlas_hash: &str, candidates: &[PathBuf], stored: &str) -> Option<String> {
    let Some(dir) = candidates
        .iter()
        .find(|d| super::publish::content_of(d).is_ok_and(|h| h == atlas_hash))
    else {
        return Some(format!(
            "its atlas {atlas_hash} is neither published nor in the atlas directory given"
        ));
    };
    let atlas = match stylet_atlas::load(dir) {
        Ok(a) => a,
        Err(e) => return Some(format!("its atlas does not load: {e}")),
    };
    let scorer = match stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None) {
        Ok(s) => s,
        Err(e) => return Some(format!("no scorer: {e}")),
    };
    let session = match stylet_recorder::reader::recover(file) {
        Ok(s) => s,
        Err(e) => return Some(format!("{}: {e}", file.display())),
    };
    let fresh = match scorer.score_session(&session) {
        // Through the same text as the stored report, so that both numbers are parsed alike
        // (serde_json's parser may round the last digit; the text is exact).
        Ok(r) => serde_json::from_str::<serde_json::Value>(&serde_json::to_string(&r).expect("a report serialises"))
            .expect("a report reads back"),
        Err(e) => return Some(format!("replay failed: {e}")),
    };
    let stored: serde_json::Value = match serde_json::from_str(stored) {
        Ok(v) => v,
        Err(e) => return Some(format!("the stored report does not read: {e}")),
    };
    // The grade is left out: at levels with relative deductions it was measured against the
    // expert references of its scoring time; the replay's own results must be identical.
    for key in ["replay_verified", "ticks", "digests_checked", "metrics"] {
        if fresh[key] != stored[key] {
            let which = match (fresh[key].as_object(), stored[key].as_object()) {
                (Some(f), Some(s)) => f
                    .iter()
                    .filter(|(k, v)| s.get(*k) != Some(v))
                    .map(|(k, v)| {
                        format!(
                            "{key}.{k}: {v} replayed, {} stored",
                            s.get(k).unwrap_or(&serde_json::Value::Null)
                        )
                    })
                    .next()
                    .unwrap_or_else(|| key.to_string()),
                _ => format!("{key}: {} replayed, {} stored", fresh[key], stored[key]),
            };
            return Some(format!("its replay differs from the restored score ({which})"));
        }
    }
    None
}

/// Backs up (as [`backup`]) into the object-store location `target` (`s3://bucket/prefix`,
/// credentials from the `AWS_*` environment): made in the local folder `staging` first (removed
/// after), then each file put under the prefix, the manifest last — a prefix without
/// `manifest.json` is not a backup. A prefix that already holds a manifest is refused.
pub async fn backup_to_store(
    storage: &Storage,
    database_url: &str,
    target: &str,
    staging: &Path,
) -> Result<Manifest, BackupError> {
    let local = staging.join("backup");
    let store = Storage::open(&local, Some(target))?;
    if store.has(MANIFEST).await? {
        return Err(BackupError::TargetExists(PathBuf::from(target)));
    }
    let done = async {
        let manifest = backup(storage, database_url, &local).await?;
        for f in &manifest.files {
            store.keep(&f.path).await?;
        }
        store.keep(MANIFEST).await?;
        Ok(manifest)
    }
    .await;
    let _ = std::fs::remove_dir_all(staging);
    done
}

/// Restores (as [`restore`]) the backup at the object-store location `from` (`s3://…`): its
/// manifest (at most [`MAX_MANIFEST_BYTES`]) and then every file it lists (at most the size it
/// lists) are fetched into the local folder `staging` (removed after), checked, and restored.
pub async fn restore_from_store(
    storage: &Storage,
    from: &str,
    staging: &Path,
    data_dir: &Path,
    database_url: &str,
) -> Result<Manifest, BackupError> {
    let local = staging.join("backup");
    let source = Storage::open(&local, Some(from))?;
    let done = async {
        let path = source.fetch(MANIFEST, MAX_MANIFEST_BYTES).await.map_err(|e| {
            if e.is_missing() {
                BackupError::Manifest(PathBuf::from(from), "no manifest.json there: not a backup".into())
            } else {
                e.into()
            }
        })?;
        let manifest = read_manifest(&path, MAX_MANIFEST_BYTES)?;
        for f in &manifest.files {
            source.fetch(&f.path, f.bytes).await?;
        }
        restore(storage, &local, data_dir, database_url).await
    }
    .await;
    let _ = std::fs::remove_dir_all(staging);
    done
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manifest_over_the_limit_is_refused_before_it_is_read() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("manifest.json"), vec![b' '; 100]).unwrap();
        let e = check_within(dir.path(), 99).unwrap_err().to_string();
        assert!(e.contains("100 bytes, more than the 99"), "{e}");
        // Within the limit it is read (and this one is no manifest).
        let e = check_within(dir.path(), 100).unwrap_err().to_string();
        assert!(e.contains("not a backup manifest"), "{e}");
    }
}
