-- Recovery from storage failures such as a read-only data directory.
-- A scoring job that could not run for a passing reason (its file unreadable for a moment, the
-- database refusing writes) goes back to the queue and is not claimed again before not_before.
ALTER TABLE scoring_jobs ADD COLUMN not_before TEXT;
-- One row the health check writes to: /healthz is 503 while the store cannot write.
CREATE TABLE service_health (
    id BIGINT PRIMARY KEY,
    checked_at TEXT NOT NULL
);
INSERT INTO service_health (id, checked_at) VALUES (1, '');
