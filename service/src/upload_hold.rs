//! A place for one upload (a session or an atlas archive): one of the server's upload slots (in
//! memory: they bound this replica's work) and one of the account's (in the database: the
//! per-account cap holds across replicas), the latter's lease renewed while the upload runs.
//! [`UploadHold::release`] gives both back once the upload is done; dropping the hold (a request
//! cut short) gives them back too, a moment later.

use super::AppState;
use super::error::{ApiError, RETRY_AFTER_S};
use super::slots::Slot;
use super::store::{Store, UploadSlotKey};

/// A held upload place.
pub struct UploadHold {
    _server: Slot,
    account: Option<(Store, UploadSlotKey)>,
    renewing: tokio::task::JoinHandle<()>,
}

/// Takes an upload place for `account` (an account id): 503 when the server receives as many
/// uploads as it may, 429 when the account sends as many as it may (on any replica).
pub async fn take(s: &AppState, account: &str) -> Result<UploadHold, ApiError> {
    let server = s.upload_slots.take(account)?;
    let cap = s.config.limits.max_uploads_per_account;
    let Some(key) = s.store.take_upload_slot(account, cap).await? else {
        tracing::info!(account, cap, "refused: the account's uploads are at the cap");
        return Err(ApiError::Throttled {
            message: format!("you have {cap} uploads in progress, the most one account may; wait for one to finish"),
            retry_after_s: RETRY_AFTER_S,
        });
    };
    let renewing = tokio::spawn(renew(s.store.clone(), key.clone()));
    Ok(UploadHold {
        _server: server,
        account: Some((s.store.clone(), key)),
        renewing,
    })
}

/// Renews the slot's lease every third of its length until aborted.
async fn renew(store: Store, key: UploadSlotKey) {
    let mut every = tokio::time::interval(Store::UPLOAD_SLOT_LEASE / 3);
    every.tick().await;
    loop {
        every.tick().await;
        match store.renew_upload_slot(&key).await {
            Ok(true) => {}
            Ok(false) => return,
            Err(e) => tracing::warn!(error = %e, "cannot renew an upload slot's lease"),
        }
    }
}

impl UploadHold {
    /// Gives the place back now (the next upload of the account may start at once).
    pub async fn release(mut self) {
        self.renewing.abort();
        if let Some((store, key)) = self.account.take()
            && let Err(e) = store.release_upload_slot(&key).await
        {
            // Its lease runs out on its own.
            tracing::warn!(error = %e, "cannot give an upload slot back");
        }
    }
}

impl Drop for UploadHold {
    fn drop(&mut self) {
        self.renewing.abort();
        if let Some((store, key)) = self.account.take()
            && let Ok(runtime) = tokio::runtime::Handle::try_current()
        {
            runtime.spawn(async move {
                if let Err(e) = store.release_upload_slot(&key).await {
                    tracing::warn!(error = %e, "cannot give an upload slot back");
                }
            });
        }
    }
}
