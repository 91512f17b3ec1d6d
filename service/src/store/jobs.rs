//! Scoring jobs: queued in the database, claimed by the worker pool, finished exactly once.

use sqlx::Row;

use stylet_scoring::{Exercise, Outcome};

use super::{SessionStatus, Store, StoreError, from_now, now};

/// Which jobs may be claimed at `$1` (now): queued ones past their back-off, and running ones
/// whose lease ran out (their replica died; `NULL`: claimed by a server from before leases).
const CLAIMABLE: &str = "((j.state = 'queued' AND (j.not_before IS NULL OR j.not_before <= $1)) \
     OR (j.state = 'running' AND (j.lease_until IS NULL OR j.lease_until < $1)))";

impl Store {
    /// At start: the jobs this replica held when its previous run stopped (killed, or the
    /// machine lost) go back to the queue at once; other replicas' jobs are theirs until their
    /// leases run out. Returns how many.
    pub async fn release_own_leases(&self) -> Result<u64, StoreError> {
        let mut tx = self.begin_write().await?;
        sqlx::query(
            "UPDATE sessions SET status = $1 WHERE id IN \
             (SELECT session_id FROM scoring_jobs WHERE state = 'running' AND lease_owner = $2)",
        )
        .bind(SessionStatus::Queued.as_str())
        .bind(self.replica.to_string())
        .execute(&mut *tx)
        .await?;
        let r = sqlx::query(
            "UPDATE scoring_jobs SET state = 'queued', started_at = NULL, lease_owner = NULL, lease_until = NULL \
             WHERE state = 'running' AND lease_owner = $1",
        )
        .bind(self.replica.to_string())
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(r.rows_affected())
    }

    /// Claims the oldest claimable job with a lease of [`Store::with_job_lease`] for this
    /// replica. PostgreSQL picks it `FOR UPDATE SKIP LOCKED`, so replicas claiming at once take
    /// different jobs without waiting on each other; SQLite has one writer at a time, and the
    /// pick and the claim happen under its write lock. Either way the claim is conditional: a
    /// job is claimed by one replica at a time.
    pub async fn claim_job(&self) -> Result<Option<Job>, StoreError> {
        let now = now();
        let until = from_now(self.job_lease);
        let pick = if self.sqlite {
            format!("SELECT j.id FROM scoring_jobs j WHERE {CLAIMABLE} ORDER BY j.created_at, j.id LIMIT 1")
        } else {
            format!(
                "SELECT j.id FROM scoring_jobs j WHERE {CLAIMABLE} ORDER BY j.created_at, j.id LIMIT 1 FOR UPDATE SKIP LOCKED"
            )
        };
        let mut tx = self.begin_write().await?;
        let Some(id) = sqlx::query(sqlx::AssertSqlSafe(pick))
            .bind(now.clone())
            .fetch_optional(&mut *tx)
            .await?
            .map(|r| r.try_get::<String, _>("id"))
            .transpose()?
        else {
            tx.rollback().await?;
            return Ok(None);
        };
        let claimed = sqlx::query(sqlx::AssertSqlSafe(format!(
            "UPDATE scoring_jobs SET state = 'running', started_at = $1, attempts = attempts + 1, lease_owner = $2, \
             lease_until = $3 WHERE id = $4 AND id IN (SELECT j.id FROM scoring_jobs j WHERE {CLAIMABLE})"
        )))
        .bind(now.clone())
        .bind(self.replica.to_string())
        .bind(until)
        .bind(id.clone())
        .execute(&mut *tx)
        .await?;
        if claimed.rows_affected() != 1 {
            tx.rollback().await?;
            return Ok(None);
        }
        let row = sqlx::query(
            "SELECT j.id, j.session_id, j.attempts, j.request_id, s.file_sha256, s.atlas_hash FROM scoring_jobs j \
             JOIN sessions s ON s.id = j.session_id WHERE j.id = $1",
        )
        .bind(id)
        .fetch_one(&mut *tx)
        .await?;
        let job = Job {
            id: row.try_get("id")?,
            session_id: row.try_get("session_id")?,
            attempts: row.try_get("attempts")?,
            file_sha256: row.try_get("file_sha256")?,
            atlas_hash: row.try_get("atlas_hash")?,
            request_id: row.try_get("request_id")?,
            claimed_at: std::time::Instant::now(),
        };
        sqlx::query("UPDATE sessions SET status = $2 WHERE id = $1")
            .bind(job.session_id.clone())
            .bind(SessionStatus::Scoring.as_str())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(Some(job))
    }

