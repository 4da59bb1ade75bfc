//! Building and running the service: state, workers, listener, graceful shutdown.

use std::net::SocketAddr;
use std::sync::Arc;
use tokio::net::TcpListener;

use crate::api::{self, AppState, Readiness};
use crate::config::{Config, ServeArgs};
use crate::jobs::{Grounder, JobSystem, WorkerConfig};
use crate::metrics::Metrics;
use crate::store::Store;

/// A built, not yet serving application.
pub struct Application {
    listener: TcpListener,
    state: AppState,
}

impl Application {
    /// Open the store, recover interrupted jobs, bind the listener, start the workers.
    pub async fn build(cfg: Config) -> anyhow::Result<Self> {
        let store = Store::open(&cfg.data_dir).await?;
        let (requeued, failed) = store.recover_jobs(cfg.max_attempts).await?;
        if requeued + failed > 0 {
            tracing::info!(requeued, failed, "recovered jobs interrupted by the previous process");
        }
        // Leftovers of uploads interrupted by a crash.
        let _ = std::fs::remove_dir_all(cfg.data_dir.join("tmp"));
        let metrics = Arc::new(Metrics::default());
        let mut readiness = Readiness::default();
        let grounder = build_grounder(&cfg, &store, &mut readiness)?;
        let jobs = JobSystem::new(store.clone(), grounder, metrics.clone(), WorkerConfig { workers: cfg.workers, data_dir: cfg.data_dir.clone() });
        let listener = TcpListener::bind(&cfg.addr).await.map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", cfg.addr))?;
        let on_scene_stored = crate::jobs::indexing::hook(&cfg, store.clone(), jobs.clone(), &mut readiness);
        let state = AppState {
            cfg: Arc::new(cfg),
            store,
            jobs,
            metrics,
            readiness: Arc::new(std::sync::RwLock::new(readiness)),
            on_scene_stored,
        };
        crate::jobs::indexing::resume(&state.store, &state.on_scene_stored).await?;
        state.jobs.start();
        Ok(Self { listener, state })
    }

    pub fn local_addr(&self) -> anyhow::Result<SocketAddr> {
        Ok(self.listener.local_addr()?)
    }

    /// Serve until `shutdown` resolves; then stop workers, leaving running jobs queued.
    pub async fn run_until<F: std::future::Future<Output = ()> + Send + 'static>(self, shutdown: F) -> anyhow::Result<()> {
        let jobs = self.state.jobs.clone();
        let app = api::router(self.state);
        axum::serve(self.listener, app).with_graceful_shutdown(shutdown).await?;
        jobs.shutdown().await;
        Ok(())
    }
}

fn build_grounder(cfg: &Config, _store: &Store, _readiness: &mut Readiness) -> anyhow::Result<Arc<dyn Grounder>> {
    if cfg.pipeline.starts_with("test") {
        return Ok(Arc::new(crate::jobs::test_grounder::TestGrounder::from_spec(&cfg.pipeline)?));
    }
    anyhow::bail!("unknown pipeline {:?} (known: test, test:delay_ms=N)", cfg.pipeline)
}

/// `grounder serve`.
pub async fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let cfg = Config::load(&args)?;
    let app = Application::build(cfg).await?;
    let addr = app.local_addr()?;
    println!("listening on http://{addr}");
    app.run_until(shutdown_signal()).await
}

async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! { _ = ctrl_c => {}, _ = term => {} }
    tracing::info!("shutting down: running jobs will be resumed at next start");
}
