-- Exercises and outcomes: what a session practises, whether it passed, failed or could
-- not be graded, and why in plain words, on its row, for the lists, reports and the CSV.
-- exercise: 'puncture' | 'palpation' | 'ultrasound_survey' (the scenario's, docs/atlas.md).
-- outcome: NULL until scored; 'passed' | 'failed' | 'not_gradeable' (the computed result; an
-- instructor's override changes final_score / final_passed only).
-- reasons: the report's reasons joined with a line feed, NULL until scored.
-- target_reached (0/1) and risk_structures (names, ';'-separated): for the CSV, NULL until scored.
ALTER TABLE sessions ADD COLUMN exercise TEXT NOT NULL DEFAULT 'puncture'
    CHECK (exercise IN ('puncture', 'palpation', 'ultrasound_survey'));
ALTER TABLE sessions ADD COLUMN outcome TEXT CHECK (outcome IN ('passed', 'failed', 'not_gradeable'));
ALTER TABLE sessions ADD COLUMN reasons TEXT;
ALTER TABLE sessions ADD COLUMN target_reached BIGINT;
ALTER TABLE sessions ADD COLUMN risk_structures TEXT;
-- Existing rows: the shipped PTCD scenarios that are not punctures (atlases/ptcd.toml); the
-- outcome from the score (an incomplete recording is not gradeable, else its computed pass).
-- Their reasons, target_reached and risk_structures are filled from the stored report when the
-- server starts (Store::open).
UPDATE sessions SET exercise = 'palpation' WHERE scenario = 'palpation-sweep';
UPDATE sessions SET exercise = 'ultrasound_survey' WHERE scenario IN ('probe-parallel', 'probe-across');
UPDATE sessions SET outcome = CASE WHEN sc.passed THEN 'passed' ELSE 'failed' END
    FROM scores sc WHERE sc.session_id = sessions.id;
UPDATE sessions SET outcome = 'not_gradeable'
    WHERE id IN (SELECT session_id FROM scores WHERE incomplete);
CREATE INDEX sessions_outcome ON sessions (outcome);
