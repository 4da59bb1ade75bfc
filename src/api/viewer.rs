//! The viewer: static HTML/JS/CSS pages embedded in the binary (`assets/viewer/`), which
//! read the JSON API from the browser. three.js is vendored (no CDN, no build step).

use super::auth::Caller;
use axum::extract::{Path, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Extension;

use super::{ApiError, AppState};

const JOB_HTML: &str = include_str!("../../assets/viewer/job.html");
const SCENE_HTML: &str = include_str!("../../assets/viewer/scene.html");

/// (name, content type, bytes) of every file under `/v1/viewer/`.
const ASSETS: &[(&str, &str, &[u8])] = &[
    (
        "viewer.css",
        "text/css; charset=utf-8",
        include_bytes!("../../assets/viewer/viewer.css"),
    ),
    (
        "common.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../../assets/viewer/common.js"),
    ),
    (
        "points3d.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../../assets/viewer/points3d.js"),
    ),
    (
        "job.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../../assets/viewer/job.js"),
    ),
    (
        "scene.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../../assets/viewer/scene.js"),
    ),
    (
        "three.module.min.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../../assets/viewer/vendor/three/three.module.min.js"),
    ),
    (
        "OrbitControls.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../../assets/viewer/vendor/three/OrbitControls.js"),
    ),
    (
        "three-LICENSE.txt",
        "text/plain; charset=utf-8",
        include_bytes!("../../assets/viewer/vendor/three/LICENSE"),
    ),
];

fn valid_id(id: &str) -> bool {
    !id.is_empty() && id.chars().all(|c| c.is_ascii_hexdigit() || c == '-')
}

fn page(template: &str, id: &str) -> Response {
    // The id is checked to be hex digits and dashes, so it needs no escaping.
    let html = template.replace("{{ID}}", id);
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        html,
    )
        .into_response()
}

/// One job in a page: the query and analysis, the grids the VLM saw, every VLM exchange,
/// the chosen frame with its candidates and mask, the other views, a 3D view of the scene
/// with the box and the object's points, timings. Live while the job runs.
#[utoipa::path(get, path = "/v1/jobs/{id}/view", tag = "viewer", params(("id" = String, Path)),
    responses((status = 200, content_type = "text/html", body = String),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn job_page(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    if !valid_id(&id)
        || !state
            .store
            .get_job(&id)
            .await?
            .is_some_and(|j| caller.sees(j.owner))
    {
        return Err(ApiError::not_found("job", &id));
    }
    Ok(page(JOB_HTML, &id))
}

/// One scene in a page: frame thumbnails with detections, unusable frames marked, the
/// camera path and the scene's points in 3D, and the scene's jobs.
#[utoipa::path(get, path = "/v1/scenes/{id}/view", tag = "viewer", params(("id" = String, Path)),
    responses((status = 200, content_type = "text/html", body = String),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn scene_page(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    if !valid_id(&id)
        || !state
            .store
            .get_scene(&id)
            .await?
            .is_some_and(|s| caller.sees(s.owner))
    {
        return Err(ApiError::not_found("scene", &id));
    }
    Ok(page(SCENE_HTML, &id))
}

/// The viewer's scripts, style sheet and vendored libraries (with their licences).
#[utoipa::path(get, path = "/v1/viewer/{file}", tag = "viewer", params(("file" = String, Path)),
    responses((status = 200, content((String = "text/javascript"), (String = "text/css"), (String = "text/plain"))),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn asset(Path(file): Path<String>) -> Result<Response, ApiError> {
    let (name, ct, bytes) = ASSETS.iter().find(|(n, _, _)| *n == file).ok_or_else(|| {
        ApiError::new(
            StatusCode::NOT_FOUND,
            "asset_not_found",
            format!("the viewer has no file {file:?}"),
        )
    })?;
    // For work on the pages: GROUNDER_VIEWER_DIR=assets/viewer serves the scripts from
    // disk (not the vendored libraries), so a change needs no rebuild.
    if let Some(dir) = std::env::var_os("GROUNDER_VIEWER_DIR") {
        if let Ok(b) = tokio::fs::read(std::path::Path::new(&dir).join(name)).await {
            return Ok(([(header::CONTENT_TYPE, *ct)], b).into_response());
        }
    }
    Ok((
        [
            (header::CONTENT_TYPE, *ct),
            (header::CACHE_CONTROL, "public, max-age=3600"),
        ],
        *bytes,
    )
        .into_response())
}
