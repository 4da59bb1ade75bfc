//! Building and running the service: state, workers, listener, graceful shutdown.

use std::net::SocketAddr;
use std::sync::Arc;
use tokio::net::TcpListener;

use crate::agent::VlmGrounder;
use crate::api::{self, AppState, Readiness};
use crate::config::{Config, ServeArgs};
use crate::jobs::{Grounder, JobSystem, WorkerConfig};
use crate::metrics::Metrics;
use crate::store::{Claim, Store};
use crate::vision::Detector;
use crate::vlm::prompts::Prompts;
use crate::vlm::VlmClient;

/// A built, not yet serving application.
pub struct Application {
    listener: TcpListener,
    state: AppState,
}

/// Whether the service may answer without keys: on loopback, or when told to.
fn anonymous_allowed(addr: &SocketAddr, allow_anonymous: bool) -> bool {
    allow_anonymous || addr.ip().is_loopback()
}

impl Application {
    /// Open the store, recover interrupted jobs, bind the listener, start the workers.
    pub async fn build(cfg: Config) -> anyhow::Result<Self> {
        Self::build_with_env(cfg, &crate::config::load::process_env()).await
    }

    /// [`Self::build`] with `env` in place of the process environment for the settings
    /// read from outside the configuration (the `AWS_*` variables of an `s3://` storage).
    pub async fn build_with_env(cfg: Config, env: &[(String, String)]) -> anyhow::Result<Self> {
        let store = Store::open_config(&cfg).await?;
        if store.pg() {
            // Alive from the start: what this replica holds is never taken as a dead one's.
            store.heartbeat().await?;
        }
        let (requeued, failed) = store.recover_jobs(cfg.max_attempts).await?;
        if requeued + failed > 0 {
            tracing::info!(
                requeued,
                failed,
                "recovered jobs interrupted by the previous process"
            );
        }
        let storage = crate::storage::Storage::open_with(
            &cfg.storage,
            &cfg.data_dir,
            cfg.storage_cache_mb << 20,
            env,
            &cfg.remote_limits(),
        )
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))?;
        if let Some(url) = storage.remote_url() {
            tracing::info!(
                cached_mb = storage.cached_bytes() >> 20,
                "scene files and artifacts live in {url}"
            );
        }
        // One process per SQLite database: no request of the previous process is still in
        // flight, and leftovers of uploads, imports and deletes interrupted by a crash are
        // its own. On PostgreSQL other replicas may be mid-request or mid-import right now:
        // only dead replicas' keys and rows go, and files only once settled (see
        // docs/scale-out.md).
        let mode = if store.pg() {
            store.idempotency_release_dead().await?;
            crate::jobs::sweep::Mode::Shared {
                grace: std::time::Duration::from_secs(cfg.sweep_grace_secs),
            }
        } else {
            store.idempotency_release_in_flight().await?;
            crate::jobs::sweep::Mode::Alone
        };
        let swept = crate::jobs::sweep::reconcile(&store, &cfg.data_dir, &storage, mode).await?;
        if !swept.is_empty() {
            tracing::info!(?swept, "cleaned up after stopped processes");
        }
        let metrics = Arc::new(Metrics::default());
        let mut readiness = Readiness::default();
        let detector = load_detector(&cfg)?;
        let grounder = build_grounder(&cfg, detector.clone(), &mut readiness)?;
        let jobs = JobSystem::new(
            store.clone(),
            grounder,
            metrics.clone(),
            storage,
            WorkerConfig {
                scene_cache_bytes: cfg.scene_cache_mb << 20,
                tile_cache_bytes: cfg.tile_cache_mb << 20,
                max_memory_mb: cfg.max_memory_mb,
                job_memory_mb: cfg.job_memory_mb,
                max_concurrent_indexing: cfg.max_concurrent_indexing,
                job_retention: (cfg.job_retention_days > 0.0).then(|| {
                    std::time::Duration::from_secs_f64(
                        (cfg.job_retention_days * 86_400.0).min(1e12),
                    )
                }),
                max_attempts: cfg.max_attempts,
                claim_pause: std::time::Duration::from_millis(cfg.test_claim_pause_ms),
                ..WorkerConfig::new(cfg.workers, cfg.data_dir.clone())
            },
        );
        let listener = TcpListener::bind(&cfg.addr)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", cfg.addr))?;
        let bound = listener.local_addr()?;
        let anonymous = anonymous_allowed(&bound, cfg.allow_anonymous);
        if !store.any_active_key().await? {
            if !anonymous {
                anyhow::bail!(
                    "refusing to listen on {bound} without API keys: anyone reaching it would see every scene and job. \
                     Create a key with `grounder keys create --name NAME`, or pass --allow-anonymous"
                );
            }
            if !bound.ip().is_loopback() {
                tracing::warn!("no API keys and --allow-anonymous: anyone reaching {bound} can use the service");
                eprintln!("warning: serving anonymously on {bound} (--allow-anonymous): anyone reaching it sees every scene and job");
            }
        }
        let needs_instances = detector.as_ref().is_some_and(|d| d.needs_instances());
        let candidates =
            cfg.agent
                .candidates
                .enabled
                .then(|| crate::jobs::indexing::CandidateSetup {
                    params: cfg.agent.candidates.clone(),
                    layout: cfg.agent.geometry.layout.clone(),
                });
        let indexer = crate::jobs::indexing::Indexer::new(
            cfg.detector.clone(),
            detector,
            candidates,
            store.clone(),
            jobs.clone(),
        );
        let on_scene_stored = indexer.hook();
        let uploads = Arc::new(tokio::sync::Semaphore::new(
            cfg.max_concurrent_uploads.max(1),
        ));
        let state = AppState {
            cfg: Arc::new(cfg),
            store,
            jobs,
            metrics,
            readiness: Arc::new(std::sync::RwLock::new(readiness)),
            on_scene_stored,
            detector_needs_instances: needs_instances,
            auth: Arc::new(api::auth::Auth::new(anonymous)),
            uploads,
        };
        // Indexing left by a stopped process is resumed by any replica, whatever its role:
        // alone on SQLite all of it now; on PostgreSQL whatever no live indexer holds,
        // now and every third of the lease (with the other replica housekeeping).
        let role = state.cfg.role;
        let max_index_attempts = state.cfg.max_index_attempts;
        if state.store.pg() {
            crate::jobs::indexing::resume(&indexer, max_index_attempts, Claim::TakeOver).await?;
            state.jobs.spawn_background(crate::jobs::replicas::run(
                state.store.clone(),
                state.jobs.storage().clone(),
                indexer,
                max_index_attempts,
                state.jobs.stopping(),
            ));
        } else {
            crate::jobs::indexing::resume(&indexer, max_index_attempts, Claim::Force).await?;
        }
        if role.runs_workers() {
            state.jobs.start();
        }
        tracing::info!(?role, backend = ?state.store.backend, "service built");
        Ok(Self { listener, state })
    }

    /// The job system (tests reach its hooks through it).
    pub fn jobs(&self) -> JobSystem {
        self.state.jobs.clone()
    }

    pub fn local_addr(&self) -> anyhow::Result<SocketAddr> {
        Ok(self.listener.local_addr()?)
    }

    /// Serve until `shutdown` resolves; then stop workers, leaving running jobs queued.
    pub async fn run_until<F: std::future::Future<Output = ()> + Send + 'static>(
        self,
        shutdown: F,
    ) -> anyhow::Result<()> {
        let jobs = self.state.jobs.clone();
        let hooks_stop = tokio_util::sync::CancellationToken::new();
        let dispatcher = crate::jobs::webhooks::Dispatcher::new(
            self.state.store.clone(),
            self.state.cfg.webhook_allow_private,
        )?;
        let hooks = tokio::spawn(dispatcher.run(hooks_stop.clone()));
        let closing = self.state.store.events.closing.clone();
        let app = if self.state.cfg.role.serves_api() {
            api::router(self.state)
        } else {
            api::health_router(self.state)
        };
        let served = axum::serve(self.listener, app)
            .with_graceful_shutdown(async move {
                shutdown.await;
                closing.cancel();
            })
            .await;
        hooks_stop.cancel();
        let _ = hooks.await;
        served?;
        jobs.shutdown().await;
        Ok(())
    }
}

