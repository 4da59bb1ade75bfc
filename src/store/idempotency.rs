//! Stored responses of requests sent with an `Idempotency-Key` (kept 24 h).

use sqlx::Row;

use super::{Store, StoreError};

/// How long a key is remembered.
pub const KEEP_SECS: i64 = 24 * 3600;

/// A response as stored for replay.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoredResponse {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

/// What to do with a request carrying an idempotency key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Begin {
    /// First use: the caller now holds the key and must `finish` or `abandon` it.
    Proceed,
    /// Same key, same body, finished: answer this.
    Replay(StoredResponse),
    /// Same key, another body.
    Mismatch,
    /// Same key, same body, the first request has not finished.
    InFlight,
}

fn now_secs() -> i64 {
    time::OffsetDateTime::now_utc().unix_timestamp()
}

impl Store {
    /// Claim `(owner, route, key)` for a request whose body hashes to `body_sha256`.
    pub async fn idempotency_begin(
        &self,
        owner: i64,
        route: &str,
        key: &str,
        body_sha256: &str,
    ) -> Result<Begin, StoreError> {
        let now = now_secs();
        sqlx::query(&self.sql("DELETE FROM idempotency WHERE created_at < ?"))
            .bind(now - KEEP_SECS)
            .execute(&self.pool)
            .await?;
        let inserted = sqlx::query(&self.sql("INSERT INTO idempotency (owner, route, key, body_sha256, created_at, holder) VALUES (?,?,?,?,?,?) \
             ON CONFLICT DO NOTHING"))
        .bind(owner)
        .bind(route)
        .bind(key)
        .bind(body_sha256)
        .bind(now)
        .bind(self.replica.as_str())
        .execute(&self.pool)
        .await?
        .rows_affected();
        if inserted == 1 {
            return Ok(Begin::Proceed);
        }
        let Some(row) = sqlx::query(&self.sql("SELECT body_sha256, status, headers, body FROM idempotency WHERE owner = ? AND route = ? AND key = ?"))
        .bind(owner)
        .bind(route)
        .bind(key)
        .fetch_optional(&self.pool)
        .await?
        else {
            // Abandoned between our insert and read: try once more.
            return Box::pin(self.idempotency_begin(owner, route, key, body_sha256)).await;
        };
        let hash: String = row.try_get("body_sha256")?;
        if hash != body_sha256 {
            return Ok(Begin::Mismatch);
        }
        let Some(status) = row.try_get::<Option<i64>, _>("status")? else {
            return Ok(Begin::InFlight);
        };
        let headers: Option<String> = row.try_get("headers")?;
        let headers: Vec<(String, String)> = match headers {
            Some(h) => serde_json::from_str(&h)
                .map_err(|e| StoreError::Corrupt(format!("stored headers: {e}")))?,
            None => Vec::new(),
        };
        Ok(Begin::Replay(StoredResponse {
            status: status as u16,
            headers,
            body: row
                .try_get::<Option<Vec<u8>>, _>("body")?
                .unwrap_or_default(),
        }))
    }

    /// Store the response of a request that `Proceed`ed.
    pub async fn idempotency_finish(
        &self,
        owner: i64,
        route: &str,
        key: &str,
        resp: &StoredResponse,
    ) -> Result<(), StoreError> {
        let headers = serde_json::to_string(&resp.headers)
            .map_err(|e| StoreError::Corrupt(format!("headers: {e}")))?;
        sqlx::query(&self.sql("UPDATE idempotency SET status = ?, headers = ?, body = ? WHERE owner = ? AND route = ? AND key = ?"))
        .bind(resp.status as i64)
        .bind(headers)
        .bind(&resp.body)
        .bind(owner)
        .bind(route)
        .bind(key)
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Release a key whose request ended in a way worth retrying (server error, quota).
    pub async fn idempotency_abandon(
        &self,
        owner: i64,
        route: &str,
        key: &str,
    ) -> Result<(), StoreError> {
        sqlx::query(&self.sql(
            "DELETE FROM idempotency WHERE owner = ? AND route = ? AND key = ? AND status IS NULL",
        ))
        .bind(owner)
        .bind(route)
        .bind(key)
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// At start-up of the only process (SQLite): no request of a previous process is still
    /// in flight. Replicas on PostgreSQL release only dead replicas' keys
    /// ([`Store::idempotency_release_dead`]).
    pub async fn idempotency_release_in_flight(&self) -> Result<u64, StoreError> {
        Ok(
            sqlx::query(&self.sql("DELETE FROM idempotency WHERE status IS NULL"))
                .execute(&self.pool)
                .await?
                .rows_affected(),
        )
    }
}
