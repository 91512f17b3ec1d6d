//! Room on the data directory's disk for what is arriving: each upload reserves its size before
//! its body is read, and is refused (503, `Retry-After`) when the free space, less what the
//! uploads already arriving may still write, would fall under [`Limits::min_free_disk_bytes`].
//! The margin keeps room for the database, for deleting (SQLite writes its journal even to
//! delete) and for the scores of sessions already stored.
//!
//! [`Limits::min_free_disk_bytes`]: crate::Limits::min_free_disk_bytes

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use super::error::ApiError;

/// Bytes reserved by the uploads arriving now.
#[derive(Debug, Default)]
pub struct DiskBudget {
    reserved: AtomicU64,
}

/// Free bytes for an unprivileged writer on the file system of `path`.
pub fn free_bytes(path: &Path) -> std::io::Result<u64> {
    let st = rustix::fs::statvfs(path)?;
    Ok(st.f_bavail.saturating_mul(st.f_frsize))
}

impl DiskBudget {
    /// Reserves `bytes` on the disk of `dir` leaving at least `min_free`, or 503 with
    /// `Retry-After`. The reservation ends when the returned guard is dropped.
    pub fn reserve(self: &Arc<Self>, dir: &Path, bytes: u64, min_free: u64) -> Result<Reservation, ApiError> {
        let free = free_bytes(dir).map_err(|e| {
            tracing::error!(error = %e, dir = %dir.display(), "cannot read the free disk space");
            ApiError::Unavailable("the server cannot check its disk space right now; try again later".into())
        })?;
        let before = self.reserved.fetch_add(bytes, Ordering::SeqCst);
        let guard = Reservation {
            budget: self.clone(),
            bytes,
        };
        if free < before.saturating_add(bytes).saturating_add(min_free) {
            tracing::warn!(
                free,
                reserved = before,
                asked = bytes,
                min_free,
                "upload refused: the disk is too full"
            );
            return Err(ApiError::Unavailable(
                "the server's disk is too full to take this upload now; try again later".into(),
            ));
        }
        Ok(guard)
    }

    /// Bytes reserved now.
    pub fn reserved(&self) -> u64 {
        self.reserved.load(Ordering::SeqCst)
    }
}

/// Reserved room; dropping it frees the reservation (what was written stays counted by the
/// file system itself).
#[derive(Debug)]
pub struct Reservation {
    budget: Arc<DiskBudget>,
    bytes: u64,
}

impl Drop for Reservation {
    fn drop(&mut self) {
        self.budget.reserved.fetch_sub(self.bytes, Ordering::SeqCst);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reservations_add_up_and_are_refused_past_the_free_space() {
        let dir = tempfile::tempdir().unwrap();
        let free = free_bytes(dir.path()).unwrap();
        assert!(free > 0);
        let budget = Arc::new(DiskBudget::default());
        let half = budget.reserve(dir.path(), free / 2, 0).unwrap();
        assert_eq!(budget.reserved(), free / 2);
        // Another half and a margin do not fit beside the first.
        let e = budget.reserve(dir.path(), free / 2, free / 8).unwrap_err();
        assert_eq!(e.status(), axum::http::StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(budget.reserved(), free / 2, "a refused reservation holds nothing");
        drop(half);
        assert_eq!(budget.reserved(), 0);
        assert!(budget.reserve(dir.path(), free / 2, 0).is_ok());
    }
}
