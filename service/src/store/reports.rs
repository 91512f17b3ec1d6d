//! What curriculum staff read about a cohort over time: scored sessions per upload day, exercise
//! and difficulty (the dashboard groups the days into calendar weeks), and why sessions failed
//! (the rubric requirement or the pass mark behind each failure).

use std::collections::BTreeMap;

use sqlx::Row;

use stylet_scoring::Exercise;

use super::{SessionFilter, Store, StoreError};

/// Upload days read for the trends at most (3 difficulties × 3 exercises × ~3 years of days).
pub const TREND_ROWS_MAX: i64 = 10_000;

/// Failed sessions read for the reasons breakdown at most (the latest ones).
pub const FAILED_READ_MAX: i64 = 1_000;

/// Scored sessions of one exercise at one difficulty uploaded on one day (UTC).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DayCount {
    /// `YYYY-MM-DD`.
    pub day: String,
    pub exercise: Exercise,
    pub difficulty: String,
    /// Scored sessions, the not-gradeable ones included.
    pub scored: i64,
    /// Passed (final grade: an instructor's override where there is one).
    pub passed: i64,
    /// Scored but not gradeable (a recording that was cut or damaged): no pass, no fail.
    pub not_gradeable: i64,
}

/// What made a session fail.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
pub enum FailureCause {
    /// A rubric requirement on this metric was not met (its identifier, e.g. `risk_hits`).
    Requirement(String),
    /// Every requirement met, but the score fell below the level's pass mark; the metric that
    /// cost the most points (`None`: no deduction recorded).
    BelowPassMark(Option<String>),
    /// The computed grade passed; an instructor's override failed it.
    Override,
}

/// Failed sessions of a selection by cause (a session that missed two requirements counts under
/// both), per exercise.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct FailureBreakdown {
    /// Failed sessions in the selection.
    pub failed: i64,
    /// Of those, the latest read for the causes (at most [`FAILED_READ_MAX`]).
    pub examined: i64,
    /// (exercise, cause) → sessions, largest first.
    pub causes: Vec<(Exercise, FailureCause, i64)>,
}

/// The part of a stored report the breakdown reads (serde skips the rest).
#[derive(serde::Deserialize)]
struct ReportGrade {
    grade: GradePart,
}

#[derive(serde::Deserialize)]
struct GradePart {
    passed: bool,
    /// Reports before rubric v2: the requirements not met as `"<metric> = <value> is above <max>"`.
    #[serde(default)]
    failed: Vec<String>,
    /// Rubric v2: the requirements not met, as numbers.
    #[serde(default)]
    unmet: Vec<UnmetPart>,
    #[serde(default)]
    deductions: Vec<DeductionPart>,
}

#[derive(serde::Deserialize)]
struct UnmetPart {
    metric: String,
}

#[derive(serde::Deserialize)]
struct DeductionPart {
    metric: String,
    points: f64,
}

/// The metric a failed requirement names: the rubric writes `"<metric> = <value> is above <max>"`.
fn requirement_metric(text: &str) -> Option<&str> {
    let id = text.split_whitespace().next()?;
    let ok = !id.is_empty()
        && id
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_');
    ok.then_some(id)
}

/// A stored exercise identifier (the column's CHECK allows only these).
fn exercise_of(id: &str) -> Result<Exercise, StoreError> {
    Exercise::parse(id).ok_or_else(|| StoreError::Invalid(format!("unknown exercise '{id}' in the sessions table")))
}

/// Why one failed session failed, from its stored report.
fn causes_of(report_json: &str) -> Vec<FailureCause> {
    let Ok(r) = serde_json::from_str::<ReportGrade>(report_json) else {
        return Vec::new();
    };
    if r.grade.passed {
        return vec![FailureCause::Override];
    }
    let mut out: Vec<FailureCause> = if r.grade.unmet.is_empty() {
        r.grade
            .failed
            .iter()
            .filter_map(|f| requirement_metric(f))
            .map(|m| FailureCause::Requirement(m.to_string()))
            .collect()
    } else {
        r.grade
            .unmet
            .iter()
            .map(|u| FailureCause::Requirement(u.metric.clone()))
            .collect()
    };
    out.dedup();
    if out.is_empty() {
        let main = r
            .grade
            .deductions
            .iter()
            .filter(|d| d.points.is_finite())
            .max_by(|a, b| a.points.total_cmp(&b.points))
            .map(|d| d.metric.clone());
        out.push(FailureCause::BelowPassMark(main));
    }
    out
}

