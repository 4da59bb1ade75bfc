//! Several replicas on one database: who is alive, and who holds what.
//!
//! Every replica writes a heartbeat (`replicas` row, database clock) every third of the
//! lease; one whose heartbeat is older than a lease is dead. An idempotency key in flight
//! and a scene row left `importing` or `deleting` record the replica holding them
//! (`holder`): another replica releases or finishes them only once that replica is dead.
//! Indexing a scene is claimed like a job: a lease (`index_owner`, `index_until`) its
//! indexer renews, which any replica may take over once it ran out.

use super::{Backend, Store, StoreError};

/// The database clock in unix milliseconds.
fn now_ms(backend: Backend) -> &'static str {
    match backend {
        Backend::Postgres => "(extract(epoch FROM clock_timestamp()) * 1000)::BIGINT",
        Backend::Sqlite => "CAST((julianday('now') - 2440587.5) * 86400000 AS INTEGER)",
    }
}

/// How [`Store::claim_indexing`] may take a scene's indexing lease.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Claim {
    /// The indexer the upload (append, re-index) started: unless another indexer holds a
    /// lease that has not run out. A scene just published holds an ownerless lease for
    /// its indexer to take.
    Start,
    /// A replica picking up abandoned indexing: only once the lease ran out.
    TakeOver,
    /// The previous (only) process is gone: whatever the lease says (SQLite start-up).
    Force,
}

/// The clock expression for "now" (unix ms) on `backend`, for other store modules.
pub(crate) fn clock_ms(backend: Backend) -> &'static str {
    now_ms(backend)
}

impl Store {
    /// SQL true when `col` names no live replica (none, or one whose heartbeat is older
    /// than a lease).
    fn held_by_dead(&self, col: &str) -> String {
        format!(
            "({col} IS NULL OR {col} NOT IN (SELECT id FROM replicas WHERE heartbeat_ms >= {} - {}))",
            now_ms(self.backend),
            self.lease_ms()
        )
    }

