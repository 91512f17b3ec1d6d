//! What instructors' tools read (docs/dashboard.md): the "needs review" queue, a trainee's
//! progress over calendar time, and the session search that picks sessions to compare.
//!
//! Visibility is the sessions list's: a trainee sees their own sessions, an instructor those of
//! their cohorts' trainees, curriculum staff and admins all. Every list is one indexed query with
//! a `LIMIT` (pages), so the pages stay fast with tens of thousands of sessions.

use sqlx::Row;
use stylet_scoring::Difficulty;
use stylet_scoring::{Exercise, Outcome};

use super::{Role, SessionStatus, Store, StoreError, User};

/// Queue lines per page.
pub const QUEUE_PAGE: i64 = 50;
/// Search results per page on the comparison page.
pub const SEARCH_PAGE: i64 = 20;
/// Scored sessions a progress chart shows at most (the latest).
pub const PROGRESS_POINTS: i64 = 500;
/// Latest sessions (and sessions with risk hits) listed on a progress page.
pub const PROGRESS_RECENT: i64 = 20;

/// Why a session waits in the review queue; every queued session is at least not yet commented.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum QueueReason {
    /// The needle touched a risk structure.
    RiskHit,
    /// Graded and failed.
    Failed,
    /// The recording is incomplete: no grade could be given.
    NotGradeable,
    /// The replay could not score the file.
    ScoringFailed,
    /// Neither commented nor overridden yet.
    NotCommented,
}

impl QueueReason {
    /// In words, for people.
    pub fn words(self) -> &'static str {
        match self {
            QueueReason::RiskHit => "risk structure hit",
            QueueReason::Failed => "failed",
            QueueReason::NotGradeable => "not gradeable",
            QueueReason::ScoringFailed => "scoring failed",
            QueueReason::NotCommented => "not yet commented",
        }
    }
}

/// A session as the queue, the progress page and the search list it: the final grade (an
/// override's when overridden).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReviewLine {
    pub id: String,
    pub trainee: String,
    pub scenario: String,
    pub difficulty: String,
    pub status: SessionStatus,
    pub uploaded_at: String,
    pub score: Option<f64>,
    pub passed: Option<bool>,
    pub overridden: bool,
    pub attempts: Option<i64>,
    pub risk_hits: Option<i64>,
    /// Why scoring failed (status `failed`).
    pub error: Option<String>,
    pub exercise: Exercise,
    /// The computed result; `None` until scored.
    pub outcome: Option<Outcome>,
    /// Why, in plain words (the scoring's reasons).
    pub reasons: Vec<String>,
}

impl ReviewLine {
    /// Why it is (or would be) in the review queue, most serious first.
    pub fn queue_reasons(&self) -> Vec<QueueReason> {
        let mut out = Vec::new();
        if self.risk_hits.unwrap_or(0) > 0 {
            out.push(QueueReason::RiskHit);
        }
        if self.status == SessionStatus::Failed {
            out.push(QueueReason::ScoringFailed);
        } else if self.outcome == Some(Outcome::NotGradeable) {
            out.push(QueueReason::NotGradeable);
        } else if self.passed == Some(false) {
            out.push(QueueReason::Failed);
        }
        out.push(QueueReason::NotCommented);
        out
    }
}

/// Which queued sessions to list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum QueueScope {
    /// Every session not yet commented or overridden.
    #[default]
    All,
    /// Only those with a risk hit, a failed grade or a failed scoring.
    Flagged,
}

/// How a comparison search narrows results by outcome.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutcomeFilter {
    #[default]
    Any,
    Passed,
    Failed,
    RiskHit,
}

impl OutcomeFilter {
    pub const ALL: [OutcomeFilter; 4] = [
        OutcomeFilter::Any,
        OutcomeFilter::Passed,
        OutcomeFilter::Failed,
        OutcomeFilter::RiskHit,
    ];

