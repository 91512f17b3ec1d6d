//! Cohorts as the dashboard lists them: who sees which cohorts, their totals, and each
//! trainee's recent scores (sparklines).

use sqlx::Row;

use super::{Role, SessionFilter, Store, StoreError, User};

/// A cohort with its totals (final grades).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CohortLine {
    pub name: String,
    pub trainees: i64,
    pub instructors: i64,
    pub sessions: i64,
    pub scored: i64,
    pub passed: i64,
    pub mean_score: Option<f64>,
}

/// One scored session of a trainee, for a sparkline.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ScorePoint {
    pub trainee: String,
    pub session_id: String,
    pub uploaded_at: String,
    pub difficulty: String,
    pub score: f64,
    pub passed: bool,
}

/// A trainee's results at one difficulty (a report line).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportLine {
    pub trainee: String,
    pub difficulty: String,
    pub sessions: i64,
    pub scored: i64,
    pub passed: i64,
    pub mean_score: Option<f64>,
    pub best_score: Option<f64>,
    pub mean_attempts: Option<f64>,
    pub risk_hits: i64,
    /// Mean skill estimate against the experts over the scored sessions that have one.
    pub mean_skill_z: Option<f64>,
    pub first_upload: Option<String>,
    pub last_upload: Option<String>,
}

impl Store {
    /// Per trainee and difficulty, the sessions of a cohort that match `filter`'s scenario,
    /// difficulty and dates (final grades), by trainee then difficulty.
    pub async fn cohort_report(&self, cohort_id: &str, filter: &SessionFilter) -> Result<Vec<ReportLine>, StoreError> {
        let mut binds = vec![cohort_id.to_string()];
        let conds = super::sessions::narrowing(filter, &mut binds);
        let q = format!(
            "SELECT u.username AS trainee, s.difficulty, COUNT(*) AS sessions, \
             CAST(COALESCE(SUM(CASE WHEN s.status = 'scored' THEN 1 ELSE 0 END), 0) AS BIGINT) AS scored, \
             CAST(COALESCE(SUM(CASE WHEN s.status = 'scored' THEN s.final_passed ELSE 0 END), 0) AS BIGINT) AS passed, \
             AVG(CASE WHEN s.status = 'scored' THEN s.final_score END) AS mean_score, \
             MAX(CASE WHEN s.status = 'scored' THEN s.final_score END) AS best_score, \
             AVG(CAST(s.attempts AS DOUBLE PRECISION)) AS mean_attempts, \
             CAST(COALESCE(SUM(s.risk_hits), 0) AS BIGINT) AS risk_hits, \
             AVG(CASE WHEN s.status = 'scored' THEN s.skill_z END) AS mean_skill_z, \
             MIN(s.uploaded_at) AS first_upload, MAX(s.uploaded_at) AS last_upload \
             FROM sessions s JOIN users u ON u.id = s.trainee_id \
             WHERE s.trainee_id IN (SELECT user_id FROM cohort_members WHERE cohort_id = $1){conds} \
             GROUP BY u.username, s.difficulty ORDER BY u.username, s.difficulty"
        );
        let query = super::bound_query(q, binds);
        let rows = query.fetch_all(&self.pool).await?;
        rows.iter()
            .map(|r| {
                Ok(ReportLine {
                    trainee: r.try_get("trainee")?,
                    difficulty: r.try_get("difficulty")?,
                    sessions: r.try_get("sessions")?,
                    scored: r.try_get("scored")?,
                    passed: r.try_get("passed")?,
                    mean_score: r.try_get("mean_score")?,
                    best_score: r.try_get("best_score")?,
                    mean_attempts: r.try_get("mean_attempts")?,
                    risk_hits: r.try_get("risk_hits")?,
                    mean_skill_z: r.try_get("mean_skill_z")?,
                    first_upload: r.try_get("first_upload")?,
                    last_upload: r.try_get("last_upload")?,
                })
            })
            .collect::<Result<_, sqlx::Error>>()
            .map_err(StoreError::from)
    }

