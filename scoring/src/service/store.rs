//! The service's database (sqlx, `Any` driver): SQLite in WAL mode by default, PostgreSQL for
//! multi-site use. One set of migrations (`migrations/`) and one SQL dialect for both: `$n`
//! placeholders (SQLite reads them as numbered parameters), text ids and times. Booleans are read
//! back as `CAST(CASE WHEN b THEN 1 ELSE 0 END AS BIGINT)`: the `Any` driver cannot decode
//! SQLite's BOOLEAN.

use sqlx::any::{AnyPoolOptions, install_default_drivers};
use sqlx::{AnyPool, Row};

use super::auth;

/// Roles, from least to most administrative.
pub const ROLES: [&str; 4] = ["trainee", "instructor", "curriculum", "admin"];

#[derive(Debug, Clone, PartialEq)]
pub struct User {
    pub id: String,
    pub username: String,
    pub role: String,
}

/// A stored session row.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SessionRow {
    pub id: String,
    pub trainee: String,
    pub scenario: String,
    pub difficulty: String,
    pub status: String,
    pub uploaded_at: String,
    pub duration_s: f64,
    pub error: Option<String>,
    pub score: Option<serde_json::Value>,
}

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database: {0}")]
    Db(#[from] sqlx::Error),
    #[error("migrations: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("{0}")]
    Invalid(String),
}

/// Now, RFC 3339 UTC with microseconds: equal-length strings that sort in time order.
pub fn now() -> String {
    humantime::format_rfc3339_micros(std::time::SystemTime::now()).to_string()
}

pub fn new_id() -> String {
    stylet_recorder::new_session_id()
}

#[derive(Clone)]
pub struct Store {
    pub pool: AnyPool,
}

impl Store {
    /// Connects, sets SQLite to WAL, applies the migrations.
    pub async fn open(url: &str) -> Result<Store, StoreError> {
        install_default_drivers();
        let sqlite = url.starts_with("sqlite:");
        let pool = AnyPoolOptions::new()
            .max_connections(8)
            .after_connect(move |conn, _| {
                Box::pin(async move {
                    if sqlite {
                        sqlx::query("PRAGMA busy_timeout = 10000").execute(&mut *conn).await?;
                        sqlx::query("PRAGMA foreign_keys = ON").execute(&mut *conn).await?;
                    }
                    Ok(())
                })
            })
            .connect(url)
            .await?;
        if sqlite {
            sqlx::query("PRAGMA journal_mode = WAL").execute(&pool).await?;
        }
        sqlx::migrate!("../migrations").run(&pool).await?;
        Ok(Store { pool })
    }

