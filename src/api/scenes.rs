//! `/v1/scenes`: upload, list, get, delete.

use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::IntoResponse;
use futures::StreamExt;
use serde::Serialize;
use tokio::io::AsyncWriteExt;

use super::{ApiError, AppState};
use crate::jobs::ingest::{prepare_scene, Cleanup};
use crate::scene::archive::Limits;
use crate::store::SceneRecord;

#[derive(Serialize, utoipa::ToSchema)]
pub struct SceneList {
    pub scenes: Vec<SceneRecord>,
}

/// Upload a scene archive (tar, tar.gz or zip of one FORMATS §1 scene directory).
#[utoipa::path(post, path = "/v1/scenes", tag = "scenes",
    request_body(content = Vec<u8>, description = "Scene archive", content_type = "application/x-tar"),
    responses(
        (status = 201, body = SceneRecord, headers(("Location" = String, description = "URL of the new scene"))),
        (status = 400, body = super::Problem, content_type = "application/problem+json"),
        (status = 413, body = super::Problem, content_type = "application/problem+json"),
        (status = 415, body = super::Problem, content_type = "application/problem+json"),
        (status = 422, body = super::Problem, content_type = "application/problem+json")))]
pub async fn upload(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> Result<impl IntoResponse, ApiError> {
    let limit = state.cfg.max_upload_bytes;
    let too_large = || {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "body_too_large",
            format!("the upload exceeds the limit of {limit} bytes"),
        )
    };
    if let Some(len) = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
    {
        if len > limit {
            return Err(too_large());
        }
    }
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string);
    let id = uuid::Uuid::now_v7().to_string();
    let tmp = state.cfg.data_dir.join("tmp");
    tokio::fs::create_dir_all(&tmp)
        .await
        .map_err(|e| ApiError::internal(format!("cannot create temp dir: {e}")))?;
    let upload_path = tmp.join(format!("{id}.upload"));
    let _upload_guard = Cleanup(Some(upload_path.clone()));

    // Spool the body to disk, counting bytes.
    let mut file = tokio::fs::File::create(&upload_path)
        .await
        .map_err(|e| ApiError::internal(format!("cannot spool upload: {e}")))?;
    let mut stream = body.into_data_stream();
    let mut total: u64 = 0;
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| {
            ApiError::bad_request(
                "body_read_failed",
                format!("the upload could not be read to the end: {e}"),
            )
        })?;
        total += chunk.len() as u64;
        if total > limit {
            return Err(too_large());
        }
        file.write_all(&chunk)
            .await
            .map_err(|e| ApiError::internal(format!("cannot spool upload: {e}")))?;
    }
    file.flush()
        .await
        .map_err(|e| ApiError::internal(format!("cannot spool upload: {e}")))?;
    drop(file);

    let limits = Limits {
        max_bytes: state.cfg.max_unpacked_bytes,
        max_files: state.cfg.max_archive_files,
    };
    let work_dir = tmp.join(&id);
    let scene_dir = state.jobs.scene_dir(&id);
    let (up, sd) = (upload_path.clone(), scene_dir.clone());
    let scene = tokio::task::spawn_blocking(move || {
        prepare_scene(&up, content_type.as_deref(), &work_dir, &sd, limits)
    })
    .await
    .map_err(|e| ApiError::internal(format!("import task failed: {e}")))??;

    if state.detector_needs_instances && !scene.frames.iter().any(|f| f.instance_path.is_some()) {
        let _ = std::fs::remove_dir_all(&scene_dir);
        return Err(ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "instance_masks_required", format!("the configured detector {:?} reads ground-truth instance masks (instance/<frame>.png + instance/labels.json) and this scene has none", state.cfg.detector)));
    }
    let detector = (state.cfg.detector != "none").then_some(state.cfg.detector.as_str());
    let status = if detector.is_some() && scene.frames.iter().any(|f| f.usable) {
        "indexing"
    } else {
        "ready"
    };
    let mut scene_guard = Cleanup(Some(scene_dir));
    state
        .store
        .insert_scene(
            &id,
            &scene,
            status,
            detector.filter(|_| status == "indexing"),
        )
        .await?;
    scene_guard.disarm();
    // Read the record before indexing starts, so the answer shows the scene as stored,
    // not a state a fast indexer reached meanwhile.
    let record = state.store.get_scene(&id).await;
    if status == "indexing" {
        (state.on_scene_stored)(id.clone());
    } else {
        state.jobs.wake();
        state.jobs.warm_scene_points(&id);
    }
    let record = record?.ok_or_else(|| ApiError::internal("scene vanished after insert"))?;
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, format!("/v1/scenes/{id}"))],
        axum::Json(record),
    ))
}

/// List scenes.
#[utoipa::path(get, path = "/v1/scenes", tag = "scenes", responses((status = 200, body = SceneList)))]
pub async fn list(State(state): State<AppState>) -> Result<axum::Json<SceneList>, ApiError> {
    Ok(axum::Json(SceneList {
        scenes: state.store.list_scenes().await?,
    }))
}

/// One scene.
#[utoipa::path(get, path = "/v1/scenes/{id}", tag = "scenes", params(("id" = String, Path)),
    responses((status = 200, body = SceneRecord), (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn get(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<axum::Json<SceneRecord>, ApiError> {
    state
        .store
        .get_scene(&id)
        .await?
        .map(axum::Json)
        .ok_or_else(|| ApiError::not_found("scene", &id))
}

/// Delete a scene and its files (409 while a job on it runs; queued jobs are canceled).
#[utoipa::path(delete, path = "/v1/scenes/{id}", tag = "scenes", params(("id" = String, Path)),
    responses((status = 204), (status = 404, body = super::Problem, content_type = "application/problem+json"),
              (status = 409, body = super::Problem, content_type = "application/problem+json")))]
pub async fn delete(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    if state.store.get_scene(&id).await?.is_none() {
        return Err(ApiError::not_found("scene", &id));
    }
    if !state.store.delete_scene_if_idle(&id).await? {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "scene_busy",
            format!("scene {id} has a running job; cancel it or wait"),
        ));
    }
    state.jobs.forget_scene(&id);
    let dir = state.jobs.scene_dir(&id);
    let _ = tokio::fs::remove_dir_all(&dir).await;
    Ok(StatusCode::NO_CONTENT)
}

/// Run the configured detector over the scene again (e.g. after changing detector); the
/// scene is `indexing` until done and jobs on it wait.
#[utoipa::path(post, path = "/v1/scenes/{id}/index", tag = "scenes", params(("id" = String, Path)),
    responses((status = 202, body = SceneRecord), (status = 404, body = super::Problem, content_type = "application/problem+json"),
              (status = 409, body = super::Problem, content_type = "application/problem+json")))]
pub async fn reindex(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<(StatusCode, axum::Json<SceneRecord>), ApiError> {
    let scene = state
        .store
        .get_scene(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("scene", &id))?;
    if scene.status == "indexing" {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "scene_indexing",
            format!("scene {id} is being indexed already"),
        ));
    }
    if state.cfg.detector == "none" {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "no_detector",
            "the service runs without a detector (detector = \"none\")",
        ));
    }
    let usable = scene.frames as usize - scene.unusable_frames.len();
    state
        .store
        .reset_index(&id, &state.cfg.detector, usable)
        .await?;
    (state.on_scene_stored)(id.clone());
    let record = state
        .store
        .get_scene(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("scene", &id))?;
    Ok((StatusCode::ACCEPTED, axum::Json(record)))
}
