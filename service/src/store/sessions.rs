//! Uploaded sessions: storing a validated upload and reading sessions back.

use sqlx::Row;

use super::{Role, SessionRow, User};
use super::{Store, StoreError, audit_in, new_id, now};

impl Store {
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
        let mut tx = self.begin_write().await?;
        sqlx::query(
            "INSERT INTO sessions (id, file_sha256, size_bytes, session_uuid, trainee_id, uploaded_by, scenario, difficulty, \
             atlas_hash, physics_version, duration_s, recorded_at, uploaded_at, status, error) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, NULL)",
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
        .bind(super::SessionStatus::Queued.as_str())
        .execute(&mut *tx)
        .await?;
        sqlx::query(
            "INSERT INTO scoring_jobs (id, session_id, state, attempts, created_at, request_id) VALUES ($1, $2, 'queued', 0, $3, $4)",
        )
        .bind(new_id())
        .bind(id.clone())
        .bind(now())
        .bind(s.request_id.clone())
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

    /// Dates a session back to `at`, its recording and upload time (written as [`now`] writes
    /// times, so that they sort with the others): for the demo, whose sessions are recorded at
    /// once but stand for weeks of practice. False if there is no such session.
    pub async fn set_session_times(&self, id: &str, at: std::time::SystemTime) -> Result<bool, StoreError> {
        let at = humantime::format_rfc3339_micros(at).to_string();
        let changed = sqlx::query("UPDATE sessions SET recorded_at = $1, uploaded_at = $2 WHERE id = $3")
            .bind(at.clone())
            .bind(at)
            .bind(id.to_string())
            .execute(&self.pool)
            .await?
            .rows_affected();
        Ok(changed == 1)
    }

    const SESSION_COLUMNS: &str = "s.id, u.username AS trainee, s.scenario, s.difficulty, s.status, s.uploaded_at, \
        s.recorded_at, s.duration_s, s.error, s.file_sha256, s.atlas_hash, s.size_bytes, sc.report_json, \
        s.exercise, s.outcome, s.reasons";

    fn session_of(row: &sqlx::any::AnyRow) -> Result<SessionRow, sqlx::Error> {
        let report: Option<String> = row.try_get("report_json")?;
        Ok(SessionRow {
            id: row.try_get("id")?,
            trainee: row.try_get("trainee")?,
            scenario: row.try_get("scenario")?,
            difficulty: row.try_get("difficulty")?,
            status: row.try_get("status")?,
            uploaded_at: row.try_get("uploaded_at")?,
            recorded_at: row.try_get("recorded_at")?,
            duration_s: row.try_get("duration_s")?,
            error: row.try_get("error")?,
            file_sha256: row.try_get("file_sha256")?,
            atlas_hash: row.try_get("atlas_hash")?,
            size_bytes: row.try_get("size_bytes")?,
            score: report.and_then(|r| serde_json::from_str(&r).ok()),
            exercise: stylet_scoring::Exercise::parse(&row.try_get::<String, _>("exercise")?).unwrap_or_default(),
            outcome: row
                .try_get::<Option<String>, _>("outcome")?
                .and_then(|o| stylet_scoring::Outcome::parse(&o)),
            reasons: super::jobs::split_reasons(row.try_get::<Option<String>, _>("reasons")?.as_deref()),
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

    /// Columns of a listed session: its row only (migration 0002), never the report.
    const LINE_COLUMNS: &str = "s.id, u.username AS trainee, s.scenario, s.difficulty, s.status, s.uploaded_at, \
        s.recorded_at, s.duration_s, s.error, s.final_score, s.final_passed, s.overridden, s.attempts, s.risk_hits, \
        s.replay_verified, s.rubric_version, s.physics_version, s.exercise, s.outcome, s.reasons";

    fn line_of(row: &sqlx::any::AnyRow) -> Result<SessionLine, sqlx::Error> {
        let flag = |name: &str| -> Result<Option<bool>, sqlx::Error> {
            Ok(row.try_get::<Option<i64>, _>(name)?.map(|v| v != 0))
        };
        Ok(SessionLine {
            id: row.try_get("id")?,
            trainee: row.try_get("trainee")?,
            scenario: row.try_get("scenario")?,
            difficulty: row.try_get("difficulty")?,
            status: row.try_get("status")?,
            uploaded_at: row.try_get("uploaded_at")?,
            recorded_at: row.try_get("recorded_at")?,
            duration_s: row.try_get("duration_s")?,
            error: row.try_get("error")?,
            score: row.try_get("final_score")?,
            passed: flag("final_passed")?,
            overridden: row.try_get::<i64, _>("overridden")? != 0,
            attempts: row.try_get("attempts")?,
            risk_hits: row.try_get("risk_hits")?,
            replay_verified: flag("replay_verified")?,
            rubric_version: row.try_get("rubric_version")?,
            physics_version: row.try_get("physics_version")?,
            exercise: stylet_scoring::Exercise::parse(&row.try_get::<String, _>("exercise")?).unwrap_or_default(),
            outcome: row
                .try_get::<Option<String>, _>("outcome")?
                .and_then(|o| stylet_scoring::Outcome::parse(&o)),
            reasons: super::jobs::split_reasons(row.try_get::<Option<String>, _>("reasons")?.as_deref()),
        })
    }

    /// The WHERE clause of `filter` as seen by `viewer` (a trainee sees their own sessions, an
    /// instructor those of their cohorts' trainees, curriculum staff and admins all), with its
    /// bound values in order.
    fn where_clause(viewer: &User, filter: &SessionFilter) -> (String, Vec<String>) {
        let mut conds: Vec<String> = Vec::new();
        let mut binds: Vec<String> = Vec::new();
        let bind = |v: &str, binds: &mut Vec<String>| {
            binds.push(v.to_string());
            format!("${}", binds.len())
        };
        match viewer.role {
            Role::Trainee => conds.push(format!("s.trainee_id = {}", bind(&viewer.id, &mut binds))),
            Role::Instructor => conds.push(format!(
                "s.trainee_id IN (SELECT b.user_id FROM cohort_members a JOIN cohort_members b \
                 ON a.cohort_id = b.cohort_id WHERE a.user_id = {})",
                bind(&viewer.id, &mut binds)
            )),
            Role::Curriculum | Role::Admin => {}
        }
        if let Some(v) = &filter.trainee_id {
            conds.push(format!("s.trainee_id = {}", bind(v, &mut binds)));
        }
        if let Some(v) = &filter.cohort_id {
            conds.push(format!(
                "s.trainee_id IN (SELECT user_id FROM cohort_members WHERE cohort_id = {})",
                bind(v, &mut binds)
            ));
        }
        if let Some(v) = filter.status {
            conds.push(format!("s.status = {}", bind(v.as_str(), &mut binds)));
        }
        let mut clause = String::from(" WHERE 1 = 1");
        for c in conds {
            clause += " AND ";
            clause += &c;
        }
        clause += &narrowing(filter, &mut binds);
        (clause, binds)
    }

    /// The sessions `viewer` may see that match `filter`, newest first unless
    /// `filter.oldest_first`, one page (`limit`, `offset`).
    pub async fn sessions(&self, viewer: &User, filter: &SessionFilter) -> Result<Vec<SessionLine>, StoreError> {
        let (clause, binds) = Self::where_clause(viewer, filter);
        let order = if filter.oldest_first { "ASC" } else { "DESC" };
        let q = format!(
            "SELECT {} FROM sessions s JOIN users u ON u.id = s.trainee_id{clause} \
             ORDER BY s.uploaded_at {order}, s.id {order} LIMIT ${} OFFSET ${}",
            Self::LINE_COLUMNS,
            binds.len() + 1,
            binds.len() + 2
        );
        let query = super::bound_query(q, binds);
        let rows = query
            .bind(filter.limit.max(0))
            .bind(filter.offset.max(0))
            .fetch_all(&self.pool)
            .await?;
        Ok(rows.iter().map(Self::line_of).collect::<Result<_, _>>()?)
    }

    /// How many sessions `viewer` may see match `filter` (for paging).
    pub async fn count_sessions(&self, viewer: &User, filter: &SessionFilter) -> Result<i64, StoreError> {
        let (clause, binds) = Self::where_clause(viewer, filter);
        let q = format!("SELECT COUNT(*) AS n FROM sessions s{clause}");
        let query = super::bound_query(q, binds);
        Ok(query.fetch_one(&self.pool).await?.try_get("n")?)
    }

    /// The scenarios of the sessions `viewer` may see, narrowed to a cohort when given (filter
    /// menus; a scenario name is text from an uploaded file, so others' stay private).
    pub async fn scenarios(&self, viewer: &User, cohort_id: Option<&str>) -> Result<Vec<String>, StoreError> {
        let filter = SessionFilter {
            cohort_id: cohort_id.map(str::to_string),
            ..SessionFilter::default()
        };
        let (clause, binds) = Self::where_clause(viewer, &filter);
        let q = format!("SELECT DISTINCT s.scenario FROM sessions s{clause} ORDER BY s.scenario");
        let query = super::bound_query(q, binds);
        let rows = query.fetch_all(&self.pool).await?;
        Ok(rows.iter().map(|r| r.try_get("scenario")).collect::<Result<_, _>>()?)
    }
}

/// ` AND …` conditions on `s` (a sessions row) for `filter`'s scenario, difficulty and dates, their
/// values appended to `binds` (placeholders numbered after what is there).
pub(super) fn narrowing(filter: &SessionFilter, binds: &mut Vec<String>) -> String {
    let mut out = String::new();
    let difficulty = filter.difficulty.map(|d| d.as_str().to_string());
    for (col, op, v) in [
        ("s.scenario", "=", &filter.scenario),
        ("s.difficulty", "=", &difficulty),
        ("s.uploaded_at", ">=", &filter.uploaded_from),
        ("s.uploaded_at", "<", &filter.uploaded_before),
    ] {
        if let Some(v) = v {
            binds.push(v.clone());
            out += &format!(" AND {col} {op} ${}", binds.len());
        }
    }
    out
}

/// Which sessions to list. Dates compare with `uploaded_at` (the server's clock, RFC 3339 UTC).
#[derive(Debug, Clone)]
pub struct SessionFilter {
    pub trainee_id: Option<String>,
    pub cohort_id: Option<String>,
    pub scenario: Option<String>,
    pub difficulty: Option<stylet_scoring::Difficulty>,
    pub status: Option<super::SessionStatus>,
    /// Inclusive.
    pub uploaded_from: Option<String>,
    /// Exclusive.
    pub uploaded_before: Option<String>,
    pub oldest_first: bool,
    pub limit: i64,
    pub offset: i64,
}

impl Default for SessionFilter {
    fn default() -> Self {
        SessionFilter {
            trainee_id: None,
            cohort_id: None,
            scenario: None,
            difficulty: None,
            status: None,
            uploaded_from: None,
            uploaded_before: None,
            oldest_first: false,
            limit: 100,
            offset: 0,
        }
    }
}

/// A session as lists, pages and exports show it: the final grade (the latest override's when
/// overridden), attempts, risk hits and the replay check; `None` until scored.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct SessionLine {
    pub id: String,
    pub trainee: String,
    pub scenario: String,
    pub difficulty: String,
    pub status: super::SessionStatus,
    pub uploaded_at: String,
    pub recorded_at: String,
    pub duration_s: f64,
    pub error: Option<String>,
    pub score: Option<f64>,
    pub passed: Option<bool>,
    pub overridden: bool,
    pub attempts: Option<i64>,
    pub risk_hits: Option<i64>,
    pub replay_verified: Option<bool>,
    pub rubric_version: Option<i64>,
    pub physics_version: i64,
    /// What the scenario exercises (migrations 0005, 0012): puncture, palpation, ultrasound_survey or
    /// drainage.
    #[schema(value_type = String)]
    pub exercise: stylet_scoring::Exercise,
    /// passed, failed or not_gradeable once scored (an instructor's override sets passed/failed).
    #[schema(value_type = Option<String>)]
    pub outcome: Option<stylet_scoring::Outcome>,
    /// Why, in plain words (docs/metrics.md "Reasons").
    pub reasons: Vec<String>,
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
    /// The id of the request that uploaded it, kept with its scoring job (logs).
    pub request_id: Option<String>,
}

impl Store {
    /// Deletes a session and everything about it (score, job, comments, grade overrides) in one
    /// transaction, audited; returns its file's SHA-256 (the caller removes the file and derived
    /// data), or `None` if there is no such session.
    pub async fn delete_session(&self, id: &str, actor: &User) -> Result<Option<String>, StoreError> {
        let mut tx = self.begin_write().await?;
        let row = sqlx::query(
            "SELECT s.file_sha256, s.scenario, u.username FROM sessions s JOIN users u ON u.id = s.trainee_id WHERE s.id = $1",
        )
        .bind(id.to_string())
        .fetch_optional(&mut *tx)
        .await?;
        let Some(row) = row else {
            tx.rollback().await?;
            return Ok(None);
        };
        let sha: String = row.try_get("file_sha256")?;
        let detail = format!(
            "session of {} ({}), file {sha}",
            row.try_get::<String, _>("username")?,
            row.try_get::<String, _>("scenario")?
        );
        for table in [
            "scores",
            "comments",
            "grade_overrides",
            "scoring_jobs",
            "expert_references",
        ] {
            sqlx::query(sqlx::AssertSqlSafe(format!(
                "DELETE FROM {table} WHERE session_id = $1"
            )))
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?;
        }
        sqlx::query("DELETE FROM sessions WHERE id = $1")
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?;
        audit_in(&mut tx, &actor.id, "session.delete", id, &detail).await?;
        tx.commit().await?;
        Ok(Some(sha))
    }
}

#[cfg(test)]
mod tests {
    use super::super::new_id;
    use super::*;

    #[tokio::test]
    async fn a_session_can_be_dated_back() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(&format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display()))
            .await
            .unwrap();
        store.register_atlas("atlas-hash", "phantom", "/nowhere").await.unwrap();
        let trainee = store
            .add_user("tina", "trainee", "tina-password", None, None)
            .await
            .unwrap();
        let new = |sha: char| NewSession {
            file_sha256: sha.to_string().repeat(64),
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
        };
        let old = store.insert_session(&new('a')).await.unwrap();
        let recent = store.insert_session(&new('b')).await.unwrap();
        let three_weeks = std::time::Duration::from_secs(21 * 86_400);
        let at = std::time::SystemTime::now() - three_weeks;
        assert!(store.set_session_times(&old, at).await.unwrap());
        assert!(!store.set_session_times("no-such-session", at).await.unwrap());
        let (row, _) = store.session(&old).await.unwrap().unwrap();
        let want = humantime::format_rfc3339_micros(at).to_string();
        assert_eq!(
            (row.uploaded_at.as_str(), row.recorded_at.as_str()),
            (want.as_str(), want.as_str())
        );
        // Written like `now()`: same length, so that times still sort as strings.
        assert_eq!(row.uploaded_at.len(), now().len());
        let (other, _) = store.session(&recent).await.unwrap().unwrap();
        assert!(row.uploaded_at < other.uploaded_at);
    }
}
