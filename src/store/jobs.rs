//! Job rows and their traces: the persistent queue.

use serde::Serialize;
use serde_json::value::RawValue;
use serde_json::Value;
use sqlx::Row;

use super::{now_rfc3339, Store, StoreError};

/// Lifecycle of a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum JobStatus {
    Queued,
    Running,
    Succeeded,
    Failed,
    Canceled,
}

impl JobStatus {
    pub const ALL: [JobStatus; 5] = [
        JobStatus::Queued,
        JobStatus::Running,
        JobStatus::Succeeded,
        JobStatus::Failed,
        JobStatus::Canceled,
    ];

    pub fn as_str(&self) -> &'static str {
        match self {
            JobStatus::Queued => "queued",
            JobStatus::Running => "running",
            JobStatus::Succeeded => "succeeded",
            JobStatus::Failed => "failed",
            JobStatus::Canceled => "canceled",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|x| x.as_str() == s)
    }

    pub fn is_terminal(&self) -> bool {
        matches!(
            self,
            JobStatus::Succeeded | JobStatus::Failed | JobStatus::Canceled
        )
    }
}

/// A job row.
#[derive(Debug, Clone)]
pub struct JobRecord {
    pub seq: i64,
    pub id: String,
    pub scene_id: String,
    pub query: String,
    pub status: JobStatus,
    pub attempts: i64,
    pub created_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
    pub error: Option<Value>,
    pub result: Option<Value>,
    /// The API key that created the job (None: created without keys).
    pub owner: Option<i64>,
    pub webhook_url: Option<String>,
    /// How many frames the scene had when this job was claimed (set by
    /// `claim_next_job` only): frames appended later do not reach the running job.
    pub scene_frames: Option<i64>,
}

/// Jobs to create at once (one per query, same scene).
#[derive(Debug, Clone)]
pub struct NewJobs<'a> {
    /// (id, query) per job, in the order the caller wants them back.
    pub jobs: Vec<(String, String)>,
    pub scene_id: &'a str,
    pub owner: Option<i64>,
    pub webhook_url: Option<&'a str>,
    /// Refuse (return None) when the owner would have more queued + running jobs.
    pub max_active: Option<i64>,
}

/// Filters for listing jobs.
#[derive(Debug, Clone, Default)]
pub struct ListJobs {
    /// Only this owner's jobs (None: everyone's).
    pub owner: Option<i64>,
    pub scene_id: Option<String>,
    pub status: Option<JobStatus>,
    pub limit: i64,
    /// Only jobs with seq below this (newest first pagination).
    pub before_seq: Option<i64>,
}

fn parse_json(s: Option<String>) -> Option<Value> {
    s.and_then(|t| serde_json::from_str(&t).ok())
}

pub(super) fn job_from_row(r: &sqlx::any::AnyRow) -> Result<JobRecord, StoreError> {
    let status: String = r.try_get("status")?;
    Ok(JobRecord {
        seq: r.try_get("seq")?,
        id: r.try_get("id")?,
        scene_id: r.try_get("scene_id")?,
        query: r.try_get("query")?,
        status: JobStatus::parse(&status)
            .ok_or_else(|| StoreError::Corrupt(format!("job status {status:?}")))?,
        attempts: r.try_get("attempts")?,
        created_at: r.try_get("created_at")?,
        started_at: r.try_get("started_at")?,
        finished_at: r.try_get("finished_at")?,
        error: parse_json(r.try_get("error")?),
        result: parse_json(r.try_get("result")?),
        owner: r.try_get("owner")?,
        webhook_url: r.try_get("webhook_url")?,
        scene_frames: None,
    })
}

pub(super) const JOB_COLS: &str = "seq, id, scene_id, query, status, attempts, created_at, started_at, finished_at, error, result, owner, webhook_url";

impl Store {
    pub async fn create_job(
        &self,
        id: &str,
        scene_id: &str,
        query: &str,
    ) -> Result<JobRecord, StoreError> {
        // RETURNING gives the row as inserted: a worker may claim the job before a second
        // read, and the caller must still see it queued.
        let r = sqlx::query(&self.sql(format!("INSERT INTO jobs (id, scene_id, query, status, created_at) VALUES (?,?,?,'queued',?) RETURNING {JOB_COLS}")))
            .bind(id)
            .bind(scene_id)
            .bind(query)
            .bind(now_rfc3339())
            .fetch_one(&self.pool)
            .await;
        self.job_written(id);
        job_from_row(&r?)
    }

