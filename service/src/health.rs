//! `GET /healthz`: whether the service can write its database and its data directory (checked by
//! writing, at most once a second).

use std::sync::Arc;

use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::json;

use super::AppState;
use super::error::err;

/// GET /healthz: 200 while the service can read and write its database and data directory,
/// 503 otherwise (checked by writing, at most once a second).
#[utoipa::path(get, path = "/healthz", tag = "service",
    summary = "Health: the database and the data directory can be written",
    responses(
        (status = 200, description = "healthy", body = Health),
        (status = 503, description = "the database or the data directory cannot be written", body = super::openapi::ErrorBody),
    ))]
pub async fn healthz(State(s): State<Arc<AppState>>) -> Response {
    let probe = async {
        if let Err(e) = s.store.probe_write().await {
            tracing::warn!(error = %e, "health check: the database cannot write");
            return false;
        }
        let file = s.config.data_dir.join("sessions").join(".health-check");
        let written = tokio::fs::write(&file, b"ok").await;
        let _ = tokio::fs::remove_file(&file).await;
        if let Err(e) = written {
            tracing::warn!(error = %e, "health check: the data directory cannot write");
            return false;
        }
        true
    };
    if s.health.check(probe).await {
        Json(json!({ "status": "ok" })).into_response()
    } else {
        err(
            StatusCode::SERVICE_UNAVAILABLE,
            "unhealthy: the database or the data directory cannot be written",
        )
        .into_response()
    }
}

/// `GET /healthz`.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct Health {
    /// "ok".
    pub status: String,
}