    /// Renews this replica's lease on a job it is replaying; `false` when the job is no longer
    /// its (the lease ran out and another replica claimed it, or it was closed).
    pub async fn renew_lease(&self, job: &Job) -> Result<bool, StoreError> {
        let r = sqlx::query(
            "UPDATE scoring_jobs SET lease_until = $1 WHERE id = $2 AND state = 'running' AND lease_owner = $3",
        )
        .bind(from_now(self.job_lease))
        .bind(job.id.clone())
        .bind(self.replica.to_string())
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Stores a score and closes its job in one transaction, unless the job is no longer this
    /// worker's (finished elsewhere, or its session deleted meanwhile); a second score for the
    /// same session is refused by the key (never scored twice).
    ///
    /// With `xapi_home` (an LRS is configured: the service's public address), the session's
    /// xAPI statements are queued in the same transaction ([`crate::xapi`]).
    pub async fn finish_job(
        &self,
        job: &Job,
        report: &stylet_scoring::ScoreReport,
        xapi_home: Option<&str>,
    ) -> Result<(), StoreError> {
        let json = serde_json::to_string(report).map_err(|e| StoreError::Invalid(e.to_string()))?;
        let mut tx = self.begin_write().await?;
        let closed =
            sqlx::query("UPDATE scoring_jobs SET state = 'done', finished_at = $1, lease_until = NULL WHERE id = $2 AND state = 'running' AND lease_owner = $3")
                .bind(now())
                .bind(job.id.clone())
                .bind(self.replica.to_string())
                .execute(&mut *tx)
                .await?;
        if closed.rows_affected() != 1 {
            tx.rollback().await?;
            return Ok(());
        }
        sqlx::query(
            "INSERT INTO scores (session_id, score, passed, difficulty, rubric, rubric_version, physics_version, replay_verified, \
             incomplete, report_json, scored_at) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11)",
        )
        .bind(job.session_id.clone())
        .bind(report.grade.score)
        .bind(report.grade.passed)
        .bind(report.grade.difficulty.as_str().to_string())
        .bind(report.grade.rubric.clone())
        .bind(report.grade.rubric_version as i64)
        .bind(report.physics_version as i64)
        .bind(report.replay_verified)
        .bind(report.incomplete)
        .bind(json)
        .bind(now())
        .execute(&mut *tx)
        .await?;
        write_summary(&mut tx, &job.session_id, &Summary::from_report(report)).await?;
        if let Some(home) = xapi_home {
            let row = sqlx::query(
                "SELECT u.username, s.scenario, s.difficulty, s.recorded_at, s.duration_s FROM sessions s \
                 JOIN users u ON u.id = s.trainee_id WHERE s.id = $1",
            )
            .bind(job.session_id.clone())
            .fetch_one(&mut *tx)
            .await?;
            let (trainee, scenario, difficulty, recorded_at): (String, String, String, String) = (
                row.try_get("username")?,
                row.try_get("scenario")?,
                row.try_get("difficulty")?,
                row.try_get("recorded_at")?,
            );
            let session = crate::xapi::ScoredSession {
                session_id: &job.session_id,
                trainee: &trainee,
                scenario: &scenario,
                difficulty: &difficulty,
                recorded_at: &recorded_at,
                duration_s: row.try_get("duration_s")?,
                report,
            };
            let statements: Vec<super::OutboxStatement> = crate::xapi::statements(home, &session)
                .into_iter()
                .map(|(verb, id, json)| (id, verb.name(), json.to_string()))
                .collect();
            Self::queue_statements(&mut tx, &job.session_id, &statements).await?;
        }
        if !report.incomplete {
            let scored_at = now();
            Self::queue_grades(&mut tx, &job.session_id, |subject| {
                crate::lti::grades::score_json(subject, report, &scored_at)
            })
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    /// Puts a running job back in the queue, not to be claimed again for `after` (its file could
    /// not be read for a passing reason). Unless it is no longer this worker's.
    pub async fn requeue_job(&self, job: &Job, after: std::time::Duration) -> Result<(), StoreError> {
        let not_before = from_now(after);
        let mut tx = self.begin_write().await?;
        let back = sqlx::query(
            "UPDATE scoring_jobs SET state = 'queued', started_at = NULL, not_before = $1, lease_owner = NULL, lease_until = NULL \
             WHERE id = $2 AND state = 'running' AND lease_owner = $3",
        )
        .bind(not_before)
        .bind(job.id.clone())
        .bind(self.replica.to_string())
        .execute(&mut *tx)
        .await?;
        if back.rows_affected() != 1 {
            tx.rollback().await?;
            return Ok(());
        }
        sqlx::query("UPDATE sessions SET status = $2 WHERE id = $1")
            .bind(job.session_id.clone())
            .bind(SessionStatus::Queued.as_str())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(())
    }

    /// Marks a job and its session failed, unless the job is no longer this worker's to close
    /// (finished or re-queued meanwhile): a late failure never overwrites a score.
    pub async fn fail_job(&self, job: &Job, error: &str) -> Result<(), StoreError> {
        let mut tx = self.begin_write().await?;
        let closed = sqlx::query(
            "UPDATE scoring_jobs SET state = 'failed', finished_at = $1, lease_until = NULL WHERE id = $2 AND state = 'running' \
             AND lease_owner = $3",
        )
        .bind(now())
        .bind(job.id.clone())
        .bind(self.replica.to_string())
        .execute(&mut *tx)
        .await?;
        if closed.rows_affected() != 1 {
            tx.rollback().await?;
            return Ok(());
        }
        sqlx::query("UPDATE sessions SET status = $3, error = $1 WHERE id = $2")
            .bind(error.to_string())
            .bind(job.session_id.clone())
            .bind(SessionStatus::Failed.as_str())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(())
    }
}

impl Store {
    /// Phrases the reasons of sessions scored before migration 0005 from their stored reports
    /// (once: later scores write them as they happen). Bounded: 500 rows per call, called until
    /// none is left.
    pub(super) async fn fill_session_reasons(&self) -> Result<(), StoreError> {
        loop {
            let rows = sqlx::query(
                "SELECT s.id, sc.report_json FROM sessions s JOIN scores sc ON sc.session_id = s.id \
                 WHERE s.reasons IS NULL ORDER BY s.id LIMIT 500",
            )
            .fetch_all(&self.pool)
            .await?;
            if rows.is_empty() {
                return Ok(());
            }
            for r in rows {
                let id: String = r.try_get("id")?;
                let report: stylet_scoring::ScoreReport = serde_json::from_str(&r.try_get::<String, _>("report_json")?)
                    .map_err(|e| StoreError::Invalid(format!("stored report of session {id}: {e}")))?;
                let summary = Summary::from_report(&report);
                sqlx::query(
                    "UPDATE sessions SET outcome = $1, reasons = $2, target_reached = $3, risk_structures = $4 WHERE id = $5",
                )
                .bind(summary.outcome.as_str())
                .bind(join_reasons(&summary.reasons))
                .bind(i64::from(summary.target_reached))
                .bind(join_structures(&summary.risk_structures))
                .bind(id)
                    .execute(&self.pool)
                    .await?;
            }
        }
    }
}

impl Store {
    /// The outcome columns of every session, by id (one query: the CSV export joins them to its
    /// lines).
    pub async fn outcome_columns(&self) -> Result<std::collections::BTreeMap<String, OutcomeColumns>, StoreError> {
        let rows = sqlx::query(
            "SELECT id, exercise, outcome, reasons, target_reached, risk_structures, skill_z FROM sessions",
        )
        .fetch_all(&self.pool)
        .await?;
        let mut out = std::collections::BTreeMap::new();
        for r in rows {
            let structures: Option<String> = r.try_get("risk_structures")?;
            out.insert(
                r.try_get::<String, _>("id")?,
                OutcomeColumns {
                    exercise: Exercise::parse(&r.try_get::<String, _>("exercise")?).unwrap_or_default(),
                    outcome: r
                        .try_get::<Option<String>, _>("outcome")?
                        .and_then(|o| Outcome::parse(&o)),
                    reasons: split_reasons(r.try_get::<Option<String>, _>("reasons")?.as_deref()),
                    target_reached: r.try_get::<Option<i64>, _>("target_reached")?.map(|v| v != 0),
                    risk_structures: structures
                        .map(|s| s.split(';').filter(|n| !n.is_empty()).map(str::to_string).collect())
                        .unwrap_or_default(),
                    skill_z: r.try_get("skill_z")?,
                },
            );
        }
        Ok(out)
    }
}

/// A claimed scoring job.
#[derive(Debug, Clone)]
pub struct Job {
    pub id: String,
    pub session_id: String,
    /// How many times it has been claimed, this time included.
    pub attempts: i64,
    pub file_sha256: String,
    pub atlas_hash: String,
    /// The id of the request that queued it (the upload), if it came from one.
    pub request_id: Option<String>,
    /// When this replica claimed it (job durations).
    pub claimed_at: std::time::Instant,
}

/// What a session's row keeps of its score (migrations 0002 and 0005).
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    pub score: f64,
    pub passed: bool,
    pub attempts: i64,
    pub risk_hits: i64,
    pub replay_verified: bool,
    pub rubric_version: i64,
    pub exercise: Exercise,
    pub outcome: Outcome,
    /// In plain words, one per line on the row.
    pub reasons: Vec<String>,
    pub target_reached: bool,
    /// Names of the risk structures hit.
    pub risk_structures: Vec<String>,
    /// The skill estimate against the experts (mean spreads from their mean), when there was one.
    pub skill_z: Option<f64>,
}

impl Summary {
    pub fn from_report(r: &stylet_scoring::ScoreReport) -> Summary {
        Summary {
            score: r.grade.score,
            passed: r.grade.passed,
            attempts: i64::from(r.metrics.attempts),
            risk_hits: r.metrics.risk_hits.len() as i64,
            replay_verified: r.replay_verified,
            rubric_version: i64::from(r.grade.rubric_version),
            exercise: r.exercise,
            outcome: r.outcome,
            reasons: r.reasons.clone(),
            target_reached: r.metrics.target_reached,
            risk_structures: r.metrics.risk_hits.iter().map(|h| h.structure.clone()).collect(),
            skill_z: r.skill.as_ref().map(|s| s.z_mean),
        }
    }

    /// From a stored report (JSON of [`stylet_scoring::ScoreReport`], any age: reports stored
    /// before exercises and outcomes get theirs from the grade).
    pub fn from_json(v: &serde_json::Value) -> Option<Summary> {
        let report: stylet_scoring::ScoreReport = serde_json::from_value(v.clone()).ok()?;
        Some(Summary::from_report(&report))
    }
}

/// A session's reasons as stored on its row: one per line (a reason never holds a line break).
pub fn join_reasons(reasons: &[String]) -> String {
    reasons
        .iter()
        .map(|r| r.replace(['\n', '\r'], " "))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Risk structure names as stored: `;`-separated (a `;` inside a name becomes `,`).
fn join_structures(names: &[String]) -> String {
    names.iter().map(|n| n.replace(';', ",")).collect::<Vec<_>>().join(";")
}

/// What the CSV shows of a session's outcome (migration 0005), by session id.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OutcomeColumns {
    pub exercise: Exercise,
    pub outcome: Option<Outcome>,
    pub reasons: Vec<String>,
    pub target_reached: Option<bool>,
    pub risk_structures: Vec<String>,
    /// The skill estimate against the experts (migration 0011).
    pub skill_z: Option<f64>,
}

/// The reasons of a row's `reasons` column.
pub fn split_reasons(stored: Option<&str>) -> Vec<String> {
    stored
        .map(|s| s.lines().filter(|l| !l.is_empty()).map(str::to_string).collect())
        .unwrap_or_default()
}

/// Marks a session scored and writes its summary; the final grade is the computed one unless an
/// instructor has overridden it already.
pub(super) async fn write_summary(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    session_id: &str,
    s: &Summary,
) -> Result<(), StoreError> {
    sqlx::query(
        "UPDATE sessions SET status = 'scored', attempts = $1, risk_hits = $2, replay_verified = $3, rubric_version = $4, \
         final_score = CASE WHEN overridden = 1 THEN final_score ELSE $5 END, \
         final_passed = CASE WHEN overridden = 1 THEN final_passed ELSE $6 END, \
         exercise = $8, outcome = $9, reasons = $10, target_reached = $11, risk_structures = $12 WHERE id = $7",
    )
    .bind(s.attempts)
    .bind(s.risk_hits)
    .bind(i64::from(s.replay_verified))
    .bind(s.rubric_version)
    .bind(s.score)
    .bind(i64::from(s.passed))
    .bind(session_id.to_string())
    .bind(s.exercise.as_str())
    .bind(s.outcome.as_str())
    .bind(join_reasons(&s.reasons))
    .bind(i64::from(s.target_reached))
    .bind(join_structures(&s.risk_structures))
    .execute(&mut **tx)
    .await?;
    // The skill estimate in a statement of its own, NULL written as a literal: through sqlx's
    // `Any` driver PostgreSQL refuses a number for a parameter its connection first saw as NULL
    // ("incorrect binary data format in bind parameter"), and a score that cannot be stored
    // leaves its session scoring.
    match s.skill_z {
        Some(z) => {
            sqlx::query("UPDATE sessions SET skill_z = $1 WHERE id = $2")
                .bind(z)
                .bind(session_id.to_string())
                .execute(&mut **tx)
                .await?
        }
        None => {
            sqlx::query("UPDATE sessions SET skill_z = NULL WHERE id = $1")
                .bind(session_id.to_string())
                .execute(&mut **tx)
                .await?
        }
    };
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::{NewSession, SessionStatus, new_id};
    use super::*;

    /// Sessions scored with and without a skill estimate, in turns, and comments with and without
    /// a moment, in turns, all stored (PostgreSQL refused a bound number after a bound NULL).
    async fn numbers_after_nulls_are_stored(store: Store) {
        store.register_atlas("atlas-hash", "phantom", "/nowhere").await.unwrap();
        let trainee = store
            .add_user("tina", "trainee", "tina-password", None, None)
            .await
            .unwrap();
        let author = store.user_by_name("tina").await.unwrap().unwrap();
        let report: stylet_scoring::ScoreReport =
            serde_json::from_str(include_str!("../../tests/data/report.json")).unwrap();
        for (k, skill) in [None, Some(1.25), None, Some(-0.5)].into_iter().enumerate() {
            let session_id = store
                .insert_session(&NewSession {
                    file_sha256: format!("{k}").repeat(64),
                    size_bytes: 10,
                    session_uuid: new_id(),
                    trainee_id: trainee.clone(),
                    uploaded_by: trainee.clone(),
                    scenario: "success".into(),
                    difficulty: "beginner".into(),
                    atlas_hash: "atlas-hash".into(),
                    physics_version: 2,
                    duration_s: 1.0,
                    recorded_at: now(),
                    request_id: None,
                })
                .await
                .unwrap();
            let job = store.claim_job().await.unwrap().expect("the queued job");
            let mut r = report.clone();
            r.session_id = session_id.clone();
            r.skill = skill.map(|z| stylet_scoring::benchmark::SkillEstimate {
                experts: 3,
                z_mean: z,
                metrics: Vec::new(),
            });
            store.finish_job(&job, &r, None).await.unwrap();
            assert_eq!(store.outcome_columns().await.unwrap()[&session_id].skill_z, skill);
            store
                .add_comment(&session_id, &author, "look here", skill.map(|z| z.abs()))
                .await
                .unwrap();
        }
    }

    #[tokio::test]
    async fn numbers_after_nulls_are_stored_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        let url = format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display());
        numbers_after_nulls_are_stored(Store::open(&url).await.unwrap()).await;
    }

