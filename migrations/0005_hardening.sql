-- Issue 29 / 24: crash-safe ingest, indexing attempts, retention.
-- Scene rows also take the hidden states 'importing' (written before the files are moved
-- in) and 'deleting' (written before the files are removed); start-up finishes or undoes
-- both. Indexing attempts are counted so a scene that keeps killing the process fails.
ALTER TABLE scenes ADD COLUMN index_attempts INTEGER NOT NULL DEFAULT 0;
CREATE INDEX scenes_by_status ON scenes(status);
-- Retention: finished jobs by age.
CREATE INDEX jobs_by_finished ON jobs(finished_at) WHERE finished_at IS NOT NULL;
