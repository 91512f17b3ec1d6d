//! The expert benchmark (docs/metrics.md "Expert benchmark"): instructors mark sessions as
//! expert references of their scenario; the benchmark is computed from the references' stored
//! metrics whenever it is asked for (the review, the API) or a session of the scenario is scored.
//!
//! - `POST /api/sessions/{id}/expert`: mark (the session's instructors and admins; audited).
//! - `DELETE /api/sessions/{id}/expert`: unmark (the same people; audited).
//! - `GET /api/sessions/{id}/benchmark`: the benchmark of the session's scenario and the
//!   session's metrics against it (whoever may see the session).

use std::sync::Arc;

use axum::Json;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::json;
use stylet_scoring::{Benchmark, Outcome, ScoreReport};

use super::AppState;
use super::access::{reviewable, visible_session};
use super::error::{ApiError, err};
use super::extract::{Actor, Reader};
use super::store::{ExpertReference, Marked, Role, SessionRow, SessionStatus, StoreError, User};

/// The benchmark of `scenario` on the atlas `atlas_hash` and the references it comes from
/// (references whose report cannot be read, or was scored by another physics version, are left
/// out and logged): the one list the grades, the review and the expert corridor use.
pub async fn benchmark(
    s: &AppState,
    atlas_hash: &str,
    scenario: &str,
) -> Result<(Benchmark, Vec<ExpertReference>), StoreError> {
    let rows = s.store.expert_references(atlas_hash, scenario).await?;
    let exercise = s
        .catalogue
        .get(atlas_hash)
        .map_or_else(Default::default, |e| e.summary.exercise_of(scenario));
    let mut reports = Vec::new();
    let mut references = Vec::new();
    for (reference, json) in rows {
        match json.as_deref().map(serde_json::from_str::<ScoreReport>) {
            Some(Ok(report)) if report.physics_version == stylet_physics::PHYSICS_VERSION => {
                reports.push((reference.session_id.clone(), report));
                references.push(reference);
            }
            Some(Ok(_)) => {
                tracing::info!(session = %reference.session_id, "an expert reference scored by another physics version; left out of the benchmark")
            }
            _ => {
                tracing::warn!(session = %reference.session_id, "an expert reference has no readable score; left out of the benchmark")
            }
        }
    }
    let metrics: Vec<(String, &stylet_scoring::Metrics)> =
        reports.iter().map(|(id, r)| (id.clone(), &r.metrics)).collect();
    Ok((Benchmark::from_sessions(scenario, exercise, &metrics), references))
}

/// Fewer references than this are one or two named people's metrics, not a benchmark: a trainee
/// sees the figures (and the corridor) only from this many on; staff always do.
pub const MIN_SHOWN_TO_TRAINEES: usize = 3;

/// Whether `user` sees the figures of a benchmark of `experts` references.
pub fn figures_shown(user: &User, experts: usize) -> bool {
    user.role != Role::Trainee || experts >= MIN_SHOWN_TO_TRAINEES
}

/// The references `user` may know by name: all of them for curriculum staff and admins, those of
/// an instructor's own trainees, none for a trainee (`None`: they learn only how many there are).
pub async fn visible_references(
    s: &AppState,
    user: &User,
    references: &[ExpertReference],
) -> Result<Option<Vec<ExpertReference>>, StoreError> {
    match user.role {
        Role::Trainee => Ok(None),
        Role::Instructor => {
            let mut mine = Vec::new();
            for r in references {
                if let Some((_, trainee_id)) = s.store.session(&r.session_id).await?
                    && s.store.teaches(&user.id, &trainee_id).await?
                {
                    mine.push(r.clone());
                }
            }
            Ok(Some(mine))
        }
        Role::Curriculum | Role::Admin => Ok(Some(references.to_vec())),
    }
}

/// A short name for a set of references (the first 12 hex digits of the SHA-256 of their sorted
/// session ids; "none" for none): pictures drawn with the expert corridor carry it, so marking
/// or unmarking draws them anew.
pub fn references_key(references: &[ExpertReference]) -> String {
    use sha2::Digest;
    if references.is_empty() {
        return "none".into();
    }
    let mut ids: Vec<&str> = references.iter().map(|r| r.session_id.as_str()).collect();
    ids.sort_unstable();
    let digest = sha2::Sha256::digest(ids.join(",").as_bytes());
    digest.iter().take(6).map(|b| format!("{b:02x}")).collect()
}

