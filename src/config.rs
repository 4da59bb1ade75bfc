//! Service configuration: the keys and their defaults. Loaded in layers (defaults with the
//! `method` preset, TOML file, environment, flags) by [`load`]; printed by [`show`].

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

pub mod load;
mod preset;
pub mod show;

pub use load::ConfigError;
pub use preset::Method;

#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Address to listen on (also GROUNDER_ADDR).
    #[arg(long)]
    pub addr: Option<String>,
    /// Directory holding the database and scene files (also GROUNDER_DATA_DIR).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Optional TOML configuration file (keys as in `Config`).
    #[arg(long, env = "GROUNDER_CONFIG")]
    pub config: Option<PathBuf>,
    /// What to run: api, worker or all (also GROUNDER_ROLE).
    #[arg(long, value_enum)]
    pub role: Option<Role>,
    /// Serve without API keys on a non-loopback address (anyone reaching the port sees
    /// everything). Also GROUNDER_ALLOW_ANONYMOUS=1.
    #[arg(long)]
    pub allow_anonymous: bool,
}

/// Which parts of the service a `serve` process runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// The HTTP API and the workers (one process does everything).
    All,
    /// The HTTP API only: jobs are left to worker replicas (it indexes the scenes it
    /// stores; indexing a stopped replica left is taken over by any replica).
    Api,
    /// Workers only (jobs, and indexing taken over); HTTP answers the health endpoints alone.
    Worker,
}

impl Role {
    /// True when this process claims jobs.
    pub fn runs_workers(self) -> bool {
        self != Role::Api
    }

    /// True when this process serves the full API.
    pub fn serves_api(self) -> bool {
        self != Role::Worker
    }
}