    /// Create several queued jobs in one statement, unless that would take the owner over
    /// `max_active` queued + running jobs (then `Ok(None)` and nothing is created).
    pub async fn create_jobs(&self, n: &NewJobs<'_>) -> Result<Option<Vec<JobRecord>>, StoreError> {
        if n.jobs.is_empty() {
            return Ok(Some(Vec::new()));
        }
        let values = vec!["(?,?)"; n.jobs.len()].join(",");
        let sql = format!(
            "INSERT INTO jobs (id, scene_id, query, status, created_at, owner, webhook_url) \
             SELECT column1, ?, column2, 'queued', ?, ?, ? FROM (VALUES {values}) AS v \
             WHERE ? IS NULL OR (SELECT COUNT(*) FROM jobs WHERE owner IS NOT DISTINCT FROM ? AND status IN ('queued','running')) + ? <= ? \
             ORDER BY 1 RETURNING {JOB_COLS}"
        );
        let sql = self.sql(sql);
        let mut q = sqlx::query(&sql)
            .bind(n.scene_id)
            .bind(now_rfc3339())
            .bind(n.owner)
            .bind(n.webhook_url);
        for (id, query) in &n.jobs {
            q = q.bind(id).bind(query);
        }
        let r = q
            .bind(n.max_active)
            .bind(n.owner)
            .bind(n.jobs.len() as i64)
            .bind(n.max_active)
            .fetch_all(&self.pool)
            .await;
        self.job_cache.invalidate();
        let rows = r?;
        if rows.is_empty() {
            return Ok(None);
        }
        let mut recs = rows
            .iter()
            .map(job_from_row)
            .collect::<Result<Vec<_>, _>>()?;
        let order = |id: &str| n.jobs.iter().position(|(j, _)| j == id);
        recs.sort_by_key(|r| order(&r.id));
        for r in &recs {
            self.events.changed(&r.id);
        }
        Ok(Some(recs))
    }

    pub async fn get_job(&self, id: &str) -> Result<Option<JobRecord>, StoreError> {
        let row = sqlx::query(&self.sql(format!("SELECT {JOB_COLS} FROM jobs WHERE id = ?")))
            .bind(id)
            .fetch_optional(&self.pool)
            .await?;
        row.as_ref().map(job_from_row).transpose()
    }

    /// Newest first; `before_seq` continues a previous page.
    pub async fn list_jobs(&self, q: &ListJobs) -> Result<Vec<JobRecord>, StoreError> {
        let rows = sqlx::query(&self.sql(format!(
            "SELECT {JOB_COLS} FROM jobs WHERE (?1 IS NULL OR scene_id = ?1) AND (?2 IS NULL OR status = ?2) \
             AND (?3 IS NULL OR seq < ?3) AND (?5 IS NULL OR owner = ?5) ORDER BY seq DESC LIMIT ?4"
        )))
        .bind(&q.scene_id)
        .bind(q.status.map(|s| s.as_str()))
        .bind(q.before_seq)
        .bind(q.limit)
        .bind(q.owner)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(job_from_row).collect()
    }

    /// Fail every queued job on a scene that failed indexing, with kind `scene_failed` and
    /// the scene's reason. Returns how many were failed.
    pub async fn fail_queued_jobs_of_failed_scenes(&self) -> Result<u64, StoreError> {
        let r = sqlx::query(&self.sql("UPDATE jobs SET status = 'failed', finished_at = ?1, \
             error = json_object('code', 'scene_failed', 'detail', \
                 'the scene failed to index: ' || COALESCE((SELECT s.error FROM scenes s WHERE s.id = jobs.scene_id), 'no reason recorded')) \
             WHERE status = 'queued' AND scene_id IN (SELECT id FROM scenes WHERE status = 'failed')"))
        .bind(now_rfc3339())
        .execute(&self.pool)
        .await;
        self.job_cache.invalidate();
        Ok(r?.rows_affected())
    }

    /// Cancel a job in any non-terminal state. Returns the job after the change, or None
    /// when it does not exist.
    pub async fn cancel_job(&self, id: &str) -> Result<Option<JobRecord>, StoreError> {
        let r = sqlx::query(&self.sql("UPDATE jobs SET status = 'canceled', cancel_requested = 1, finished_at = ?, \
             error = '{\"code\":\"canceled\",\"detail\":\"canceled by request\"}' WHERE id = ? AND status IN ('queued','running')"))
        .bind(now_rfc3339())
        .bind(id)
        .execute(&self.pool)
        .await;
        self.job_written(id);
        r?;
        self.get_job(id).await
    }