    #[tokio::test]
    async fn numbers_after_nulls_are_stored_postgres() {
        let url = super::super::fresh_postgres_database("nulls").await;
        numbers_after_nulls_are_stored(Store::open(&url).await.unwrap()).await;
    }

    /// A trainee and `n` uploaded sessions (each with its queued job) in `store`.
    async fn sessions(store: &Store, n: usize) -> Vec<String> {
        store.register_atlas("atlas-hash", "phantom", "/nowhere").await.unwrap();
        let trainee = store
            .add_user("tina", "trainee", "tina-password", None, None)
            .await
            .unwrap();
        let mut out = Vec::new();
        for k in 0..n {
            out.push(
                store
                    .insert_session(&NewSession {
                        file_sha256: format!("{k:064x}"),
                        size_bytes: 10,
                        session_uuid: new_id(),
                        trainee_id: trainee.clone(),
                        uploaded_by: trainee.clone(),
                        scenario: "success".into(),
                        difficulty: "beginner".into(),
                        atlas_hash: "atlas-hash".into(),
                        physics_version: 2,
                        duration_s: 1.0,
                        recorded_at: now(),
                        request_id: None,
                    })
                    .await
                    .unwrap(),
            );
        }
        out
    }

    async fn scores_of(store: &Store, session_id: &str) -> i64 {
        sqlx::query("SELECT COUNT(*) AS n FROM scores WHERE session_id = $1")
            .bind(session_id.to_string())
            .fetch_one(&store.pool)
            .await
            .unwrap()
            .try_get("n")
            .unwrap()
    }

