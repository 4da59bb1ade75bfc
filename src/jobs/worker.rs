//! Worker pool: claims queued jobs from the store, runs the pipeline, records the outcome.

use serde_json::{json, Value};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::Notify;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use super::{
    Grounder, GroundingOutput, JobContext, JobFailure, RunningJobs, SceneCache, TraceSink,
};
use crate::metrics::{Metrics, OutcomeLabels};
use crate::storage::{ScenePin, Storage};
use crate::store::{JobRecord, JobStatus, Store};

#[derive(Debug, Clone)]
pub struct WorkerConfig {
    pub workers: usize,
    pub data_dir: PathBuf,
    /// Bound of the decoded-scene cache in bytes.
    pub scene_cache_bytes: u64,
    /// Bound of the agent's tile cache in bytes (counted under `max_memory_mb`).
    pub tile_cache_bytes: u64,
    /// Memory the jobs may use, in MB (0: no bound; see [`MemoryGate`]).
    pub max_memory_mb: u64,
    /// Memory one running job is counted for, in MB.
    pub job_memory_mb: u64,
    /// Scenes indexed at the same time.
    pub max_concurrent_indexing: usize,
    /// How long finished jobs and their artifacts are kept (None: for ever).
    pub job_retention: Option<Duration>,
    /// Attempts before a job whose lease keeps running out fails (PostgreSQL).
    pub max_attempts: i64,
    /// Fault injection for the race tests: pause between claiming a job and loading its
    /// scene (zero in service).
    pub claim_pause: Duration,
}

impl WorkerConfig {
    pub fn new(workers: usize, data_dir: PathBuf) -> Self {
        Self {
            workers,
            data_dir,
            scene_cache_bytes: super::scene_cache::DEFAULT_SCENE_CACHE_MB << 20,
            tile_cache_bytes: crate::stitch::DEFAULT_TILE_CACHE_MB << 20,
            max_memory_mb: 0,
            job_memory_mb: DEFAULT_JOB_MEMORY_MB,
            max_concurrent_indexing: 2,
            job_retention: None,
            max_attempts: 3,
            claim_pause: Duration::ZERO,
        }
    }
}

/// Memory one running job is counted for when none is configured (MB): what a job added to
/// the process's peak in the memory benchmark (docs/memory.md), rounded up.
pub const DEFAULT_JOB_MEMORY_MB: u64 = 60;
/// What the process holds besides jobs and the scene cache (code, runtime, SQLite, the
/// points export), MB: the benchmark's idle resident size less its cached scene.
pub const BASE_MEMORY_MB: u64 = 160;

/// Admission by memory: a worker takes a job from the queue only once it can reserve the
/// job's estimated memory within `max_memory_mb` (less the scene cache's bound and the
/// base); otherwise the job stays queued. One job can always run, however small the bound.
pub struct MemoryGate {
    permits: Option<Arc<tokio::sync::Semaphore>>,
    per_job: u32,
}

impl MemoryGate {
    pub fn new(cfg: &WorkerConfig) -> Self {
        if cfg.max_memory_mb == 0 {
            return Self {
                permits: None,
                per_job: 0,
            };
        }
        let cache_mb =
            (cfg.scene_cache_bytes.saturating_add(cfg.tile_cache_bytes)).div_ceil(1 << 20);
        let budget = cfg.max_memory_mb.saturating_sub(cache_mb + BASE_MEMORY_MB);
        let per_job = cfg.job_memory_mb.clamp(1, u32::MAX as u64 / 2);
        // One job always fits, so a bound below one job's need serialises instead of stalling.
        let total = budget.max(per_job).min(u32::MAX as u64 / 2);
        Self {
            permits: Some(Arc::new(tokio::sync::Semaphore::new(total as usize))),
            per_job: per_job.min(total) as u32,
        }
    }

    /// Jobs that can run at once under the bound (None: unbounded).
    pub fn capacity(&self) -> Option<usize> {
        self.permits
            .as_ref()
            .map(|s| s.available_permits() / self.per_job.max(1) as usize)
    }

    /// Wait for room for one job; the reservation ends when the returned value is dropped.
    async fn reserve(&self) -> Option<tokio::sync::OwnedSemaphorePermit> {
        let s = self.permits.as_ref()?;
        s.clone().acquire_many_owned(self.per_job).await.ok()
    }
}

/// The shared job machinery; cheap to clone.
#[derive(Clone)]
pub struct JobSystem {
    pub store: Store,
    grounder: Arc<dyn Grounder>,
    cache: Arc<SceneCache>,
    memory: Arc<MemoryGate>,
    points: Arc<super::exports::PointsCache>,
    running: Arc<RunningJobs>,
    wake: Arc<Notify>,
    shutdown: CancellationToken,
    tracker: TaskTracker,
    metrics: Arc<Metrics>,
    storage: Arc<Storage>,
    cfg: WorkerConfig,
    /// Slots of the scenes indexed at the same time, and how many wait for one.
    indexing: Arc<tokio::sync::Semaphore>,
    indexing_waiting: Arc<std::sync::atomic::AtomicUsize>,
    /// Workers alive and the jobs this process claimed (see [`super::watchdog`]).
    pub(super) watch: Arc<super::watchdog::Watch>,
}