    /// Record that this replica is alive.
    pub async fn heartbeat(&self) -> Result<(), StoreError> {
        let now = now_ms(self.backend);
        sqlx::query(&self.sql(format!(
            "INSERT INTO replicas (id, heartbeat_ms, started_at) VALUES (?, {now}, ?) \
             ON CONFLICT (id) DO UPDATE SET heartbeat_ms = {now}"
        )))
        .bind(self.replica.as_str())
        .bind(super::now_rfc3339())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// This replica stops (gracefully): its row goes, and with it what it still holds
    /// becomes another replica's to release.
    pub async fn leave(&self) -> Result<(), StoreError> {
        sqlx::query(&self.sql("DELETE FROM replicas WHERE id = ?"))
            .bind(self.replica.as_str())
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// Remove the rows of replicas dead for a day (their ids are never reused).
    pub async fn forget_dead_replicas(&self) -> Result<u64, StoreError> {
        Ok(sqlx::query(&self.sql(format!(
            "DELETE FROM replicas WHERE heartbeat_ms < {} - 86400000",
            now_ms(self.backend)
        )))
        .execute(&self.pool)
        .await?
        .rows_affected())
    }

    /// Release the idempotency keys left in flight by dead replicas (their request will
    /// never finish); returns how many.
    pub async fn idempotency_release_dead(&self) -> Result<u64, StoreError> {
        Ok(sqlx::query(&self.sql(format!(
            "DELETE FROM idempotency WHERE status IS NULL AND {}",
            self.held_by_dead("holder")
        )))
        .execute(&self.pool)
        .await?
        .rows_affected())
    }

    /// Scenes left `importing` or `deleting` by a dead replica: (id, status).
    pub async fn hidden_scenes_of_dead(&self) -> Result<Vec<(String, String)>, StoreError> {
        Ok(sqlx::query_as(&self.sql(format!(
            "SELECT id, status FROM scenes WHERE status IN ('importing', 'deleting') AND {} ORDER BY id",
            self.held_by_dead("holder")
        )))
        .fetch_all(&self.pool)
        .await?)
    }

    /// Does a scene row exist (whatever its state)?
    pub async fn scene_exists(&self, id: &str) -> Result<bool, StoreError> {
        let n: Option<i64> = sqlx::query_scalar(&self.sql("SELECT 1 FROM scenes WHERE id = ?"))
            .bind(id)
            .fetch_optional(&self.pool)
            .await?;
        Ok(n.is_some())
    }

    /// Take the indexing lease of a visible scene as `owner` (one indexer at a time), as
    /// `how` allows. False when another indexer holds it, or the scene is gone or hidden.
    pub async fn claim_indexing(
        &self,
        id: &str,
        owner: &str,
        how: Claim,
    ) -> Result<bool, StoreError> {
        let now = now_ms(self.backend);
        let free = match how {
            Claim::Start => {
                format!("(index_owner IS NULL OR index_until IS NULL OR index_until < {now})")
            }
            Claim::TakeOver => format!("(index_until IS NULL OR index_until < {now})"),
            Claim::Force => "1 = 1".to_string(),
        };
        let r = sqlx::query(&self.sql(format!(
            "UPDATE scenes SET index_owner = ?, index_until = {now} + ? \
             WHERE id = ? AND status NOT IN ('importing', 'deleting') AND {free}"
        )))
        .bind(owner)
        .bind(self.lease_ms())
        .bind(id)
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Does a live indexer hold the lease of this (visible) scene?
    pub async fn indexing_held(&self, id: &str) -> Result<bool, StoreError> {
        let n: Option<i64> = sqlx::query_scalar(&self.sql(format!(
            "SELECT 1 FROM scenes WHERE id = ? AND status NOT IN ('importing', 'deleting') \
             AND index_owner IS NOT NULL AND index_until >= {}",
            now_ms(self.backend)
        )))
        .bind(id)
        .fetch_optional(&self.pool)
        .await?;
        Ok(n.is_some())
    }

    /// Extend `owner`'s indexing lease; false when it is no longer `owner`'s, or the scene
    /// is being deleted (its indexer then stops instead of writing beside a delete).
    pub async fn renew_indexing(&self, id: &str, owner: &str) -> Result<bool, StoreError> {
        let r = sqlx::query(&self.sql(format!(
            "UPDATE scenes SET index_until = {} + ? WHERE id = ? AND index_owner = ? \
             AND status <> 'deleting'",
            now_ms(self.backend)
        )))
        .bind(self.lease_ms())
        .bind(id)
        .bind(owner)
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Indexing by `owner` ended: record `status` (unless the row is hidden meanwhile),
    /// reset the attempts and free the lease. False (nothing written) when the lease is no
    /// longer `owner`'s.
    pub async fn end_indexing(
        &self,
        id: &str,
        owner: &str,
        status: &str,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        let r = sqlx::query(&self.sql(
            "UPDATE scenes SET status = CASE WHEN status IN ('importing', 'deleting') THEN status ELSE ? END, \
             error = CASE WHEN status IN ('importing', 'deleting') THEN error ELSE ? END, \
             index_attempts = 0, index_owner = NULL, index_until = NULL \
             WHERE id = ? AND index_owner = ?",
        ))
        .bind(status)
        .bind(error)
        .bind(id)
        .bind(owner)
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Free `owner`'s indexing lease and leave the scene as it is (`indexing`), for another
    /// indexer to take at once; `uncount` takes back the attempt [`Self::begin_index_attempt`]
    /// counted. False (nothing written) when the lease is no longer `owner`'s.
    pub async fn release_indexing(
        &self,
        id: &str,
        owner: &str,
        uncount: bool,
    ) -> Result<bool, StoreError> {
        let attempts = if uncount {
            "CASE WHEN index_attempts > 0 THEN index_attempts - 1 ELSE 0 END"
        } else {
            "index_attempts"
        };
        let r = sqlx::query(&self.sql(format!(
            "UPDATE scenes SET index_owner = NULL, index_until = NULL, index_attempts = {attempts} \
             WHERE id = ? AND index_owner = ?"
        )))
        .bind(id)
        .bind(owner)
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Scenes `indexing` whose lease ran out (their indexer, or the replica that stored
    /// them before its indexer claimed them, died), with their attempts so far.
    pub async fn unclaimed_indexing(&self) -> Result<Vec<(String, i64)>, StoreError> {
        Ok(sqlx::query_as(&self.sql(format!(
            "SELECT id, index_attempts FROM scenes WHERE status = 'indexing' \
             AND (index_until IS NULL OR index_until < {}) ORDER BY id",
            now_ms(self.backend)
        )))
        .fetch_all(&self.pool)
        .await?)
    }
}
