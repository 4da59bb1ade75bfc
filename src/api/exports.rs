//! Exports: a job's object points (PLY) and masks (PNG); a scene's points (PLY), frames
//! (cameras and detections) and frame images. The files are made by `jobs`; this module
//! only finds and serves them.

use axum::extract::{Path, Query, State};
use axum::http::{header, StatusCode};
use axum::response::IntoResponse;
use serde::{Deserialize, Serialize};

use super::auth::Caller;
use super::{ApiError, AppState};
use crate::jobs::exports::{voxel_mm, ExportError, FrameInfo};
use crate::jobs::{mask_artifact, OBJECT_PLY};
use axum::Extension;

const PLY: &str = "application/octet-stream";

impl From<ExportError> for ApiError {
    fn from(e: ExportError) -> Self {
        match e {
            ExportError::SceneNotFound(id) => ApiError::not_found("scene", &id),
            ExportError::BadVoxel(_) => ApiError::bad_request("invalid_voxel", e.to_string()),
            ExportError::Internal(d) => ApiError::internal(d),
            ExportError::Stopping => ApiError::unavailable("shutting_down", e.to_string()),
        }
    }
}

fn valid_id(id: &str) -> bool {
    !id.is_empty() && id.chars().all(|c| c.is_ascii_hexdigit() || c == '-')
}

/// A job's artifact file, or 404 naming what is missing (the job itself, or the file).
async fn job_file(
    state: &AppState,
    caller: &Caller,
    id: &str,
    name: &str,
    what: &str,
) -> Result<Vec<u8>, ApiError> {
    if !valid_id(id)
        || !state
            .store
            .get_job(id)
            .await?
            .is_some_and(|j| caller.sees(j.owner))
    {
        return Err(ApiError::not_found("job", id));
    }
    state
        .jobs
        .storage()
        .read_artifact(id, name)
        .await
        .map_err(|e| ApiError::internal(e.to_string()))?
        .ok_or_else(|| {
            ApiError::new(
                StatusCode::NOT_FOUND,
                "export_not_found",
                format!("job {id} has no {what} (it exists once the job has projected its mask)"),
            )
        })
}

/// The object's fused points: binary little-endian PLY (`x y z` float, `red green blue`
/// uchar), in the frame of the job's box.
#[utoipa::path(get, path = "/v1/jobs/{id}/object.ply", tag = "exports", params(("id" = String, Path)),
    responses((status = 200, content_type = "application/octet-stream", body = Vec<u8>, description = "binary PLY"),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn object_ply(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<impl IntoResponse, ApiError> {
    let bytes = job_file(&state, &caller, &id, OBJECT_PLY, "object points").await?;
    Ok((
        [
            (header::CONTENT_TYPE, PLY.to_string()),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"object-{id}.ply\""),
            ),
        ],
        bytes,
    ))
}

/// One view's mask (8-bit PNG, 255 inside) by its five-digit image id, e.g.
/// `masks/00012.png`: the chosen view and every other view the box was fused from.
#[utoipa::path(get, path = "/v1/jobs/{id}/masks/{frame}.png", tag = "exports",
    params(("id" = String, Path), ("frame" = String, Path, description = "five-digit image id of the trace")),
    responses((status = 200, content_type = "image/png", body = Vec<u8>),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn mask_png(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path((id, file)): Path<(String, String)>,
) -> Result<impl IntoResponse, ApiError> {
    let Some(frame) = file
        .strip_suffix(".png")
        .filter(|f| !f.is_empty() && f.chars().all(|c| c.is_ascii_digit()))
    else {
        return Err(ApiError::new(
            StatusCode::NOT_FOUND,
            "export_not_found",
            format!("{file:?} is not a mask name (masks/<five-digit image id>.png)"),
        ));
    };
    let bytes = job_file(
        &state,
        &caller,
        &id,
        &mask_artifact(frame),
        &format!("mask for image {frame}"),
    )
    .await?;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        ],
        bytes,
    ))
}

#[derive(Debug, Deserialize, utoipa::IntoParams)]
pub struct PointsParams {
    /// Voxel size in metres, 0.01..=1 (default 0.05).
    #[param(minimum = 0.01, maximum = 1.0)]
    pub voxel: Option<f64>,
}

/// The scene's points from every usable frame's depth, coloured and voxel-downsampled:
/// binary PLY in the frame of the jobs' boxes (axis-aligned when the scene has the matrix).
/// Computed once per scene and voxel size, then served from the cache.
#[utoipa::path(get, path = "/v1/scenes/{id}/points.ply", tag = "exports", params(("id" = String, Path), PointsParams),
    responses((status = 200, content_type = "application/octet-stream", body = Vec<u8>, description = "binary PLY"),
              (status = 400, body = super::Problem, content_type = "application/problem+json"),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn scene_points(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
    Query(p): Query<PointsParams>,
) -> Result<impl IntoResponse, ApiError> {
    let mm = voxel_mm(p.voxel)?;
    if !state
        .store
        .get_scene(&id)
        .await?
        .is_some_and(|s| caller.sees(s.owner))
    {
        return Err(ApiError::not_found("scene", &id));
    }
    let bytes = state.jobs.scene_points(&id, mm).await?;
    Ok((
        [
            (header::CONTENT_TYPE, PLY.to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"scene-{id}-{mm}mm.ply\""),
            ),
        ],
        bytes.as_ref().clone(),
    ))
}

#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct FrameList {
    pub frames: Vec<FrameInfo>,
}

/// Every frame's camera (position, viewing direction) and cached detections.
#[utoipa::path(get, path = "/v1/scenes/{id}/frames", tag = "exports", params(("id" = String, Path)),
    responses((status = 200, body = FrameList),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn scene_frames(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<axum::Json<FrameList>, ApiError> {
    if !state
        .store
        .get_scene(&id)
        .await?
        .is_some_and(|s| caller.sees(s.owner))
    {
        return Err(ApiError::not_found("scene", &id));
    }
    let frames = state.jobs.scene_frames(&id, &state.cfg.detector).await?;
    Ok(axum::Json(FrameList { frames }))
}

/// A frame's image (the half-size preview when indexing stored one), by five-digit image id.
#[utoipa::path(get, path = "/v1/scenes/{id}/frames/{frame}.jpg", tag = "exports",
    params(("id" = String, Path), ("frame" = String, Path, description = "five-digit image id")),
    responses((status = 200, content_type = "image/jpeg", body = Vec<u8>),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn frame_jpeg(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path((id, file)): Path<(String, String)>,
) -> Result<impl IntoResponse, ApiError> {
    let missing = || {
        ApiError::new(
            StatusCode::NOT_FOUND,
            "frame_not_found",
            format!("scene {id} has no frame {file:?}"),
        )
    };
    if !valid_id(&id)
        || !state
            .store
            .get_scene(&id)
            .await?
            .is_some_and(|s| caller.sees(s.owner))
    {
        return Err(ApiError::not_found("scene", &id));
    }
    let idx: usize = file
        .strip_suffix(".jpg")
        .filter(|f| !f.is_empty() && f.chars().all(|c| c.is_ascii_digit()))
        .and_then(|f| f.parse().ok())
        .ok_or_else(missing)?;
    let bytes = state
        .jobs
        .frame_jpeg(&id, idx)
        .await
        .map_err(|e| match e {
            crate::jobs::exports::ExportError::SceneNotFound(_) => {
                ApiError::not_found("scene", &id)
            }
            e => ApiError::internal(e.to_string()),
        })?
        .ok_or_else(missing)?;
    Ok(([(header::CONTENT_TYPE, "image/jpeg")], bytes))
}
