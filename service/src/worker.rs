//! The scoring worker pool: one dispatcher claims queued jobs from the database (so jobs survive
//! restarts, and replicas on one database share them) and runs each replay on a blocking thread,
//! at most `workers` at a time, renewing the job's lease while it runs.

use std::sync::Arc;
use std::time::Duration;

use stylet_scoring::Difficulty;

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
            if state.stopping.load(std::sync::atomic::Ordering::SeqCst) {
                return;
            }
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
            // The job's log lines name its session and the request that queued it.
            let span = tracing::info_span!(
                "job",
                session = %job.session_id,
                request = job.request_id.as_deref().unwrap_or("")
            );
            let job_task = async move {
                let _permit = permit;
                if job.attempts > MAX_ATTEMPTS {
                    let why = format!(
                        "claimed {} times without a result (each time the replica scoring it stopped, or its file could not be read)",
                        job.attempts - 1
                    );
                    store_outcome(&state, &job, Outcome::Failed(why)).await;
                    return;
                }
                let heartbeat = tokio::spawn(renew_while_running(state.clone(), job.clone()));
                let outcome = replay(&state, &job).await;
                store_outcome(&state, &job, outcome).await;
                heartbeat.abort();
            };
            tokio::spawn(tracing::Instrument::instrument(job_task, span));
        }
    });
}

/// Renews the job's lease every third of its length until aborted; stops when the job is no
/// longer this replica's (its result will then not be stored: another replica's will).
async fn renew_while_running(state: Arc<AppState>, job: super::store::Job) {
    let mut every = tokio::time::interval(state.store.job_lease() / 3);
    every.tick().await;
    loop {
        every.tick().await;
        match state.store.renew_lease(&job).await {
            Ok(true) => {}
            Ok(false) => {
                tracing::warn!(session = %job.session_id, "the scoring job's lease was lost: another replica has it");
                return;
            }
            Err(e) => tracing::warn!(session = %job.session_id, error = %e, "cannot renew a scoring job's lease"),
        }
    }
}

/// How a replay ended.
enum Outcome {
    Scored(Box<stylet_scoring::ScoreReport>),
    /// The session cannot be scored (damaged beyond use, diverging, no atlas): final.
    Failed(String),
    /// The file could not be read for a reason that may pass (I/O): try again later.
    Retry(String),
}

/// Replays the job's session on a blocking thread; the same replay writes the review trace.
async fn replay(state: &Arc<AppState>, job: &super::store::Job) -> Outcome {
    let file = match state.session_copy(&job.file_sha256).await {
        Ok(file) => file,
        Err(e) if e.is_missing() => return Outcome::Failed(e.to_string()),
        // The object storage may answer later.
        Err(e) => return Outcome::Retry(e.to_string()),
    };
    let trace_file = super::traces::trace_path(&state.config.data_dir, &job.file_sha256);
    let scorer = match super::shared_atlases::loaded(state, &job.atlas_hash).await {
        Ok(l) => Some(l.scorer),
        Err(super::catalogue::LoadError::Unknown(_)) => None,
        // A folder that cannot be read now may be readable later.
        Err(e) => return Outcome::Retry(e.to_string()),
    };
    // The scenario's expert benchmark, when the rubric has one: read now, so the grade (which
    // records it) and the skill estimate measure against the references marked at scoring time.
    let benchmark = match &scorer {
        Some(sc) if sc.rubric().benchmark.is_some() => match expert_benchmark(state, job, sc).await {
            Ok(b) => b,
            Err(e) => return Outcome::Retry(format!("cannot read the expert benchmark: {e}")),
        },
        _ => None,
    };
    let outcome = tokio::task::spawn_blocking(move || {
        let Some(scorer) = scorer else {
            return Outcome::Failed("the session's atlas is not loaded on this server".into());
        };
        let session = match stylet_recorder::reader::recover(&file) {
            Ok(s) => s,
            Err(e @ stylet_recorder::ReadError::Io(_)) => return Outcome::Retry(e.to_string()),
            Err(e) => return Outcome::Failed(format!("{}: {e}", file.display())),
        };
        let replay_started = std::time::Instant::now();
        match scorer.score_session_traced_against(&session, benchmark.as_ref()) {
            Ok((report, trace)) => {
                let ticks = session.ticks.len() as u64;
                metrics::counter!(super::telemetry::REPLAY_TICKS).increment(ticks);
                let replay_s = replay_started.elapsed().as_secs_f64();
                if replay_s > 0.0 {
                    metrics::histogram!(super::telemetry::REPLAY_SPEED).record(ticks as f64 / replay_s);
                }
                // A cache: a failure to store it only costs a replay later.
                if let Err(e) = super::traces::write_trace(&trace_file, &trace) {
                    tracing::warn!(error = %e, "cannot store a review trace");
                }
                Outcome::Scored(Box::new(report))
            }
            Err(e) => Outcome::Failed(e.to_string()),
        }
    })
    .await
    .unwrap_or_else(|e| Outcome::Failed(format!("scoring panicked: {e}")));
    if matches!(outcome, Outcome::Scored(_)) {
        super::traces::share_trace(state, &job.file_sha256).await;
    }
    outcome
}