/// Load the configured detector once (shared by indexing and the pipeline). A detector
/// that cannot load stops start-up: every upload's indexing and every job would fail.
fn load_detector(cfg: &Config) -> anyhow::Result<Option<Arc<dyn Detector>>> {
    if cfg.detector == "none" {
        return Ok(None);
    }
    crate::vision::build_detector(&cfg.detector, &cfg.vision())
        .map(Some)
        .map_err(|e| anyhow::anyhow!("detector {:?} cannot be loaded: {e:#}", cfg.detector))
}

/// A pipeline that fails every job because a component could not be loaded.
struct Unavailable(String);

impl Grounder for Unavailable {
    fn ground(
        &self,
        _ctx: crate::jobs::JobContext,
    ) -> futures::future::BoxFuture<'_, Result<crate::jobs::GroundingOutput, crate::jobs::JobFailure>>
    {
        Box::pin(async move {
            Err(crate::jobs::JobFailure::new(
                "pipeline_unavailable",
                self.0.clone(),
            ))
        })
    }
}

fn build_grounder(
    cfg: &Config,
    detector: Option<Arc<dyn Detector>>,
    readiness: &mut Readiness,
) -> anyhow::Result<Arc<dyn Grounder>> {
    if cfg.pipeline.starts_with("test") {
        return Ok(Arc::new(
            crate::jobs::test_grounder::TestGrounder::from_spec(&cfg.pipeline)?,
        ));
    }
    if cfg.pipeline != "vlm" {
        anyhow::bail!(
            "unknown pipeline {:?} (known: vlm, test, test:delay_ms=N)",
            cfg.pipeline
        );
    }
    if let Some(missing) = vlm_missing(&cfg.vlm.clone().unwrap_or_default()) {
        tracing::warn!("{missing}");
        readiness.problems.push(missing);
    }
    match build_vlm_grounder(cfg, detector) {
        Ok(g) => {
            let g = Arc::new(g);
            readiness.vlm = Some(g.client.health());
            // Ask the server about itself now, so that /readyz reports a model that is
            // not served or cannot take images before the first job finds out.
            let probe = g.clone();
            tokio::spawn(async move {
                probe.client.server_info().await;
            });
            Ok(g)
        }
        Err(e) => {
            let msg = format!("the grounding pipeline cannot start: {e:#}");
            tracing::error!("{msg}");
            readiness.problems.push(msg.clone());
            Ok(Arc::new(Unavailable(msg)))
        }
    }
}

