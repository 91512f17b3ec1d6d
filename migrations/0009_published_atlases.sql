-- Published atlases: who published an atlas through the API and when. NULL for the
-- atlases of the service's configured directory. Publishing is also audited ('atlas.publish').
ALTER TABLE atlases ADD COLUMN published_by TEXT REFERENCES users(id);
ALTER TABLE atlases ADD COLUMN published_at TEXT;
