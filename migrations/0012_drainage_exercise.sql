-- The drainage exercise (the puncture, then the catheter placed over a guide wire): sessions.exercise
-- may now be 'drainage'. Neither engine changes a column's CHECK in place, so the column is
-- copied into a new one with the wider CHECK, the old one dropped and the new one renamed
-- (SQLite ≥ 3.35 and PostgreSQL alike; nothing indexes, references or views the column).
ALTER TABLE sessions ADD COLUMN exercise_kind TEXT NOT NULL DEFAULT 'puncture'
    CHECK (exercise_kind IN ('puncture', 'palpation', 'ultrasound_survey', 'drainage'));
UPDATE sessions SET exercise_kind = exercise;
ALTER TABLE sessions DROP COLUMN exercise;
ALTER TABLE sessions RENAME COLUMN exercise_kind TO exercise;
