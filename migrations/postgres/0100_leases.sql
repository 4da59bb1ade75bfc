-- PostgreSQL only (issue 22): leases on running jobs and change notifications, for several
-- replicas on one database. SQLite keeps one process per database and recovers its running
-- jobs at start-up instead. Numbered 0100 so the mirrors of SQLite's migrations keep
-- their own numbers.

-- Who runs a job (a replica's id) and until when (unix ms, database clock). A running job
-- whose lease ran out is queued again by any replica, as an attempt.
ALTER TABLE jobs ADD COLUMN lease_owner TEXT;
ALTER TABLE jobs ADD COLUMN lease_until BIGINT;
CREATE INDEX jobs_running_leases ON jobs(lease_until) WHERE status = 'running';

-- Every replica LISTENs on grounder_jobs: a job's status change or new trace step wakes
-- its waiters (long polls, event streams, the worker running it) wherever they are.
-- Lease renewals change neither, so they notify nobody.
CREATE FUNCTION grounder_notify_job() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    IF TG_TABLE_NAME = 'job_trace' THEN
        PERFORM pg_notify('grounder_jobs', NEW.job_id);
    ELSE
        PERFORM pg_notify('grounder_jobs', NEW.id);
    END IF;
    RETURN NULL;
END;
$$;
CREATE TRIGGER jobs_notify AFTER INSERT OR UPDATE OF status, result, error ON jobs
    FOR EACH ROW EXECUTE FUNCTION grounder_notify_job();
CREATE TRIGGER job_trace_notify AFTER INSERT ON job_trace
    FOR EACH ROW EXECUTE FUNCTION grounder_notify_job();
