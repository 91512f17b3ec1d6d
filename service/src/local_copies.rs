//! With object storage, the session files in the data directory are this replica's copies of
//! objects the store holds; they are bounded by [`crate::Limits::local_copies_bytes`]. Every use
//! of a copy ([`crate::AppState::session_copy`]) marks it (its modification time), and the
//! housekeeping deletes the least recently used past the bound — sparing those used within
//! [`MIN_AGE`], so that an upload not yet in the store or a replay just starting keeps its
//! file. (Deleting a file a replay has open is harmless: it reads on.) Without a store the
//! data directory is the storage and nothing is deleted.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// Copies used more recently than this are kept, whatever the bound.
pub const MIN_AGE: Duration = Duration::from_secs(10 * 60);

/// What [`trim`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Trimmed {
    pub deleted: usize,
    /// Bytes of the copies left.
    pub kept_bytes: u64,
}

/// Deletes the least recently used session copies (`<dir>/<two hex digits>/<sha256>.mcap`)
/// while they take more than `max_bytes`, sparing those used within `min_age` of `now`. Other
/// files (fetches and uploads in progress) are never touched.
pub fn trim(dir: &Path, max_bytes: u64, min_age: Duration, now: SystemTime) -> std::io::Result<Trimmed> {
    let mut copies: Vec<(SystemTime, PathBuf, u64)> = Vec::new();
    for prefix in std::fs::read_dir(dir)? {
        let prefix = prefix?.path();
        let is_prefix = prefix
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.len() == 2 && n.chars().all(|c| c.is_ascii_hexdigit()));
        if !is_prefix || !prefix.is_dir() {
            continue;
        }
        for file in std::fs::read_dir(&prefix)? {
            let file = file?;
            let path = file.path();
            if path.extension().is_some_and(|e| e == "mcap")
                && let Ok(meta) = file.metadata()
                && meta.is_file()
            {
                copies.push((meta.modified().unwrap_or(SystemTime::UNIX_EPOCH), path, meta.len()));
            }
        }
    }
    copies.sort();
    let mut kept_bytes: u64 = copies.iter().map(|c| c.2).sum();
    let mut deleted = 0;
    for (used, path, bytes) in copies {
        if kept_bytes <= max_bytes {
            break;
        }
        if now.duration_since(used).unwrap_or(Duration::ZERO) < min_age {
            // The rest were used later still.
            break;
        }
        match std::fs::remove_file(&path) {
            Ok(()) => {
                deleted += 1;
                kept_bytes -= bytes;
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => kept_bytes -= bytes,
            Err(e) => return Err(e),
        }
    }
    Ok(Trimmed { deleted, kept_bytes })
}

/// Marks the copy at `path` as used now.
pub fn mark_used(path: &Path) {
    if let Ok(file) = std::fs::File::options().append(true).open(path) {
        let _ = file.set_modified(SystemTime::now());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn copy(dir: &Path, n: u8, age: Duration, now: SystemTime) -> PathBuf {
        let sha = format!("{n:02x}").repeat(32);
        let path = dir.join(&sha[..2]).join(format!("{sha}.mcap"));
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, [0u8; 100]).unwrap();
        std::fs::File::options()
            .append(true)
            .open(&path)
            .unwrap()
            .set_modified(now - age)
            .unwrap();
        path
    }

    #[test]
    fn the_least_recently_used_copies_go_first_and_recent_ones_stay() {
        let dir = tempfile::tempdir().unwrap();
        let now = SystemTime::now();
        let hour = Duration::from_secs(3600);
        let a = copy(dir.path(), 0xa1, hour, now);
        let b = copy(dir.path(), 0xb2, 2 * hour, now);
        let c = copy(dir.path(), 0xc3, 3 * hour, now);
        let fresh = copy(dir.path(), 0xd4, Duration::from_secs(60), now);
        // A fetch in progress is not a copy.
        let partial = dir.path().join("a1").join("x.fetch-1-2");
        std::fs::write(&partial, [0u8; 1000]).unwrap();

        let t = trim(dir.path(), 250, MIN_AGE, now).unwrap();
        assert_eq!(
            t,
            Trimmed {
                deleted: 2,
                kept_bytes: 200
            }
        );
        assert!(!c.exists() && !b.exists() && a.exists() && fresh.exists());

        // Under any bound, a copy used within MIN_AGE stays.
        let t = trim(dir.path(), 0, MIN_AGE, now).unwrap();
        assert_eq!(
            t,
            Trimmed {
                deleted: 1,
                kept_bytes: 100
            }
        );
        assert!(!a.exists() && fresh.exists() && partial.exists());

        // Used again: it is the newest.
        let old = copy(dir.path(), 0xe5, 5 * hour, now);
        mark_used(&old);
        let t = trim(dir.path(), 100, MIN_AGE, SystemTime::now() + MIN_AGE + hour).unwrap();
        assert_eq!(t.deleted, 1);
        assert!(old.exists() && !fresh.exists());
    }
}