    /// Two replicas on one database: a claimed job stays its claimer's while the claimer renews
    /// its lease; when the renewals stop (the replica died) the other replica takes it over, and
    /// the first one's late result is neither stored nor able to fail the job.
    async fn a_dead_replicas_job_is_taken_over(url: &str) {
        let lease = std::time::Duration::from_millis(400);
        let a = Store::open(url)
            .await
            .unwrap()
            .with_replica("replica-a")
            .with_job_lease(lease);
        let b = Store::open(url)
            .await
            .unwrap()
            .with_replica("replica-b")
            .with_job_lease(lease);
        let session_id = sessions(&a, 1).await.remove(0);
        let job_a = a.claim_job().await.unwrap().expect("the queued job");
        assert_eq!(job_a.attempts, 1);
        assert!(b.claim_job().await.unwrap().is_none(), "held by replica a");
        for _ in 0..3 {
            tokio::time::sleep(lease / 2).await;
            assert!(a.renew_lease(&job_a).await.unwrap());
            assert!(b.claim_job().await.unwrap().is_none(), "renewed by replica a");
        }
        // Replica a dies: no more renewals.
        tokio::time::sleep(lease + lease / 2).await;
        let job_b = b.claim_job().await.unwrap().expect("taken over");
        assert_eq!((job_b.id.as_str(), job_b.attempts), (job_a.id.as_str(), 2));
        assert!(!a.renew_lease(&job_a).await.unwrap(), "no longer replica a's");
        let report: stylet_scoring::ScoreReport =
            serde_json::from_str(include_str!("../../tests/data/report.json")).unwrap();
        let report = stylet_scoring::ScoreReport {
            session_id: session_id.clone(),
            ..report
        };
        a.finish_job(&job_a, &report, None).await.unwrap();
        a.fail_job(&job_a, "late").await.unwrap();
        assert_eq!(scores_of(&a, &session_id).await, 0, "replica a's late result");
        let (row, _) = a.session(&session_id).await.unwrap().unwrap();
        assert_eq!(row.status, SessionStatus::Scoring);
        b.finish_job(&job_b, &report, None).await.unwrap();
        assert_eq!(scores_of(&a, &session_id).await, 1);
        let (row, _) = a.session(&session_id).await.unwrap().unwrap();
        assert_eq!((row.status, row.error), (SessionStatus::Scored, None));
        assert!(a.claim_job().await.unwrap().is_none() && b.claim_job().await.unwrap().is_none());
    }

