-- LTI 1.3 (docs/integration.md "Launching from a learning management system"): the platforms an
-- admin registered, the tool's signing key, launches in progress (state and nonce, each used
-- once), the accounts and cohorts launches made, the activities deep linking made, and the
-- grades waiting for the platform's gradebook (written with the score, so none is lost while
-- the platform is unreachable). Additive: a server of the previous release ignores the tables.
CREATE TABLE lti_platforms (
    id TEXT PRIMARY KEY,
    issuer TEXT NOT NULL,
    client_id TEXT NOT NULL,
    -- One deployment id a line.
    deployment_ids TEXT NOT NULL,
    keyset_url TEXT NOT NULL,
    auth_url TEXT NOT NULL,
    token_url TEXT NOT NULL,
    -- The LTI roles (short names or URIs, one a line) that make an instructor.
    instructor_roles TEXT NOT NULL,
    created_at TEXT NOT NULL,
    UNIQUE (issuer, client_id)
);

-- The tool's RSA key (PKCS#8 PEM), published at /lti/jwks under its kid: one row, in the slot
-- 'signing' (replicas making one at once keep the first that was written).
CREATE TABLE lti_tool_keys (
    slot TEXT PRIMARY KEY,
    kid TEXT NOT NULL,
    private_pem TEXT NOT NULL,
    created_at TEXT NOT NULL
);

-- A launch between the OIDC login initiation and the id_token: its state (hashed) and nonce.
CREATE TABLE lti_launch_states (
    state_sha256 TEXT PRIMARY KEY,
    nonce TEXT NOT NULL,
    platform_id TEXT NOT NULL REFERENCES lti_platforms(id) ON DELETE CASCADE,
    client_address TEXT NOT NULL,
    created_at TEXT NOT NULL,
    expires_at TEXT NOT NULL,
    used_at TEXT
);
CREATE INDEX lti_launch_states_address ON lti_launch_states (client_address, expires_at);
CREATE INDEX lti_launch_states_expiry ON lti_launch_states (expires_at);

-- The account an LTI user (the platform's `sub`) was given.
CREATE TABLE lti_users (
    platform_id TEXT NOT NULL REFERENCES lti_platforms(id) ON DELETE CASCADE,
    subject TEXT NOT NULL,
    user_id TEXT NOT NULL REFERENCES users(id),
    PRIMARY KEY (platform_id, subject)
);

-- The cohort of a course (the platform's context).
CREATE TABLE lti_contexts (
    platform_id TEXT NOT NULL REFERENCES lti_platforms(id) ON DELETE CASCADE,
    context_id TEXT NOT NULL,
    cohort_id TEXT NOT NULL REFERENCES cohorts(id),
    PRIMARY KEY (platform_id, context_id)
);

-- An activity (resource link) a learner launched: its exercise and the line item its grades go to.
CREATE TABLE lti_links (
    platform_id TEXT NOT NULL REFERENCES lti_platforms(id) ON DELETE CASCADE,
    resource_link_id TEXT NOT NULL,
    user_id TEXT NOT NULL REFERENCES users(id),
    subject TEXT NOT NULL,
    scenario TEXT NOT NULL,
    difficulty TEXT NOT NULL,
    lineitem_url TEXT,
    launched_at TEXT NOT NULL,
    PRIMARY KEY (platform_id, resource_link_id, user_id)
);
CREATE INDEX lti_links_user ON lti_links (user_id, scenario, difficulty);

-- A deep linking request waiting for the instructor's choice (its token hashed; used once).
CREATE TABLE lti_deep_links (
    token_sha256 TEXT PRIMARY KEY,
    platform_id TEXT NOT NULL REFERENCES lti_platforms(id) ON DELETE CASCADE,
    deployment_id TEXT NOT NULL,
    return_url TEXT NOT NULL,
    data TEXT,
    user_id TEXT NOT NULL REFERENCES users(id),
    expires_at TEXT NOT NULL,
    used_at TEXT
);

-- Grades for the platforms' line items (Assignment and Grade Services), one a session and line item.
CREATE TABLE lti_grade_outbox (
    id TEXT PRIMARY KEY,
    session_id TEXT NOT NULL,
    platform_id TEXT NOT NULL REFERENCES lti_platforms(id) ON DELETE CASCADE,
    lineitem_url TEXT NOT NULL,
    -- The LTI user (`userId` of the score): a later session's grade supersedes an undelivered one.
    subject TEXT NOT NULL,
    score_json TEXT NOT NULL,
    created_at TEXT NOT NULL,
    attempts BIGINT NOT NULL DEFAULT 0,
    next_attempt_at TEXT NOT NULL,
    delivered_at TEXT,
    last_error TEXT
);
CREATE INDEX lti_grade_outbox_due ON lti_grade_outbox (delivered_at, next_attempt_at);
CREATE INDEX lti_grade_outbox_line ON lti_grade_outbox (platform_id, lineitem_url, subject);
