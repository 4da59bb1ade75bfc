//! The embedded SQLite store (WAL mode, migrations from `migrations/`).

pub mod cache;
pub mod events;
pub mod frames;
pub mod idempotency;
pub mod jobs;
pub mod keys;
pub mod lifecycle;
pub mod scenes;
pub mod webhooks;

use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::SqlitePool;
use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

pub use jobs::{JobRecord, JobStatus, ListJobs, NewJobs};
pub use keys::{KeyRecord, KeySpec, NewKey};
pub use scenes::SceneRecord;

/// Handle to the database; cheap to clone.
#[derive(Debug, Clone)]
pub struct Store {
    pub pool: SqlitePool,
    /// Polled jobs, valid until the next job write (see [`cache`]).
    pub(crate) job_cache: std::sync::Arc<cache::JobCache>,
    /// Wakes whoever waits on a job's changes (long polls, event streams).
    pub events: std::sync::Arc<events::Hub>,
}

/// Errors from the store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database error: {0}")]
    Db(#[from] sqlx::Error),
    #[error("stored data is corrupt: {0}")]
    Corrupt(String),
}

impl Store {
    /// Open (creating if needed) `grounder.db` under `data_dir` and run migrations.
    pub async fn open(data_dir: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(data_dir)
            .map_err(|e| anyhow::anyhow!("cannot create data dir {}: {e}", data_dir.display()))?;
        let path = data_dir.join("grounder.db");
        let opts = SqliteConnectOptions::from_str(&format!("sqlite://{}", path.display()))?
            .create_if_missing(true)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Normal)
            .foreign_keys(true)
            .busy_timeout(Duration::from_secs(10));
        let pool = SqlitePoolOptions::new()
            .max_connections(8)
            .connect_with(opts)
            .await
            .map_err(|e| anyhow::anyhow!("cannot open database {}: {e}", path.display()))?;
        sqlx::migrate!("./migrations")
            .run(&pool)
            .await
            .map_err(|e| anyhow::anyhow!("database migration failed: {e}"))?;
        Ok(Self {
            pool,
            job_cache: Default::default(),
            events: Default::default(),
        })
    }

    /// After a write to one job: drop cached reads and wake its waiters.
    pub(crate) fn job_written(&self, id: &str) {
        self.job_cache.invalidate();
        self.events.changed(id);
    }

    /// True when a trivial query succeeds.
    pub async fn ping(&self) -> bool {
        sqlx::query("SELECT 1").execute(&self.pool).await.is_ok()
    }
}

/// Current time as RFC 3339 (UTC, millisecond precision).
pub fn now_rfc3339() -> String {
    let now = time::OffsetDateTime::now_utc();
    let now = now
        .replace_nanosecond(now.millisecond() as u32 * 1_000_000)
        .unwrap_or(now);
    now.format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}
