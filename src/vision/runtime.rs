//! ONNX Runtime: locating and loading the shared library once, a pool of sessions per model
//! file, signature checks, and a bounded blocking pool so inference never runs on the async
//! runtime's worker threads.
//!
//! Library lookup order: the configured path (`[vision] ort_dylib` / [`set_configured_path`]),
//! then `ORT_DYLIB_PATH`, then `./.ort/libonnxruntime.so.1.31.1` (what
//! `scripts/setup-ort.sh` installs).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use anyhow::{anyhow, bail, Context, Result};
use ort::environment::Environment;
use ort::session::Session;

/// File name of the runtime library the project pins.
pub const ORT_LIB_NAME: &str = "libonnxruntime.so.1.31.1";
/// Default install folder of `scripts/setup-ort.sh`, relative to the working directory.
pub const ORT_DEFAULT_DIR: &str = ".ort";

static CONFIGURED: Mutex<Option<PathBuf>> = Mutex::new(None);
static ENV: OnceLock<(PathBuf, Environment)> = OnceLock::new();
static INIT_LOCK: Mutex<()> = Mutex::new(());

/// Whether the runtime library can be used (for `/readyz`).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum RuntimeStatus {
    /// Loaded from `path`.
    Ok { path: PathBuf },
    /// Not usable; `message` names the path tried and how to fix it.
    Missing { message: String },
}

impl RuntimeStatus {
    /// True when the library is loaded.
    pub fn is_ok(&self) -> bool {
        matches!(self, RuntimeStatus::Ok { .. })
    }
}

/// Set (or clear) the configured library path; takes precedence over `ORT_DYLIB_PATH`.
/// Has no effect once the library has been loaded.
pub fn set_configured_path(path: Option<PathBuf>) {
    if let Ok(mut g) = CONFIGURED.lock() {
        *g = path;
    }
}

/// The library path that would be used and where it came from.
pub fn resolve_library_path() -> (PathBuf, &'static str) {
    if let Some(p) = CONFIGURED.lock().ok().and_then(|g| g.clone()) {
        return (p, "the configured ort_dylib path");
    }
    match std::env::var("ORT_DYLIB_PATH") {
        Ok(s) if !s.trim().is_empty() => (PathBuf::from(s), "ORT_DYLIB_PATH"),
        _ => default_library_candidates()
            .into_iter()
            .find(|p| p.is_file())
            .map(|p| (p, "the default location"))
            .unwrap_or_else(|| {
                (
                    Path::new(ORT_DEFAULT_DIR).join(ORT_LIB_NAME),
                    "the default location",
                )
            }),
    }
}

/// Where the library is looked for when no path is configured, in order: `.ort/` under the
/// working directory, beside the executable (`.ort/` or the file itself), and the source
/// checkout the binary was built from (so `target/*/grounder` runs from any directory).
pub fn default_library_candidates() -> Vec<PathBuf> {
    let mut out = vec![Path::new(ORT_DEFAULT_DIR).join(ORT_LIB_NAME)];
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    {
        out.push(dir.join(ORT_DEFAULT_DIR).join(ORT_LIB_NAME));
        out.push(dir.join(ORT_LIB_NAME));
    }
    out.push(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(ORT_DEFAULT_DIR)
            .join(ORT_LIB_NAME),
    );
    out
}

/// Load the runtime library (once per process) and return the shared environment.
pub fn environment() -> Result<&'static Environment> {
    if let Some((_, env)) = ENV.get() {
        return Ok(env);
    }
    let _guard = INIT_LOCK
        .lock()
        .map_err(|_| anyhow!("ONNX Runtime init lock poisoned"))?;
    if let Some((_, env)) = ENV.get() {
        return Ok(env);
    }
    let (path, source) = resolve_library_path();
    if !path.is_file() {
        bail!(
            "ONNX Runtime library not found at {} (from {source}); run scripts/setup-ort.sh or set ORT_DYLIB_PATH",
            path.display()
        );
    }
    let builder = ort::init_from(&path).map_err(|e| {
        anyhow!(
            "cannot load ONNX Runtime library {} (from {source}): {e}; run scripts/setup-ort.sh",
            path.display()
        )
    })?;
    let env = builder.with_name("grounder").build().map_err(|e| {
        anyhow!(
            "cannot create ONNX Runtime environment from {}: {e}",
            path.display()
        )
    })?;
    let _ = ENV.set((path, env));
    ENV.get()
        .map(|(_, e)| e)
        .ok_or_else(|| anyhow!("ONNX Runtime environment missing after init"))
}