    /// The query value (`passed`, `failed`, `risk-hit`; empty: any).
    pub fn as_str(self) -> &'static str {
        match self {
            OutcomeFilter::Any => "",
            OutcomeFilter::Passed => "passed",
            OutcomeFilter::Failed => "failed",
            OutcomeFilter::RiskHit => "risk-hit",
        }
    }

    pub fn words(self) -> &'static str {
        match self {
            OutcomeFilter::Any => "any",
            OutcomeFilter::Passed => "passed",
            OutcomeFilter::Failed => "failed",
            OutcomeFilter::RiskHit => "risk structure hit",
        }
    }

    /// The filter of a query value, or a named error.
    pub fn parse(v: &str) -> Result<OutcomeFilter, StoreError> {
        OutcomeFilter::ALL
            .into_iter()
            .find(|o| o.as_str() == v.trim())
            .ok_or_else(|| {
                StoreError::Invalid(format!(
                    "unknown outcome '{v}' (passed, failed, risk-hit, or empty for any)"
                ))
            })
    }

    fn condition(self) -> &'static str {
        match self {
            OutcomeFilter::Any => "",
            OutcomeFilter::Passed => " AND s.final_passed = 1",
            OutcomeFilter::Failed => " AND s.final_passed = 0",
            OutcomeFilter::RiskHit => " AND s.risk_hits > 0",
        }
    }
}

/// A comparison search: scored sessions the viewer may see, narrowed (all optional).
#[derive(Debug, Clone, Default)]
pub struct CompareSearch {
    pub trainee_id: Option<String>,
    pub scenario: Option<String>,
    /// RFC 3339, inclusive.
    pub uploaded_from: Option<String>,
    /// RFC 3339, exclusive.
    pub uploaded_before: Option<String>,
    pub outcome: OutcomeFilter,
}

/// One exercise's totals at one difficulty on a progress page (final grades).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LevelTotals {
    pub exercise: Exercise,
    pub difficulty: String,
    pub sessions: i64,
    pub scored: i64,
    pub passed: i64,
    pub mean_score: Option<f64>,
    pub risk_hits: i64,
}

/// A graded puncture on a progress chart.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DatedScore {
    pub session_id: String,
    pub uploaded_at: String,
    pub difficulty: String,
    pub score: f64,
    pub passed: bool,
}

/// A session with risk hits and the structures hit (from its score report).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RiskSession {
    pub line: ReviewLine,
    /// Structure names as the report gives them ("right lung", "portal vein"), in hit order.
    pub structures: Vec<String>,
}

/// What a trainee's progress page shows.
#[derive(Debug, Clone, PartialEq)]
pub struct TraineeProgress {
    pub trainee: User,
    pub totals: Vec<LevelTotals>,
    /// Graded punctures, oldest first (at most [`PROGRESS_POINTS`], the latest); other exercises
    /// have scores of another kind and are not mixed in.
    pub scores: Vec<DatedScore>,
    /// The latest sessions, newest first.
    pub recent: Vec<ReviewLine>,
    /// How many sessions the trainee has.
    pub total_sessions: i64,
    /// The latest sessions with risk hits, newest first.
    pub risk_sessions: Vec<RiskSession>,
}

const LINE_COLUMNS: &str = "s.id, u.username AS trainee, s.scenario, s.difficulty, s.status, s.uploaded_at, \
    s.final_score, s.final_passed, s.overridden, s.attempts, s.risk_hits, s.error, s.exercise, s.outcome, s.reasons";

fn line_of(row: &sqlx::any::AnyRow) -> Result<ReviewLine, sqlx::Error> {
    Ok(ReviewLine {
        id: row.try_get("id")?,
        trainee: row.try_get("trainee")?,
        scenario: row.try_get("scenario")?,
        difficulty: row.try_get("difficulty")?,
        status: row.try_get("status")?,
        uploaded_at: row.try_get("uploaded_at")?,
        score: row.try_get("final_score")?,
        passed: row.try_get::<Option<i64>, _>("final_passed")?.map(|v| v != 0),
        overridden: row.try_get::<i64, _>("overridden")? != 0,
        attempts: row.try_get("attempts")?,
        risk_hits: row.try_get("risk_hits")?,
        error: row.try_get("error")?,
        exercise: Exercise::parse(&row.try_get::<String, _>("exercise")?).unwrap_or_default(),
        outcome: row
            .try_get::<Option<String>, _>("outcome")?
            .as_deref()
            .and_then(Outcome::parse),
        reasons: super::split_reasons(row.try_get::<Option<String>, _>("reasons")?.as_deref()),
    })
}

