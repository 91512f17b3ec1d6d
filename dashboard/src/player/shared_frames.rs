//! Player frames shared through the object store (`stylet serve --storage`): a frame one replica
//! drew is served by the others from the store instead of being drawn again (a frame costs a
//! replay to the tick and a render; reading it back costs one GET).
//!
//! A frame's key is its path in the data directory (`frames/ab/<sha>/<name>.png`). Each session
//! shares at most [`SHARED_BYTES_PER_SESSION`] of frames — the store grows with the sessions
//! stored, which the accounts' limits bound, not with how many frames instructors look at —
//! and past it frames stay in each replica's own cache. Deleting a session deletes its shared
//! frames. Sharing is best effort: a frame is drawn and served whether or not the store takes it.

use std::path::Path;
use std::sync::Arc;

use stylet_service::AppState;
use stylet_service::storage::frames_prefix;

use super::frames::FrameCache;

/// Most bytes of one session's frames in the object store: about 400 frames of the player's
/// sizes (a few minutes of playback at its pace).
pub const SHARED_BYTES_PER_SESSION: u64 = 64 << 20;

/// Largest frame read back from the store (the largest drawn are well under 1 MiB).
const MAX_FRAME_BYTES: u64 = 8 << 20;

/// The frame at `path` from the object store, kept in this replica's cache too; None without a
/// store, when no replica shared it, or when the store does not answer (then it is drawn).
pub async fn fetch(s: &AppState, cache: &Arc<FrameCache>, path: &Path) -> Option<Vec<u8>> {
    if !s.storage.is_shared() {
        return None;
    }
    let key = key_of(s, path)?;
    match s.storage.read_shared(&key, MAX_FRAME_BYTES).await {
        Ok(Some(png)) => {
            let (cache, path, kept) = (Arc::clone(cache), path.to_path_buf(), png.clone());
            // The local copy is a small write; it must not hold up the answer.
            tokio::task::spawn_blocking(move || cache.put(&path, &kept));
            Some(png)
        }
        Ok(None) => None,
        Err(e) => {
            tracing::warn!(error = %e, "cannot read a shared player frame; drawing it");
            None
        }
    }
}

/// Puts a frame this replica drew of the session file `sha` into the object store, in the
/// background, unless the session's shared frames would go over [`SHARED_BYTES_PER_SESSION`].
pub fn share(s: &Arc<AppState>, sha: &str, path: &Path, png: Vec<u8>) {
    if !s.storage.is_shared() {
        return;
    }
    let Some(key) = key_of(s, path) else { return };
    let (s, prefix) = (Arc::clone(s), frames_prefix(sha));
    tokio::spawn(async move {
        let shared = async {
            let stored = s.storage.shared_folder_bytes(&prefix).await?;
            if fits(stored, png.len() as u64) {
                s.storage.write_shared(&key, png).await?;
            }
            Ok::<(), stylet_service::storage::StorageError>(())
        };
        if let Err(e) = shared.await {
            tracing::warn!(error = %e, "cannot share a player frame");
        }
    });
}

/// Whether a frame of `bytes` joins a session's `stored` shared bytes within the bound.
fn fits(stored: u64, bytes: u64) -> bool {
    stored.saturating_add(bytes) <= SHARED_BYTES_PER_SESSION
}

/// The object key of a frame: its path relative to the data directory, with `/`.
fn key_of(s: &AppState, path: &Path) -> Option<String> {
    let rel = path.strip_prefix(&s.config.data_dir).ok()?;
    Some(rel.to_string_lossy().replace('\\', "/"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sessions_shared_frames_stop_at_the_bound() {
        assert!(fits(0, 1000));
        assert!(fits(SHARED_BYTES_PER_SESSION - 1000, 1000));
        assert!(!fits(SHARED_BYTES_PER_SESSION - 999, 1000));
        // A folder listed as over the object count reads as u64::MAX bytes.
        assert!(!fits(u64::MAX, 1));
    }
}
