//! Where the service keeps its objects — session files, review traces, published atlases, player
//! frames: in
//! the data directory (the default), or in an S3-compatible object store
//! (`stylet serve --storage s3://bucket/prefix`), shared by every replica.
//!
//! An object has a key, its path relative to the data directory (`sessions/ab/<sha256>.mcap`).
//! With a store, the data directory is this replica's local copy: an object is written to the
//! store before the database row that names it commits ([`Storage::keep`]), and fetched into
//! the data directory when this replica first needs it ([`Storage::fetch`]). The store's
//! endpoint, region and credentials come from the usual `AWS_*` environment variables
//! (`AWS_ENDPOINT`, `AWS_REGION`, `AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`, `AWS_ALLOW_HTTP`).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use futures_util::StreamExt;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStore, ObjectStoreExt};
use tokio::io::AsyncWriteExt;

/// What went wrong with the storage.
#[derive(Debug, thiserror::Error)]
pub enum StorageError {
    #[error("storage {url:?}: {reason}")]
    Url { url: String, reason: String },
    #[error("the object {key} is not in the storage")]
    Missing { key: String },
    #[error("the object {key} has {bytes} bytes, more than the {limit} this may fetch")]
    TooLarge { key: String, bytes: u64, limit: u64 },
    #[error("object storage, {key}: {source}")]
    Store {
        key: String,
        #[source]
        source: object_store::Error,
    },
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl StorageError {
    /// Whether the object is not there (rather than the store not answering).
    pub fn is_missing(&self) -> bool {
        matches!(self, StorageError::Missing { .. })
    }

    fn store(key: &str, source: object_store::Error) -> StorageError {
        match source {
            object_store::Error::NotFound { .. } => StorageError::Missing { key: key.to_string() },
            source => StorageError::Store {
                key: key.to_string(),
                source,
            },
        }
    }
}

/// The storage of a service: its data directory, and the object store when it has one.
#[derive(Debug, Clone)]
pub struct Storage {
    data_dir: PathBuf,
    remote: Option<Remote>,
}

#[derive(Debug, Clone)]
struct Remote {
    store: Arc<dyn ObjectStore>,
    /// The `--storage` URL, for messages.
    url: String,
}

impl Storage {
    /// The data directory alone: every object is a file under it.
    pub fn local(data_dir: &Path) -> Storage {
        Storage {
            data_dir: data_dir.to_path_buf(),
            remote: None,
        }
    }

    /// The storage a `--storage` URL names: `s3://bucket[/prefix]` (endpoint, region and
    /// credentials from the `AWS_*` environment variables), or none for the data directory.
    pub fn open(data_dir: &Path, url: Option<&str>) -> Result<Storage, StorageError> {
        let Some(url) = url else {
            return Ok(Storage::local(data_dir));
        };
        let bad = |reason: &str| StorageError::Url {
            url: url.to_string(),
            reason: reason.to_string(),
        };
        let rest = url
            .strip_prefix("s3://")
            .ok_or_else(|| bad("only s3://bucket/prefix is supported (or no --storage: the data directory)"))?;
        let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
        if bucket.is_empty() {
            return Err(bad("no bucket named"));
        }
        let s3 = object_store::aws::AmazonS3Builder::from_env()
            .with_bucket_name(bucket)
            .build()
            .map_err(|e| bad(&e.to_string()))?;
        let prefix = prefix.trim_matches('/');
        let store: Arc<dyn ObjectStore> = if prefix.is_empty() {
            Arc::new(s3)
        } else {
            let prefix = ObjectPath::parse(prefix).map_err(|e| bad(&e.to_string()))?;
            Arc::new(object_store::prefix::PrefixStore::new(s3, prefix))
        };
        Ok(Storage {
            data_dir: data_dir.to_path_buf(),
            remote: Some(Remote {
                store,
                url: url.to_string(),
            }),
        })
    }

    /// The `--storage` URL, or none for the data directory.
    pub fn url(&self) -> Option<&str> {
        self.remote.as_ref().map(|r| r.url.as_str())
    }

    /// Where the object `key` is (or is put when fetched) in the data directory.
    pub fn local_path(&self, key: &str) -> PathBuf {
        self.data_dir.join(key)
    }