/// Everything the service can be configured with.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Which method the defaults follow: "grounder" (ours) or "paper" (the paper's box).
    pub method: Method,
    /// Address the HTTP service listens on (host:port; port 0 picks a free one).
    pub addr: String,
    /// Folder holding the database and the uploaded scenes.
    pub data_dir: PathBuf,
    /// Where scene files and artifacts live: "" (the data dir), `file://DIR` or
    /// `s3://bucket/prefix` (settings from the AWS_* variables); see docs/storage.md.
    pub storage: String,
    /// Bound of the local cache of scenes downloaded from an `s3://` storage, MB.
    pub storage_cache_mb: u64,
    /// `s3://` storage: longest wait for a connection to the object store, s.
    pub storage_connect_timeout_secs: u64,
    /// `s3://` storage: longest one request to the object store may take, s (a download
    /// of one frame included).
    pub storage_request_timeout_secs: u64,
    /// `s3://` storage: retries of a failed request (with back-off) before it fails.
    pub storage_retries: usize,
    /// `s3://` storage: no retry starts later than this after a request's first try, s.
    pub storage_retry_timeout_secs: u64,
    /// PostgreSQL replicas: a replica's start-up sweep removes a leftover file or folder
    /// (no row names it) only when nothing in it changed for this long, s; another replica
    /// may be writing it.
    pub sweep_grace_secs: u64,
    /// The database: `sqlite://PATH` or `postgres://USER:PASSWORD@HOST:PORT/DB` (unset:
    /// `grounder.db` in `data_dir`). Replicas that share a PostgreSQL database share one
    /// queue; they share either `data_dir` (one volume) or an `s3://` storage.
    pub database_url: Option<String>,
    /// What `serve` runs: "all" (API and workers), "api" (no workers) or "worker" (claims
    /// jobs and indexes scenes; answers only the health endpoints).
    pub role: Role,
    /// Seconds a running job's lease lasts (PostgreSQL). Its worker renews it; a job whose
    /// lease ran out (its replica died) is queued again by any replica, as an attempt.
    pub lease_seconds: u64,
    /// Largest accepted upload body in bytes (413 above).
    pub max_upload_bytes: u64,
    /// Largest total unpacked size of an archive in bytes.
    pub max_unpacked_bytes: u64,
    /// Most entries an archive may hold.
    pub max_archive_files: u64,
    /// Most pixels one uploaded image (colour, depth, instance mask) may declare; checked
    /// from the image's header before decoding (413 `image_too_large` above).
    pub max_image_pixels: u64,
    /// Most pixels a whole scene may hold: frames x (colour + depth pixels), checked from
    /// the first frame's headers at upload and at each append (413 `scene_too_large`).
    pub max_scene_pixels: u64,
    /// Upload bodies (scenes and frame appends) received at the same time; one more is
    /// answered 503 `too_many_uploads` with Retry-After.
    pub max_concurrent_uploads: usize,
    /// Scenes indexed at the same time; more wait `indexing` for a slot.
    pub max_concurrent_indexing: usize,
    /// Scenes waiting for an indexing slot before uploads, appends and re-indexing are
    /// answered 503 `indexing_busy` with Retry-After (with a detector).
    pub max_queued_indexing: usize,
    /// Longest pause between two pieces of an upload body, s (408 `upload_timeout`).
    pub upload_idle_timeout_secs: u64,
    /// Longest time an upload body may take in all, s (408 `upload_timeout`).
    pub upload_timeout_secs: u64,
    /// Free space the data dir's file system must keep, MB: an upload that would leave
    /// less is refused (507 `insufficient_storage`).
    pub min_free_disk_mb: u64,
    /// Days finished jobs (and their artifacts) are kept; 0 keeps them for ever.
    pub job_retention_days: f64,
    /// Concurrent grounding jobs.
    pub workers: usize,
    /// Bound of the decoded-scene cache shared by the jobs (depth maps and cameras), MB.
    pub scene_cache_mb: u64,
    /// Bound of the resized grid tiles kept between queries, MB (0: none).
    pub tile_cache_mb: u64,
    /// Memory bound for running jobs, MB (0: none). A job starts only when its estimate
    /// (`job_memory_mb`) fits beside the others, the scene cache and a base; else it waits
    /// queued. One job always runs.
    pub max_memory_mb: u64,
    /// Memory one running job is counted for under `max_memory_mb`, MB.
    pub job_memory_mb: u64,
    /// Attempts before a job that keeps dying with the process is failed.
    pub max_attempts: i64,
    /// Indexing attempts before a scene whose indexing keeps dying with the process (out
    /// of memory, a crashing model) ends `failed` instead of being resumed again.
    pub max_index_attempts: i64,
    /// The pipeline the workers run: "vlm" (the method) or "test:delay_ms=N" (testing).
    pub pipeline: String,
    /// Detector used to index uploaded scenes ("none" to skip indexing).
    pub detector: String,
    /// Segmenter used by the pipeline.
    pub segmenter: String,
    /// Folder with the vendored models (default: ./models, or GROUNDER_MODEL_DIR).
    pub model_dir: Option<PathBuf>,
    /// Path of libonnxruntime (else ORT_DYLIB_PATH, else ./.ort/).
    pub ort_dylib: Option<PathBuf>,
    /// Sessions per vision model = inferences that may run at the same time.
    pub vision_concurrency: usize,
    /// Folder whose prompt files override the built-in ones (GROUNDER_PROMPTS_DIR).
    pub prompts_dir: Option<PathBuf>,
    /// Answer without API keys (when none exist) even on a non-loopback address.
    pub allow_anonymous: bool,
    /// Accept webhook URLs on loopback and private addresses (tests, closed networks).
    pub webhook_allow_private: bool,
    /// Fault injection for the crash tests: pause this long between the steps of a scene
    /// import or delete (env `GROUNDER_TEST_STEP_PAUSE_MS`; 0, the default, in service).
    pub test_step_pause_ms: u64,
    /// Fault injection for the race tests: a worker pauses this long between claiming a
    /// job and loading its scene (env `GROUNDER_TEST_CLAIM_PAUSE_MS`; 0 in service).
    pub test_claim_pause_ms: u64,
    /// Method settings (`[agent]` table).
    pub agent: crate::agent::AgentParams,
    /// VLM client settings (`[vlm]` table); [`load`] always sets them, a `Config` built in
    /// code without them uses `VlmConfig::default()`.
    pub vlm: Option<crate::vlm::VlmConfig>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            method: Method::default(),
            addr: "127.0.0.1:8080".into(),
            data_dir: PathBuf::from("./data"),
            storage: String::new(),
            storage_cache_mb: crate::storage::DEFAULT_CACHE_MB,
            storage_connect_timeout_secs: 5,
            storage_request_timeout_secs: 60,
            storage_retries: 3,
            storage_retry_timeout_secs: 15,
            sweep_grace_secs: 600,
            database_url: None,
            role: Role::All,
            lease_seconds: 30,
            max_upload_bytes: 2 << 30,
            max_unpacked_bytes: 8 << 30,
            max_archive_files: 200_000,
            max_image_pixels: crate::scene::import::DEFAULT_MAX_IMAGE_PIXELS,
            max_scene_pixels: crate::scene::import::DEFAULT_MAX_SCENE_PIXELS,
            max_concurrent_uploads: 8,
            max_concurrent_indexing: 2,
            max_queued_indexing: 16,
            upload_idle_timeout_secs: 60,
            upload_timeout_secs: 3600,
            min_free_disk_mb: 1024,
            job_retention_days: 7.0,
            workers: 2,
            scene_cache_mb: crate::jobs::scene_cache::DEFAULT_SCENE_CACHE_MB,
            tile_cache_mb: crate::stitch::DEFAULT_TILE_CACHE_MB,
            max_memory_mb: 0,
            job_memory_mb: crate::jobs::worker::DEFAULT_JOB_MEMORY_MB,
            max_attempts: 3,
            max_index_attempts: 3,
            pipeline: "vlm".into(),
            detector: "centernet".into(),
            segmenter: "depth".into(),
            model_dir: None,
            ort_dylib: None,
            vision_concurrency: 1,
            prompts_dir: None,
            allow_anonymous: false,
            webhook_allow_private: false,
            test_step_pause_ms: 0,
            test_claim_pause_ms: 0,
            agent: crate::agent::AgentParams::default(),
            vlm: None,
        }
    }
}

