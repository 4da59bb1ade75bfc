//! Job change notifications and the job event log (`job_events`, written by triggers).
//!
//! Every job write in the store calls [`Hub::changed`] with the job's id after it commits
//! (or [`Hub::changed_all`] for bulk writes). Waiters (long polls, event streams) hold a
//! `watch` receiver per job, so a change that lands between their read and their wait is
//! never missed.

use std::collections::HashMap;
use std::sync::Mutex;

use serde_json::value::RawValue;
use sqlx::Row;
use tokio::sync::watch;

use super::{Store, StoreError};

/// Per-job change counters.
#[derive(Debug, Default)]
pub struct Hub {
    jobs: Mutex<HashMap<String, watch::Sender<u64>>>,
    /// Cancelled when the server begins to shut down: streams end so it can.
    pub closing: tokio_util::sync::CancellationToken,
    /// Woken by every change another replica made (PostgreSQL notifications): idle
    /// workers look at the queue again, so a job created elsewhere starts at once.
    pub remote: tokio::sync::Notify,
}

impl Hub {
    /// A receiver that sees every change to this job after this call.
    pub fn subscribe(&self, job_id: &str) -> watch::Receiver<u64> {
        let mut map = self.jobs.lock().unwrap_or_else(|e| e.into_inner());
        if map.len() > 1024 {
            map.retain(|_, tx| tx.receiver_count() > 0);
        }
        map.entry(job_id.to_string())
            .or_insert_with(|| watch::channel(0).0)
            .subscribe()
    }

    /// The job changed: wake its waiters.
    pub fn changed(&self, job_id: &str) {
        let mut map = self.jobs.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(tx) = map.get(job_id) {
            if tx.receiver_count() == 0 {
                map.remove(job_id);
            } else {
                tx.send_modify(|n| *n += 1);
            }
        }
    }

    /// Many jobs changed at once.
    pub fn changed_all(&self) {
        let mut map = self.jobs.lock().unwrap_or_else(|e| e.into_inner());
        map.retain(|_, tx| tx.receiver_count() > 0);
        for tx in map.values() {
            tx.send_modify(|n| *n += 1);
        }
    }
}

/// One entry of a job's event log.
#[derive(Debug)]
pub struct JobEvent {
    pub id: i64,
    /// `step` or `status`.
    pub kind: String,
    pub data: Box<RawValue>,
}

impl Store {
    /// A job's events with id above `after`, in order.
    pub async fn job_events_after(
        &self,
        job_id: &str,
        after: i64,
    ) -> Result<Vec<JobEvent>, StoreError> {
        let rows =
            sqlx::query(&self.sql(
                "SELECT id, kind, data FROM job_events WHERE job_id = ? AND id > ? ORDER BY id",
            ))
            .bind(job_id)
            .bind(after)
            .fetch_all(&self.pool)
            .await?;
        rows.iter()
            .map(|r| {
                let data: String = r.try_get("data")?;
                Ok(JobEvent {
                    id: r.try_get("id")?,
                    kind: r.try_get("kind")?,
                    data: RawValue::from_string(data)
                        .map_err(|e| StoreError::Corrupt(format!("event of job {job_id}: {e}")))?,
                })
            })
            .collect()
    }
}
