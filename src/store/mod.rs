//! The store: SQLite (embedded default, WAL mode, migrations from `migrations/`) or
//! PostgreSQL (`database_url = "postgres://..."`, migrations from `migrations/postgres/`),
//! both through one `sqlx::AnyPool`; see [`dialect`] for how SQL differs between them.

pub mod cache;
pub mod detections;
pub mod dialect;
pub mod events;
pub mod frames;
pub mod idempotency;
pub mod jobs;
pub mod keys;
pub mod lifecycle;
pub mod notify;
pub mod queue;
pub mod replicas;
pub mod scenes;
pub mod webhooks;

use sqlx::any::{AnyConnectOptions, AnyPoolOptions};
use sqlx::sqlite::SqliteConnectOptions;
use sqlx::{AnyPool, ConnectOptions, Executor};
use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

pub use dialect::Backend;

pub use jobs::{JobRecord, JobStatus, ListJobs, NewJobs};
pub use keys::{KeyRecord, KeySpec, NewKey};
pub use replicas::Claim;
pub use scenes::SceneRecord;

/// Handle to the database; cheap to clone.
#[derive(Debug, Clone)]
pub struct Store {
    pub pool: AnyPool,
    /// Which database `pool` talks to.
    pub backend: Backend,
    /// This process's id as a lease holder (PostgreSQL), unique per opened store.
    pub replica: std::sync::Arc<String>,
    /// How long a claimed job's lease lasts, ms (see [`queue`]).
    lease_ms: i64,
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
        Self::connect(&default_database_url(data_dir), data_dir).await
    }

    /// Open the database `cfg` names (`database_url`, else `grounder.db` in `data_dir`).
    pub async fn open_config(cfg: &crate::config::Config) -> anyhow::Result<Self> {
        match &cfg.database_url {
            Some(url) => Self::connect(url, &cfg.data_dir).await,
            None => Self::open(&cfg.data_dir).await,
        }
        .map(|s| s.with_lease_seconds(cfg.lease_seconds))
    }

    /// Open the database `url` names (`sqlite://...` or `postgres://...`) and run its
    /// migrations; `data_dir` is created for a SQLite file that lives there.
    pub async fn connect(url: &str, data_dir: &Path) -> anyhow::Result<Self> {
        sqlx::any::install_default_drivers();
        let backend = Backend::of_url(url).ok_or_else(|| {
            anyhow::anyhow!("database_url must start with sqlite:// or postgres://")
        })?;
        let (opts, shown) = match backend {
            Backend::Sqlite => {
                std::fs::create_dir_all(data_dir).map_err(|e| {
                    anyhow::anyhow!("cannot create data dir {}: {e}", data_dir.display())
                })?;
                let sqlite = SqliteConnectOptions::from_str(url)
                    .map_err(|e| anyhow::anyhow!("bad database_url: {e}"))?
                    .create_if_missing(true);
                let shown = sqlite.get_filename().display().to_string();
                (AnyConnectOptions::from_url(&sqlite.to_url_lossy())?, shown)
            }
            Backend::Postgres => {
                let opts = AnyConnectOptions::from_str(url)
                    .map_err(|e| anyhow::anyhow!("bad database_url: {e}"))?;
                (opts, redact(url))
            }
        };
        let pool = AnyPoolOptions::new()
            .max_connections(8)
            .acquire_timeout(Duration::from_secs(15))
            .after_connect(move |conn, _| {
                Box::pin(async move {
                    match backend {
                        Backend::Sqlite => conn.execute(
                            "PRAGMA journal_mode = WAL; PRAGMA synchronous = NORMAL; \
                             PRAGMA foreign_keys = ON; PRAGMA busy_timeout = 10000;",
                        ),
                        // Notices ("already exists, skipping") are not worth a log line.
                        Backend::Postgres => conn.execute("SET client_min_messages TO warning"),
                    }
                    .await?;
                    Ok(())
                })
            })
            .connect_with(opts)
            .await
            .map_err(|e| anyhow::anyhow!("cannot open database {shown}: {e}"))?;
        let migrated = match backend {
            Backend::Sqlite => sqlx::migrate!("./migrations").run(&pool).await,
            Backend::Postgres => sqlx::migrate!("./migrations/postgres").run(&pool).await,
        };
        migrated.map_err(|e| anyhow::anyhow!("database migration failed: {e}"))?;
        let store = Self {
            pool,
            backend,
            replica: std::sync::Arc::new(uuid::Uuid::now_v7().to_string()),
            lease_ms: 30_000,
            job_cache: Default::default(),
            events: Default::default(),
        };
        if backend == Backend::Postgres {
            notify::start(url, &store.events, &store.job_cache).await?;
        }
        Ok(store)
    }

    /// The same store with leases of `secs` seconds (at least one).
    pub fn with_lease_seconds(mut self, secs: u64) -> Self {
        self.lease_ms = (secs.clamp(1, 86_400) * 1000) as i64;
        self
    }

    /// How long a lease lasts, ms.
    pub fn lease_ms(&self) -> i64 {
        self.lease_ms
    }

    /// `sql` (written with SQLite's `?` placeholders) in this store's dialect.
    pub(crate) fn sql<'a>(
        &self,
        sql: impl Into<std::borrow::Cow<'a, str>>,
    ) -> std::borrow::Cow<'a, str> {
        self.backend.sql(sql)
    }

    /// The two-argument maximum: `MAX(a, b)` on SQLite, `GREATEST(a, b)` on PostgreSQL.
    pub(crate) fn greatest(&self) -> &'static str {
        match self.backend {
            Backend::Sqlite => "MAX",
            Backend::Postgres => "GREATEST",
        }
    }

    /// A transaction that holds the write lock from its start (checks then writes):
    /// `BEGIN IMMEDIATE` on SQLite; on PostgreSQL a lock on `scenes` and `jobs` that
    /// excludes every other writer of them (readers go on) until commit.
    pub(crate) async fn begin_write(
        &self,
    ) -> Result<sqlx::Transaction<'static, sqlx::Any>, sqlx::Error> {
        match self.backend {
            Backend::Sqlite => self.pool.begin_with("BEGIN IMMEDIATE").await,
            Backend::Postgres => {
                let mut tx = self.pool.begin().await?;
                sqlx::query("LOCK TABLE scenes, jobs IN SHARE ROW EXCLUSIVE MODE")
                    .execute(&mut *tx)
                    .await?;
                Ok(tx)
            }
        }
    }

    /// True on PostgreSQL.
    pub(crate) fn pg(&self) -> bool {
        self.backend == Backend::Postgres
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

/// The database used when `database_url` is not set: `grounder.db` in the data dir.
pub fn default_database_url(data_dir: &Path) -> String {
    format!("sqlite://{}", data_dir.join("grounder.db").display())
}

/// A database URL without its password, for messages.
pub fn redact(url: &str) -> String {
    match url::Url::parse(url) {
        Ok(mut u) => {
            if u.password().is_some() {
                let _ = u.set_password(Some("***"));
            }
            u.to_string()
        }
        Err(_) => "(unparsable database_url)".into(),
    }
}