/// Why a session cannot be an expert reference, if it cannot: it must be scored, a complete
/// recording, its replay must have verified (its metrics are then the physics', bit for bit) and
/// it must have passed its grade (see [`report_reference_problem`]).
pub fn reference_problem(row: &SessionRow) -> Option<String> {
    if row.status != SessionStatus::Scored {
        return Some(format!(
            "session {} is {}: only a scored session can be an expert reference",
            row.id, row.status
        ));
    }
    let report: Option<ScoreReport> = row.score.clone().and_then(|v| serde_json::from_value(v).ok());
    match report {
        None => Some("the session's score cannot be read".into()),
        Some(r) => report_reference_problem(&r),
    }
}

/// Why a scored session's report keeps it from being an expert reference, if it does: an
/// incomplete recording, a replay that did not verify, or a grade it did not pass. The computed
/// outcome decides, not an instructor's override: the benchmark is built from the metrics, which
/// an override does not change. The API, the dashboard's form and its button use this one rule.
pub fn report_reference_problem(r: &ScoreReport) -> Option<String> {
    if r.incomplete {
        Some("the recording is incomplete: it cannot be an expert reference".into())
    } else if !r.replay_verified {
        Some("the session's replay did not verify: its metrics cannot be an expert reference".into())
    } else {
        let why = match r.outcome {
            Outcome::Passed => return None,
            Outcome::Failed => "the session failed its grade",
            Outcome::NotGradeable => "the session has no grade",
        };
        Some(format!("{why}: only a passed session can be an expert reference"))
    }
}

/// Marks (`true`) or unmarks a session for `user` (API and dashboard): its reviewers only; a
/// session that cannot be a reference, or a scenario with the most references, is a 409.
/// Returns whether the session is a reference now.
pub async fn set_expert(s: &AppState, user: &User, id: &str, expert: bool) -> Result<bool, ApiError> {
    reviewable(s, user, id).await?;
    if !expert {
        s.store.unmark_expert(id, user).await?;
        return Ok(false);
    }
    let row = visible_session(s, user, id).await?;
    if let Some(problem) = reference_problem(&row) {
        return Err(err(StatusCode::CONFLICT, problem));
    }
    match s.store.mark_expert(id, user).await? {
        Marked::Now | Marked::Already => Ok(true),
        Marked::Full => Err(err(
            StatusCode::CONFLICT,
            format!(
                "scenario '{}' has {} expert references already: unmark one first",
                row.scenario,
                stylet_scoring::benchmark::MAX_EXPERTS
            ),
        )),
    }
}