/// ` AND …` limiting `s` (a sessions row) to what `viewer` may see, its value appended to `binds`.
fn visible_to(viewer: &User, binds: &mut Vec<String>) -> String {
    match viewer.role {
        Role::Trainee => {
            binds.push(viewer.id.clone());
            format!(" AND s.trainee_id = ${}", binds.len())
        }
        Role::Instructor => {
            binds.push(viewer.id.clone());
            format!(
                " AND s.trainee_id IN (SELECT b.user_id FROM cohort_members a JOIN cohort_members b \
                 ON a.cohort_id = b.cohort_id WHERE a.user_id = ${})",
                binds.len()
            )
        }
        Role::Curriculum | Role::Admin => String::new(),
    }
}

/// Not commented, not overridden: the review is still to do. `NOT IN` an uncorrelated subquery:
/// both engines read the commented sessions once into a hash or temporary index (a correlated
/// `NOT EXISTS` scanned the comments once per session on SQLite, whose `comments` table has no
/// index on `session_id`: 0.8 s for 2 500 sessions).
const UNREVIEWED: &str = " AND s.status IN ('scored', 'failed') AND s.overridden = 0 \
    AND s.id NOT IN (SELECT c.session_id FROM comments c)";

const FLAGGED: &str = " AND (s.status = 'failed' OR s.final_passed = 0 OR s.risk_hits > 0 \
    OR s.outcome = 'not_gradeable')";

impl Store {
    /// The sessions waiting for `viewer`'s review, newest first, one page, and how many wait in
    /// all. Only reviewers have a queue (instructors: their cohorts'; admins: all); anyone else
    /// gets an empty one (pages answer 403 before asking).
    pub async fn review_queue(
        &self,
        viewer: &User,
        scope: QueueScope,
        limit: i64,
        offset: i64,
    ) -> Result<(Vec<ReviewLine>, i64), StoreError> {
        if !matches!(viewer.role, Role::Instructor | Role::Admin) {
            return Ok((Vec::new(), 0));
        }
        let mut binds = Vec::new();
        let mut clause = format!(" WHERE 1 = 1{}{UNREVIEWED}", visible_to(viewer, &mut binds));
        if scope == QueueScope::Flagged {
            clause += FLAGGED;
        }
        self.page_of_lines(&clause, binds, limit, offset).await
    }

