-- Pairing a desktop simulator with a short code instead of a typed password or token
-- (docs/integration.md "Pairing a simulator"). Additive: a server of the previous release ignores
-- the tables.

-- Short codes, stored only as the SHA-256 of their normalised text. Each is made by a logged-in
-- account for one purpose, lasts minutes and is used once:
--   'simulator': the simulator that presents it gets an upload-scoped API token of its maker;
--   'lab':       the machine that presents it becomes a lab machine of `cohort_id` (made by an
--                instructor of the cohort or an admin);
--   'sign_in':   a lab machine of one of its maker's cohorts signs the maker (a trainee) in.
CREATE TABLE pairing_codes (
    code_sha256 TEXT PRIMARY KEY,
    purpose TEXT NOT NULL CHECK (purpose IN ('simulator', 'lab', 'sign_in')),
    user_id TEXT NOT NULL REFERENCES users(id),
    cohort_id TEXT REFERENCES cohorts(id),
    created_at TEXT NOT NULL,
    expires_at TEXT NOT NULL,
    used_at TEXT
);
CREATE INDEX pairing_codes_user ON pairing_codes (user_id, expires_at);
CREATE INDEX pairing_codes_expiry ON pairing_codes (expires_at);

-- Lab machines: a simulator in a skills lab, paired to a cohort, on which the cohort's trainees
-- sign in one after another with their own codes. Its token (a 256-bit random value, stored as
-- SHA-256) may only exchange sign-in codes for short upload tokens of the cohort's trainees.
CREATE TABLE lab_machines (
    id TEXT PRIMARY KEY,
    token_sha256 TEXT NOT NULL UNIQUE,
    cohort_id TEXT NOT NULL REFERENCES cohorts(id),
    label TEXT NOT NULL,
    paired_by TEXT NOT NULL REFERENCES users(id),
    created_at TEXT NOT NULL,
    expires_at TEXT NOT NULL,
    revoked_at TEXT
);
CREATE INDEX lab_machines_cohort ON lab_machines (cohort_id, created_at);
