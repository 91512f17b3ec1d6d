//! Replay engine, metrics and rubrics; the axum scoring service and its sqlx store.
//!
//! Empty on purpose: the replay/scoring and service issues fill it. Nothing here pretends to work yet.
