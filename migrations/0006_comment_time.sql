-- A comment may point at a moment of the session: seconds from the session start (NULL: about
-- the session as a whole). The review page lists it with its time and marks it on the charts.
ALTER TABLE comments ADD COLUMN at_s DOUBLE PRECISION;
