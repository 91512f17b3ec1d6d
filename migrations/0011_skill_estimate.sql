-- A session's skill estimate against its scenario's experts when it was scored (the mean of its
-- metrics' spreads from the expert mean, + worse; docs/metrics.md "Skill estimate"): NULL when the
-- scenario had too few expert references, and for sessions scored before it was measured. The
-- cohort report averages it per trainee and level; the sessions CSV exports it.
ALTER TABLE sessions ADD COLUMN skill_z DOUBLE PRECISION;
