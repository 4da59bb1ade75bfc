//! The job queue: claiming, finishing, requeueing and recovering running jobs.
//!
//! On PostgreSQL several replicas share the queue: a claim skips rows another replica is
//! claiming (`FOR UPDATE SKIP LOCKED`), and a running job holds a lease (owner, expiry on
//! the database's clock) that its worker renews. A job whose lease ran out is queued again
//! by whichever replica sweeps first, as an attempt; after `max_attempts` it fails
//! `too_many_attempts`, like a job a single process kept dying on. On SQLite one process
//! owns the database and recovers its running jobs at start-up instead.

use serde_json::Value;

use super::jobs::{job_from_row, JOB_COLS};
use super::{now_rfc3339, Backend, JobRecord, JobStatus, Store, StoreError};

/// The database clock in unix milliseconds (PostgreSQL).
const PG_NOW_MS: &str = "(extract(epoch FROM clock_timestamp()) * 1000)::BIGINT";

/// The error a job gets when it used up its attempts.
const TOO_MANY_ATTEMPTS: &str = "json_object('code','too_many_attempts','detail', \
    'the job was interrupted ' || attempts || ' times while running and was given up')";

impl Store {
    /// Atomically take the oldest queued job whose scene is ready; marks it running,
    /// counts the attempt and clears any trace of an earlier attempt. On PostgreSQL the
    /// job's lease is taken by this replica.
    pub async fn claim_next_job(&self) -> Result<Option<JobRecord>, StoreError> {
        let r = self.claim_next_job_tx().await;
        self.job_cache.invalidate();
        if let Ok(Some(j)) = &r {
            self.events.changed(&j.id);
        }
        r
    }

    async fn claim_next_job_tx(&self) -> Result<Option<JobRecord>, StoreError> {
        let sql = match self.backend {
            Backend::Sqlite => format!(
                "UPDATE jobs SET status = 'running', attempts = attempts + 1, started_at = ?1 \
                 WHERE seq = (SELECT j.seq FROM jobs j JOIN scenes s ON s.id = j.scene_id \
                              WHERE j.status = 'queued' AND s.status = 'ready' ORDER BY j.seq LIMIT 1) \
                 RETURNING {JOB_COLS}"
            ),
            Backend::Postgres => format!(
                "UPDATE jobs SET status = 'running', attempts = attempts + 1, started_at = ?1, \
                 lease_owner = ?2, lease_until = {PG_NOW_MS} + ?3 \
                 WHERE status = 'queued' AND seq = (SELECT j.seq FROM jobs j JOIN scenes s ON s.id = j.scene_id \
                              WHERE j.status = 'queued' AND s.status = 'ready' ORDER BY j.seq LIMIT 1 \
                              FOR UPDATE OF j SKIP LOCKED) \
                 RETURNING {JOB_COLS}"
            ),
        };
        let mut tx = self.pool.begin().await?;
        let sql = self.sql(sql);
        let mut q = sqlx::query(&sql).bind(now_rfc3339());
        if self.pg() {
            q = q.bind(self.replica.as_str()).bind(self.lease_ms());
        }
        let Some(row) = q.fetch_optional(&mut *tx).await? else {
            tx.commit().await?;
            return Ok(None);
        };
        let mut job = job_from_row(&row)?;
        // Read in the claim's transaction: an append that a caller starts once it sees the
        // job running commits after this, so it is never counted.
        job.scene_frames =
            sqlx::query_scalar(&self.sql("SELECT frame_count FROM scenes WHERE id = ?"))
                .bind(&job.scene_id)
                .fetch_optional(&mut *tx)
                .await?;
        sqlx::query(&self.sql("DELETE FROM job_trace WHERE job_id = ?"))
            .bind(&job.id)
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(Some(job))
    }

    /// Finish a running job; only a job still `running` is changed (a cancel wins), and on
    /// PostgreSQL only while this replica holds its lease (a job given to another replica
    /// is that replica's to finish).
    pub async fn finish_job(
        &self,
        id: &str,
        status: JobStatus,
        result: Option<&Value>,
        error: Option<&Value>,
    ) -> Result<bool, StoreError> {
        let owned = if self.pg() {
            " AND lease_owner = ?"
        } else {
            ""
        };
        let sql = self.sql(format!(
            "UPDATE jobs SET status = ?, result = ?, error = ?, finished_at = ? WHERE id = ? AND status = 'running'{owned}"
        ));
        let mut q = sqlx::query(&sql)
            .bind(status.as_str())
            .bind(result.map(|v| v.to_string()))
            .bind(error.map(|v| v.to_string()))
            .bind(now_rfc3339())
            .bind(id);
        if self.pg() {
            q = q.bind(self.replica.as_str());
        }
        let r = q.execute(&self.pool).await;
        self.job_written(id);
        Ok(r?.rows_affected() == 1)
    }

