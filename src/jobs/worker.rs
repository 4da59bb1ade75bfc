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
use crate::store::{JobRecord, JobStatus, Store};

#[derive(Debug, Clone)]
pub struct WorkerConfig {
    pub workers: usize,
    pub data_dir: PathBuf,
}

/// The shared job machinery; cheap to clone.
#[derive(Clone)]
pub struct JobSystem {
    pub store: Store,
    grounder: Arc<dyn Grounder>,
    cache: Arc<SceneCache>,
    points: Arc<super::exports::PointsCache>,
    running: Arc<RunningJobs>,
    wake: Arc<Notify>,
    shutdown: CancellationToken,
    tracker: TaskTracker,
    metrics: Arc<Metrics>,
    cfg: WorkerConfig,
}

impl JobSystem {
    pub fn new(
        store: Store,
        grounder: Arc<dyn Grounder>,
        metrics: Arc<Metrics>,
        cfg: WorkerConfig,
    ) -> Self {
        Self {
            store,
            grounder,
            cache: Arc::new(SceneCache::default()),
            points: Arc::new(Default::default()),
            running: Arc::new(RunningJobs::default()),
            wake: Arc::new(Notify::new()),
            shutdown: CancellationToken::new(),
            tracker: TaskTracker::new(),
            metrics,
            cfg,
        }
    }

    /// Start the workers.
    pub fn start(&self) {
        for n in 0..self.cfg.workers.max(1) {
            let me = self.clone();
            self.tracker.spawn(async move { me.worker_loop(n).await });
        }
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

    pub(crate) fn points_cache(&self) -> &super::exports::PointsCache {
        &self.points
    }

    pub fn artifact_dir(&self, job_id: &str) -> PathBuf {
        self.cfg.data_dir.join("artifacts").join(job_id)
    }

    pub fn scene_dir(&self, scene_id: &str) -> PathBuf {
        self.cfg.data_dir.join("scenes").join(scene_id)
    }

    async fn worker_loop(self, n: usize) {
        tracing::debug!("worker {n} started");
        loop {
            if self.shutdown.is_cancelled() {
                break;
            }
            match self.store.claim_next_job().await {
                Ok(Some(job)) => {
                    self.run(job).await;
                    continue;
                }
                Ok(None) => {}
                Err(e) => tracing::error!("worker {n}: cannot claim a job: {e}"),
            }
            tokio::select! {
                _ = self.shutdown.cancelled() => break,
                _ = self.wake.notified() => {}
                _ = tokio::time::sleep(Duration::from_millis(500)) => {}
            }
        }
    }

    /// The scene decoded for the pipeline, from the cache when it is there.
    pub(crate) async fn load_scene(
        &self,
        scene_id: &str,
    ) -> Result<Arc<crate::scene::SceneData>, JobFailure> {
        if let Some(s) = self.cache.get(scene_id) {
            return Ok(s);
        }
        let loaded = self
            .store
            .load_scene(scene_id, &self.scene_dir(scene_id))
            .await
            .map_err(|e| JobFailure::new("storage_error", e.to_string()))?
            .ok_or_else(|| {
                JobFailure::new(
                    "scene_not_found",
                    format!("scene {scene_id} no longer exists"),
                )
            })?;
        let s = Arc::new(loaded);
        self.cache.put(scene_id, s.clone());
        Ok(s)
    }

    async fn run(&self, job: JobRecord) {
        let started = Instant::now();
        let token = self.shutdown.child_token();
        self.running.insert(&job.id, token.clone());
        tracing::info!(job = %job.id, attempt = job.attempts, "job started");
        let outcome = match self.load_scene(&job.scene_id).await {
            Ok(scene) => {
                let ctx = JobContext {
                    job_id: job.id.clone(),
                    query: job.query.clone(),
                    scene,
                    store: self.store.clone(),
                    trace: TraceSink::new(
                        self.store.clone(),
                        job.id.clone(),
                        self.artifact_dir(&job.id),
                    ),
                    cancel: token.clone(),
                };
                // Each job runs in a task of its own: a panic in the pipeline ends this
                // job `failed` (kind `internal`) and the worker goes on to the next one.
                let grounder = self.grounder.clone();
                match tokio::spawn(async move { grounder.ground(ctx).await }).await {
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
        self.running.remove(&job.id);
        let outcome_label;
        if self.shutdown.is_cancelled() && token.is_cancelled() {
            // Interrupted by shutdown (not by the user): leave it resumable.
            if let Err(e) = self.store.requeue_job(&job.id).await {
                tracing::error!(job = %job.id, "cannot requeue job at shutdown: {e}");
            }
            tracing::info!(job = %job.id, "job interrupted by shutdown; queued again");
            return;
        }
        let written = match outcome {
            Ok(out) => {
                outcome_label = "succeeded";
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
                outcome_label = if f.code == "canceled" {
                    "canceled"
                } else {
                    "failed"
                };
                let err = json!({"code": f.code, "detail": f.detail});
                self.store
                    .finish_job(&job.id, JobStatus::Failed, None, Some(&err))
                    .await
            }
        };
        match written {
            Ok(true) => tracing::info!(job = %job.id, outcome = outcome_label, "job finished"),
            Ok(false) => tracing::info!(job = %job.id, "job was canceled while running"),
            Err(e) => tracing::error!(job = %job.id, "cannot record job outcome: {e}"),
        }
        self.metrics
            .job_duration
            .get_or_create(&OutcomeLabels {
                outcome: outcome_label.to_string(),
            })
            .observe(started.elapsed().as_secs_f64());
    }
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
