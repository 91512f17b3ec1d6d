//! What every replica does now and then: delete logins past their expiry, login-attempt windows
//! that have passed, upload slots whose lease ran out (their replica died); with object storage,
//! let go of the least recently used local copies of session files past their bound
//! ([`super::local_copies`]); bring its atlas
//! catalogue in line with the publications made at other replicas
//! ([`super::shared_atlases::sync`]). Each replica runs it; the deletions are idempotent, so
//! replicas running it at once only repeat each other.

use std::sync::Arc;
use std::time::Duration;

use super::AppState;

/// How often the expired rows are deleted.
pub const EVERY: Duration = Duration::from_secs(60);

/// Starts the housekeeping task; it ends with the process.
pub fn start(state: Arc<AppState>) {
    let catalogue_state = state.clone();
    tokio::spawn(async move {
        let mut every = tokio::time::interval(super::shared_atlases::SYNC_EVERY);
        // The first tick is at once: serve() has just synced.
        every.tick().await;
        loop {
            every.tick().await;
            if catalogue_state.stopping.load(std::sync::atomic::Ordering::SeqCst) {
                return;
            }
            super::shared_atlases::sync(&catalogue_state).await;
        }
    });
    tokio::spawn(async move {
        let mut every = tokio::time::interval(EVERY);
        loop {
            every.tick().await;
            if state.stopping.load(std::sync::atomic::Ordering::SeqCst) {
                return;
            }
            match state.store.purge_expired(super::logins::LOGIN_WINDOW).await {
                Ok(0) => {}
                Ok(deleted) => tracing::debug!(deleted, "expired rows deleted"),
                Err(e) => tracing::warn!(error = %e, "cannot delete expired rows"),
            }
            if state.storage.url().is_some() {
                let (dir, max) = (
                    state.config.data_dir.join("sessions"),
                    state.config.limits.local_copies_bytes,
                );
                let trimmed = tokio::task::spawn_blocking(move || {
                    super::local_copies::trim(&dir, max, super::local_copies::MIN_AGE, std::time::SystemTime::now())
                })
                .await;
                match trimmed {
                    Ok(Ok(t)) if t.deleted > 0 => {
                        tracing::info!(
                            deleted = t.deleted,
                            kept_bytes = t.kept_bytes,
                            "local copies of session files let go"
                        )
                    }
                    Ok(Ok(_)) => {}
                    Ok(Err(e)) => tracing::warn!(error = %e, "cannot trim the local copies of session files"),
                    Err(e) => tracing::warn!(error = %e, "trimming the local copies panicked"),
                }
            }
        }
    });
}
