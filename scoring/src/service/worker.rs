//! The scoring worker pool: one dispatcher claims queued jobs from the database (so jobs survive
//! restarts) and runs each replay on a blocking thread, at most `workers` at a time.

use std::sync::Arc;
use std::time::Duration;

use super::AppState;

pub fn start(state: Arc<AppState>) {
    tokio::spawn(async move {
        let permits = Arc::new(tokio::sync::Semaphore::new(state.config.workers.max(1)));
        loop {
            let permit = permits
                .clone()
                .acquire_owned()
                .await
                .expect("the semaphore is never closed");
            let job = match state.store.claim_job().await {
                Ok(Some(job)) => job,
                Ok(None) => {
                    drop(permit);
                    // New uploads wake the dispatcher; the timeout is a safety net.
                    let _ = tokio::time::timeout(Duration::from_millis(500), state.wake.notified()).await;
                    continue;
                }
                Err(e) => {
                    tracing::error!(error = %e, "cannot claim a scoring job");
                    drop(permit);
                    tokio::time::sleep(Duration::from_secs(1)).await;
                    continue;
                }
            };
            let state = state.clone();
            tokio::spawn(async move {
                let _permit = permit;
                let file = state.session_file(&job.file_sha256);
                let scorer = state.scorers.get(&job.atlas_hash).cloned();
                let result = tokio::task::spawn_blocking(move || match scorer {
                    Some(s) => s.score_file(&file).map_err(|e| e.to_string()),
                    None => Err("the session's atlas is not loaded on this server".to_string()),
                })
                .await
                .unwrap_or_else(|e| Err(format!("scoring panicked: {e}")));
                let stored = match &result {
                    Ok(report) => state.store.finish_job(&job, report).await,
                    Err(e) => state.store.fail_job(&job, e).await,
                };
                match (stored, result) {
                    (Ok(()), Ok(r)) => {
                        tracing::info!(session = %job.session_id, score = r.grade.score, verified = r.replay_verified, "scored")
                    }
                    (Ok(()), Err(e)) => tracing::warn!(session = %job.session_id, error = %e, "scoring failed"),
                    (Err(e), _) => tracing::error!(session = %job.session_id, error = %e, "cannot store the result"),
                }
            });
        }
    });
}
