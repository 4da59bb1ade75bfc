//! The job system: a persistent queue in SQLite, a worker pool, cancellation, traces.
//! The pipeline itself is behind the [`Grounder`] trait.

pub mod exports;
pub mod indexing;
pub mod ingest;
pub mod redact;
pub mod retention;
pub mod scene_cache;
pub mod sweep;
pub mod test_grounder;
pub mod watchdog;
pub mod webhooks;
pub mod worker;

use futures::future::BoxFuture;
use serde::Serialize;
use serde_json::Value;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use tokio_util::sync::CancellationToken;

use crate::geometry::Aabb;
use crate::scene::SceneData;
use crate::store::Store;

pub use scene_cache::SceneCache;
pub use worker::{JobSystem, WorkerConfig};

/// What a successful grounding returns.
#[derive(Debug, Clone, Serialize)]
pub struct GroundingOutput {
    #[serde(rename = "box")]
    pub bbox: Aabb,
    /// Extra result fields (chosen image id, detection, ...).
    #[serde(flatten)]
    pub extra: serde_json::Map<String, Value>,
}

/// A failure with a stable code and a sentence for people.
#[derive(Debug, Clone, Serialize, thiserror::Error)]
#[error("{code}: {detail}")]
pub struct JobFailure {
    pub code: String,
    pub detail: String,
}

impl JobFailure {
    pub fn new(code: &str, detail: impl Into<String>) -> Self {
        Self {
            code: code.to_string(),
            detail: detail.into(),
        }
    }
}

/// Artifact name of the object's fused points (binary PLY), served at `object.ply`.
pub const OBJECT_PLY: &str = "object.ply";

/// Artifact name of a view's mask (PNG), by the five-digit image id of the trace; served at
/// `masks/{image_id}.png`.
pub fn mask_artifact(image_id: &str) -> String {
    format!("mask_{image_id}.png")
}

/// Writes a job's trace steps and artifacts.
#[derive(Debug, Clone)]
pub struct TraceSink {
    store: Store,
    job_id: String,
    artifact_dir: PathBuf,
}

impl TraceSink {
    pub fn new(store: Store, job_id: String, artifact_dir: PathBuf) -> Self {
        Self {
            store,
            job_id,
            artifact_dir,
        }
    }

    /// Append a step (an object; `step` is added). Trace failures are logged, not fatal.
    pub async fn step(&self, step: &str, data: Value) {
        if let Err(e) = self.store.append_trace(&self.job_id, step, &data).await {
            tracing::warn!(job = %self.job_id, "cannot write trace step {step}: {e}");
        }
    }

    /// Store an artifact (e.g. a stitched JPEG) and return its URL path.
    pub async fn artifact(&self, name: &str, bytes: Vec<u8>) -> Result<String, JobFailure> {
        let safe = name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
            && !name.starts_with('.');
        if !safe {
            return Err(JobFailure::new(
                "internal",
                format!("invalid artifact name {name:?}"),
            ));
        }
        let dir = self.artifact_dir.clone();
        let path = dir.join(name);
        // Written beside its final name and renamed, so a reader never sees half a file.
        let tmp = dir.join(format!(".{name}.{}.tmp", uuid::Uuid::now_v7()));
        tokio::task::spawn_blocking(move || {
            std::fs::create_dir_all(&dir)?;
            std::fs::write(&tmp, bytes)?;
            std::fs::rename(&tmp, &path).inspect_err(|_| {
                let _ = std::fs::remove_file(&tmp);
            })
        })
        .await
        .map_err(|e| JobFailure::new("internal", format!("artifact writer failed: {e}")))?
        .map_err(|e| {
            JobFailure::new(
                "storage_error",
                format!("cannot write artifact {name}: {e}"),
            )
        })?;
        Ok(format!("/v1/jobs/{}/artifacts/{name}", self.job_id))
    }

    pub fn job_id(&self) -> &str {
        &self.job_id
    }
}

/// Everything a pipeline run gets.
pub struct JobContext {
    pub job_id: String,
    pub query: String,
    pub scene: Arc<SceneData>,
    pub store: Store,
    pub trace: TraceSink,
    pub cancel: CancellationToken,
}

/// The grounding pipeline as the worker sees it.
pub trait Grounder: Send + Sync + 'static {
    fn ground(&self, ctx: JobContext) -> BoxFuture<'_, Result<GroundingOutput, JobFailure>>;
}

/// Tokens of the jobs running in this process.
#[derive(Default)]
pub struct RunningJobs {
    inner: Mutex<HashMap<String, CancellationToken>>,
}

impl RunningJobs {
    pub fn insert(&self, id: &str, t: CancellationToken) {
        if let Ok(mut g) = self.inner.lock() {
            g.insert(id.to_string(), t);
        }
    }
    pub fn remove(&self, id: &str) {
        if let Ok(mut g) = self.inner.lock() {
            g.remove(id);
        }
    }
    pub fn contains(&self, id: &str) -> bool {
        self.inner
            .lock()
            .map(|g| g.contains_key(id))
            .unwrap_or(true)
    }
    pub fn cancel(&self, id: &str) -> bool {
        self.inner
            .lock()
            .ok()
            .and_then(|g| g.get(id).map(|t| t.cancel()))
            .is_some()
    }
}