    /// Put a running job back in the queue (process shutting down); the attempt is not counted.
    pub async fn requeue_job(&self, id: &str) -> Result<(), StoreError> {
        let lease = if self.pg() {
            ", lease_owner = NULL, lease_until = NULL"
        } else {
            ""
        };
        let r = sqlx::query(&self.sql(format!(
            "UPDATE jobs SET status = 'queued', attempts = {}(attempts - 1, 0), started_at = NULL{lease} \
             WHERE id = ? AND status = 'running'",
            self.greatest()
        )))
        .bind(id)
        .execute(&self.pool)
        .await;
        self.job_written(id);
        r?;
        Ok(())
    }

    /// Extend this replica's lease on a running job. False when the job is no longer
    /// this replica's to run (canceled, finished, or requeued after its lease ran out):
    /// its worker should stop. Always true on SQLite (no leases; cancels are local).
    pub async fn renew_lease(&self, id: &str) -> Result<bool, StoreError> {
        if !self.pg() {
            return Ok(true);
        }
        let r = sqlx::query(&self.sql(format!(
            "UPDATE jobs SET lease_until = {PG_NOW_MS} + ? \
             WHERE id = ? AND status = 'running' AND lease_owner = ?"
        )))
        .bind(self.lease_ms())
        .bind(id)
        .bind(self.replica.as_str())
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// PostgreSQL: running jobs whose lease ran out go back to the queue, or fail when
    /// they have used `max_attempts`. Any replica may run this at any time. Returns
    /// (requeued, failed); (0, 0) on SQLite.
    pub async fn expire_leases(&self, max_attempts: i64) -> Result<(u64, u64), StoreError> {
        if !self.pg() {
            return Ok((0, 0));
        }
        let failed = sqlx::query(&self.sql(format!(
            "UPDATE jobs SET status = 'failed', finished_at = ?, lease_owner = NULL, lease_until = NULL, \
             error = {TOO_MANY_ATTEMPTS} \
             WHERE status = 'running' AND lease_until < {PG_NOW_MS} AND attempts >= ?"
        )))
        .bind(now_rfc3339())
        .bind(max_attempts)
        .execute(&self.pool)
        .await?
        .rows_affected();
        let requeued = sqlx::query(&self.sql(format!(
            "UPDATE jobs SET status = 'queued', started_at = NULL, lease_owner = NULL, lease_until = NULL \
             WHERE status = 'running' AND lease_until < {PG_NOW_MS}"
        )))
        .execute(&self.pool)
        .await?
        .rows_affected();
        if requeued + failed > 0 {
            self.job_cache.invalidate();
            self.events.changed_all();
        }
        Ok((requeued, failed))
    }

    /// At start-up: jobs left `running` by a dead process go back to the queue, or fail
    /// when they have used `max_attempts`. Returns (requeued, failed). On PostgreSQL other
    /// replicas may be running jobs, so only jobs whose lease ran out are recovered.
    pub async fn recover_jobs(&self, max_attempts: i64) -> Result<(u64, u64), StoreError> {
        if self.pg() {
            return self.expire_leases(max_attempts).await;
        }
        let r = self.recover_jobs_sql(max_attempts).await;
        self.job_cache.invalidate();
        self.events.changed_all();
        r
    }

    async fn recover_jobs_sql(&self, max_attempts: i64) -> Result<(u64, u64), StoreError> {
        let failed = sqlx::query(&self.sql(format!(
            "UPDATE jobs SET status = 'failed', finished_at = ?, error = {TOO_MANY_ATTEMPTS} \
             WHERE status = 'running' AND attempts >= ?"
        )))
        .bind(now_rfc3339())
        .bind(max_attempts)
        .execute(&self.pool)
        .await?
        .rows_affected();
        let requeued =
            sqlx::query(&self.sql(
                "UPDATE jobs SET status = 'queued', started_at = NULL WHERE status = 'running'",
            ))
            .execute(&self.pool)
            .await?
            .rows_affected();
        Ok((requeued, failed))
    }
}
