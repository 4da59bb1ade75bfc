-- Issue 22: several replicas on one database. Each replica writes a heartbeat; what a
-- replica holds (an idempotency key in flight, a scene row importing or deleting) names it,
-- so that others release or finish it only once it is dead. Indexing a scene is claimed
-- like a job: the indexer holds a lease (unix ms, database clock) that it renews.
CREATE TABLE replicas (
    id           TEXT PRIMARY KEY,
    heartbeat_ms INTEGER NOT NULL,
    started_at   TEXT NOT NULL
);
ALTER TABLE idempotency ADD COLUMN holder TEXT;
ALTER TABLE scenes ADD COLUMN holder TEXT;
ALTER TABLE scenes ADD COLUMN index_owner TEXT;
ALTER TABLE scenes ADD COLUMN index_until INTEGER;
