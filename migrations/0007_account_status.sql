-- Accounts can be disabled: a disabled account's logins and API tokens are refused on
-- every request from that moment; its rows (sessions, comments, tokens) stay. NULL: active.
ALTER TABLE users ADD COLUMN disabled_at TEXT;