    /// Four replicas claiming at once: every job is claimed, each by one replica only.
    async fn replicas_claiming_at_once_take_each_job_once(url: &str) {
        let first = Store::open(url).await.unwrap();
        let ids = sessions(&first, 24).await;
        let mut claimers = Vec::new();
        for k in 0..4 {
            let store = Store::open(url).await.unwrap().with_replica(&format!("replica-{k}"));
            claimers.push(tokio::spawn(async move {
                let mut mine = Vec::new();
                while let Some(job) = store.claim_job().await.unwrap() {
                    mine.push(job.session_id);
                }
                mine
            }));
        }
        let mut claimed = Vec::new();
        for c in claimers {
            claimed.extend(c.await.unwrap());
        }
        claimed.sort();
        let mut want = ids;
        want.sort();
        assert_eq!(claimed, want, "each job once");
    }

    /// A restarted replica (the same name) takes back at once the jobs its previous run held;
    /// another replica's running job stays that replica's.
    async fn a_restart_releases_only_its_own_jobs(url: &str) {
        let a = Store::open(url).await.unwrap().with_replica("replica-a");
        let b = Store::open(url).await.unwrap().with_replica("replica-b");
        sessions(&a, 2).await;
        let job_a = a.claim_job().await.unwrap().unwrap();
        let job_b = b.claim_job().await.unwrap().unwrap();
        let restarted = Store::open(url).await.unwrap().with_replica("replica-a");
        assert_eq!(restarted.release_own_leases().await.unwrap(), 1);
        let again = restarted
            .claim_job()
            .await
            .unwrap()
            .expect("its own job, back in the queue");
        assert_eq!((again.id.as_str(), again.attempts), (job_a.id.as_str(), 2));
        assert!(
            restarted.claim_job().await.unwrap().is_none(),
            "replica b's job is still b's"
        );
        assert!(b.renew_lease(&job_b).await.unwrap());
    }

