//! The workers' watchdog. It counts the workers alive (a gauge in /metrics; `/readyz` is
//! not ready without one) and reconciles the jobs this process claimed with the jobs it
//! actually runs: a claimed job whose task is gone (its worker ended half-way) would stay
//! `running` for ever, holding its scene; it is failed with kind `internal` instead.

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::task::AbortHandle;

use super::{JobSystem, RunningJobs};
use crate::store::JobStatus;

/// How often the watchdog looks.
pub const INTERVAL: Duration = Duration::from_millis(500);

/// Ticks a claimed job may go without a live task before it is failed (a claim and the
/// start of its run are not one step).
const GRACE_TICKS: u32 = 2;

/// What the watchdog watches.
#[derive(Default)]
pub struct Watch {
    live: AtomicUsize,
    workers: Mutex<Vec<AbortHandle>>,
    /// Jobs this process claimed and has not settled, with the ticks seen without a task.
    claimed: Mutex<HashMap<String, u32>>,
}

impl Watch {
    pub fn live(&self) -> usize {
        self.live.load(Ordering::SeqCst)
    }

    pub(super) fn add_worker(&self, h: AbortHandle) {
        if let Ok(mut w) = self.workers.lock() {
            w.push(h);
        }
    }

    /// Abort one worker task still running (a test hook).
    pub(super) fn abort_one(&self) -> bool {
        let Ok(mut w) = self.workers.lock() else {
            return false;
        };
        w.retain(|h| !h.is_finished());
        match w.pop() {
            Some(h) => {
                h.abort();
                true
            }
            None => false,
        }
    }

    pub(super) fn claimed(&self, id: &str) {
        if let Ok(mut c) = self.claimed.lock() {
            c.insert(id.to_string(), 0);
        }
    }

    /// The job's outcome is recorded (or it was put back in the queue).
    pub(super) fn settled(&self, id: &str) {
        if let Ok(mut c) = self.claimed.lock() {
            c.remove(id);
        }
    }

    /// Claimed jobs without a live task for longer than the grace; they are forgotten.
    fn orphans(&self, running: &RunningJobs) -> Vec<String> {
        let Ok(mut c) = self.claimed.lock() else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for (id, missed) in c.iter_mut() {
            if running.contains(id) {
                *missed = 0;
            } else {
                *missed += 1;
                if *missed >= GRACE_TICKS {
                    out.push(id.clone());
                }
            }
        }
        for id in &out {
            c.remove(id);
        }
        out
    }
}

/// Held by a worker's task while it lives.
pub struct Alive(Arc<Watch>);

impl Alive {
    pub fn new(watch: &Arc<Watch>) -> Self {
        watch.live.fetch_add(1, Ordering::SeqCst);
        Self(watch.clone())
    }
}

impl Drop for Alive {
    fn drop(&mut self) {
        self.0.live.fetch_sub(1, Ordering::SeqCst);
        if !std::thread::panicking() {
            tracing::debug!("a worker ended");
        }
    }
}

/// A job's entry among the running ones, for as long as its run lasts: dropped half-way
/// (the worker's task ended), it stops the job's own task and leaves the registry.
pub struct LiveJob<'a> {
    running: &'a RunningJobs,
    id: String,
    task: Option<AbortHandle>,
}

impl<'a> LiveJob<'a> {
    pub fn new(running: &'a RunningJobs, id: &str) -> Self {
        Self {
            running,
            id: id.to_string(),
            task: None,
        }
    }

    pub fn task(&mut self, h: AbortHandle) {
        self.task = Some(h);
    }
}

impl Drop for LiveJob<'_> {
    fn drop(&mut self) {
        if let Some(t) = self.task.take() {
            t.abort();
        }
        self.running.remove(&self.id);
    }
}

/// Look every `interval` until shutdown.
pub async fn run(jobs: JobSystem, interval: Duration) {
    loop {
        tokio::select! {
            _ = jobs.shutdown_signal() => break,
            _ = tokio::time::sleep(interval) => {}
        }
        if jobs.is_shutting_down() {
            break;
        }
        tick(&jobs).await;
    }
}

async fn tick(jobs: &JobSystem) {
    for id in jobs.watch.orphans(jobs.running()) {
        let err = serde_json::json!({
            "code": "internal",
            "detail": "the worker running the job stopped before it finished; the server log has the cause",
        });
        match jobs
            .store()
            .finish_job(&id, JobStatus::Failed, None, Some(&err))
            .await
        {
            Ok(true) => tracing::error!(job = %id, "watchdog: the job's worker is gone; failed"),
            Ok(false) => {}
            Err(e) => tracing::error!(job = %id, "watchdog: cannot fail an orphaned job: {e}"),
        }
    }
    if jobs.watch.live() == 0 {
        tracing::error!("no worker is alive: queued jobs will not run");
    }
}