    async fn audit(
        &self,
        actor: Option<&str>,
        action: &str,
        target: Option<&str>,
        detail: &str,
    ) -> Result<(), StoreError> {
        sqlx::query("INSERT INTO audit_log (id, at, actor_id, action, target, detail) VALUES ($1, $2, $3, $4, $5, $6)")
            .bind(new_id())
            .bind(now())
            .bind(actor.map(str::to_string))
            .bind(action.to_string())
            .bind(target.map(str::to_string))
            .bind(detail.to_string())
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// Adds an account (argon2id password hash); with `cohort`, also its cohort membership
    /// (the cohort is created if new).
    pub async fn add_user(
        &self,
        username: &str,
        role: &str,
        password: &str,
        cohort: Option<&str>,
    ) -> Result<String, StoreError> {
        if !ROLES.contains(&role) {
            return Err(StoreError::Invalid(format!(
                "unknown role '{role}' (roles: {})",
                ROLES.join(", ")
            )));
        }
        let valid = |c: char| c.is_ascii_alphanumeric() || "._-@".contains(c);
        if username.is_empty() || username.len() > 64 || !username.chars().all(valid) {
            return Err(StoreError::Invalid(
                "a username is 1–64 letters, digits or . _ - @".into(),
            ));
        }
        if password.chars().count() < 8 {
            return Err(StoreError::Invalid("a password needs at least 8 characters".into()));
        }
        let hash = auth::hash_password(password).map_err(StoreError::Invalid)?;
        let id = new_id();
        let mut tx = self.pool.begin().await?;
        let exists = sqlx::query("SELECT id FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        if exists.is_some() {
            return Err(StoreError::Invalid(format!("user '{username}' already exists")));
        }
        sqlx::query("INSERT INTO users (id, username, role, password_hash, created_at) VALUES ($1, $2, $3, $4, $5)")
            .bind(id.clone())
            .bind(username.to_string())
            .bind(role.to_string())
            .bind(hash)
            .bind(now())
            .execute(&mut *tx)
            .await?;
        if let Some(name) = cohort {
            let row = sqlx::query("SELECT id FROM cohorts WHERE name = $1")
                .bind(name.to_string())
                .fetch_optional(&mut *tx)
                .await?;
            let cohort_id = match row {
                Some(r) => r.try_get::<String, _>("id")?,
                None => {
                    let cid = new_id();
                    sqlx::query("INSERT INTO cohorts (id, name, created_at) VALUES ($1, $2, $3)")
                        .bind(cid.clone())
                        .bind(name.to_string())
                        .bind(now())
                        .execute(&mut *tx)
                        .await?;
                    cid
                }
            };
            sqlx::query("INSERT INTO cohort_members (cohort_id, user_id) VALUES ($1, $2)")
                .bind(cohort_id)
                .bind(id.clone())
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        self.audit(None, "user.add", Some(&id), &format!("{username} as {role}"))
            .await?;
        Ok(id)
    }

    fn user_of(row: &sqlx::any::AnyRow) -> Result<User, sqlx::Error> {
        Ok(User {
            id: row.try_get("id")?,
            username: row.try_get("username")?,
            role: row.try_get("role")?,
        })
    }

    /// The user with this username and password (argon2id check), if any.
    pub async fn check_login(&self, username: &str, password: &str) -> Result<Option<User>, StoreError> {
        let row = sqlx::query("SELECT id, username, role, password_hash FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&self.pool)
            .await?;
        let Some(row) = row else {
            // Same work as a real check, so timing does not reveal which usernames exist.
            let _ = auth::verify_password(password, auth::DUMMY_HASH);
            return Ok(None);
        };
        let hash: String = row.try_get("password_hash")?;
        Ok(auth::verify_password(password, &hash)
            .then(|| Self::user_of(&row))
            .transpose()?)
    }

    pub async fn user_by_name(&self, username: &str) -> Result<Option<User>, StoreError> {
        let row = sqlx::query("SELECT id, username, role FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.as_ref().map(Self::user_of).transpose()?)
    }

    /// Starts a login session; returns the cookie token and its CSRF token (only the token's
    /// hash is stored).
    pub async fn create_login(&self, user: &User, ttl_s: u64) -> Result<(String, String), StoreError> {
        let (token, csrf) = (auth::random_token(), auth::random_token());
        let expires =
            humantime::format_rfc3339_micros(std::time::SystemTime::now() + std::time::Duration::from_secs(ttl_s))
                .to_string();
        sqlx::query("INSERT INTO auth_sessions (token_sha256, user_id, csrf_token, created_at, expires_at) VALUES ($1, $2, $3, $4, $5)")
            .bind(auth::sha256_hex(&token))
            .bind(user.id.clone())
            .bind(csrf.clone())
            .bind(now())
            .bind(expires)
            .execute(&self.pool)
            .await?;
        self.audit(Some(&user.id), "login", None, "").await?;
        Ok((token, csrf))
    }

    /// The user of a login token that has not expired, and the login's CSRF token.
    pub async fn user_for_login(&self, token: &str) -> Result<Option<(User, String)>, StoreError> {
        let row = sqlx::query(
            "SELECT u.id, u.username, u.role, s.csrf_token FROM auth_sessions s JOIN users u ON u.id = s.user_id \
             WHERE s.token_sha256 = $1 AND s.expires_at > $2",
        )
        .bind(auth::sha256_hex(token))
        .bind(now())
        .fetch_optional(&self.pool)
        .await?;
        Ok(match row {
            Some(r) => Some((Self::user_of(&r)?, r.try_get("csrf_token")?)),
            None => None,
        })
    }

    /// A new API token for `user` (for the desktop app's uploads); returned once, stored hashed.
    pub async fn create_api_token(&self, user: &User, label: &str) -> Result<String, StoreError> {
        let token = auth::random_token();
        sqlx::query("INSERT INTO api_tokens (token_sha256, user_id, label, created_at) VALUES ($1, $2, $3, $4)")
            .bind(auth::sha256_hex(&token))
            .bind(user.id.clone())
            .bind(label.to_string())
            .bind(now())
            .execute(&self.pool)
            .await?;
        self.audit(Some(&user.id), "token.create", None, label).await?;
        Ok(token)
    }

    pub async fn user_for_api_token(&self, token: &str) -> Result<Option<User>, StoreError> {
        let row = sqlx::query("SELECT u.id, u.username, u.role FROM api_tokens t JOIN users u ON u.id = t.user_id WHERE t.token_sha256 = $1")
            .bind(auth::sha256_hex(token))
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.as_ref().map(Self::user_of).transpose()?)
    }

    pub async fn end_login(&self, token: &str) -> Result<(), StoreError> {
        sqlx::query("DELETE FROM auth_sessions WHERE token_sha256 = $1")
            .bind(auth::sha256_hex(token))
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    pub async fn register_atlas(&self, hash: &str, name: &str, dir: &str) -> Result<(), StoreError> {
        let known = sqlx::query("SELECT content_hash FROM atlases WHERE content_hash = $1")
            .bind(hash.to_string())
            .fetch_optional(&self.pool)
            .await?;
        if known.is_none() {
            sqlx::query("INSERT INTO atlases (content_hash, name, dir, registered_at) VALUES ($1, $2, $3, $4)")
                .bind(hash.to_string())
                .bind(name.to_string())
                .bind(dir.to_string())
                .bind(now())
                .execute(&self.pool)
                .await?;
        }
        Ok(())
    }

    /// Whether `instructor` teaches `trainee` (they share a cohort).
    pub async fn teaches(&self, instructor_id: &str, trainee_id: &str) -> Result<bool, StoreError> {
        let row = sqlx::query(
            "SELECT 1 AS one FROM cohort_members a JOIN cohort_members b ON a.cohort_id = b.cohort_id \
             WHERE a.user_id = $1 AND b.user_id = $2",
        )
        .bind(instructor_id.to_string())
        .bind(trainee_id.to_string())
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.is_some())
    }

    /// The session id of a file already uploaded (same bytes).
    pub async fn session_by_file(&self, sha: &str) -> Result<Option<String>, StoreError> {
        let row = sqlx::query("SELECT id FROM sessions WHERE file_sha256 = $1")
            .bind(sha.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.map(|r| r.try_get("id")).transpose()?)
    }

    /// Records a validated upload and its scoring job in one transaction.
    pub async fn insert_session(&self, s: &NewSession) -> Result<String, StoreError> {
        let id = new_id();
        let mut tx = self.pool.begin().await?;
        sqlx::query(
            "INSERT INTO sessions (id, file_sha256, size_bytes, session_uuid, trainee_id, uploaded_by, scenario, difficulty, \
             atlas_hash, physics_version, duration_s, recorded_at, uploaded_at, status, error) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, 'queued', NULL)",
        )
        .bind(id.clone())
        .bind(s.file_sha256.clone())
        .bind(s.size_bytes)
        .bind(s.session_uuid.clone())
        .bind(s.trainee_id.clone())
        .bind(s.uploaded_by.clone())
        .bind(s.scenario.clone())
        .bind(s.difficulty.clone())
        .bind(s.atlas_hash.clone())
        .bind(s.physics_version)
        .bind(s.duration_s)
        .bind(s.recorded_at.clone())
        .bind(now())
        .execute(&mut *tx)
        .await?;
        sqlx::query(
            "INSERT INTO scoring_jobs (id, session_id, state, attempts, created_at) VALUES ($1, $2, 'queued', 0, $3)",
        )
        .bind(new_id())
        .bind(id.clone())
        .bind(now())
        .execute(&mut *tx)
        .await?;
        sqlx::query("INSERT INTO audit_log (id, at, actor_id, action, target, detail) VALUES ($1, $2, $3, 'session.upload', $4, $5)")
            .bind(new_id())
            .bind(now())
            .bind(s.uploaded_by.clone())
            .bind(id.clone())
            .bind(s.file_sha256.clone())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(id)
    }

    const SESSION_COLUMNS: &str = "s.id, u.username AS trainee, s.scenario, s.difficulty, s.status, s.uploaded_at, \
        s.duration_s, s.error, sc.report_json";

    fn session_of(row: &sqlx::any::AnyRow) -> Result<SessionRow, sqlx::Error> {
        let report: Option<String> = row.try_get("report_json")?;
        Ok(SessionRow {
            id: row.try_get("id")?,
            trainee: row.try_get("trainee")?,
            scenario: row.try_get("scenario")?,
            difficulty: row.try_get("difficulty")?,
            status: row.try_get("status")?,
            uploaded_at: row.try_get("uploaded_at")?,
            duration_s: row.try_get("duration_s")?,
            error: row.try_get("error")?,
            score: report.and_then(|r| serde_json::from_str(&r).ok()),
        })
    }

    /// A session with its trainee's id (for authorization).
    pub async fn session(&self, id: &str) -> Result<Option<(SessionRow, String)>, StoreError> {
        let q = format!(
            "SELECT {}, s.trainee_id FROM sessions s JOIN users u ON u.id = s.trainee_id \
             LEFT JOIN scores sc ON sc.session_id = s.id WHERE s.id = $1",
            Self::SESSION_COLUMNS
        );
        // Built from constants only; values are bound.
        let row = sqlx::query(sqlx::AssertSqlSafe(q))
            .bind(id.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(match row {
            Some(r) => Some((Self::session_of(&r)?, r.try_get("trainee_id")?)),
            None => None,
        })
    }

    /// Columns of a listed session: the score as a summary, not the whole report.
    const LIST_COLUMNS: &str = "s.id, u.username AS trainee, s.scenario, s.difficulty, s.status, s.uploaded_at, \
        s.duration_s, s.error, sc.score AS grade_score, CAST(CASE WHEN sc.passed THEN 1 ELSE 0 END AS BIGINT) AS grade_passed, \
        CAST(CASE WHEN sc.replay_verified THEN 1 ELSE 0 END AS BIGINT) AS verified, sc.rubric_version";

    fn listed_session_of(row: &sqlx::any::AnyRow) -> Result<SessionRow, sqlx::Error> {
        let score: Option<f64> = row.try_get("grade_score")?;
        let summary = match score {
            Some(v) => Some(serde_json::json!({
                "grade": { "score": v, "passed": row.try_get::<i64, _>("grade_passed")? != 0,
                           "rubric_version": row.try_get::<Option<i64>, _>("rubric_version")? },
                "replay_verified": row.try_get::<i64, _>("verified")? != 0,
            })),
            None => None,
        };
        Ok(SessionRow {
            id: row.try_get("id")?,
            trainee: row.try_get("trainee")?,
            scenario: row.try_get("scenario")?,
            difficulty: row.try_get("difficulty")?,
            status: row.try_get("status")?,
            uploaded_at: row.try_get("uploaded_at")?,
            duration_s: row.try_get("duration_s")?,
            error: row.try_get("error")?,
            score: summary,
        })
    }

    /// The sessions `user` may see (a trainee their own, an instructor their cohorts' trainees',
    /// curriculum staff and admins all), newest first, each with a score summary
    /// `{grade: {score, passed, rubric_version}, replay_verified}`.
    pub async fn sessions_for(&self, user: &User, limit: i64) -> Result<Vec<SessionRow>, StoreError> {
        let base = format!(
            "SELECT {} FROM sessions s JOIN users u ON u.id = s.trainee_id LEFT JOIN scores sc ON sc.session_id = s.id",
            Self::LIST_COLUMNS
        );
        let (q, bind_user) = match user.role.as_str() {
            "trainee" => (
                format!("{base} WHERE s.trainee_id = $1 ORDER BY s.uploaded_at DESC, s.id LIMIT $2"),
                true,
            ),
            "instructor" => (
                format!(
                    "{base} WHERE s.trainee_id IN (SELECT b.user_id FROM cohort_members a JOIN cohort_members b \
                     ON a.cohort_id = b.cohort_id WHERE a.user_id = $1) ORDER BY s.uploaded_at DESC, s.id LIMIT $2"
                ),
                true,
            ),
            _ => (format!("{base} ORDER BY s.uploaded_at DESC, s.id LIMIT $1"), false),
        };
        // Built from constants only; values are bound.
        let mut query = sqlx::query(sqlx::AssertSqlSafe(q));
        if bind_user {
            query = query.bind(user.id.clone());
        }
        let rows = query.bind(limit).fetch_all(&self.pool).await?;
        Ok(rows.iter().map(Self::listed_session_of).collect::<Result<_, _>>()?)
    }

    /// At start: jobs a killed server left running go back to the queue.
    pub async fn requeue_running(&self) -> Result<u64, StoreError> {
        let r = sqlx::query("UPDATE scoring_jobs SET state = 'queued', started_at = NULL WHERE state = 'running'")
            .execute(&self.pool)
            .await?;
        sqlx::query("UPDATE sessions SET status = 'queued' WHERE status = 'scoring'")
            .execute(&self.pool)
            .await?;
        Ok(r.rows_affected())
    }

    /// Takes the oldest queued job (one dispatcher per server claims jobs, so no race).
    pub async fn claim_job(&self) -> Result<Option<Job>, StoreError> {
        let row = sqlx::query(
            "SELECT j.id, j.session_id, s.file_sha256, s.atlas_hash FROM scoring_jobs j JOIN sessions s ON s.id = j.session_id \
             WHERE j.state = 'queued' ORDER BY j.created_at, j.id LIMIT 1",
        )
        .fetch_optional(&self.pool)
        .await?;
        let Some(row) = row else { return Ok(None) };
        let job = Job {
            id: row.try_get("id")?,
            session_id: row.try_get("session_id")?,
            file_sha256: row.try_get("file_sha256")?,
            atlas_hash: row.try_get("atlas_hash")?,
        };
        let mut tx = self.pool.begin().await?;
        sqlx::query("UPDATE scoring_jobs SET state = 'running', started_at = $1, attempts = attempts + 1 WHERE id = $2 AND state = 'queued'")
            .bind(now())
            .bind(job.id.clone())
            .execute(&mut *tx)
            .await?;
        sqlx::query("UPDATE sessions SET status = 'scoring' WHERE id = $1")
            .bind(job.session_id.clone())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(Some(job))
    }

    /// Stores a score and closes its job in one transaction; a second score for the same session
    /// is refused by the key (never scored twice).
    pub async fn finish_job(&self, job: &Job, report: &crate::ScoreReport) -> Result<(), StoreError> {
        let json = serde_json::to_string(report).map_err(|e| StoreError::Invalid(e.to_string()))?;
        let mut tx = self.pool.begin().await?;
        sqlx::query(
            "INSERT INTO scores (session_id, score, passed, difficulty, rubric, rubric_version, physics_version, replay_verified, \
             incomplete, report_json, scored_at) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11)",
        )
        .bind(job.session_id.clone())
        .bind(report.grade.score)
        .bind(report.grade.passed)
        .bind(report.grade.difficulty.clone())
        .bind(report.grade.rubric.clone())
        .bind(report.grade.rubric_version as i64)
        .bind(report.physics_version as i64)
        .bind(report.replay_verified)
        .bind(report.incomplete)
        .bind(json)
        .bind(now())
        .execute(&mut *tx)
        .await?;
        sqlx::query("UPDATE scoring_jobs SET state = 'done', finished_at = $1 WHERE id = $2")
            .bind(now())
            .bind(job.id.clone())
            .execute(&mut *tx)
            .await?;
        sqlx::query("UPDATE sessions SET status = 'scored' WHERE id = $1")
            .bind(job.session_id.clone())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(())
    }

    pub async fn fail_job(&self, job: &Job, error: &str) -> Result<(), StoreError> {
        let mut tx = self.pool.begin().await?;
        sqlx::query("UPDATE scoring_jobs SET state = 'failed', finished_at = $1 WHERE id = $2")
            .bind(now())
            .bind(job.id.clone())
            .execute(&mut *tx)
            .await?;
        sqlx::query("UPDATE sessions SET status = 'failed', error = $1 WHERE id = $2")
            .bind(error.to_string())
            .bind(job.session_id.clone())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(())
    }

    /// The ids of the cohorts `user` belongs to or teaches, and whether a cohort by that name exists.
    pub async fn cohort_id(&self, name: &str) -> Result<Option<String>, StoreError> {
        let row = sqlx::query("SELECT id FROM cohorts WHERE name = $1")
            .bind(name.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.map(|r| r.try_get("id")).transpose()?)
    }

    pub async fn in_cohort(&self, user_id: &str, cohort_id: &str) -> Result<bool, StoreError> {
        let row = sqlx::query("SELECT 1 AS one FROM cohort_members WHERE user_id = $1 AND cohort_id = $2")
            .bind(user_id.to_string())
            .bind(cohort_id.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.is_some())
    }

    /// The latest override of a session, if any: (score, passed).
    async fn override_of(&self, session_id: &str) -> Result<Option<(f64, bool)>, StoreError> {
        let row = sqlx::query(
            "SELECT score, CAST(CASE WHEN passed THEN 1 ELSE 0 END AS BIGINT) AS passed FROM grade_overrides \
             WHERE session_id = $1 ORDER BY created_at DESC, id DESC LIMIT 1",
        )
        .bind(session_id.to_string())
        .fetch_optional(&self.pool)
        .await?;
        Ok(match row {
            Some(r) => Some((r.try_get("score")?, r.try_get::<i64, _>("passed")? != 0)),
            None => None,
        })
    }

    /// A trainee's scored sessions in upload order, per difficulty as recorded.
    pub async fn progress(&self, trainee_id: &str) -> Result<Vec<ProgressPoint>, StoreError> {
        let rows = sqlx::query(
            "SELECT s.id, s.uploaded_at, s.scenario, s.difficulty, sc.score, \
             CAST(CASE WHEN sc.passed THEN 1 ELSE 0 END AS BIGINT) AS passed FROM sessions s \
             JOIN scores sc ON sc.session_id = s.id WHERE s.trainee_id = $1 ORDER BY s.uploaded_at, s.id",
        )
        .bind(trainee_id.to_string())
        .fetch_all(&self.pool)
        .await?;
        let mut out = Vec::with_capacity(rows.len());
        for r in rows {
            let id: String = r.try_get("id")?;
            let over = self.override_of(&id).await?;
            out.push(ProgressPoint {
                session_id: id,
                uploaded_at: r.try_get("uploaded_at")?,
                scenario: r.try_get("scenario")?,
                difficulty: r.try_get("difficulty")?,
                score: over.map_or(r.try_get("score")?, |o| o.0),
                passed: over.map_or(r.try_get::<i64, _>("passed")? != 0, |o| o.1),
                overridden: over.is_some(),
            });
        }
        Ok(out)
    }

    /// Per trainee of a cohort: sessions, scored, passed, mean score, last upload.
    pub async fn cohort_summary(&self, cohort_id: &str) -> Result<Vec<TraineeSummary>, StoreError> {
        let rows = sqlx::query(
            "SELECT u.username, COUNT(s.id) AS sessions, COUNT(sc.session_id) AS scored, \
             CAST(SUM(CASE WHEN sc.passed THEN 1 ELSE 0 END) AS BIGINT) AS passed, AVG(sc.score) AS mean_score, MAX(s.uploaded_at) AS last_upload \
             FROM cohort_members m JOIN users u ON u.id = m.user_id \
             LEFT JOIN sessions s ON s.trainee_id = u.id LEFT JOIN scores sc ON sc.session_id = s.id \
             WHERE m.cohort_id = $1 AND u.role = 'trainee' GROUP BY u.username ORDER BY u.username",
        )
        .bind(cohort_id.to_string())
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(TraineeSummary {
                    username: r.try_get("username")?,
                    sessions: r.try_get("sessions")?,
                    scored: r.try_get("scored")?,
                    passed: r.try_get::<Option<i64>, _>("passed")?.unwrap_or(0),
                    mean_score: r.try_get("mean_score")?,
                    last_upload: r.try_get("last_upload")?,
                })
            })
            .collect::<Result<_, sqlx::Error>>()
            .map_err(StoreError::from)
    }

    /// Overrides a grade (the reason is required and audited).
    pub async fn override_grade(
        &self,
        session_id: &str,
        author: &User,
        score: f64,
        passed: bool,
        reason: &str,
    ) -> Result<(), StoreError> {
        let mut tx = self.pool.begin().await?;
        sqlx::query("INSERT INTO grade_overrides (id, session_id, author_id, score, passed, reason, created_at) VALUES ($1, $2, $3, $4, $5, $6, $7)")
            .bind(new_id())
            .bind(session_id.to_string())
            .bind(author.id.clone())
            .bind(score)
            .bind(passed)
            .bind(reason.to_string())
            .bind(now())
            .execute(&mut *tx)
            .await?;
        sqlx::query("INSERT INTO audit_log (id, at, actor_id, action, target, detail) VALUES ($1, $2, $3, 'grade.override', $4, $5)")
            .bind(new_id())
            .bind(now())
            .bind(author.id.clone())
            .bind(session_id.to_string())
            .bind(format!("score {score}, passed {passed}: {reason}"))
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(())
    }

    pub async fn add_comment(&self, session_id: &str, author: &User, body: &str) -> Result<String, StoreError> {
        let id = new_id();
        sqlx::query("INSERT INTO comments (id, session_id, author_id, body, created_at) VALUES ($1, $2, $3, $4, $5)")
            .bind(id.clone())
            .bind(session_id.to_string())
            .bind(author.id.clone())
            .bind(body.to_string())
            .bind(now())
            .execute(&self.pool)
            .await?;
        Ok(id)
    }

    /// Comments and overrides of a session, oldest first: (kind, author, text, created_at).
    pub async fn annotations(&self, session_id: &str) -> Result<serde_json::Value, StoreError> {
        let comments = sqlx::query(
            "SELECT u.username, c.body, c.created_at FROM comments c JOIN users u ON u.id = c.author_id \
             WHERE c.session_id = $1 ORDER BY c.created_at, c.id",
        )
        .bind(session_id.to_string())
        .fetch_all(&self.pool)
        .await?;
        let overrides = sqlx::query(
            "SELECT u.username, o.score, CAST(CASE WHEN o.passed THEN 1 ELSE 0 END AS BIGINT) AS passed, o.reason, o.created_at \
             FROM grade_overrides o JOIN users u ON u.id = o.author_id \
             WHERE o.session_id = $1 ORDER BY o.created_at, o.id",
        )
        .bind(session_id.to_string())
        .fetch_all(&self.pool)
        .await?;
        let c: Vec<serde_json::Value> = comments
            .iter()
            .map(|r| -> Result<_, sqlx::Error> {
                Ok(serde_json::json!({"author": r.try_get::<String, _>("username")?, "body": r.try_get::<String, _>("body")?, "at": r.try_get::<String, _>("created_at")?}))
            })
            .collect::<Result<_, _>>()?;
        let o: Vec<serde_json::Value> = overrides
            .iter()
            .map(|r| -> Result<_, sqlx::Error> {
                Ok(serde_json::json!({"author": r.try_get::<String, _>("username")?, "score": r.try_get::<f64, _>("score")?,
                    "passed": r.try_get::<i64, _>("passed")? != 0, "reason": r.try_get::<String, _>("reason")?, "at": r.try_get::<String, _>("created_at")?}))
            })
            .collect::<Result<_, _>>()?;
        Ok(serde_json::json!({ "comments": c, "overrides": o }))
    }

    /// Every session `user` may see, for the CSV export, oldest first.
    pub async fn export_rows(&self, user: &User) -> Result<Vec<ExportRow>, StoreError> {
        let rows = self.sessions_for(user, i64::MAX / 2).await?;
        let mut out = Vec::with_capacity(rows.len());
        for r in rows.into_iter().rev() {
            let meta = sqlx::query(
                "SELECT s.recorded_at, s.physics_version, (SELECT COUNT(*) FROM grade_overrides o WHERE o.session_id = s.id) AS n_over \
                 FROM sessions s WHERE s.id = $1",
            )
            .bind(r.id.clone())
            .fetch_one(&self.pool)
            .await?;
            let cohorts = sqlx::query(
                "SELECT c.name FROM cohorts c JOIN cohort_members m ON m.cohort_id = c.id JOIN users u ON u.id = m.user_id \
                 WHERE u.username = $1 ORDER BY c.name",
            )
            .bind(r.trainee.clone())
            .fetch_all(&self.pool)
            .await?
            .iter()
            .map(|c| c.try_get::<String, _>("name"))
            .collect::<Result<Vec<_>, _>>()?
            .join(";");
            let over = self.override_of(&r.id).await?;
            let grade = r.score.as_ref().map(|s| &s["grade"]);
            out.push(ExportRow {
                session_id: r.id.clone(),
                trainee: r.trainee.clone(),
                cohorts,
                scenario: r.scenario.clone(),
                difficulty: r.difficulty.clone(),
                status: r.status.clone(),
                recorded_at: meta.try_get("recorded_at")?,
                uploaded_at: r.uploaded_at.clone(),
                duration_s: r.duration_s,
                score: over.map(|o| o.0).or_else(|| grade.and_then(|g| g["score"].as_f64())),
                passed: over.map(|o| o.1).or_else(|| grade.and_then(|g| g["passed"].as_bool())),
                overridden: meta.try_get::<i64, _>("n_over")? > 0,
                replay_verified: r.score.as_ref().and_then(|s| s["replay_verified"].as_bool()),
                rubric_version: grade.and_then(|g| g["rubric_version"].as_i64()),
                physics_version: meta.try_get("physics_version")?,
            });
        }
        Ok(out)
    }

    /// Count of scores per session (tests: exactly once).
    pub async fn score_count(&self, session_id: &str) -> Result<i64, StoreError> {
        let row = sqlx::query("SELECT COUNT(*) AS n FROM scores WHERE session_id = $1")
            .bind(session_id.to_string())
            .fetch_one(&self.pool)
            .await?;
        Ok(row.try_get("n")?)
    }
}

/// One point of a trainee's progress: a scored session (the override's values when overridden).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ProgressPoint {
    pub session_id: String,
    pub uploaded_at: String,
    pub scenario: String,
    pub difficulty: String,
    pub score: f64,
    pub passed: bool,
    pub overridden: bool,
}

/// One trainee's line of a cohort summary.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TraineeSummary {
    pub username: String,
    pub sessions: i64,
    pub scored: i64,
    pub passed: i64,
    pub mean_score: Option<f64>,
    pub last_upload: Option<String>,
}

/// A row of the sessions CSV export.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportRow {
    pub session_id: String,
    pub trainee: String,
    pub cohorts: String,
    pub scenario: String,
    pub difficulty: String,
    pub status: String,
    pub recorded_at: String,
    pub uploaded_at: String,
    pub duration_s: f64,
    pub score: Option<f64>,
    pub passed: Option<bool>,
    pub overridden: bool,
    pub replay_verified: Option<bool>,
    pub rubric_version: Option<i64>,
    pub physics_version: i64,
}

/// A validated upload about to be stored.
pub struct NewSession {
    pub file_sha256: String,
    pub size_bytes: i64,
    pub session_uuid: String,
    pub trainee_id: String,
    pub uploaded_by: String,
    pub scenario: String,
    pub difficulty: String,
    pub atlas_hash: String,
    pub physics_version: i64,
    pub duration_s: f64,
    pub recorded_at: String,
}

/// A claimed scoring job.
#[derive(Debug, Clone)]
pub struct Job {
    pub id: String,
    pub session_id: String,
    pub file_sha256: String,
    pub atlas_hash: String,
}