    #[tokio::test]
    async fn job_leases_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        let url = |name: &str| format!("sqlite://{}?mode=rwc", dir.path().join(name).display());
        a_dead_replicas_job_is_taken_over(&url("takeover.db")).await;
        replicas_claiming_at_once_take_each_job_once(&url("race.db")).await;
        a_restart_releases_only_its_own_jobs(&url("restart.db")).await;
    }

    #[tokio::test]
    async fn job_leases_postgres() {
        a_dead_replicas_job_is_taken_over(&super::super::fresh_postgres_database("lease_takeover").await).await;
        replicas_claiming_at_once_take_each_job_once(&super::super::fresh_postgres_database("lease_race").await).await;
        a_restart_releases_only_its_own_jobs(&super::super::fresh_postgres_database("lease_restart").await).await;
    }

    #[tokio::test]
    async fn a_late_failure_never_overwrites_a_score() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(&format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display()))
            .await
            .unwrap();
        let session_id = sessions(&store, 1).await.remove(0);
        let job = store.claim_job().await.unwrap().expect("the queued job");
        assert_eq!(job.session_id, session_id);
        // Meanwhile the job was finished elsewhere (another server after a re-queue).
        sqlx::query("UPDATE scoring_jobs SET state = 'done' WHERE id = $1")
            .bind(job.id.clone())
            .execute(&store.pool)
            .await
            .unwrap();
        sqlx::query("UPDATE sessions SET status = 'scored' WHERE id = $1")
            .bind(session_id.clone())
            .execute(&store.pool)
            .await
            .unwrap();
        store.fail_job(&job, "replay diverged").await.unwrap();
        let (row, _) = store.session(&session_id).await.unwrap().unwrap();
        assert_eq!((row.status, row.error), (SessionStatus::Scored, None));
        // A job still running is closed as failed, with its reason.
        sqlx::query("UPDATE scoring_jobs SET state = 'running' WHERE id = $1")
            .bind(job.id.clone())
            .execute(&store.pool)
            .await
            .unwrap();
        store.fail_job(&job, "replay diverged").await.unwrap();
        let (row, _) = store.session(&session_id).await.unwrap().unwrap();
        assert_eq!(
            (row.status, row.error.as_deref()),
            (SessionStatus::Failed, Some("replay diverged"))
        );
    }
}