    /// A job is queued on a ready scene (a worker will take it as soon as one is free).
    pub async fn has_runnable_jobs(&self) -> Result<bool, StoreError> {
        let row: Option<i64> = sqlx::query_scalar(&self.sql("SELECT 1 FROM jobs j JOIN scenes s ON s.id = j.scene_id WHERE j.status = 'queued' AND s.status = 'ready' LIMIT 1"))
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.is_some())
    }

    pub async fn count_jobs_by_status(&self) -> Result<Vec<(String, i64)>, StoreError> {
        let rows = sqlx::query(&self.sql("SELECT status, COUNT(*) AS n FROM jobs GROUP BY status"))
            .fetch_all(&self.pool)
            .await?;
        rows.iter()
            .map(|r| Ok((r.try_get("status")?, r.try_get("n")?)))
            .collect()
    }

    /// Append one step to a job's trace.
    pub async fn append_trace(
        &self,
        job_id: &str,
        step: &str,
        data: &Value,
    ) -> Result<(), StoreError> {
        let r = sqlx::query(&self.sql("INSERT INTO job_trace (job_id, seq, step, data) VALUES (?1, (SELECT COALESCE(MAX(seq), -1) + 1 FROM job_trace WHERE job_id = ?1), ?2, ?3)"))
            .bind(job_id)
            .bind(step)
            .bind(data.to_string())
            .execute(&self.pool)
            .await;
        self.job_written(job_id);
        r?;
        Ok(())
    }

    /// A job's trace as one JSON array text: each stored step object with its `step` name
    /// added (a step whose data is not an object becomes `{step, data}`). Built by the
    /// database, so a poll costs one statement and the trace is never parsed on the way out.
    fn trace_json(&self) -> &'static str {
        match self.backend {
            super::Backend::Sqlite => "(SELECT json_group_array(json(CASE \
                WHEN json_valid(t.data) AND json_type(t.data) = 'object' THEN json_set(t.data, '$.step', t.step) \
                WHEN json_valid(t.data) THEN json_object('step', t.step, 'data', json(t.data)) \
                ELSE json_object('step', t.step, 'data', NULL) END) ORDER BY t.seq) \
                FROM job_trace t WHERE t.job_id = jobs.id)",
            // grounder_step: migrations/postgres/0001_init.sql (the same rule).
            super::Backend::Postgres => "(SELECT COALESCE(jsonb_agg(grounder_step(t.step, t.data) ORDER BY t.seq), '[]'::jsonb)::text \
                FROM job_trace t WHERE t.job_id = jobs.id)",
        }
    }

    /// A job and its trace (see [`Self::get_trace`]) in one statement: what a poll needs.
    pub async fn get_job_with_trace(
        &self,
        id: &str,
    ) -> Result<Option<(JobRecord, Box<RawValue>)>, StoreError> {
        if let Some(hit) = self.job_cache.get(id) {
            return Ok(Some(hit));
        }
        let epoch = self.job_cache.epoch();
        let row = sqlx::query(&self.sql(format!(
            "SELECT {JOB_COLS}, {} AS trace FROM jobs WHERE id = ?",
            self.trace_json()
        )))
        .bind(id)
        .fetch_optional(&self.pool)
        .await?;
        let Some(row) = row else { return Ok(None) };
        let job = job_from_row(&row)?;
        let text: Option<String> = row.try_get("trace")?;
        let trace = RawValue::from_string(text.unwrap_or_else(|| "[]".into()))
            .map_err(|e| StoreError::Corrupt(format!("trace of job {id}: {e}")))?;
        self.job_cache.put(epoch, &job, &trace);
        Ok(Some((job, trace)))
    }

    /// A job's trace, parsed (same shape as in [`Self::get_job_with_trace`]).
    pub async fn get_trace(&self, job_id: &str) -> Result<Vec<Value>, StoreError> {
        let row = sqlx::query(&self.sql(format!(
            "SELECT {} AS trace FROM jobs WHERE id = ?",
            self.trace_json()
        )))
        .bind(job_id)
        .fetch_optional(&self.pool)
        .await?;
        let text: Option<String> = match row {
            Some(r) => r.try_get("trace")?,
            None => None,
        };
        match text {
            None => Ok(Vec::new()),
            Some(t) => serde_json::from_str(&t)
                .map_err(|e| StoreError::Corrupt(format!("trace of job {job_id}: {e}"))),
        }
    }
}