impl JobSystem {
    pub fn new(
        store: Store,
        grounder: Arc<dyn Grounder>,
        metrics: Arc<Metrics>,
        storage: Arc<Storage>,
        cfg: WorkerConfig,
    ) -> Self {
        Self {
            store,
            grounder,
            cache: Arc::new(SceneCache::new(cfg.scene_cache_bytes)),
            memory: Arc::new(MemoryGate::new(&cfg)),
            points: Arc::new(Default::default()),
            running: Arc::new(RunningJobs::default()),
            wake: Arc::new(Notify::new()),
            shutdown: CancellationToken::new(),
            tracker: TaskTracker::new(),
            metrics,
            watch: Arc::new(Default::default()),
            indexing: Arc::new(tokio::sync::Semaphore::new(
                cfg.max_concurrent_indexing.max(1),
            )),
            indexing_waiting: Arc::new(Default::default()),
            storage,
            cfg,
        }
    }

    /// Start the workers and their watchdog.
    pub fn start(&self) {
        for n in 0..self.cfg.workers.max(1) {
            let me = self.clone();
            let alive = super::watchdog::Alive::new(&self.watch);
            let task = self.tracker.spawn(async move {
                let _alive = alive;
                me.worker_loop(n).await
            });
            self.watch.add_worker(task.abort_handle());
        }
        let me = self.clone();
        self.tracker
            .spawn(async move { super::watchdog::run(me, super::watchdog::INTERVAL).await });
        if let Some(keep) = self.cfg.job_retention {
            let me = self.clone();
            self.tracker
                .spawn(async move { super::retention::run(me, keep).await });
        }
        if self.store.pg() {
            let (store, wake, stop) =
                (self.store.clone(), self.wake.clone(), self.shutdown.clone());
            let max_attempts = self.cfg.max_attempts;
            self.tracker
                .spawn(super::lease::sweep(store, max_attempts, wake, stop));
        }
    }

    /// Run `task` beside the workers, whatever the role; [`Self::shutdown`] waits for it
    /// (it should end when [`Self::stopping`] is cancelled).
    pub fn spawn_background(&self, task: impl std::future::Future<Output = ()> + Send + 'static) {
        self.tracker.spawn(task);
    }

    /// Cancelled when the job system shuts down.
    pub fn stopping(&self) -> CancellationToken {
        self.shutdown.clone()
    }

    /// Wait for one of the `max_concurrent_indexing` slots; held until dropped.
    pub async fn indexing_slot(&self) -> Option<tokio::sync::OwnedSemaphorePermit> {
        use std::sync::atomic::Ordering;
        self.indexing_waiting.fetch_add(1, Ordering::SeqCst);
        let slot = self.indexing.clone().acquire_owned().await.ok();
        self.indexing_waiting.fetch_sub(1, Ordering::SeqCst);
        slot
    }

