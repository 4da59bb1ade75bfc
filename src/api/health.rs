//! Liveness, readiness and metrics.

use axum::extract::State;
use axum::http::header;
use axum::response::IntoResponse;
use serde::Serialize;

use super::{ApiError, AppState};
use crate::metrics::StateLabels;
use crate::store::JobStatus;

#[derive(Serialize, utoipa::ToSchema)]
pub struct Health {
    pub status: String,
}

/// The process is up.
#[utoipa::path(get, path = "/healthz", tag = "health", responses((status = 200, body = Health)))]
pub async fn healthz() -> axum::Json<Health> {
    axum::Json(Health {
        status: "ok".into(),
    })
}

/// The database answers, every configured model is loaded and a job worker is alive.
#[utoipa::path(get, path = "/readyz", tag = "health", responses((status = 200, body = Health), (status = 503, body = super::Problem, content_type = "application/problem+json")))]
pub async fn readyz(State(state): State<AppState>) -> Result<axum::Json<Health>, ApiError> {
    if !state.store.ping().await {
        return Err(ApiError::unavailable(
            "database_unavailable",
            "the database does not answer",
        ));
    }
    let mut problems = state
        .readiness
        .read()
        .map(|r| r.problems.clone())
        .unwrap_or_default();
    let vlm = state.readiness.read().ok().and_then(|r| r.vlm.clone());
    if let Some(p) = vlm.and_then(|h| h.problem()) {
        problems.push(p);
    }
    if state.jobs.live_workers() == 0 {
        problems.push("no job worker is alive: queued jobs will not run".into());
    }
    if !problems.is_empty() {
        // The log at start-up holds the full reasons; the caller sees file names only.
        let detail = crate::jobs::redact::without_paths(&problems.join("; "));
        return Err(ApiError::unavailable("not_ready", detail));
    }
    Ok(axum::Json(Health {
        status: "ready".into(),
    }))
}

/// Prometheus text format.
#[utoipa::path(get, path = "/metrics", tag = "health", responses((status = 200, content_type = "text/plain", body = String)))]
pub async fn metrics(State(state): State<AppState>) -> Result<impl IntoResponse, ApiError> {
    let counts = state.store.count_jobs_by_status().await?;
    for s in JobStatus::ALL {
        let n = counts
            .iter()
            .find(|(k, _)| k == s.as_str())
            .map(|(_, n)| *n)
            .unwrap_or(0);
        state
            .metrics
            .jobs_by_state
            .get_or_create(&StateLabels {
                state: s.as_str().into(),
            })
            .set(n);
    }
    state
        .metrics
        .workers_alive
        .set(state.jobs.live_workers() as i64);
    Ok((
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        state.metrics.encode(),
    ))
}
