//! What instructors and curriculum staff add and read: comments, grade overrides, progress,
//! cohort summaries and the export.

use sqlx::Row;

use super::{SessionFilter, SessionLine, User};
use super::{Store, StoreError, new_id, now};

impl Store {
    /// A trainee's graded punctures in upload order, with the final grade (the override's when
    /// overridden). Palpation, ultrasound-survey and drainage exercises are graded by their own
    /// rubrics and a recording that is not gradeable has no grade: neither says how the trainee punctures, so
    /// neither moves the scores over time or the suggested difficulty.
    pub async fn progress(&self, trainee_id: &str) -> Result<Vec<ProgressPoint>, StoreError> {
        let rows = sqlx::query(
            "SELECT id, uploaded_at, scenario, difficulty, final_score, final_passed, overridden FROM sessions \
             WHERE trainee_id = $1 AND status = 'scored' AND exercise = 'puncture' \
             AND (overridden = 1 OR outcome IS NULL OR outcome <> 'not_gradeable') ORDER BY uploaded_at, id",
        )
        .bind(trainee_id.to_string())
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(ProgressPoint {
                    session_id: r.try_get("id")?,
                    uploaded_at: r.try_get("uploaded_at")?,
                    scenario: r.try_get("scenario")?,
                    difficulty: r.try_get("difficulty")?,
                    score: r.try_get("final_score")?,
                    passed: r.try_get::<i64, _>("final_passed")? != 0,
                    overridden: r.try_get::<i64, _>("overridden")? != 0,
                })
            })
            .collect::<Result<_, sqlx::Error>>()
            .map_err(StoreError::from)
    }

    /// Per trainee of a cohort: sessions, scored, passed, mean score (final grades), last upload;
    /// only sessions that match `filter`'s scenario, difficulty and dates count.
    pub async fn cohort_summary(
        &self,
        cohort_id: &str,
        filter: &SessionFilter,
    ) -> Result<Vec<TraineeSummary>, StoreError> {
        let mut binds = vec![cohort_id.to_string()];
        let on = format!("s.trainee_id = u.id{}", super::sessions::narrowing(filter, &mut binds));
        let q = format!(
            "SELECT u.username, COUNT(s.id) AS sessions, \
             CAST(COALESCE(SUM(CASE WHEN s.status = 'scored' THEN 1 ELSE 0 END), 0) AS BIGINT) AS scored, \
             CAST(COALESCE(SUM(CASE WHEN s.status = 'scored' THEN s.final_passed ELSE 0 END), 0) AS BIGINT) AS passed, \
             AVG(CASE WHEN s.status = 'scored' THEN s.final_score END) AS mean_score, MAX(s.uploaded_at) AS last_upload \
             FROM cohort_members m JOIN users u ON u.id = m.user_id LEFT JOIN sessions s ON {on} \
             WHERE m.cohort_id = $1 AND u.role = 'trainee' GROUP BY u.username ORDER BY u.username"
        );
        let query = super::bound_query(q, binds);
        let rows = query.fetch_all(&self.pool).await?;
        rows.iter()
            .map(|r| {
                Ok(TraineeSummary {
                    username: r.try_get("username")?,
                    sessions: r.try_get("sessions")?,
                    scored: r.try_get("scored")?,
                    passed: r.try_get("passed")?,
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
        let mut tx = self.begin_write().await?;
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
        write_final_grade(&mut tx, session_id, score, passed).await?;
        tx.commit().await?;
        Ok(())
    }

    /// A comment on a session, optionally at a moment `at_s` (seconds from its start; checked by
    /// the review's `check_comment_time`).
    pub async fn add_comment(
        &self,
        session_id: &str,
        author: &User,
        body: &str,
        at_s: Option<f64>,
    ) -> Result<String, StoreError> {
        let id = new_id();
        // No bound `Option<f64>`: through sqlx's `Any` driver PostgreSQL refuses a number for a
        // parameter its connection first saw as NULL ("incorrect binary data format"), so a
        // comment without a moment would break the next comments with one. NULL is a literal.
        let insert = match at_s {
            Some(_) => {
                "INSERT INTO comments (id, session_id, author_id, body, created_at, at_s) VALUES ($1, $2, $3, $4, $5, $6)"
            }
            None => {
                "INSERT INTO comments (id, session_id, author_id, body, created_at, at_s) VALUES ($1, $2, $3, $4, $5, NULL)"
            }
        };
        let mut query = sqlx::query(insert)
            .bind(id.clone())
            .bind(session_id.to_string())
            .bind(author.id.clone())
            .bind(body.to_string())
            .bind(now());
        if let Some(at_s) = at_s {
            query = query.bind(at_s);
        }
        query.execute(&self.pool).await?;
        Ok(id)
    }

    /// Comments and overrides of a session, oldest first: comments `{author, body, at, at_s}`
    /// (`at_s`: the moment of the session, or null), overrides `{author, score, passed, reason, at}`.
    pub async fn annotations(&self, session_id: &str) -> Result<serde_json::Value, StoreError> {
        let comments = sqlx::query(
            "SELECT u.username, c.body, c.created_at, c.at_s FROM comments c JOIN users u ON u.id = c.author_id \
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
                Ok(serde_json::json!({"author": r.try_get::<String, _>("username")?, "body": r.try_get::<String, _>("body")?,
                    "at": r.try_get::<String, _>("created_at")?, "at_s": r.try_get::<Option<f64>, _>("at_s")?}))
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

    /// The sessions `viewer` may see that match `filter`, oldest first, each with its trainee's
    /// cohorts (`;`-separated), for the CSV export.
    pub async fn export_rows(&self, viewer: &User, filter: &SessionFilter) -> Result<Vec<ExportRow>, StoreError> {
        let mut f = filter.clone();
        f.oldest_first = true;
        f.limit = i64::MAX / 2;
        f.offset = 0;
        let lines = self.sessions(viewer, &f).await?;
        let members = sqlx::query(
            "SELECT u.username, c.name FROM cohort_members m JOIN cohorts c ON c.id = m.cohort_id \
             JOIN users u ON u.id = m.user_id ORDER BY c.name",
        )
        .fetch_all(&self.pool)
        .await?;
        let mut cohorts: std::collections::BTreeMap<String, Vec<String>> = Default::default();
        for m in &members {
            cohorts
                .entry(m.try_get("username")?)
                .or_default()
                .push(m.try_get("name")?);
        }
        let mut outcomes = self.outcome_columns().await?;
        Ok(lines
            .into_iter()
            .map(|line| ExportRow {
                cohorts: cohorts.get(&line.trainee).map(|c| c.join(";")).unwrap_or_default(),
                outcome: outcomes.remove(&line.id).unwrap_or_default(),
                line,
            })
            .collect())
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
    pub line: SessionLine,
    pub cohorts: String,
    /// Exercise, outcome, reasons, target reached, structures hit (migration 0005).
    pub outcome: super::OutcomeColumns,
}

/// The latest override of a session, if any: (score, passed).
pub(super) async fn latest_override(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    session_id: &str,
) -> Result<Option<(f64, bool)>, StoreError> {
    let row = sqlx::query(
        "SELECT score, CAST(CASE WHEN passed THEN 1 ELSE 0 END AS BIGINT) AS passed FROM grade_overrides \
         WHERE session_id = $1 ORDER BY created_at DESC, id DESC LIMIT 1",
    )
    .bind(session_id.to_string())
    .fetch_optional(&mut **tx)
    .await?;
    Ok(match row {
        Some(r) => Some((r.try_get("score")?, r.try_get::<i64, _>("passed")? != 0)),
        None => None,
    })
}

/// An override becomes the session's final grade (lists, progress, summaries, export).
pub(super) async fn write_final_grade(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    session_id: &str,
    score: f64,
    passed: bool,
) -> Result<(), StoreError> {
    sqlx::query("UPDATE sessions SET final_score = $1, final_passed = $2, overridden = 1 WHERE id = $3")
        .bind(score)
        .bind(i64::from(passed))
        .bind(session_id.to_string())
        .execute(&mut **tx)
        .await?;
    Ok(())
}
