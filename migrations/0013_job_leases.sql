-- Scoring jobs are claimed with a lease, so that several replicas can share one database
-- (docs/operations.md "Several replicas"): the replica that holds a running job and until when.
-- The holder renews the lease while it replays; a running job whose lease ran out (its replica
-- died) may be claimed by another replica. Additive: a server of the previous release ignores
-- the columns.
ALTER TABLE scoring_jobs ADD COLUMN lease_owner TEXT;
ALTER TABLE scoring_jobs ADD COLUMN lease_until TEXT;
