//! HTTP API: axum routes, problem+json errors, OpenAPI. Knows nothing of geometry.

pub mod auth;
pub mod capture;
pub mod conditional;
pub mod error;
pub mod events;
pub mod exports;
pub mod frames;
pub mod health;
pub mod idempotency;
mod job_schema;
pub mod jobs;
pub mod openapi;
pub mod rejection;
pub mod scenes;
pub mod spool;
pub mod viewer;

use axum::extract::{MatchedPath, Request, State};
use axum::middleware::Next;
use axum::response::Response;
use axum::routing::{get, post};
use axum::Router;
use std::sync::Arc;
use std::time::Instant;

use crate::config::Config;
use crate::jobs::JobSystem;
use crate::metrics::{HttpLabels, Metrics};
use crate::store::Store;

pub use error::{ApiError, Problem};

/// Readiness of optional components, filled at start-up.
#[derive(Debug, Clone, Default)]
pub struct Readiness {
    /// Problems that make the service not ready (e.g. a missing model file).
    pub problems: Vec<String>,
    /// Lasting problems the VLM client has seen (e.g. a model that cannot take images).
    pub vlm: Option<Arc<crate::vlm::VlmHealth>>,
}

/// Shared state of every handler.
#[derive(Clone)]
pub struct AppState {
    pub cfg: Arc<Config>,
    pub store: Store,
    pub jobs: JobSystem,
    pub metrics: Arc<Metrics>,
    pub readiness: Arc<std::sync::RwLock<Readiness>>,
    /// Hook run after a scene is stored (starts detector indexing); returns the initial status.
    pub on_scene_stored: crate::jobs::indexing::IndexHook,
    /// The detector reads ground-truth instance masks (oracle): scenes must carry them.
    pub detector_needs_instances: bool,
    /// API keys and anonymous access.
    pub auth: Arc<auth::Auth>,
    /// Slots of the upload bodies received at the same time (`max_concurrent_uploads`).
    pub uploads: Arc<tokio::sync::Semaphore>,
}

/// All routes.
pub fn router(state: AppState) -> Router {
    Router::new()
        .route("/v1/scenes", post(scenes::upload).get(scenes::list))
        .route("/v1/scenes/{id}", get(scenes::get).delete(scenes::delete))
        .route("/v1/scenes/{id}/index", post(scenes::reindex))
        // One route per path: the frame's image (GET) and its removal (DELETE) share it.
        .route(
            "/v1/scenes/{id}/frames",
            post(frames::append).get(exports::scene_frames),
        )
        .route(
            "/v1/scenes/{id}/frames/{name}",
            get(exports::frame_jpeg).delete(frames::remove),
        )
        .route("/v1/jobs", post(jobs::create).get(jobs::list))
        .route("/v1/jobs/{id}", get(jobs::get))
        .route("/v1/jobs/{id}/events", get(events::events))
        .route("/v1/jobs/{id}/cancel", post(jobs::cancel))
        .route("/v1/jobs/{id}/artifacts/{name}", get(jobs::artifact))
        .route("/v1/jobs/{id}/object.ply", get(exports::object_ply))
        .route("/v1/jobs/{id}/masks/{file}", get(exports::mask_png))
        .route("/v1/jobs/{id}/view", get(viewer::job_page))
        .route("/v1/scenes/{id}/points.ply", get(exports::scene_points))
        .route("/v1/scenes/{id}/view", get(viewer::scene_page))
        .route("/v1/viewer/{file}", get(viewer::asset))
        .route("/healthz", get(health::healthz))
        .route("/readyz", get(health::readyz))
        .route("/metrics", get(health::metrics))
        .route("/openapi.yaml", get(openapi::serve_yaml))
        .fallback(fallback)
        .layer(axum::middleware::from_fn(
            rejection::problems_for_rejections,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::authenticate,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            track_http,
        ))
        .with_state(state)
}

/// The routes of a `--role worker` process: health, readiness and metrics only (the API
/// is served by other replicas; anything else is a 404 problem naming the role).
pub fn health_router(state: AppState) -> Router {
    Router::new()
        .route("/healthz", get(health::healthz))
        .route("/readyz", get(health::readyz))
        .route("/metrics", get(health::metrics))
        .fallback(worker_fallback)
        .with_state(state)
}

async fn worker_fallback(req: Request) -> ApiError {
    ApiError::new(
        axum::http::StatusCode::NOT_FOUND,
        "route_not_found",
        format!(
            "no route for {} {}: this replica runs --role worker (health endpoints only)",
            req.method(),
            req.uri().path()
        ),
    )
}

async fn fallback(req: Request) -> ApiError {
    ApiError::new(
        axum::http::StatusCode::NOT_FOUND,
        "route_not_found",
        format!("no route for {} {}", req.method(), req.uri().path()),
    )
}

async fn track_http(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let started = Instant::now();
    let method = method_label(req.method()).to_string();
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map(|m| m.as_str().to_string())
        .unwrap_or_else(|| "unmatched".into());
    let resp = next.run(req).await;
    state
        .metrics
        .http_duration
        .get_or_create(&HttpLabels {
            method,
            route,
            status: resp.status().as_u16(),
        })
        .observe(started.elapsed().as_secs_f64());
    resp
}

/// A metric label for a request method: the standard ones, anything else `other` (a
/// client must not mint label values without bound).
fn method_label(m: &axum::http::Method) -> &'static str {
    use axum::http::Method;
    match *m {
        Method::GET => "GET",
        Method::POST => "POST",
        Method::PUT => "PUT",
        Method::DELETE => "DELETE",
        Method::PATCH => "PATCH",
        Method::HEAD => "HEAD",
        Method::OPTIONS => "OPTIONS",
        _ => "other",
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn unknown_methods_share_one_metric_label() {
        use axum::http::Method;
        assert_eq!(super::method_label(&Method::GET), "GET");
        assert_eq!(super::method_label(&Method::DELETE), "DELETE");
        let odd = Method::from_bytes(b"XYZZY123").expect("a token");
        assert_eq!(super::method_label(&odd), "other");
        assert_eq!(super::method_label(&Method::TRACE), "other");
    }
}
