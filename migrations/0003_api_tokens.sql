-- API tokens get an id (to list and revoke them without the secret), a scope, an expiry and a
-- revocation time. Portable SQLite/PostgreSQL: ALTER TABLE … ADD COLUMN, text times
-- (RFC 3339 UTC, as everywhere), `substr` and `||` only.
--
-- scope: 'upload' (the desktop simulator: upload sessions and read their status) or 'full' (the
-- account's rights). The column's default is the narrow scope; the store always writes one.
-- expires_at: NULL never authenticates (the store compares it with the clock). last4: the last
-- four hex digits of the token, so that its owner can tell tokens apart; the token itself is
-- never stored, only its SHA-256.
ALTER TABLE api_tokens ADD COLUMN id TEXT;
ALTER TABLE api_tokens ADD COLUMN scope TEXT NOT NULL DEFAULT 'upload' CHECK (scope IN ('upload', 'full'));
ALTER TABLE api_tokens ADD COLUMN expires_at TEXT;
ALTER TABLE api_tokens ADD COLUMN revoked_at TEXT;
ALTER TABLE api_tokens ADD COLUMN last4 TEXT;

-- Tokens issued before this migration never expired, carried all of the account's rights and
-- may have been minted by another token: they are closed, not carried over. They keep the scope
-- they had ('full', for the record) and expire at their creation time, so they are listed as
-- expired and their owners create new ones. Their id is derived from the stored hash (the first
-- 16 of its 64 hex digits; the hash of a 256-bit random token reveals nothing of it).
UPDATE api_tokens
SET id = 'legacy-' || substr(token_sha256, 1, 16), scope = 'full', expires_at = created_at;

CREATE UNIQUE INDEX api_tokens_id ON api_tokens (id);
CREATE INDEX api_tokens_user ON api_tokens (user_id, created_at);
