-- What a session's line on a page or in a report shows, kept on the session row so that lists of
-- 10 000 sessions need neither the report JSON nor a look-up of overrides per row. The store
-- writes these with the score (finish_job) and with every grade override, in the same
-- transaction; rows scored before this migration are filled in at start (Store::open).
-- Flags are BIGINT 0/1: the sqlx `Any` driver cannot decode SQLite's BOOLEAN.
ALTER TABLE sessions ADD COLUMN final_score DOUBLE PRECISION;
ALTER TABLE sessions ADD COLUMN final_passed BIGINT;
ALTER TABLE sessions ADD COLUMN overridden BIGINT NOT NULL DEFAULT 0;
ALTER TABLE sessions ADD COLUMN attempts BIGINT;
ALTER TABLE sessions ADD COLUMN risk_hits BIGINT;
ALTER TABLE sessions ADD COLUMN replay_verified BIGINT;
ALTER TABLE sessions ADD COLUMN rubric_version BIGINT;
CREATE INDEX sessions_uploaded ON sessions (uploaded_at);
CREATE INDEX cohort_members_user ON cohort_members (user_id);
