-- Withdrawn atlases: an admin withdrew the atlas from the catalogue (DELETE /api/atlases/{hash},
-- stylet atlas unpublish). It takes no new sessions; the sessions on it stay readable and
-- replayable. NULL: the atlas takes sessions. Withdrawing and republishing are audited.
ALTER TABLE atlases ADD COLUMN withdrawn_at TEXT;
ALTER TABLE atlases ADD COLUMN withdrawn_by TEXT REFERENCES users(id);
