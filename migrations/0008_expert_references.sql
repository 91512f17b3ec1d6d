-- Expert references: sessions an instructor marked as showing how experts do their
-- scenario. A scenario's expert benchmark (docs/metrics.md "Expert benchmark") is computed from
-- the scores of its references on the same atlas. Unmarking deletes the row; marking and
-- unmarking are both audited ('expert.mark', 'expert.unmark').
CREATE TABLE expert_references (
    session_id TEXT PRIMARY KEY REFERENCES sessions(id),
    atlas_hash TEXT NOT NULL,
    scenario TEXT NOT NULL,
    marked_by TEXT NOT NULL REFERENCES users(id),
    marked_at TEXT NOT NULL
);
CREATE INDEX expert_references_scenario ON expert_references (atlas_hash, scenario);