    /// Makes the object `key`, already written to [`Storage::local_path`], durable: with an
    /// object store, uploads it (in parts when large) and returns once the store has it all.
    pub async fn keep(&self, key: &str) -> Result<(), StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(());
        };
        let path = self.local_path(key);
        let io = |source| StorageError::Io {
            path: path.clone(),
            source,
        };
        let mut file = tokio::fs::File::open(&path).await.map_err(io)?;
        let mut writer = object_store::buffered::BufWriter::new(remote.store.clone(), object_path(key)?);
        let copied = tokio::io::copy(&mut file, &mut writer).await;
        let done = match copied {
            Ok(_) => writer.shutdown().await,
            Err(e) => {
                let _ = writer.abort().await;
                Err(e)
            }
        };
        done.map_err(|e| StorageError::Store {
            key: key.to_string(),
            source: object_store::Error::Generic {
                store: "S3",
                source: Box::new(e),
            },
        })
    }

    /// The local path of the object `key`, fetched from the object store into the data
    /// directory first if it is not there yet (at most `max_bytes`, checked before it is read).
    pub async fn fetch(&self, key: &str, max_bytes: u64) -> Result<PathBuf, StorageError> {
        let path = self.local_path(key);
        match tokio::fs::metadata(&path).await {
            Ok(_) => return Ok(path),
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(StorageError::Io { path, source: e });
            }
            Err(_) => {}
        }
        let Some(remote) = &self.remote else {
            return Err(StorageError::Missing { key: key.to_string() });
        };
        fetch_to(remote, key, &path, max_bytes).await?;
        Ok(path)
    }

    /// Puts every file under the data directory's folder `prefix` into the object store (keys
    /// `prefix/<path>`), but for hidden ones (`.stylet-cache`: what this machine derived).
    pub async fn keep_folder(&self, prefix: &str) -> Result<(), StorageError> {
        if self.remote.is_none() {
            return Ok(());
        }
        let root = self.local_path(prefix);
        let mut pending = vec![root.clone()];
        while let Some(dir) = pending.pop() {
            let mut entries = tokio::fs::read_dir(&dir).await.map_err(|source| StorageError::Io {
                path: dir.clone(),
                source,
            })?;
            while let Some(e) = entries.next_entry().await.map_err(|source| StorageError::Io {
                path: dir.clone(),
                source,
            })? {
                let path = e.path();
                if e.file_name().to_string_lossy().starts_with('.') {
                    continue;
                }
                if path.is_dir() {
                    pending.push(path);
                } else if let Ok(rel) = path.strip_prefix(&self.data_dir) {
                    self.keep(&rel.to_string_lossy().replace('\\', "/")).await?;
                }
            }
        }
        Ok(())
    }

    /// The data directory's folder `prefix`, fetched first from the objects under `prefix/`
    /// when it is not there (at most `max_bytes` in all, checked from the listing before
    /// anything is read; made whole beside it, then renamed into place).
    pub async fn fetch_folder(&self, prefix: &str, max_bytes: u64) -> Result<PathBuf, StorageError> {
        let dest = self.local_path(prefix);
        if dest.is_dir() {
            return Ok(dest);
        }
        let Some(remote) = &self.remote else {
            return Err(StorageError::Missing {
                key: prefix.to_string(),
            });
        };
        let listed = list_folder(remote, prefix).await?;
        if listed.is_empty() {
            return Err(StorageError::Missing {
                key: prefix.to_string(),
            });
        }
        let bytes: u64 = listed.iter().map(|m| m.size).sum();
        if bytes > max_bytes || listed.len() > MAX_FOLDER_OBJECTS {
            return Err(StorageError::TooLarge {
                key: prefix.to_string(),
                bytes,
                limit: max_bytes,
            });
        }
        let n = NEXT_TEMPORARY.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let name = dest
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = dest.with_file_name(format!(".fetching-{name}-{}-{n}", std::process::id()));
        let fetched = async {
            for meta in &listed {
                let key = meta.location.as_ref();
                let rel = key
                    .strip_prefix(prefix)
                    .map(|r| r.trim_start_matches('/'))
                    .unwrap_or(key);
                fetch_to(remote, key, &tmp.join(rel), max_bytes).await?;
            }
            match tokio::fs::rename(&tmp, &dest).await {
                Ok(()) => Ok(()),
                // Fetched meanwhile by another request: that copy is the same.
                Err(_) if dest.is_dir() => {
                    let _ = tokio::fs::remove_dir_all(&tmp).await;
                    Ok(())
                }
                Err(source) => Err(StorageError::Io {
                    path: dest.clone(),
                    source,
                }),
            }
        }
        .await;
        if fetched.is_err() {
            let _ = tokio::fs::remove_dir_all(&tmp).await;
        }
        fetched.map(|()| dest)
    }

    /// Whether the object store has the object `key` (the data directory, without one).
    pub async fn has(&self, key: &str) -> Result<bool, StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(self.local_path(key).exists());
        };
        match remote.store.head(&object_path(key)?).await {
            Ok(_) => Ok(true),
            Err(object_store::Error::NotFound { .. }) => Ok(false),
            Err(e) => Err(StorageError::store(key, e)),
        }
    }

    /// Removes the object `key` from the object store and the data directory; one already
    /// gone is not an error.
    pub async fn remove(&self, key: &str) -> Result<(), StorageError> {
        if let Some(remote) = &self.remote {
            match remote.store.delete(&object_path(key)?).await {
                Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
                Err(e) => return Err(StorageError::store(key, e)),
            }
        }
        let path = self.local_path(key);
        match tokio::fs::remove_file(&path).await {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(StorageError::Io { path, source: e }),
            _ => Ok(()),
        }
    }

    /// Whether there is an object store (`--storage`), not only the data directory.
    pub fn is_shared(&self) -> bool {
        self.remote.is_some()
    }

    /// The bytes of the object `key` in the object store (at most `max_bytes`, checked before
    /// it is read); None without a store or without the object.
    pub async fn read_shared(&self, key: &str, max_bytes: u64) -> Result<Option<Vec<u8>>, StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(None);
        };
        let got = match remote.store.get(&object_path(key)?).await {
            Ok(got) => got,
            Err(object_store::Error::NotFound { .. }) => return Ok(None),
            Err(e) => return Err(StorageError::store(key, e)),
        };
        if got.meta.size > max_bytes {
            return Err(StorageError::TooLarge {
                key: key.to_string(),
                bytes: got.meta.size,
                limit: max_bytes,
            });
        }
        let bytes = got.bytes().await.map_err(|e| StorageError::store(key, e))?;
        Ok(Some(bytes.to_vec()))
    }

    /// Puts `bytes` into the object store as `key` (nothing without a store).
    pub async fn write_shared(&self, key: &str, bytes: Vec<u8>) -> Result<(), StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(());
        };
        remote
            .store
            .put(&object_path(key)?, bytes.into())
            .await
            .map(|_| ())
            .map_err(|e| StorageError::store(key, e))
    }

    /// Bytes of the objects under `prefix/` in the object store (0 without one), counting at
    /// most [`MAX_FOLDER_OBJECTS`] objects: more count as over any bound.
    pub async fn shared_folder_bytes(&self, prefix: &str) -> Result<u64, StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(0);
        };
        let listed = list_folder(remote, prefix).await?;
        if listed.len() > MAX_FOLDER_OBJECTS {
            return Ok(u64::MAX);
        }
        Ok(listed.iter().map(|m| m.size).sum())
    }

    /// Removes every object under `prefix/` from the object store (nothing without one).
    pub async fn remove_shared_folder(&self, prefix: &str) -> Result<(), StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(());
        };
        let mut listed = remote.store.list(Some(&object_path(prefix)?));
        while let Some(meta) = listed.next().await {
            let meta = meta.map_err(|e| StorageError::store(prefix, e))?;
            match remote.store.delete(&meta.location).await {
                Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
                Err(e) => return Err(StorageError::store(meta.location.as_ref(), e)),
            }
        }
        Ok(())
    }

    /// Whether the storage answers: the data directory is there, and the object store (if
    /// any) lists its keys.
    pub async fn check(&self) -> Result<(), StorageError> {
        if let Err(source) = tokio::fs::metadata(&self.data_dir).await {
            return Err(StorageError::Io {
                path: self.data_dir.clone(),
                source,
            });
        }
        if let Some(remote) = &self.remote {
            let prefix = object_path("sessions")?;
            remote
                .store
                .list_with_delimiter(Some(&prefix))
                .await
                .map_err(|e| StorageError::store("sessions/", e))?;
        }
        Ok(())
    }
}