/// What the VLM settings lack for a job to get an answer: a hosted endpoint needs a key,
/// and without a key the base URL must name a local server.
fn vlm_missing(vlm: &crate::vlm::VlmConfig) -> Option<String> {
    if vlm.base_url.trim().is_empty() {
        return Some("no VLM base URL is set (vlm.base_url, GROUNDER_VLM_BASE_URL)".to_string());
    }
    if vlm.api_key.is_empty() && vlm.base_url == crate::vlm::config::DEFAULT_BASE_URL {
        return Some(format!(
            "no VLM API key is set for {} (vlm.api_key, GROUNDER_VLM_API_KEY or OPENAI_API_KEY), \
             and no other base URL (vlm.base_url, GROUNDER_VLM_BASE_URL) names a server without keys",
            vlm.base_url
        ));
    }
    None
}

fn build_vlm_grounder(
    cfg: &Config,
    detector: Option<Arc<dyn Detector>>,
) -> anyhow::Result<VlmGrounder> {
    let detector = detector.ok_or_else(|| {
        anyhow::anyhow!(
            "no detector is loaded (GROUNDER_DETECTOR={:?})",
            cfg.detector
        )
    })?;
    let segmenter = crate::vision::build_segmenter(&cfg.segmenter, &cfg.vision())?;
    let prompts =
        Prompts::load(cfg.prompts_dir.as_deref()).map_err(|e| anyhow::anyhow!("prompts: {e}"))?;
    let client = VlmClient::new(cfg.vlm.clone().unwrap_or_default())
        .map_err(|e| anyhow::anyhow!("VLM client: {e}"))?;
    Ok(VlmGrounder::new(
        client,
        prompts,
        detector,
        cfg.detector.clone(),
        segmenter,
        cfg.agent.clone(),
    )
    .with_tile_cache(cfg.tile_cache_mb.saturating_mul(1 << 20)))
}

