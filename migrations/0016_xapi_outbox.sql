-- Learning records for a Learning Record Store (docs/integration.md "Learning records (xAPI)"):
-- the statements of each scored session, written in the transaction that stores its score and
-- delivered from here, so that none is lost while the LRS is down and none is sent twice under
-- two ids (each id is derived from the session and the verb). Additive: a server of the
-- previous release ignores the table. Filled only while an LRS is configured (`--lrs-url`).
CREATE TABLE xapi_outbox (
    statement_id TEXT PRIMARY KEY,
    session_id TEXT NOT NULL,
    verb TEXT NOT NULL,
    statement_json TEXT NOT NULL,
    created_at TEXT NOT NULL,
    attempts BIGINT NOT NULL DEFAULT 0,
    next_attempt_at TEXT NOT NULL,
    delivered_at TEXT,
    last_error TEXT
);
CREATE INDEX xapi_outbox_due ON xapi_outbox (delivered_at, next_attempt_at);
