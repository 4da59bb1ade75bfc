//! Prometheus metrics: HTTP request durations, job durations, jobs by state (read from the
//! store at scrape time).

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::Registry;
use std::sync::Mutex;

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct HttpLabels {
    pub method: String,
    pub route: String,
    pub status: u16,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct OutcomeLabels {
    pub outcome: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct StateLabels {
    pub state: String,
}

pub struct Metrics {
    registry: Mutex<Registry>,
    pub http_duration: Family<HttpLabels, Histogram>,
    pub job_duration: Family<OutcomeLabels, Histogram>,
    pub jobs_by_state: Family<StateLabels, Gauge>,
    pub vlm_calls: Counter,
    /// Workers whose loop is running (set at scrape time).
    pub workers_alive: Gauge,
}

impl Default for Metrics {
    fn default() -> Self {
        let mut registry = Registry::with_prefix("grounder");
        let http_duration = Family::<HttpLabels, Histogram>::new_with_constructor(|| {
            Histogram::new(exponential_buckets(0.0005, 2.5, 14))
        });
        let job_duration = Family::<OutcomeLabels, Histogram>::new_with_constructor(|| {
            Histogram::new(exponential_buckets(0.05, 2.0, 14))
        });
        let jobs_by_state = Family::<StateLabels, Gauge>::default();
        let vlm_calls = Counter::default();
        let workers_alive = Gauge::default();
        registry.register(
            "workers_alive",
            "Job workers whose loop is running",
            workers_alive.clone(),
        );
        registry.register(
            "http_request_duration_seconds",
            "HTTP request latency by route and status",
            http_duration.clone(),
        );
        registry.register(
            "job_duration_seconds",
            "Wall time of finished grounding jobs by outcome",
            job_duration.clone(),
        );
        registry.register("jobs", "Jobs by state", jobs_by_state.clone());
        registry.register("vlm_calls", "VLM chat requests sent", vlm_calls.clone());
        Self {
            registry: Mutex::new(registry),
            http_duration,
            job_duration,
            jobs_by_state,
            vlm_calls,
            workers_alive,
        }
    }
}

impl Metrics {
    /// Prometheus text exposition.
    pub fn encode(&self) -> String {
        let mut out = String::new();
        if let Ok(reg) = self.registry.lock() {
            let _ = prometheus_client::encoding::text::encode(&mut out, &reg);
        }
        out
    }
}
