//! Read cache of polled jobs: `GET /v1/jobs/{id}` is the hottest request (robots poll),
//! and a SQLite round trip costs two thread hand-offs in sqlx. A job read is cached until
//! the next write to any job; every job write in the store calls [`JobCache::invalidate`]
//! after it commits (this process is the database's only writer).
//!
//! Correctness under concurrency: a reader notes the epoch before its query and stores its
//! result only if no invalidation happened since, so a result that a write may have
//! overtaken is never cached.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use serde_json::value::RawValue;

use super::JobRecord;

/// Entries kept at most; the map is emptied when full (cheap, and a poll refills it).
const CAPACITY: usize = 4096;

/// See the module documentation.
#[derive(Debug, Default)]
pub struct JobCache {
    epoch: AtomicU64,
    map: Mutex<HashMap<String, (JobRecord, Box<RawValue>)>>,
}

impl JobCache {
    /// The epoch to pass to [`Self::put`] for a read that starts now.
    pub fn epoch(&self) -> u64 {
        self.epoch.load(Ordering::Acquire)
    }

    /// A cached job and trace.
    pub fn get(&self, id: &str) -> Option<(JobRecord, Box<RawValue>)> {
        let map = self.map.lock().unwrap_or_else(|e| e.into_inner());
        map.get(id).cloned()
    }

    /// Cache a read that began at `epoch`, unless a write has happened since.
    pub fn put(&self, epoch: u64, job: &JobRecord, trace: &RawValue) {
        let mut map = self.map.lock().unwrap_or_else(|e| e.into_inner());
        if self.epoch.load(Ordering::Acquire) != epoch {
            return;
        }
        if map.len() >= CAPACITY {
            map.clear();
        }
        map.insert(job.id.clone(), (job.clone(), trace.to_owned()));
    }

    /// Forget everything; called after every committed (or attempted) job write.
    pub fn invalidate(&self) {
        let mut map = self.map.lock().unwrap_or_else(|e| e.into_inner());
        self.epoch.fetch_add(1, Ordering::AcqRel);
        map.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::JobStatus;

    fn job(id: &str, status: JobStatus) -> JobRecord {
        JobRecord {
            seq: 1,
            id: id.into(),
            scene_id: "s".into(),
            query: "q".into(),
            status,
            attempts: 0,
            created_at: "t".into(),
            started_at: None,
            finished_at: None,
            error: None,
            result: None,
            owner: None,
            webhook_url: None,
            scene_frames: None,
        }
    }

    fn raw(s: &str) -> Box<RawValue> {
        RawValue::from_string(s.into()).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn a_read_overtaken_by_a_write_is_not_cached() {
        let c = JobCache::default();
        let e = c.epoch();
        c.invalidate(); // a write lands while the read is in flight
        c.put(e, &job("a", JobStatus::Queued), &raw("[]"));
        assert!(c.get("a").is_none());

        let e = c.epoch();
        c.put(e, &job("a", JobStatus::Running), &raw(r#"[{"step":"x"}]"#));
        let (j, t) = c.get("a").unwrap_or_else(|| panic!("cached"));
        assert_eq!(
            (j.status, t.get()),
            (JobStatus::Running, r#"[{"step":"x"}]"#)
        );
        c.invalidate();
        assert!(c.get("a").is_none(), "a write empties the cache");
    }
}