impl Config {
    /// The bounds of one request to an `s3://` storage.
    pub fn remote_limits(&self) -> crate::storage::RemoteLimits {
        use std::time::Duration;
        crate::storage::RemoteLimits {
            connect_timeout: Duration::from_secs(self.storage_connect_timeout_secs.max(1)),
            request_timeout: Duration::from_secs(self.storage_request_timeout_secs.max(1)),
            retries: self.storage_retries,
            retry_timeout: Duration::from_secs(self.storage_retry_timeout_secs),
        }
    }

    /// Vision settings derived from this configuration.
    pub fn vision(&self) -> crate::vision::VisionConfig {
        let mut v = crate::vision::VisionConfig {
            detector: self.detector.clone(),
            segmenter: self.segmenter.clone(),
            ort_dylib: self.ort_dylib.clone(),
            concurrency: self.vision_concurrency,
            ..Default::default()
        };
        if let Some(d) = &self.model_dir {
            v.model_dir = d.clone();
        }
        v
    }

    /// Resolve the configuration from the command line, the process environment (read
    /// here once) and the file.
    pub fn load(args: &ServeArgs) -> Result<Self, ConfigError> {
        let env = load::process_env();
        load::resolve(&load::Sources {
            file: args.config.as_deref(),
            env: &env,
            flags: load::Flags {
                addr: args.addr.clone(),
                data_dir: args.data_dir.clone(),
                role: args.role,
                allow_anonymous: args.allow_anonymous,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Config, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn a_misspelt_nested_key_is_an_error_naming_it() {
        let err = parse("[agent.geometry.consensus]\nmask_vote = false\n")
            .err()
            .map(|e| e.to_string());
        let msg = err.unwrap_or_default();
        assert!(msg.contains("mask_vote"), "{msg}");
        for text in [
            "[agent]\nimage_limit = 3\nbogus = 1\n",
            "[agent.geometry.support]\nwal_cut = false\n",
        ] {
            assert!(parse(text).is_err(), "accepted {text:?}");
        }
    }

    #[test]
    fn correct_nested_keys_are_read() {
        let cfg = parse("workers = 3\n[agent]\nimage_limit = 5\n[agent.geometry.consensus]\nmask_votes = false\n[agent.geometry.support]\nwall_cut = false\n")
            .expect("valid config");
        assert_eq!(cfg.workers, 3);
        assert_eq!(cfg.agent.image_limit, 5);
        assert!(!cfg.agent.geometry.consensus.mask_votes);
        assert!(!cfg.agent.geometry.support.wall_cut);
    }
}