impl Store {
    /// Scored sessions of a cohort that match `filter`'s scenario, difficulty and dates, per upload
    /// day (UTC), exercise and difficulty, oldest day first; the latest [`TREND_ROWS_MAX`] rows.
    pub async fn cohort_day_counts(
        &self,
        cohort_id: &str,
        filter: &SessionFilter,
    ) -> Result<Vec<DayCount>, StoreError> {
        let mut binds = vec![cohort_id.to_string()];
        let conds = super::sessions::narrowing(filter, &mut binds);
        let q = format!(
            "SELECT substr(s.uploaded_at, 1, 10) AS day, s.exercise, s.difficulty, COUNT(*) AS scored, \
             CAST(COALESCE(SUM(CASE WHEN s.outcome = 'not_gradeable' THEN 0 ELSE s.final_passed END), 0) AS BIGINT) AS passed, \
             CAST(COALESCE(SUM(CASE WHEN s.outcome = 'not_gradeable' THEN 1 ELSE 0 END), 0) AS BIGINT) AS not_gradeable \
             FROM sessions s \
             WHERE s.status = 'scored' AND s.trainee_id IN (SELECT user_id FROM cohort_members WHERE cohort_id = $1){conds} \
             GROUP BY substr(s.uploaded_at, 1, 10), s.exercise, s.difficulty \
             ORDER BY day DESC, s.exercise, s.difficulty LIMIT ${}",
            binds.len() + 1
        );
        let rows = super::bound_query(q, binds)
            .bind(TREND_ROWS_MAX)
            .fetch_all(&self.pool)
            .await?;
        let mut out = rows
            .iter()
            .map(|r| -> Result<DayCount, StoreError> {
                Ok(DayCount {
                    day: r.try_get("day")?,
                    exercise: exercise_of(&r.try_get::<String, _>("exercise")?)?,
                    difficulty: r.try_get("difficulty")?,
                    scored: r.try_get("scored")?,
                    passed: r.try_get("passed")?,
                    not_gradeable: r.try_get("not_gradeable")?,
                })
            })
            .collect::<Result<Vec<_>, StoreError>>()?;
        out.reverse();
        Ok(out)
    }

    /// Why the failed sessions of a cohort that match `filter` failed: the requirement or the
    /// pass mark behind each failure, read from the latest [`FAILED_READ_MAX`] failed sessions'
    /// reports. Not-gradeable sessions are not failures.
    pub async fn cohort_failures(
        &self,
        cohort_id: &str,
        filter: &SessionFilter,
    ) -> Result<FailureBreakdown, StoreError> {
        let mut binds = vec![cohort_id.to_string()];
        let conds = super::sessions::narrowing(filter, &mut binds);
        let failed_where = format!(
            "s.status = 'scored' AND s.final_passed = 0 AND (s.outcome IS NULL OR s.outcome <> 'not_gradeable') \
             AND s.trainee_id IN (SELECT user_id FROM cohort_members WHERE cohort_id = $1){conds}"
        );
        let count = format!("SELECT COUNT(*) AS n FROM sessions s WHERE {failed_where}");
        let failed: i64 = super::bound_query(count, binds.clone())
            .fetch_one(&self.pool)
            .await?
            .try_get("n")?;
        let q = format!(
            "SELECT s.exercise, sc.report_json FROM sessions s JOIN scores sc ON sc.session_id = s.id \
             WHERE {failed_where} ORDER BY s.uploaded_at DESC, s.id DESC LIMIT ${}",
            binds.len() + 1
        );
        let rows = super::bound_query(q, binds)
            .bind(FAILED_READ_MAX)
            .fetch_all(&self.pool)
            .await?;
        let mut counts: BTreeMap<(Exercise, FailureCause), i64> = BTreeMap::new();
        for r in &rows {
            let exercise = exercise_of(&r.try_get::<String, _>("exercise")?)?;
            let report: String = r.try_get("report_json")?;
            for cause in causes_of(&report) {
                *counts.entry((exercise, cause)).or_default() += 1;
            }
        }
        let mut causes: Vec<(Exercise, FailureCause, i64)> = counts.into_iter().map(|((e, c), n)| (e, c, n)).collect();
        causes.sort_by(|a, b| a.0.cmp(&b.0).then(b.2.cmp(&a.2)).then(a.1.cmp(&b.1)));
        Ok(FailureBreakdown {
            failed,
            examined: rows.len() as i64,
            causes,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn causes_come_from_the_failed_requirements_or_the_pass_mark() {
        let report = r#"{"session_id":"x","grade":{"score":5.0,"passed":false,
            "failed":["target_not_reached = 1 is above 0","risk_hits = 1 is above 0","risk_hits = 1 is above 0"],
            "deductions":[{"metric":"attempts","value":2.0,"points":10.0}]}}"#;
        assert_eq!(
            causes_of(report),
            vec![
                FailureCause::Requirement("target_not_reached".into()),
                FailureCause::Requirement("risk_hits".into())
            ]
        );
        let below = r#"{"grade":{"passed":false,"failed":[],"deductions":[
            {"metric":"attempts","value":3.0,"points":20.0},{"metric":"fluoro_time_s","value":90.0,"points":15.0}]}}"#;
        assert_eq!(
            causes_of(below),
            vec![FailureCause::BelowPassMark(Some("attempts".into()))]
        );
        let v2 = r#"{"grade":{"passed":false,"failed":["The needle never reached the target."],
            "unmet":[{"metric":"target_not_reached","value":1.0,"min":null,"max":0.0}],"deductions":[]}}"#;
        assert_eq!(
            causes_of(v2),
            vec![FailureCause::Requirement("target_not_reached".into())]
        );
        let overridden = r#"{"grade":{"passed":true,"failed":[],"deductions":[]}}"#;
        assert_eq!(causes_of(overridden), vec![FailureCause::Override]);
        assert!(causes_of("not json").is_empty());
    }
}