/// Most objects one folder (a published atlas, a session's shared player frames) may hold.
pub const MAX_FOLDER_OBJECTS: usize = 4096;

/// Numbers the temporary files and folders of this process: requests may fetch the same object
/// at once.
static NEXT_TEMPORARY: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// The objects under `prefix/`, at most [`MAX_FOLDER_OBJECTS`] + 1 of them (one more than a
/// folder may hold, so that the caller sees when there are too many).
async fn list_folder(remote: &Remote, prefix: &str) -> Result<Vec<object_store::ObjectMeta>, StorageError> {
    remote
        .store
        .list(Some(&object_path(prefix)?))
        .take(MAX_FOLDER_OBJECTS + 1)
        .collect::<Vec<_>>()
        .await
        .into_iter()
        .collect::<Result<_, _>>()
        .map_err(|e| StorageError::store(prefix, e))
}

/// Fetches the object `key` into the file `path` (at most `max_bytes`, checked before it is
/// read): written beside it and renamed into place.
async fn fetch_to(remote: &Remote, key: &str, path: &Path, max_bytes: u64) -> Result<(), StorageError> {
    let got = remote
        .store
        .get(&object_path(key)?)
        .await
        .map_err(|e| StorageError::store(key, e))?;
    if got.meta.size > max_bytes {
        return Err(StorageError::TooLarge {
            key: key.to_string(),
            bytes: got.meta.size,
            limit: max_bytes,
        });
    }
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| StorageError::Io { path, source }
    };
    if let Some(dir) = path.parent() {
        tokio::fs::create_dir_all(dir).await.map_err(io(dir))?;
    }
    let n = NEXT_TEMPORARY.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = path.with_extension(format!("fetch-{}-{n}", std::process::id()));
    let written = async {
        let mut file = tokio::fs::File::create(&tmp).await.map_err(io(&tmp))?;
        let mut stream = got.into_stream();
        let mut bytes = 0u64;
        while let Some(chunk) = stream.next().await {
            let chunk = chunk.map_err(|e| StorageError::store(key, e))?;
            bytes += chunk.len() as u64;
            if bytes > max_bytes {
                return Err(StorageError::TooLarge {
                    key: key.to_string(),
                    bytes,
                    limit: max_bytes,
                });
            }
            file.write_all(&chunk).await.map_err(io(&tmp))?;
        }
        file.sync_all().await.map_err(io(&tmp))?;
        tokio::fs::rename(&tmp, path).await.map_err(io(path))
    }
    .await;
    if written.is_err() {
        let _ = tokio::fs::remove_file(&tmp).await;
    }
    written
}