/// Try to load the library and report the outcome (never panics).
pub fn status() -> RuntimeStatus {
    match environment() {
        Ok(_) => RuntimeStatus::Ok {
            path: ENV.get().map(|(p, _)| p.clone()).unwrap_or_default(),
        },
        Err(e) => RuntimeStatus::Missing {
            message: format!("{e:#}"),
        },
    }
}

/// Options for creating sessions.
#[derive(Debug, Clone, Copy)]
pub struct SessionOptions {
    /// Threads per inference (intra-op).
    pub intra_threads: usize,
    /// Number of sessions (parallel inferences) kept for one model file.
    pub sessions: usize,
}

impl Default for SessionOptions {
    fn default() -> Self {
        Self {
            intra_threads: 2,
            sessions: 1,
        }
    }
}

/// Element type and shape (`-1` = dynamic) of one model input or output.
#[derive(Debug, Clone, PartialEq)]
pub struct IoSpec {
    pub name: String,
    pub shape: Vec<i64>,
    /// Element type as ONNX Runtime names it (e.g. "Float32"); empty for non-tensors.
    pub elem: String,
}

/// One model file loaded into a small pool of sessions, shared by every job.
pub struct OrtModel {
    path: PathBuf,
    sessions: Vec<Mutex<Session>>,
    next: AtomicUsize,
    /// Model inputs in graph order.
    pub inputs: Vec<IoSpec>,
    /// Model outputs in graph order.
    pub outputs: Vec<IoSpec>,
    /// Custom metadata (e.g. Ultralytics `names`).
    pub metadata: HashMap<String, String>,
}

fn io_specs(outlets: &[ort::value::Outlet]) -> Vec<IoSpec> {
    outlets
        .iter()
        .map(|o| IoSpec {
            name: o.name().to_string(),
            shape: o
                .dtype()
                .tensor_shape()
                .map(|s| s.to_vec())
                .unwrap_or_default(),
            elem: o
                .dtype()
                .tensor_type()
                .map(|t| format!("{t:?}"))
                .unwrap_or_default(),
        })
        .collect()
}

impl OrtModel {
    /// Load `path` into `opts.sessions` sessions. Errors name the file.
    pub fn load(path: &Path, opts: SessionOptions) -> Result<Self> {
        if !path.is_file() {
            bail!("model file {} not found", path.display());
        }
        Self::build(path, opts, |b| b.commit_from_file(path))
    }

    /// Load a model held in memory (one embedded in the binary); `label` names it in
    /// errors and in [`OrtModel::path`].
    pub fn load_from_memory(label: &Path, bytes: &[u8], opts: SessionOptions) -> Result<Self> {
        Self::build(label, opts, |b| b.commit_from_memory(bytes))
    }

