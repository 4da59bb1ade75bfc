-- PostgreSQL mirror of ../0005_hardening.sql.
ALTER TABLE scenes ADD COLUMN index_attempts BIGINT NOT NULL DEFAULT 0;
CREATE INDEX scenes_by_status ON scenes(status);
CREATE INDEX jobs_by_finished ON jobs(finished_at) WHERE finished_at IS NOT NULL;
