//! The service's metrics, in the Prometheus text format on the admin port (`GET /metrics`): the
//! `metrics` facade records them where they happen, its Prometheus exporter keeps and renders
//! them. Names follow the OpenTelemetry HTTP semantic conventions where one exists
//! (`http.server.request.duration` → `http_server_request_duration_seconds`, with the attributes
//! `http.request.method`, `http.route` and `http.response.status_code` as labels); the service's
//! own are prefixed `stylet_`. Without `--admin-bind` no recorder is installed and every
//! recording is a no-op.

use std::sync::OnceLock;
use std::time::Duration;

use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};

/// Request duration by method, route and status (histogram, seconds).
pub const HTTP_REQUEST_DURATION: &str = "http_server_request_duration_seconds";
/// Scoring jobs waiting to be claimed, on the whole database (gauge, read when scraped).
pub const QUEUE_DEPTH: &str = "stylet_scoring_queue_depth";
/// Scoring jobs ended by this replica, by outcome (counter).
pub const JOBS: &str = "stylet_scoring_jobs_total";
/// Time from claim to stored outcome, by outcome (histogram, seconds).
pub const JOB_DURATION: &str = "stylet_scoring_job_duration_seconds";
/// Replay speed of each scored session (histogram, physics ticks per second of wall time).
pub const REPLAY_SPEED: &str = "stylet_replay_ticks_per_second";
/// Ticks replayed (counter).
pub const REPLAY_TICKS: &str = "stylet_replay_ticks_total";
/// Session uploads ended, by result: stored, duplicate, refused (counter).
pub const UPLOADS: &str = "stylet_uploads_total";
/// Bytes of the session files stored (counter).
pub const UPLOAD_BYTES: &str = "stylet_upload_bytes_total";
/// Logins ended, by result: success, wrong, throttled, disabled, busy (counter).
pub const LOGINS: &str = "stylet_logins_total";
/// Atlas lookups by the scoring worker, by result: hit (loaded), miss (loaded from disk now)
/// (counter).
pub const ATLAS_CACHE: &str = "stylet_atlas_cache_lookups_total";

/// The buckets of the OpenTelemetry HTTP duration histograms (seconds), as the conventions advise.
const HTTP_BUCKETS_S: &[f64] = &[
    0.005, 0.01, 0.025, 0.05, 0.075, 0.1, 0.25, 0.5, 0.75, 1.0, 2.5, 5.0, 7.5, 10.0,
];
/// Scoring jobs take from a fraction of a second to minutes.
const JOB_BUCKETS_S: &[f64] = &[0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0];
/// Replay speeds around the measured 300 K – 500 K ticks/s of one core.
const SPEED_BUCKETS: &[f64] = &[10e3, 30e3, 100e3, 200e3, 300e3, 400e3, 500e3, 700e3, 1e6, 2e6];

static HANDLE: OnceLock<PrometheusHandle> = OnceLock::new();

/// Installs the process's recorder (once; later calls return the same handle) and starts its
/// upkeep, which keeps the histograms' memory bounded between scrapes.
pub fn install() -> Result<PrometheusHandle, metrics_exporter_prometheus::BuildError> {
    if let Some(h) = HANDLE.get() {
        return Ok(h.clone());
    }
    let recorder = PrometheusBuilder::new()
        .set_buckets_for_metric(Matcher::Full(HTTP_REQUEST_DURATION.into()), HTTP_BUCKETS_S)?
        .set_buckets_for_metric(Matcher::Full(JOB_DURATION.into()), JOB_BUCKETS_S)?
        .set_buckets_for_metric(Matcher::Full(REPLAY_SPEED.into()), SPEED_BUCKETS)?
        .build_recorder();
    let handle = recorder.handle();
    // Another recorder installed first (a test process serving twice) keeps its place: this
    // handle then renders what it records, which is nothing, rather than failing the start.
    let handle = match metrics::set_global_recorder(recorder) {
        Ok(()) => handle,
        Err(_) => return Ok(HANDLE.get_or_init(|| handle).clone()),
    };
    let handle = HANDLE.get_or_init(|| handle).clone();
    describe();
    let upkeep = handle.clone();
    tokio::spawn(async move {
        let mut every = tokio::time::interval(Duration::from_secs(5));
        loop {
            every.tick().await;
            upkeep.run_upkeep();
        }
    });
    Ok(handle)
}

fn describe() {
    use metrics::{Unit, describe_counter, describe_gauge, describe_histogram};
    describe_histogram!(
        HTTP_REQUEST_DURATION,
        Unit::Seconds,
        "Duration of HTTP server requests."
    );
    describe_gauge!(
        QUEUE_DEPTH,
        Unit::Count,
        "Scoring jobs queued on the database, waiting for a replica."
    );
    describe_counter!(JOBS, Unit::Count, "Scoring jobs this replica ended, by outcome.");
    describe_histogram!(
        JOB_DURATION,
        Unit::Seconds,
        "Time from claiming a scoring job to storing its outcome."
    );
    describe_histogram!(
        REPLAY_SPEED,
        "Physics ticks replayed per second of wall time, per scored session."
    );
    describe_counter!(REPLAY_TICKS, Unit::Count, "Physics ticks replayed.");
    describe_counter!(UPLOADS, Unit::Count, "Session uploads, by result.");
    describe_counter!(UPLOAD_BYTES, Unit::Bytes, "Bytes of session files stored.");
    describe_counter!(LOGINS, Unit::Count, "Logins, by result.");
    describe_counter!(
        ATLAS_CACHE,
        Unit::Count,
        "Atlas lookups of the scoring worker, by cache result."
    );
}

/// The OpenTelemetry `http.request.method` value: the known methods as themselves, any other as
/// `_OTHER` (so that a client cannot grow the label set).
pub fn method_label(method: &axum::http::Method) -> &'static str {
    use axum::http::Method;
    match *method {
        Method::GET => "GET",
        Method::HEAD => "HEAD",
        Method::POST => "POST",
        Method::PUT => "PUT",
        Method::DELETE => "DELETE",
        Method::PATCH => "PATCH",
        Method::OPTIONS => "OPTIONS",
        Method::CONNECT => "CONNECT",
        Method::TRACE => "TRACE",
        _ => "_OTHER",
    }
}

/// Records one served request. `route` is the matched route template (`/api/sessions/{id}`),
/// empty when none matched, so the label set stays bounded by the routes.
pub fn record_request(method: &axum::http::Method, route: &str, status: u16, elapsed: Duration) {
    metrics::histogram!(
        HTTP_REQUEST_DURATION,
        "http_request_method" => method_label(method),
        "http_route" => route.to_string(),
        "http_response_status_code" => status.to_string(),
    )
    .record(elapsed.as_secs_f64());
}

/// Counts one event of `counter` with `result`.
pub fn count(counter: &'static str, result: &'static str) {
    metrics::counter!(counter, "result" => result).increment(1);
}