    /// A trainee's progress as `viewer` may see it: `None` when there is no such trainee or the
    /// viewer may not see them (the trainee themselves, their instructors, curriculum staff and
    /// admins may), so that pages answer both alike.
    pub async fn trainee_progress(&self, viewer: &User, username: &str) -> Result<Option<TraineeProgress>, StoreError> {
        let Some(trainee) = self.user_by_name(username).await? else {
            return Ok(None);
        };
        let allowed = trainee.role == Role::Trainee
            && match viewer.role {
                Role::Trainee => viewer.id == trainee.id,
                Role::Instructor => self.teaches(&viewer.id, &trainee.id).await?,
                Role::Curriculum | Role::Admin => true,
            };
        if !allowed {
            return Ok(None);
        }
        let id = trainee.id.clone();
        let totals = sqlx::query(
            "SELECT s.exercise, s.difficulty, COUNT(*) AS sessions, \
             CAST(COALESCE(SUM(CASE WHEN s.status = 'scored' THEN 1 ELSE 0 END), 0) AS BIGINT) AS scored, \
             CAST(COALESCE(SUM(CASE WHEN s.status = 'scored' THEN s.final_passed ELSE 0 END), 0) AS BIGINT) AS passed, \
             AVG(CASE WHEN s.status = 'scored' THEN s.final_score END) AS mean_score, \
             CAST(COALESCE(SUM(s.risk_hits), 0) AS BIGINT) AS risk_hits \
             FROM sessions s WHERE s.trainee_id = $1 GROUP BY s.exercise, s.difficulty ORDER BY s.exercise, s.difficulty",
        )
        .bind(id.clone())
        .fetch_all(&self.pool)
        .await?
        .iter()
        .map(|r| {
            Ok(LevelTotals {
                exercise: Exercise::parse(&r.try_get::<String, _>("exercise")?).unwrap_or_default(),
                difficulty: r.try_get("difficulty")?,
                sessions: r.try_get("sessions")?,
                scored: r.try_get("scored")?,
                passed: r.try_get("passed")?,
                mean_score: r.try_get("mean_score")?,
                risk_hits: r.try_get("risk_hits")?,
            })
        })
        .collect::<Result<Vec<_>, sqlx::Error>>()?;
        // Punctures first, then levels in their order (not alphabetical).
        let level = |d: &str| d.parse::<Difficulty>().map_or(Difficulty::ALL.len(), |l| l as usize);
        let mut totals = totals;
        totals.sort_by_key(|t| (t.exercise, level(&t.difficulty)));
        let mut scores = sqlx::query(
            "SELECT s.id, s.uploaded_at, s.difficulty, s.final_score, s.final_passed FROM sessions s \
             WHERE s.trainee_id = $1 AND s.status = 'scored' AND s.final_score IS NOT NULL \
             AND s.exercise = 'puncture' AND (s.outcome IS NULL OR s.outcome <> 'not_gradeable') \
             ORDER BY s.uploaded_at DESC, s.id DESC LIMIT $2",
        )
        .bind(id.clone())
        .bind(PROGRESS_POINTS)
        .fetch_all(&self.pool)
        .await?
        .iter()
        .map(|r| {
            Ok(DatedScore {
                session_id: r.try_get("id")?,
                uploaded_at: r.try_get("uploaded_at")?,
                difficulty: r.try_get("difficulty")?,
                score: r.try_get("final_score")?,
                passed: r.try_get::<Option<i64>, _>("final_passed")?.unwrap_or(0) != 0,
            })
        })
        .collect::<Result<Vec<_>, sqlx::Error>>()?;
        scores.reverse();
        let lines = |extra: &'static str| {
            let id = id.clone();
            async move {
                let q = format!(
                    "SELECT {LINE_COLUMNS} FROM sessions s JOIN users u ON u.id = s.trainee_id \
                     WHERE s.trainee_id = $1{extra} ORDER BY s.uploaded_at DESC, s.id DESC LIMIT $2"
                );
                let rows = sqlx::query(sqlx::AssertSqlSafe(q))
                    .bind(id)
                    .bind(PROGRESS_RECENT)
                    .fetch_all(&self.pool)
                    .await?;
                rows.iter().map(line_of).collect::<Result<Vec<_>, sqlx::Error>>()
            }
        };
        let recent = lines("").await?;
        let risky = lines(" AND s.risk_hits > 0").await?;
        let total_sessions = totals.iter().map(|t| t.sessions).sum();
        let mut risk_sessions = Vec::with_capacity(risky.len());
        for line in risky {
            let report: Option<String> = sqlx::query("SELECT report_json FROM scores WHERE session_id = $1")
                .bind(line.id.clone())
                .fetch_optional(&self.pool)
                .await?
                .map(|r| r.try_get("report_json"))
                .transpose()?;
            risk_sessions.push(RiskSession {
                structures: report.as_deref().map(structures_hit).unwrap_or_default(),
                line,
            });
        }
        Ok(Some(TraineeProgress {
            trainee,
            totals,
            scores,
            recent,
            total_sessions,
            risk_sessions,
        }))
    }

    /// Scored sessions `viewer` may see that match `search`, newest first, one page, and how
    /// many match in all.
    pub async fn compare_search(
        &self,
        viewer: &User,
        search: &CompareSearch,
        limit: i64,
        offset: i64,
    ) -> Result<(Vec<ReviewLine>, i64), StoreError> {
        let mut binds = Vec::new();
        let mut clause = format!(" WHERE s.status = 'scored'{}", visible_to(viewer, &mut binds));
        for (col, op, v) in [
            ("s.trainee_id", "=", &search.trainee_id),
            ("s.scenario", "=", &search.scenario),
            ("s.uploaded_at", ">=", &search.uploaded_from),
            ("s.uploaded_at", "<", &search.uploaded_before),
        ] {
            if let Some(v) = v {
                binds.push(v.clone());
                clause += &format!(" AND {col} {op} ${}", binds.len());
            }
        }
        clause += search.outcome.condition();
        self.page_of_lines(&clause, binds, limit, offset).await
    }

    /// One page of session lines matching `clause` (newest first, at most 1 000) and how many
    /// match in all: the queue and the comparison search page alike.
    async fn page_of_lines(
        &self,
        clause: &str,
        binds: Vec<String>,
        limit: i64,
        offset: i64,
    ) -> Result<(Vec<ReviewLine>, i64), StoreError> {
        let q = format!(
            "SELECT {LINE_COLUMNS} FROM sessions s JOIN users u ON u.id = s.trainee_id{clause} \
             ORDER BY s.uploaded_at DESC, s.id DESC LIMIT ${} OFFSET ${}",
            binds.len() + 1,
            binds.len() + 2
        );
        let rows = super::bound_query(q, binds.clone())
            .bind(limit.clamp(0, 1000))
            .bind(offset.max(0))
            .fetch_all(&self.pool)
            .await?;
        let lines = rows.iter().map(line_of).collect::<Result<Vec<_>, _>>()?;
        let count = super::bound_query(format!("SELECT COUNT(*) AS n FROM sessions s{clause}"), binds)
            .fetch_one(&self.pool)
            .await?
            .try_get("n")?;
        Ok((lines, count))
    }
}