/// POST /api/sessions/{id}/expert.
#[utoipa::path(post, path = "/api/sessions/{id}/expert", tag = "review",
    summary = "Mark the session as an expert reference of its scenario (the trainee's instructors, admins; audited)",
    description = "It must be scored, complete, its replay verified and its grade passed (the computed grade, not an override); at most 50 per scenario.",
    params(("id" = String, Path, description = "session id")),
    responses(
        (status = 201, description = "marked", body = ExpertAnswer),
        (status = 403, description = "not a reviewer of this trainee, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session", body = super::openapi::ErrorBody),
        (status = 409, description = "not scored, incomplete, not verified, not passed, or the scenario has the most references", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn mark(
    State(s): State<Arc<AppState>>,
    Actor(user): Actor,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    set_expert(&s, &user, &id, true).await?;
    Ok((StatusCode::CREATED, Json(json!({ "session": id, "expert": true }))).into_response())
}

/// DELETE /api/sessions/{id}/expert.
#[utoipa::path(delete, path = "/api/sessions/{id}/expert", tag = "review",
    summary = "Unmark an expert reference (the trainee's instructors, admins; audited)",
    params(("id" = String, Path, description = "session id")),
    responses(
        (status = 200, description = "unmarked", body = ExpertAnswer),
        (status = 403, description = "not a reviewer of this trainee, CSRF token missing, or an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn unmark(
    State(s): State<Arc<AppState>>,
    Actor(user): Actor,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    set_expert(&s, &user, &id, false).await?;
    Ok(Json(json!({ "session": id, "expert": false })).into_response())
}

/// Whether a session is an expert reference now.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct ExpertAnswer {
    pub session: String,
    pub expert: bool,
}

/// GET /api/sessions/{id}/benchmark: `{scenario, exercise, experts, metrics: [{metric, mean,
/// spread}], expert, comparison: [{metric, value, mean, spread, spreads_from_mean}]}`; the
/// references' session ids (`references`) only for staff (a trainee learns how many there are).
#[utoipa::path(get, path = "/api/sessions/{id}/benchmark", tag = "review",
    summary = "The expert benchmark of the session's scenario and the session's metrics against it",
    params(("id" = String, Path, description = "session id")),
    responses(
        (status = 200, description = "the benchmark", body = BenchmarkAnswer),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such session, or not yours to see", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn get(
    State(s): State<Arc<AppState>>,
    Reader(user): Reader,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let row = visible_session(&s, &user, &id).await?;
    let (bench, references) = benchmark(&s, &row.atlas_hash, &row.scenario).await?;
    let report: Option<ScoreReport> = row.score.clone().and_then(|v| serde_json::from_value(v).ok());
    let comparison: Vec<serde_json::Value> = report
        .iter()
        .flat_map(|r| bench.compare(&r.metrics))
        .map(|c| {
            json!({ "metric": c.metric, "value": c.value, "mean": c.mean, "spread": c.spread,
                    "spreads_from_mean": c.spreads_from_mean() })
        })
        .collect();
    let n = bench.experts.len();
    let shown = figures_shown(&user, n);
    let mut v = json!({
        "scenario": bench.scenario,
        "exercise": bench.exercise,
        "experts": n,
        "metrics": if shown { json!(bench.metrics) } else { json!([]) },
        "expert": references.iter().any(|r| r.session_id == id),
        "comparison": if shown { json!(comparison) } else { json!([]) },
    });
    if let Some(visible) = visible_references(&s, &user, &references).await? {
        v["references"] = json!(visible);
    }
    Ok(Json(v).into_response())
}

/// The expert benchmark of a session's scenario and the session's metrics against it.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct BenchmarkAnswer {
    pub scenario: String,
    pub exercise: String,
    pub experts: i64,
    #[schema(value_type = Vec<Object>)]
    pub metrics: Vec<serde_json::Value>,
    pub expert: bool,
    #[schema(value_type = Vec<Object>)]
    pub comparison: Vec<serde_json::Value>,
    /// Staff only.
    #[schema(value_type = Option<Vec<Object>>)]
    pub references: Option<Vec<serde_json::Value>>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(status: SessionStatus, incomplete: bool, verified: bool) -> SessionRow {
        row_with_outcome(status, incomplete, verified, "passed")
    }

    /// A session row whose stored report (the shipped one, which failed) says `outcome`.
    fn row_with_outcome(status: SessionStatus, incomplete: bool, verified: bool, outcome: &str) -> SessionRow {
        let score = (status == SessionStatus::Scored).then(|| {
            let mut v = serde_json::to_value(stored_report()).unwrap();
            v["incomplete"] = json!(incomplete);
            v["replay_verified"] = json!(verified);
            v["outcome"] = json!(outcome);
            v
        });
        SessionRow {
            id: "s1".into(),
            trainee: "eve".into(),
            scenario: "right-duct".into(),
            difficulty: "expert".into(),
            status,
            uploaded_at: String::new(),
            recorded_at: String::new(),
            duration_s: 20.0,
            error: None,
            file_sha256: "ab".into(),
            atlas_hash: "cd".into(),
            size_bytes: 1,
            score,
            exercise: Default::default(),
            outcome: None,
            reasons: Vec::new(),
        }
    }

    /// A report as the shipped rubric writes it, from the scoring crate's own JSON.
    fn stored_report() -> serde_json::Value {
        serde_json::from_str(include_str!("../tests/data/report.json")).unwrap()
    }

    #[test]
    fn only_scored_complete_verified_passed_sessions_can_be_references() {
        assert_eq!(reference_problem(&row(SessionStatus::Scored, false, true)), None);
        for (r, want) in [
            (row(SessionStatus::Queued, false, true), "is queued"),
            (row(SessionStatus::Scoring, false, true), "is scoring"),
            (row(SessionStatus::Failed, false, true), "is failed"),
            (row(SessionStatus::Scored, true, true), "incomplete"),
            (row(SessionStatus::Scored, false, false), "did not verify"),
            (
                row_with_outcome(SessionStatus::Scored, false, true, "failed"),
                "failed its grade",
            ),
            (
                row_with_outcome(SessionStatus::Scored, false, true, "not_gradeable"),
                "has no grade",
            ),
        ] {
            let e = reference_problem(&r).unwrap();
            assert!(e.contains(want), "expected '{want}' in: {e}");
        }
    }
}
