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
                let trace_file = super::traces::trace_path(&state.config.data_dir, &job.file_sha256);
                let scorer = state.scorers.get(&job.atlas_hash).cloned();
                let result = tokio::task::spawn_blocking(move || {
                    let scorer = scorer.ok_or("the session's atlas is not loaded on this server")?;
                    let session =
                        stylet_recorder::reader::recover(&file).map_err(|e| format!("{}: {e}", file.display()))?;
                    // One replay gives the score and what the dashboard draws (a cache: a
                    // failure to store it only costs a replay later).
                    let (report, trace) = scorer.score_session_traced(&session).map_err(|e| e.to_string())?;
                    if let Err(e) = super::traces::write_trace(&trace_file, &trace) {
                        tracing::warn!(error = %e, "cannot store a review trace");
                    }
                    Ok::<_, String>(report)
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