/// The structures a score report lists as hit (`metrics.risk_hits[].structure`), in order.
fn structures_hit(report_json: &str) -> Vec<String> {
    let Ok(v) = serde_json::from_str::<serde_json::Value>(report_json) else {
        return Vec::new();
    };
    v["metrics"]["risk_hits"]
        .as_array()
        .map(|hits| {
            hits.iter()
                .filter_map(|h| h["structure"].as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(status: &str, passed: Option<bool>, risk: Option<i64>) -> ReviewLine {
        ReviewLine {
            id: "x".into(),
            trainee: "t".into(),
            scenario: "s".into(),
            difficulty: "beginner".into(),
            status: SessionStatus::parse(status).unwrap(),
            uploaded_at: String::new(),
            score: None,
            passed,
            overridden: false,
            attempts: None,
            risk_hits: risk,
            error: None,
            exercise: Exercise::Puncture,
            outcome: passed.map(|p| if p { Outcome::Passed } else { Outcome::Failed }),
            reasons: Vec::new(),
        }
    }

    #[test]
    fn queue_reasons_say_why_most_serious_first() {
        use QueueReason::*;
        assert_eq!(
            line("scored", Some(false), Some(1)).queue_reasons(),
            vec![RiskHit, Failed, NotCommented]
        );
        assert_eq!(line("scored", Some(true), Some(0)).queue_reasons(), vec![NotCommented]);
        assert_eq!(
            line("failed", None, None).queue_reasons(),
            vec![ScoringFailed, NotCommented]
        );
        let mut incomplete = line("scored", None, Some(0));
        incomplete.outcome = Some(Outcome::NotGradeable);
        assert_eq!(incomplete.queue_reasons(), vec![NotGradeable, NotCommented]);
        assert_eq!(RiskHit.words(), "risk structure hit");
    }

    #[test]
    fn outcome_filters_parse_their_values_and_name_bad_ones() {
        for o in OutcomeFilter::ALL {
            assert_eq!(OutcomeFilter::parse(o.as_str()).unwrap(), o);
        }
        let e = OutcomeFilter::parse("great").unwrap_err().to_string();
        assert!(e.contains("unknown outcome 'great'"), "{e}");
    }

    #[test]
    fn structures_come_from_the_report() {
        let r = r#"{"metrics":{"risk_hits":[{"structure":"right lung"},{"structure":"portal vein"}]}}"#;
        assert_eq!(structures_hit(r), vec!["right lung", "portal vein"]);
        assert!(structures_hit("not json").is_empty());
    }
}