/// `grounder serve`.
pub async fn serve(args: ServeArgs) -> anyhow::Result<()> {
    // Listen for SIGTERM and Ctrl-C before anything runs: a stop that comes while the
    // service starts (the address printed, a job already claimed) is then graceful too,
    // where it would otherwise kill the process or be lost.
    let mut stop = StopSignals::listen();
    let cfg = Config::load(&args)?;
    // A stop during start-up ends it there, as a kill would (everything start-up does is
    // resumed by the next start).
    let app = tokio::select! {
        app = Application::build(cfg) => app?,
        () = stop.recv() => {
            tracing::info!("stopped while starting");
            return Ok(());
        }
    };
    let addr = app.local_addr()?;
    println!("listening on http://{addr}");
    app.run_until(async move {
        stop.recv().await;
        tracing::info!(
            "shutting down: running jobs will be resumed at next start (a second stop signal ends the process at once)"
        );
        // The graceful stop waits for the requests in flight (a slow upload, say); a second
        // signal does not wait: it ends the process as a kill would, and the next start
        // resumes what was running.
        tokio::spawn(async move {
            stop.recv().await;
            tracing::warn!("a second stop signal: exiting now");
            std::process::exit(1);
        });
    })
    .await
}

/// The process's stop signals, listened for from the moment this is made.
struct StopSignals {
    #[cfg(unix)]
    term: Option<tokio::signal::unix::Signal>,
    #[cfg(unix)]
    int: Option<tokio::signal::unix::Signal>,
}

impl StopSignals {
    fn listen() -> Self {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{signal, SignalKind};
            // A handler that cannot be installed must not end the service: log it and
            // wait on the other signal (or forever).
            let listen = |kind: SignalKind, name: &str| match signal(kind) {
                Ok(s) => Some(s),
                Err(e) => {
                    tracing::error!("cannot listen for {name}, serving on: {e}");
                    None
                }
            };
            Self {
                term: listen(SignalKind::terminate(), "SIGTERM"),
                int: listen(SignalKind::interrupt(), "Ctrl-C"),
            }
        }
        #[cfg(not(unix))]
        Self {}
    }

    /// The next stop signal (pending forever when none could be listened for): one listener
    /// serves start-up, the graceful stop and the second signal.
    async fn recv(&mut self) {
        #[cfg(unix)]
        {
            async fn next(s: &mut Option<tokio::signal::unix::Signal>) {
                match s {
                    Some(s) => {
                        s.recv().await;
                    }
                    None => std::future::pending::<()>().await,
                }
            }
            tokio::select! { _ = next(&mut self.term) => {}, _ = next(&mut self.int) => {} }
        }
        #[cfg(not(unix))]
        if let Err(e) = tokio::signal::ctrl_c().await {
            tracing::error!("cannot listen for Ctrl-C, serving on: {e}");
            std::future::pending::<()>().await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::vlm_missing;
    use crate::vlm::{ApiKey, VlmConfig};

    #[test]
    fn readiness_names_a_missing_vlm_key_or_base_url() {
        let hosted = VlmConfig::default();
        let msg = vlm_missing(&hosted).unwrap_or_default();
        assert!(msg.contains("GROUNDER_VLM_API_KEY"), "{msg}");
        let keyed = VlmConfig {
            api_key: ApiKey::new("sk-x"),
            ..VlmConfig::default()
        };
        assert_eq!(vlm_missing(&keyed), None);
        let local = VlmConfig {
            base_url: "http://127.0.0.1:8000/v1".into(),
            ..VlmConfig::default()
        };
        assert_eq!(vlm_missing(&local), None);
        let empty = VlmConfig {
            base_url: " ".into(),
            ..keyed
        };
        assert!(vlm_missing(&empty).unwrap_or_default().contains("base URL"));
    }
}
