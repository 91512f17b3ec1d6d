-- Stylet scoring service schema (portable: SQLite and PostgreSQL). Ids are UUID text; times are
-- RFC 3339 UTC text; JSON documents are text.

CREATE TABLE users (
    id TEXT PRIMARY KEY,
    username TEXT NOT NULL UNIQUE,
    role TEXT NOT NULL CHECK (role IN ('trainee', 'instructor', 'curriculum', 'admin')),
    password_hash TEXT NOT NULL,
    created_at TEXT NOT NULL
);

CREATE TABLE cohorts (
    id TEXT PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    created_at TEXT NOT NULL
);

-- Trainees belong to cohorts; instructors teach them.
CREATE TABLE cohort_members (
    cohort_id TEXT NOT NULL REFERENCES cohorts(id),
    user_id TEXT NOT NULL REFERENCES users(id),
    PRIMARY KEY (cohort_id, user_id)
);

CREATE TABLE atlases (
    content_hash TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    dir TEXT NOT NULL,
    registered_at TEXT NOT NULL
);

-- One row per distinct session file (stored by content hash under the data directory).
CREATE TABLE sessions (
    id TEXT PRIMARY KEY,
    file_sha256 TEXT NOT NULL UNIQUE,
    size_bytes BIGINT NOT NULL,
    session_uuid TEXT NOT NULL,
    trainee_id TEXT NOT NULL REFERENCES users(id),
    uploaded_by TEXT NOT NULL REFERENCES users(id),
    scenario TEXT NOT NULL,
    difficulty TEXT NOT NULL,
    atlas_hash TEXT NOT NULL REFERENCES atlases(content_hash),
    physics_version BIGINT NOT NULL,
    duration_s DOUBLE PRECISION NOT NULL,
    recorded_at TEXT NOT NULL,
    uploaded_at TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('queued', 'scoring', 'scored', 'failed')),
    error TEXT
);
CREATE INDEX sessions_trainee ON sessions (trainee_id, uploaded_at);

-- Scoring work, persisted so that a restart loses none.
CREATE TABLE scoring_jobs (
    id TEXT PRIMARY KEY,
    session_id TEXT NOT NULL UNIQUE REFERENCES sessions(id),
    state TEXT NOT NULL CHECK (state IN ('queued', 'running', 'done', 'failed')),
    attempts BIGINT NOT NULL,
    created_at TEXT NOT NULL,
    started_at TEXT,
    finished_at TEXT
);
CREATE INDEX scoring_jobs_state ON scoring_jobs (state, created_at);

-- At most one score per session (UNIQUE): a session is never scored twice.
CREATE TABLE scores (
    session_id TEXT PRIMARY KEY REFERENCES sessions(id),
    score DOUBLE PRECISION NOT NULL,
    passed BOOLEAN NOT NULL,
    difficulty TEXT NOT NULL,
    rubric TEXT NOT NULL,
    rubric_version BIGINT NOT NULL,
    physics_version BIGINT NOT NULL,
    replay_verified BOOLEAN NOT NULL,
    incomplete BOOLEAN NOT NULL,
    report_json TEXT NOT NULL,
    scored_at TEXT NOT NULL
);

CREATE TABLE comments (
    id TEXT PRIMARY KEY,
    session_id TEXT NOT NULL REFERENCES sessions(id),
    author_id TEXT NOT NULL REFERENCES users(id),
    body TEXT NOT NULL,
    created_at TEXT NOT NULL
);

CREATE TABLE grade_overrides (
    id TEXT PRIMARY KEY,
    session_id TEXT NOT NULL REFERENCES sessions(id),
    author_id TEXT NOT NULL REFERENCES users(id),
    score DOUBLE PRECISION NOT NULL,
    passed BOOLEAN NOT NULL,
    reason TEXT NOT NULL,
    created_at TEXT NOT NULL
);

CREATE TABLE audit_log (
    id TEXT PRIMARY KEY,
    at TEXT NOT NULL,
    actor_id TEXT,
    action TEXT NOT NULL,
    target TEXT,
    detail TEXT
);

-- Login sessions (cookie) and API tokens (desktop uploads); only hashes are stored.
CREATE TABLE auth_sessions (
    token_sha256 TEXT PRIMARY KEY,
    user_id TEXT NOT NULL REFERENCES users(id),
    csrf_token TEXT NOT NULL,
    created_at TEXT NOT NULL,
    expires_at TEXT NOT NULL
);

CREATE TABLE api_tokens (
    token_sha256 TEXT PRIMARY KEY,
    user_id TEXT NOT NULL REFERENCES users(id),
    label TEXT NOT NULL,
    created_at TEXT NOT NULL
);