    /// The cohorts `viewer` may look at (an instructor those they teach; curriculum staff and
    /// admins all; trainees none), by name.
    pub async fn cohorts_for(&self, viewer: &User) -> Result<Vec<CohortLine>, StoreError> {
        let only_mine = match viewer.role {
            Role::Instructor => true,
            Role::Curriculum | Role::Admin => false,
            Role::Trainee => return Ok(Vec::new()),
        };
        let q = format!(
            "SELECT c.name, \
             (SELECT COUNT(*) FROM cohort_members m JOIN users u ON u.id = m.user_id WHERE m.cohort_id = c.id AND u.role = 'trainee') AS trainees, \
             (SELECT COUNT(*) FROM cohort_members m JOIN users u ON u.id = m.user_id WHERE m.cohort_id = c.id AND u.role = 'instructor') AS instructors, \
             COUNT(s.id) AS sessions, \
             CAST(COALESCE(SUM(CASE WHEN s.status = 'scored' THEN 1 ELSE 0 END), 0) AS BIGINT) AS scored, \
             CAST(COALESCE(SUM(CASE WHEN s.status = 'scored' THEN s.final_passed ELSE 0 END), 0) AS BIGINT) AS passed, \
             AVG(CASE WHEN s.status = 'scored' THEN s.final_score END) AS mean_score \
             FROM cohorts c \
             LEFT JOIN sessions s ON s.trainee_id IN (SELECT m.user_id FROM cohort_members m WHERE m.cohort_id = c.id) \
             {} GROUP BY c.id, c.name ORDER BY c.name",
            if only_mine {
                "WHERE c.id IN (SELECT cohort_id FROM cohort_members WHERE user_id = $1)"
            } else {
                ""
            }
        );
        // Built from constants only; the viewer's id is bound.
        let mut query = sqlx::query(sqlx::AssertSqlSafe(q));
        if only_mine {
            query = query.bind(viewer.id.clone());
        }
        let rows = query.fetch_all(&self.pool).await?;
        rows.iter()
            .map(|r| {
                Ok(CohortLine {
                    name: r.try_get("name")?,
                    trainees: r.try_get("trainees")?,
                    instructors: r.try_get("instructors")?,
                    sessions: r.try_get("sessions")?,
                    scored: r.try_get("scored")?,
                    passed: r.try_get("passed")?,
                    mean_score: r.try_get("mean_score")?,
                })
            })
            .collect::<Result<_, sqlx::Error>>()
            .map_err(StoreError::from)
    }

    /// The last `per_trainee` scored sessions of every trainee of a cohort that match `filter`'s
    /// scenario, difficulty and dates, oldest first per trainee.
    pub async fn recent_scores(
        &self,
        cohort_id: &str,
        filter: &SessionFilter,
        per_trainee: i64,
    ) -> Result<Vec<ScorePoint>, StoreError> {
        let mut binds = vec![cohort_id.to_string()];
        let conds = super::sessions::narrowing(filter, &mut binds);
        let q = format!(
            "SELECT trainee, id, uploaded_at, difficulty, final_score, final_passed FROM ( \
               SELECT u.username AS trainee, s.id, s.uploaded_at, s.difficulty, s.final_score, s.final_passed, \
               ROW_NUMBER() OVER (PARTITION BY s.trainee_id ORDER BY s.uploaded_at DESC, s.id DESC) AS rn \
               FROM sessions s JOIN users u ON u.id = s.trainee_id \
               WHERE s.status = 'scored' AND s.trainee_id IN (SELECT user_id FROM cohort_members WHERE cohort_id = $1){conds} \
             ) recent WHERE rn <= ${} ORDER BY trainee, uploaded_at, id",
            binds.len() + 1
        );
        let query = super::bound_query(q, binds);
        let rows = query.bind(per_trainee).fetch_all(&self.pool).await?;
        rows.iter()
            .map(|r| {
                Ok(ScorePoint {
                    trainee: r.try_get("trainee")?,
                    session_id: r.try_get("id")?,
                    uploaded_at: r.try_get("uploaded_at")?,
                    difficulty: r.try_get("difficulty")?,
                    score: r.try_get("final_score")?,
                    passed: r.try_get::<i64, _>("final_passed")? != 0,
                })
            })
            .collect::<Result<_, sqlx::Error>>()
            .map_err(StoreError::from)
    }
}