    fn build(
        path: &Path,
        opts: SessionOptions,
        commit: impl Fn(&mut ort::session::builder::SessionBuilder) -> ort::Result<Session>,
    ) -> Result<Self> {
        let env = environment()?;
        let mut sessions = Vec::new();
        for _ in 0..opts.sessions.max(1) {
            let session = Session::builder(env)
                .and_then(|b| {
                    b.with_intra_threads(opts.intra_threads.max(1))
                        .map_err(Into::into)
                })
                .and_then(|b| b.with_inter_threads(1).map_err(Into::into))
                // Idle intra-op threads sleep instead of spinning: on a machine whose cores
                // the service shares (indexing decodes the next frame while a model runs),
                // spinning burns CPU that other work needs (#18, docs/performance.md).
                .and_then(|b| b.with_intra_op_spinning(false).map_err(Into::into))
                .and_then(|mut b| commit(&mut b))
                .map_err(|e| anyhow!("cannot load model file {}: {e}", path.display()))?;
            sessions.push(Mutex::new(session));
        }
        let first = sessions[0]
            .lock()
            .map_err(|_| anyhow!("session lock poisoned"))?;
        let inputs = io_specs(first.inputs());
        let outputs = io_specs(first.outputs());
        let mut metadata = HashMap::new();
        if let Ok(meta) = first.metadata() {
            for key in meta.custom_keys().unwrap_or_default() {
                if let Some(v) = meta.custom(&key) {
                    metadata.insert(key, v);
                }
            }
        }
        drop(first);
        Ok(Self {
            path: path.to_path_buf(),
            sessions,
            next: AtomicUsize::new(0),
            inputs,
            outputs,
            metadata,
        })
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Check that an input/output called `name` exists with `rank` dims, and that each
    /// fixed entry of `dims` (Some) matches the model (dynamic model dims are accepted).
    pub fn check_io(&self, output: bool, name: &str, dims: &[Option<i64>]) -> Result<&IoSpec> {
        let list = if output { &self.outputs } else { &self.inputs };
        let kind = if output { "output" } else { "input" };
        let spec = list.iter().find(|s| s.name == name).ok_or_else(|| {
            let names: Vec<&str> = list.iter().map(|s| s.name.as_str()).collect();
            anyhow!(
                "model {} has the wrong signature: no {kind} `{name}` (it has {names:?})",
                self.path.display()
            )
        })?;
        let ok = spec.shape.len() == dims.len()
            && spec
                .shape
                .iter()
                .zip(dims)
                .all(|(&m, want)| m < 0 || want.is_none_or(|w| w == m));
        if !ok {
            bail!(
                "model {} has the wrong signature: {kind} `{name}` has shape {:?}, expected {:?}",
                self.path.display(),
                spec.shape,
                dims.iter().map(|d| d.unwrap_or(-1)).collect::<Vec<_>>()
            );
        }
        Ok(spec)
    }

    /// Run `f` with exclusive use of one session of the pool (blocks if all are busy).
    pub fn with_session<R>(&self, f: impl FnOnce(&mut Session) -> Result<R>) -> Result<R> {
        let n = self.sessions.len();
        let start = self.next.fetch_add(1, Ordering::Relaxed);
        for i in 0..n {
            if let Ok(mut s) = self.sessions[(start + i) % n].try_lock() {
                return f(&mut s);
            }
        }
        let mut s = self.sessions[start % n]
            .lock()
            .map_err(|_| anyhow!("a session of {} panicked earlier", self.path.display()))?;
        f(&mut s).with_context(|| format!("inference with {}", self.path.display()))
    }
}

/// Runs blocking inference closures on tokio's blocking pool, at most `limit` at a time.
#[derive(Clone)]
pub struct InferencePool {
    sem: Arc<tokio::sync::Semaphore>,
}

impl InferencePool {
    /// A pool allowing `limit` (at least 1) concurrent inferences.
    pub fn new(limit: usize) -> Self {
        Self {
            sem: Arc::new(tokio::sync::Semaphore::new(limit.max(1))),
        }
    }

    /// Run `f` off the async runtime once a slot is free.
    pub async fn run<R, F>(&self, f: F) -> Result<R>
    where
        R: Send + 'static,
        F: FnOnce() -> Result<R> + Send + 'static,
    {
        let permit = self
            .sem
            .clone()
            .acquire_owned()
            .await
            .map_err(|_| anyhow!("inference pool closed"))?;
        let out = tokio::task::spawn_blocking(move || {
            let r = f();
            drop(permit);
            r
        })
        .await
        .map_err(|e| anyhow!("inference task failed: {e}"))?;
        out
    }
}