/// The object store's name of a key.
fn object_path(key: &str) -> Result<ObjectPath, StorageError> {
    ObjectPath::parse(key).map_err(|e| StorageError::Url {
        url: key.to_string(),
        reason: e.to_string(),
    })
}

/// The key of the session file whose SHA-256 is `sha`: `sessions/ab/<sha>.mcap`.
pub fn session_key(sha: &str) -> String {
    format!("sessions/{}/{sha}.mcap", sha.get(..2).unwrap_or(sha))
}

/// The key of the review trace of the session file `sha`: `traces/ab/<sha>.json.zst`.
pub fn trace_key(sha: &str) -> String {
    format!("traces/{}/{sha}.json.zst", sha.get(..2).unwrap_or(sha))
}

/// The folder of the player frames of the session file `sha`: `frames/ab/<sha>`.
pub fn frames_prefix(sha: &str) -> String {
    format!("frames/{}/{sha}", sha.get(..2).unwrap_or(sha))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_storage_url_other_than_s3_is_refused_with_the_reason() {
        let dir = std::path::Path::new("/nonexistent");
        for (url, says) in [
            ("file:///tmp/x", "only s3://bucket/prefix"),
            ("s3://", "no bucket"),
            ("s3:///prefix", "no bucket"),
        ] {
            let e = Storage::open(dir, Some(url)).unwrap_err().to_string();
            assert!(e.contains(says) && e.contains(url), "{url}: {e}");
        }
        assert_eq!(Storage::open(dir, None).unwrap().url(), None);
    }

    #[test]
    fn keys_are_the_data_directorys_layout() {
        let sha = "ab".to_string() + &"0".repeat(62);
        assert_eq!(session_key(&sha), format!("sessions/ab/{sha}.mcap"));
        assert_eq!(trace_key(&sha), format!("traces/ab/{sha}.json.zst"));
        let storage = Storage::local(std::path::Path::new("/data"));
        assert_eq!(
            storage.local_path(&session_key(&sha)),
            std::path::Path::new("/data/sessions/ab").join(format!("{sha}.mcap"))
        );
    }

    #[tokio::test]
    async fn without_a_store_the_data_directory_is_the_storage() {
        let dir = tempfile::tempdir().unwrap();
        let storage = Storage::local(dir.path());
        let key = session_key(&"cd".repeat(32));
        assert!(storage.fetch(&key, 1 << 20).await.unwrap_err().is_missing());
        assert!(!storage.has(&key).await.unwrap());
        let path = storage.local_path(&key);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, b"session").unwrap();
        storage.keep(&key).await.unwrap();
        assert_eq!(storage.fetch(&key, 1 << 20).await.unwrap(), path);
        assert!(storage.has(&key).await.unwrap());
        storage.remove(&key).await.unwrap();
        assert!(!path.exists());
        // Removing what is gone is not an error.
        storage.remove(&key).await.unwrap();
        storage.check().await.unwrap();
    }
}
