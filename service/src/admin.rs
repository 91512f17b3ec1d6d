//! The admin port (`--admin-bind ADDR`), for the operators' monitoring and the load balancer, not
//! for users (bind it to a private address): `GET /metrics` (Prometheus text format,
//! [`super::telemetry`]), `GET /livez` (the process answers) and `GET /readyz` (it should get
//! traffic: not stopping, the database answers and holds this build's migrations, the data
//! directory is there).

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use axum::Router;
use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use metrics_exporter_prometheus::PrometheusHandle;
use serde_json::json;

use super::AppState;
use super::telemetry;

/// How long `/readyz` waits for the database before it says "not ready".
pub const READY_TIMEOUT: Duration = Duration::from_secs(2);

type Admin = (Arc<AppState>, PrometheusHandle);

/// The admin routes.
pub fn router(state: Arc<AppState>, metrics: PrometheusHandle) -> Router {
    Router::new()
        .route("/metrics", get(scrape))
        .route("/livez", get(livez))
        .route("/readyz", get(readyz))
        .with_state((state, metrics))
}

/// `GET /metrics`: every metric this replica recorded, and the queue depth read from the
/// database now (it is the database's, the same at every replica).
async fn scrape(State((s, metrics)): State<Admin>) -> Response {
    match tokio::time::timeout(READY_TIMEOUT, s.store.queued_jobs()).await {
        Ok(Ok(n)) => metrics::gauge!(telemetry::QUEUE_DEPTH).set(n as f64),
        Ok(Err(e)) => tracing::warn!(error = %e, "metrics: cannot count the queued jobs"),
        Err(_) => tracing::warn!("metrics: the database did not count the queued jobs in time"),
    }
    (
        [(header::CONTENT_TYPE, "text/plain; version=0.0.4; charset=utf-8")],
        metrics.render(),
    )
        .into_response()
}

/// `GET /livez`: 200 while the process serves at all (restart it when this fails).
async fn livez() -> Response {
    axum::Json(json!({ "status": "alive" })).into_response()
}

/// `GET /readyz`: 200 when this replica should get traffic, else 503 with the reason.
async fn readyz(State((s, _)): State<Admin>) -> Response {
    let not_ready = |why: String| {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            axum::Json(json!({ "status": "not ready", "error": why })),
        )
            .into_response()
    };
    if s.stopping.load(Ordering::SeqCst) {
        return not_ready("stopping: finishing the requests in flight".into());
    }
    match tokio::time::timeout(READY_TIMEOUT, s.store.readiness()).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return not_ready(e.to_string()),
        Err(_) => return not_ready(format!("the database did not answer in {} s", READY_TIMEOUT.as_secs())),
    }
    let sessions = s.config.data_dir.join("sessions");
    if !tokio::fs::metadata(&sessions).await.is_ok_and(|m| m.is_dir()) {
        return not_ready(format!("{} is not there", sessions.display()));
    }
    match tokio::time::timeout(READY_TIMEOUT, s.storage.check()).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return not_ready(e.to_string()),
        Err(_) => {
            return not_ready(format!(
                "the object storage did not answer in {} s",
                READY_TIMEOUT.as_secs()
            ));
        }
    }
    axum::Json(json!({ "status": "ready" })).into_response()
}
