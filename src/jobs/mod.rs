//! The job system: a persistent queue in SQLite, a worker pool, cancellation, traces.
//! The pipeline itself is behind the [`Grounder`] trait.

pub mod exports;
pub mod indexing;
pub mod ingest;
pub mod lease;
pub mod redact;
pub mod replicas;
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
use std::io::Write;
use std::sync::{Arc, Mutex};
use tokio_util::sync::CancellationToken;

use crate::geometry::Aabb;
use crate::scene::SceneData;
use crate::storage::Storage;
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
    storage: Arc<Storage>,
}

impl TraceSink {
    pub fn new(store: Store, job_id: String, storage: Arc<Storage>) -> Self {
        Self {
            store,
            job_id,
            storage,
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
        let (sink, name) = (self.clone(), name.to_string());
        tokio::task::spawn_blocking(move || {
            sink.write_artifact(&name, move |w: &mut dyn Write| w.write_all(&bytes))
        })
        .await
        .map_err(|e| JobFailure::new("internal", format!("artifact writer failed: {e}")))?
    }

    /// Write an artifact as it is produced: `produce` writes into the file (buffered), which
    /// appears under its name only once complete (written beside it and renamed, so a
    /// reader never sees half a file), without the whole content ever held in memory.
    /// Blocking: call it from blocking code (e.g. inside `spawn_blocking`). Returns the
    /// artifact's URL path.
    pub fn write_artifact(
        &self,
        name: &str,
        produce: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
    ) -> Result<String, JobFailure> {
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
        let dir = &self.storage.artifact_dir(&self.job_id);
        let path = dir.join(name);
        let tmp = dir.join(format!(".{name}.{}.tmp", uuid::Uuid::now_v7()));
        let written = (|| {
            std::fs::create_dir_all(dir)?;
            let mut out = std::io::BufWriter::with_capacity(1 << 16, std::fs::File::create(&tmp)?);
            produce(&mut out)?;
            out.into_inner().map_err(|e| e.into_error())?;
            std::fs::rename(&tmp, &path)
        })();
        written.map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            JobFailure::new(
                "storage_error",
                format!("cannot write artifact {name}: {e}"),
            )
        })?;
        if self.storage.remote_url().is_some() {
            // A bucket holds the artifacts of every replica: upload the finished file (this
            // runs on a blocking thread of the runtime, so it may wait for the upload).
            let bytes = std::fs::read(&path).map_err(|e| {
                JobFailure::new(
                    "storage_error",
                    format!("cannot read artifact {name} back: {e}"),
                )
            })?;
            let handle = tokio::runtime::Handle::try_current()
                .map_err(|_| JobFailure::new("internal", "artifact upload outside the runtime"))?;
            handle
                .block_on(self.storage.put_artifact(&self.job_id, name, bytes))
                .map_err(|e| {
                    tracing::error!(job = %self.job_id, "cannot upload artifact {name}: {e}");
                    JobFailure::new(
                        "storage_error",
                        format!("cannot store artifact {name} in the object store"),
                    )
                })?;
        }
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
    /// No job is running (a poisoned lock counts as running).
    pub fn is_empty(&self) -> bool {
        self.inner.lock().map(|g| g.is_empty()).unwrap_or(false)
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

#[cfg(test)]
mod artifact_tests {
    use super::*;

    async fn sink() -> (tempfile::TempDir, TraceSink) {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(&dir.path().join("db")).await.unwrap();
        let sink = TraceSink::new(
            store,
            "j1".into(),
            crate::storage::Storage::local(dir.path()),
        );
        (dir, sink)
    }

    fn names(dir: &std::path::Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[tokio::test]
    async fn an_artifact_is_written_as_produced_and_appears_only_when_complete() {
        let (dir, sink) = sink().await;
        let art = dir.path().join("artifacts/j1");
        let seen_during = std::sync::Arc::new(Mutex::new(Vec::new()));
        let seen = seen_during.clone();
        let art2 = art.clone();
        let url = sink
            .write_artifact("big.bin", move |w| {
                for i in 0..64u8 {
                    w.write_all(&[i; 4096])?;
                }
                w.flush()?;
                // Mid-write: only the temporary file exists, already holding the bytes.
                let n = names(&art2);
                let tmp = n.iter().find(|n| n.ends_with(".tmp")).cloned();
                let len = tmp.map(|t| std::fs::metadata(art2.join(t)).unwrap().len());
                seen.lock().unwrap().push((n, len));
                Ok(())
            })
            .unwrap();
        assert_eq!(url, "/v1/jobs/j1/artifacts/big.bin");
        let (during, len) = seen_during.lock().unwrap()[0].clone();
        assert!(!during.contains(&"big.bin".to_string()), "{during:?}");
        assert_eq!(len, Some(64 * 4096), "streamed to disk before the end");
        assert_eq!(names(&art), vec!["big.bin".to_string()]);
        let bytes = std::fs::read(art.join("big.bin")).unwrap();
        assert_eq!(bytes.len(), 64 * 4096);
        assert_eq!(bytes[4096 * 63], 63);
    }

    #[tokio::test]
    async fn a_failing_producer_or_a_bad_name_leaves_no_file() {
        let (dir, sink) = sink().await;
        let e = sink
            .write_artifact("x.ply", |w| {
                w.write_all(b"half")?;
                Err(std::io::Error::other("encoder broke"))
            })
            .unwrap_err();
        assert_eq!(e.code, "storage_error");
        assert!(e.detail.contains("encoder broke"), "{}", e.detail);
        assert!(names(&dir.path().join("artifacts/j1")).is_empty());
        let e = sink.write_artifact("../x", |_| Ok(())).unwrap_err();
        assert_eq!(e.code, "internal");
        let url = sink.artifact("a.txt", b"hi".to_vec()).await.unwrap();
        assert!(url.ends_with("/a.txt"));
    }
}
