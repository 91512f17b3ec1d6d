-- What every replica on one database must see alike (docs/operations.md "Several replicas"):
-- the login attempts counted per account name, and the uploads each account is sending now.
-- Additive: a server of the previous release ignores the tables.

-- Failed logins per account name (lower-cased; existing or not, so that a refusal says nothing
-- about which accounts exist) in the current window, and the password checks of the account in
-- progress (on any replica): a check starts only while failures + pending stay under the limit.
-- A successful login forgets the failures; the row is deleted once its window has passed.
CREATE TABLE login_failures (
    account TEXT PRIMARY KEY,
    failures BIGINT NOT NULL,
    pending BIGINT NOT NULL,
    window_from TEXT NOT NULL
);

-- Upload slots per account: rows (account, 0), (account, 1), … up to the per-account cap, each
-- held by one request on one replica until the upload ends or the lease runs out (the replica
-- died).
CREATE TABLE upload_slots (
    account TEXT NOT NULL,
    slot BIGINT NOT NULL,
    holder TEXT NOT NULL,
    replica TEXT NOT NULL,
    lease_until TEXT NOT NULL,
    PRIMARY KEY (account, slot)
);

-- Expired logins are deleted by the housekeeping every replica runs.
CREATE INDEX auth_sessions_expiry ON auth_sessions (expires_at);

-- The id of the request that queued a scoring job (the upload's X-Request-Id), so that the
-- job's log lines carry it too.
ALTER TABLE scoring_jobs ADD COLUMN request_id TEXT;