    /// Scenes waiting for an indexing slot.
    pub fn indexing_backlog(&self) -> usize {
        self.indexing_waiting
            .load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Workers whose loop is running.
    pub fn live_workers(&self) -> usize {
        self.watch.live()
    }

    /// Test hook: stop one worker as a crash would (its task ends wherever it is, a job it
    /// was running included). False when no worker is left.
    #[doc(hidden)]
    pub fn abort_worker_for_test(&self) -> bool {
        self.watch.abort_one()
    }

    pub(super) fn store(&self) -> &Store {
        &self.store
    }

    pub(super) fn running(&self) -> &RunningJobs {
        &self.running
    }

    pub(super) fn is_shutting_down(&self) -> bool {
        self.shutdown.is_cancelled()
    }

    pub(super) async fn shutdown_signal(&self) {
        self.shutdown.cancelled().await
    }

    /// A job was queued or a scene became ready: wake the workers.
    pub fn wake(&self) {
        self.wake.notify_waiters();
    }

    /// Stop claiming; running jobs are interrupted and put back in the queue.
    pub async fn shutdown(&self) {
        self.shutdown.cancel();
        self.tracker.close();
        self.tracker.wait().await;
    }

    /// Signal a running job of this process to stop (its row is already `canceled`).
    pub fn interrupt(&self, job_id: &str) -> bool {
        self.running.cancel(job_id)
    }

    pub fn forget_scene(&self, scene_id: &str) {
        self.cache.remove(scene_id);
        self.points.forget_scene(scene_id);
    }

    /// The scene cache, for indexing to hand its loaded scene (with the room layout it
    /// estimated) to later jobs.
    pub(crate) fn scene_cache(&self) -> &SceneCache {
        &self.cache
    }

    pub(crate) fn points_cache(&self) -> &super::exports::PointsCache {
        &self.points
    }

    /// Where scene files and artifacts live.
    pub fn storage(&self) -> &Arc<Storage> {
        &self.storage
    }

    pub fn artifact_dir(&self, job_id: &str) -> PathBuf {
        self.storage.artifact_dir(job_id)
    }

    pub fn scene_dir(&self, scene_id: &str) -> PathBuf {
        self.storage.scene_dir(scene_id)
    }

    /// The scene's files in its local folder (fetched from the bucket when not), kept
    /// there while the pin lives.
    pub async fn acquire_scene(&self, scene_id: &str) -> Result<ScenePin, JobFailure> {
        if self.storage.remote_url().is_none() {
            return self
                .storage
                .acquire_scene(scene_id, 0)
                .await
                .map_err(|e| JobFailure::new("storage_error", e.to_string()));
        }
        let revision = match self.store.get_scene(scene_id).await {
            Ok(Some(s)) => s.revision,
            Ok(None) => {
                return Err(JobFailure::new(
                    "scene_not_found",
                    format!("scene {scene_id} no longer exists"),
                ))
            }
            Err(e) => return Err(JobFailure::new("storage_error", e.to_string())),
        };
        match self.storage.acquire_scene(scene_id, revision).await {
            Ok(pin) => Ok(pin),
            Err(e) => {
                tracing::error!(scene = %scene_id, "cannot fetch the scene's files: {e}");
                Err(JobFailure::new(
                    "storage_error",
                    format!(
                        "the files of scene {scene_id} cannot be fetched from the object store"
                    ),
                ))
            }
        }
    }

    async fn worker_loop(self, n: usize) {
        tracing::debug!("worker {n} started");
        loop {
            if self.shutdown.is_cancelled() {
                break;
            }
            // Room for one more job first: beyond `max_memory_mb` jobs wait in the queue.
            let reserved = tokio::select! {
                _ = self.shutdown.cancelled() => break,
                r = self.memory.reserve() => r,
            };
            match self.store.claim_next_job().await {
                Ok(Some(job)) => {
                    self.watch.claimed(&job.id);
                    self.run(job).await;
                    drop(reserved);
                    continue;
                }
                Ok(None) => {}
                Err(e) => tracing::error!("worker {n}: cannot claim a job: {e}"),
            }
            drop(reserved);
            tokio::select! {
                _ = self.shutdown.cancelled() => break,
                _ = self.wake.notified() => {}
                _ = self.store.events.remote.notified() => {}
                _ = tokio::time::sleep(Duration::from_millis(500)) => {}
            }
        }
    }

    /// The scene decoded for the pipeline: shared with the jobs holding it, from the cache
    /// when kept there, else loaded once however many jobs ask at the same time.
    pub(crate) async fn load_scene(
        &self,
        scene_id: &str,
    ) -> Result<Arc<crate::scene::SceneData>, JobFailure> {
        let dir = self.scene_dir(scene_id);
        self.cache
            .get_or_load(scene_id, || async {
                self.store
                    .load_scene(scene_id, &dir)
                    .await
                    .map_err(|e| JobFailure::new("storage_error", e.to_string()))?
                    .ok_or_else(|| {
                        JobFailure::new(
                            "scene_not_found",
                            format!("scene {scene_id} no longer exists"),
                        )
                    })
            })
            .await
    }

    async fn run(&self, job: JobRecord) {
        let started = Instant::now();
        let token = self.shutdown.child_token();
        self.running.insert(&job.id, token.clone());
        // Should this worker's task end half-way (a crash of the worker, the test hook),
        // the job's own task is stopped and its entry goes; the watchdog fails the row.
        let mut live = super::watchdog::LiveJob::new(&self.running, &job.id);
        // On PostgreSQL the job holds a lease renewed until this guard drops (also when
        // the worker task ends half-way).
        let lease = AbortOnDrop(super::lease::keep(
            self.store.clone(),
            job.id.clone(),
            token.clone(),
        ));
        tracing::info!(job = %job.id, attempt = job.attempts, "job started");
        if !self.cfg.claim_pause.is_zero() {
            tokio::time::sleep(self.cfg.claim_pause).await;
        }
        // The scene's files stay in the local cache while the job runs.
        let loaded = match self.acquire_scene(&job.scene_id).await {
            Ok(pin) => self.load_scene(&job.scene_id).await.map(|s| {
                (
                    super::scene_cache::frames_at_claim(s, job.scene_frames),
                    pin,
                )
            }),
            Err(e) => Err(e),
        };
        let outcome = match loaded {
            Ok((scene, _pin)) => {
                let ctx = JobContext {
                    job_id: job.id.clone(),
                    query: job.query.clone(),
                    scene,
                    store: self.store.clone(),
                    trace: TraceSink::new(self.store.clone(), job.id.clone(), self.storage.clone()),
                    cancel: token.clone(),
                };
                // Each job runs in a task of its own: a panic in the pipeline ends this
                // job `failed` (kind `internal`) and the worker goes on to the next one.
                let grounder = self.grounder.clone();
                let task = tokio::spawn(async move { grounder.ground(ctx).await });
                live.task(task.abort_handle());
                match task.await {
                    Ok(outcome) => outcome,
                    Err(e) => {
                        let why = match e.try_into_panic() {
                            Ok(p) => p
                                .downcast_ref::<&str>()
                                .map(|s| s.to_string())
                                .or_else(|| p.downcast_ref::<String>().cloned())
                                .unwrap_or_else(|| "a panic without a message".into()),
                            Err(e) => e.to_string(),
                        };
                        tracing::error!(job = %job.id, "the job's pipeline panicked: {why}");
                        Err(JobFailure::new(
                            "internal",
                            "the pipeline stopped on an internal error; the server log has the cause",
                        ))
                    }
                }
            }
            Err(e) => Err(e),
        };
        drop(lease);
        if self.shutdown.is_cancelled() && token.is_cancelled() {
            // Interrupted by shutdown (not by the user): leave it resumable.
            if let Err(e) = self.store.requeue_job(&job.id).await {
                tracing::error!(job = %job.id, "cannot requeue job at shutdown: {e}");
            }
            tracing::info!(job = %job.id, "job interrupted by shutdown; queued again");
            self.watch.settled(&job.id);
            drop(live);
            return;
        }
        let outcome_label = match &outcome {
            Ok(_) => "succeeded",
            Err(f) if f.code == "canceled" => "canceled",
            Err(_) => "failed",
        };
        // Observed before the outcome is written: a client that sees the job finished
        // must also find it counted in /metrics.
        self.metrics
            .job_duration
            .get_or_create(&OutcomeLabels {
                outcome: outcome_label.to_string(),
            })
            .observe(started.elapsed().as_secs_f64());
        let written = match outcome {
            Ok(out) => {
                self.store
                    .finish_job(
                        &job.id,
                        JobStatus::Succeeded,
                        Some(&result_json(&out)),
                        None,
                    )
                    .await
            }
            Err(f) => {
                let err = error_json(&job.id, &f);
                self.store
                    .finish_job(&job.id, JobStatus::Failed, None, Some(&err))
                    .await
            }
        };
        self.watch.settled(&job.id);
        drop(live);
        match written {
            Ok(true) => tracing::info!(job = %job.id, outcome = outcome_label, "job finished"),
            Ok(false) => tracing::info!(job = %job.id, "job was canceled while running"),
            Err(e) => tracing::error!(job = %job.id, "cannot record job outcome: {e}"),
        }
    }
}

/// A failure as the job's `error` object. Its detail names files, not their folders: a
/// path in it (a scene's or model's file, a data dir) is cut to its last component (the
/// log keeps the full text).
pub fn error_json(job_id: &str, f: &JobFailure) -> Value {
    let detail = super::redact::without_paths(&f.detail);
    if detail != f.detail {
        tracing::warn!(job = %job_id, "job failed: {}: {}", f.code, f.detail);
    }
    json!({"code": f.code, "detail": detail})
}

/// The API's `result` object: `box` with min, max, centre, size and its 8 corners (corner
/// `i` takes max x when bit 0 of `i` is set, max y for bit 1, max z for bit 2), plus extras.
pub fn result_json(out: &GroundingOutput) -> Value {
    let b = &out.bbox;
    let mut v = json!({"box": {"min": b.min, "max": b.max, "center": b.center(), "size": b.size(),
                               "corners": crate::geometry::export::corners(b)}});
    if let Some(o) = v.as_object_mut() {
        for (k, x) in &out.extra {
            o.insert(k.clone(), x.clone());
        }
    }
    v
}

/// Aborts a background task (a job's lease renewal) when dropped.
struct AbortOnDrop(Option<tokio::task::JoinHandle<()>>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        if let Some(t) = self.0.take() {
            t.abort();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_error_names_files_not_their_folders() {
        let f = JobFailure::new(
            "storage_error",
            "cannot read /srv/grounder/data/scenes/0193/color/12.jpg: No such file",
        );
        let v = error_json("j", &f);
        assert_eq!(v["code"], "storage_error");
        assert_eq!(v["detail"], "cannot read 12.jpg: No such file");
        let plain = JobFailure::new("no_target_found", "no chair in view /v1/jobs");
        assert_eq!(
            error_json("j", &plain)["detail"],
            "no chair in view /v1/jobs"
        );
    }
}
