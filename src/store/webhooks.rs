//! The webhook delivery queue and each job's delivery attempts. Rows are queued by a
//! trigger when a job with a `webhook_url` reaches a terminal state.

use serde::Serialize;
use sqlx::Row;

use super::{now_rfc3339, Store, StoreError};

/// A delivery that is due.
#[derive(Debug, Clone)]
pub struct DueWebhook {
    pub job_id: String,
    pub msg_id: String,
    pub attempts: i64,
    pub first_at_ms: i64,
}

/// One attempt as listed on the job.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Delivery {
    pub at: String,
    /// The receiver's HTTP status; absent when it did not answer.
    pub status: Option<u16>,
    pub error: Option<String>,
}

/// The outcome of an attempt.
#[derive(Debug, Clone)]
pub struct Attempt<'a> {
    pub status: Option<u16>,
    pub error: Option<&'a str>,
    /// When to try again (unix ms); None when delivered or given up.
    pub retry_at_ms: Option<i64>,
    pub delivered: bool,
}

/// Unix time in milliseconds.
pub fn now_ms() -> i64 {
    (time::OffsetDateTime::now_utc().unix_timestamp_nanos() / 1_000_000) as i64
}

impl Store {
    /// Pending deliveries whose time has come, oldest first.
    pub async fn due_webhooks(&self, limit: i64) -> Result<Vec<DueWebhook>, StoreError> {
        let rows = sqlx::query(&self.sql(
            "SELECT job_id, msg_id, attempts, first_at FROM webhook_queue \
             WHERE state = 'pending' AND next_at <= ? ORDER BY next_at LIMIT ?",
        ))
        .bind(now_ms())
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(DueWebhook {
                    job_id: r.try_get("job_id")?,
                    msg_id: r.try_get("msg_id")?,
                    attempts: r.try_get("attempts")?,
                    first_at_ms: r.try_get("first_at")?,
                })
            })
            .collect()
    }

    /// When the next pending delivery is due (unix ms).
    pub async fn next_webhook_due(&self) -> Result<Option<i64>, StoreError> {
        Ok(sqlx::query_scalar(
            &self.sql("SELECT MIN(next_at) FROM webhook_queue WHERE state = 'pending'"),
        )
        .fetch_one(&self.pool)
        .await?)
    }

    /// Record an attempt and schedule the next one (or close the delivery).
    pub async fn record_webhook_attempt(
        &self,
        job_id: &str,
        a: &Attempt<'_>,
    ) -> Result<(), StoreError> {
        let mut tx = self.pool.begin().await?;
        sqlx::query(
            &self
                .sql("INSERT INTO webhook_deliveries (job_id, at, status, error) VALUES (?,?,?,?)"),
        )
        .bind(job_id)
        .bind(now_rfc3339())
        .bind(a.status.map(i64::from))
        .bind(a.error)
        .execute(&mut *tx)
        .await?;
        let state = match (a.delivered, a.retry_at_ms) {
            (true, _) => "delivered",
            (false, Some(_)) => "pending",
            (false, None) => "failed",
        };
        sqlx::query(&self.sql("UPDATE webhook_queue SET attempts = attempts + 1, state = ?, next_at = COALESCE(?, next_at) WHERE job_id = ?"))
        .bind(state)
        .bind(a.retry_at_ms)
        .bind(job_id)
        .execute(&mut *tx)
        .await?;
        let r = tx.commit().await;
        self.job_written(job_id);
        Ok(r?)
    }

    /// A job's delivery state (`pending`, `delivered`, `failed`; None before the job ends)
    /// and its attempts in order.
    pub async fn webhook_deliveries(
        &self,
        job_id: &str,
    ) -> Result<(Option<String>, Vec<Delivery>), StoreError> {
        let state: Option<String> =
            sqlx::query_scalar(&self.sql("SELECT state FROM webhook_queue WHERE job_id = ?"))
                .bind(job_id)
                .fetch_optional(&self.pool)
                .await?;
        let rows =
            sqlx::query(&self.sql(
                "SELECT at, status, error FROM webhook_deliveries WHERE job_id = ? ORDER BY id",
            ))
            .bind(job_id)
            .fetch_all(&self.pool)
            .await?;
        let list = rows
            .iter()
            .map(|r| {
                Ok(Delivery {
                    at: r.try_get("at")?,
                    status: r.try_get::<Option<i64>, _>("status")?.map(|s| s as u16),
                    error: r.try_get("error")?,
                })
            })
            .collect::<Result<Vec<_>, StoreError>>()?;
        Ok((state, list))
    }
}
