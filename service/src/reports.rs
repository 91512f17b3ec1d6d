//! The reports of the JSON API: a trainee's progress (scored sessions per difficulty, in upload
//! order) and a cohort's summary (per trainee). Each answers 404 alike for what does not exist
//! and what is not the caller's to see.

use std::sync::Arc;

use axum::Json;
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::json;
use stylet_scoring::Difficulty;

use super::AppState;
use super::access::may_see;
use super::error::{ApiError, err};
use super::extract::Reader;
use super::list_query::ListQuery;
use super::store::{ProgressPoint, Role};

/// GET /api/trainees/{username}/progress: scored sessions in upload order, grouped by difficulty.
#[utoipa::path(get, path = "/api/trainees/{username}/progress", tag = "review",
    summary = "A trainee's scored sessions per difficulty, in upload order (overrides applied)",
    params(("username" = String, Path)),
    responses(
        (status = 200, description = "progress", body = Progress),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such trainee, or not yours to see", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn progress(
    State(s): State<Arc<AppState>>,
    Reader(user): Reader,
    Path(username): Path<String>,
) -> Result<Response, ApiError> {
    let not_found = || err(StatusCode::NOT_FOUND, format!("no trainee {username}"));
    let trainee = s
        .store
        .user_by_name(&username)
        .await?
        .filter(|t| t.role == Role::Trainee)
        .ok_or_else(not_found)?;
    if !may_see(&s, &user, &trainee.id).await? {
        return Err(not_found());
    }
    let points = s.store.progress(&trainee.id).await?;
    let mut by_level = serde_json::Map::new();
    for level in Difficulty::ALL {
        let series: Vec<&ProgressPoint> = points.iter().filter(|p| p.difficulty == level.as_str()).collect();
        by_level.insert(level.to_string(), json!(series));
    }
    Ok(Json(json!({ "trainee": trainee.username, "progress": by_level })).into_response())
}

/// A trainee's scored sessions per difficulty (`beginner`, `advanced`, `expert`), each a list of
/// `{id, uploaded_at, score, passed, …}` in upload order.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct Progress {
    pub trainee: String,
    #[schema(value_type = Object)]
    pub progress: serde_json::Value,
}

/// GET /api/cohorts/{name}/summary: per trainee counts, pass rate and mean score.
#[utoipa::path(get, path = "/api/cohorts/{name}/summary", tag = "review",
    summary = "Per trainee of a cohort: sessions, scored, passed, mean score, last upload",
    params(("name" = String, Path), ListQuery),
    responses(
        (status = 200, description = "the summary", body = CohortSummary),
        (status = 400, description = "a bad filter", body = super::openapi::ErrorBody),
        (status = 403, description = "an upload-scoped token", body = super::openapi::ErrorBody),
        (status = 404, description = "no such cohort, or not yours", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn cohort_summary(
    State(s): State<Arc<AppState>>,
    Reader(user): Reader,
    Path(name): Path<String>,
    Query(q): Query<ListQuery>,
) -> Result<Response, ApiError> {
    // "No such cohort" and "not yours" get the same 404: which cohorts exist is not for everyone.
    let not_found = || err(StatusCode::NOT_FOUND, format!("no cohort {name}"));
    let cohort = s.store.cohort_id(&name).await?.ok_or_else(not_found)?;
    let allowed = match user.role {
        Role::Instructor => s.store.in_cohort(&user.id, &cohort).await?,
        Role::Curriculum | Role::Admin => true,
        Role::Trainee => false,
    };
    if !allowed {
        return Err(not_found());
    }
    let filter = q.filter(&s).await?;
    let trainees = s.store.cohort_summary(&cohort, &filter).await?;
    Ok(Json(json!({ "cohort": name, "trainees": trainees })).into_response())
}

/// Per trainee of a cohort: sessions, scored, passed, mean score, last upload.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct CohortSummary {
    pub cohort: String,
    #[schema(value_type = Vec<Object>)]
    pub trainees: Vec<serde_json::Value>,
}