/// The expert benchmark of the job's scenario: the grade's relative deductions (at levels with
/// them) and the skill estimate beside every grade measure against it (none for a session that
/// is gone, or a level the rubric does not have).
async fn expert_benchmark(
    state: &Arc<AppState>,
    job: &super::store::Job,
    scorer: &stylet_scoring::Scorer,
) -> Result<Option<stylet_scoring::Benchmark>, super::StoreError> {
    let Some((row, _)) = state.store.session(&job.session_id).await? else {
        return Ok(None);
    };
    // The stored level was checked at upload; one that is not a level has no benchmark (and
    // will not be graded).
    let exercise = scorer.exercise_of(&row.scenario);
    let level = row
        .difficulty
        .parse::<Difficulty>()
        .ok()
        .and_then(|d| scorer.rubric().level(exercise, d));
    if level.is_none() {
        return Ok(None);
    }
    let (benchmark, _) = super::experts::benchmark(state, &row.atlas_hash, &row.scenario).await?;
    Ok(Some(benchmark))
}

/// Longest wait between two tries to store a result, or before a job is retried.
const MAX_BACKOFF: Duration = Duration::from_secs(60);
/// Claims of a job whose file cannot be read before it is marked failed (about 7 minutes of
/// back-off in all).
const MAX_READ_ATTEMPTS: i64 = 10;
/// Claims of a job in all (retries and replicas that died while scoring it) before it fails.
const MAX_ATTEMPTS: i64 = 12;

/// Stores what a replay gave. If the store cannot write (a read-only or failing disk), the
/// result is kept and stored again with back-off until it can: a finished replay is never lost
/// and its session never left `scoring`. (If the process dies meanwhile, its lease runs out and
/// another replica, or this one restarted, claims the job again.)
async fn store_outcome(state: &Arc<AppState>, job: &super::store::Job, outcome: Outcome) {
    let stored = store_outcome_with_retries(state, job, outcome).await;
    if let Some(outcome) = stored {
        metrics::counter!(super::telemetry::JOBS, "outcome" => outcome).increment(1);
        metrics::histogram!(super::telemetry::JOB_DURATION, "outcome" => outcome)
            .record(job.claimed_at.elapsed().as_secs_f64());
    }
}

/// [`store_outcome`]'s work: the outcome stored (`scored`, `failed`, `retried`), or `None` when
/// it could not be stored.
async fn store_outcome_with_retries(
    state: &Arc<AppState>,
    job: &super::store::Job,
    outcome: Outcome,
) -> Option<&'static str> {
    let outcome = match outcome {
        Outcome::Retry(e) if job.attempts >= MAX_READ_ATTEMPTS => {
            Outcome::Failed(format!("{e} (after {} attempts)", job.attempts))
        }
        other => other,
    };
    let mut wait = Duration::from_millis(500);
    loop {
        let stored = match &outcome {
            Outcome::Scored(report) => {
                let home = state.config.lrs.as_ref().map(|l| l.public_url.as_str());
                state.store.finish_job(job, report, home).await
            }
            Outcome::Failed(e) => state.store.fail_job(job, e).await,
            Outcome::Retry(_) => {
                // 2, 4, 8 … s after each failed try, at most a minute.
                let after = Duration::from_secs(1 << job.attempts.clamp(1, 6)).min(MAX_BACKOFF);
                state.store.requeue_job(job, after).await
            }
        };
        match (stored, &outcome) {
            (Ok(()), Outcome::Scored(r)) => {
                tracing::info!(session = %job.session_id, score = r.grade.score, verified = r.replay_verified, "scored");
                return Some("scored");
            }
            (Ok(()), Outcome::Failed(e)) => {
                tracing::warn!(session = %job.session_id, error = %e, "scoring failed");
                return Some("failed");
            }
            (Ok(()), Outcome::Retry(e)) => {
                tracing::warn!(session = %job.session_id, error = %e, attempts = job.attempts, "cannot read the session now; queued again");
                return Some("retried");
            }
            (Err(e), _) if e.is_transient() => {
                tracing::error!(session = %job.session_id, error = %e, retry_s = wait.as_secs_f64(), "cannot store the result; will try again");
                tokio::time::sleep(wait).await;
                wait = (wait * 2).min(MAX_BACKOFF);
            }
            (Err(e), _) => {
                // Not the disk: retrying would not help. The job stays running until its lease
                // runs out; then it is claimed again.
                tracing::error!(session = %job.session_id, error = %e, "cannot store the result");
                return None;
            }
        }
    }
}
