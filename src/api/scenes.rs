//! `/v1/scenes`: upload, list, get, delete.

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Extension;
use serde::Serialize;

use super::auth::Caller;
use super::capture::CaptureParams;
use super::spool::{check_indexing_room, spool, Spooled};
use super::{conditional, idempotency, ApiError, AppState};
use crate::jobs::ingest::{prepare_scene, Cleanup};
use crate::scene::archive::Limits;
use crate::store::SceneRecord;

#[derive(Serialize, utoipa::ToSchema)]
pub struct SceneList {
    pub scenes: Vec<SceneRecord>,
}

/// Upload a scene: a tar, tar.gz or zip archive of one FORMATS §1 scene directory or of
/// a capture (`.sens`, TUM RGB-D, nerfstudio, ARKitScenes raw; detected or named with
/// `format`), or a raw ScanNet `.sens` body (`Content-Type: application/octet-stream`).
#[utoipa::path(post, path = "/v1/scenes", tag = "scenes", params(CaptureParams),
    request_body(content = Vec<u8>, description = "Scene archive (tar, tar.gz or zip in the layout of FORMATS.md) or raw .sens", content_type = "application/x-tar"),
    responses(
        (status = 201, body = SceneRecord, headers(("Location" = String, description = "URL of the new scene"))),
        (status = 400, body = super::Problem, content_type = "application/problem+json"),
        (status = 401, body = super::Problem, content_type = "application/problem+json"),
        (status = 408, body = super::Problem, content_type = "application/problem+json", description = "upload_timeout: the body stalled (upload_idle_timeout_secs) or took too long (upload_timeout_secs)"),
        (status = 409, body = super::Problem, content_type = "application/problem+json", description = "idempotency_key_in_use"),
        (status = 413, body = super::Problem, content_type = "application/problem+json", description = "body_too_large, archive_too_large, image_too_large or scene_too_large (max_scene_pixels)"),
        (status = 415, body = super::Problem, content_type = "application/problem+json"),
        (status = 422, body = super::Problem, content_type = "application/problem+json", description = "The scene is invalid, or idempotency_key_reused"),
        (status = 429, body = super::Problem, content_type = "application/problem+json", headers(("Retry-After" = u64, description = "Seconds"))),
        (status = 503, body = super::Problem, content_type = "application/problem+json", description = "too_many_uploads (max_concurrent_uploads) or indexing_busy (max_queued_indexing)", headers(("Retry-After" = u64, description = "Seconds"))),
        (status = 507, body = super::Problem, content_type = "application/problem+json", description = "insufficient_storage: the upload would cut into min_free_disk_mb")),
    params(("Idempotency-Key" = Option<String>, Header, nullable = false, max_length = 255, pattern = "^[ -~]*[!-~][ -~]*$", description = "Makes retries safe: the same key and body within 24 h replay the first answer (1 to 255 printable ASCII characters, not all spaces)")),
    security((), ("bearer" = [])))]
pub async fn upload(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Query(params): Query<CaptureParams>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let capture = params.to_capture()?;
    let idem_key = idempotency::key_of(&headers)?;
    let used = match (caller.key_id, caller.max_scene_bytes) {
        (Some(k), Some(_)) => state.store.scene_bytes_of(k).await?,
        _ => 0,
    };
    let over_quota = |bytes: u64| {
        caller
            .max_scene_bytes
            .filter(|max| used.saturating_add(bytes as i64) > *max)
            .map(|max| {
                ApiError::too_many(
                    "quota_exceeded",
                    format!("this key may store at most {max} bytes of scenes ({used} stored); delete scenes to make room"),
                    QUOTA_RETRY_SECS,
                )
            })
    };
    check_indexing_room(&state)?;
    let id = uuid::Uuid::now_v7().to_string();
    let upload = spool(&state, &headers, body, &id, &over_quota).await?;
    let hash = upload.hash.clone();
    let st = state.clone();
    let owner = caller.key_id;
    // Without an Idempotency-Key nobody could learn the outcome once the client is gone:
    // the import is then undone instead of leaving a scene nobody knows of.
    let client_gone = tokio_util::sync::CancellationToken::new();
    let _gone_on_drop = idem_key.is_none().then(|| client_gone.clone().drop_guard());
    idempotency::run(
        &state,
        &caller,
        "POST /v1/scenes",
        idem_key,
        &hash,
        async move {
            // Its own task: a client going away never stops an import half-way.
            tokio::spawn(import(st, owner, id, upload, capture, client_gone))
                .await
                .map_err(|e| ApiError::internal(format!("import task failed: {e}")))?
        },
    )
    .await
}

/// Unpack, validate and store a spooled upload. The scene's row is written first, hidden
/// (`importing`); then its files, validated in a staging folder, are renamed into place in
/// one step; then the row turns `indexing` or `ready`. Any failure after the row exists
/// removes files and row; a crash leaves a hidden row that the start-up sweep removes.
async fn import(
    state: AppState,
    owner: Option<i64>,
    id: String,
    upload: Spooled,
    capture: crate::jobs::ingest::Capture,
    client_gone: tokio_util::sync::CancellationToken,
) -> Result<Response, ApiError> {
    let tmp = state.cfg.data_dir.join("tmp");
    let limits = limits(&state);
    let work_dir = tmp.join(&id);
    let staged = tmp.join(format!("{id}.scene"));
    let _staged_guard = Cleanup(Some(staged.clone()));
    let (up, sd, ct) = (
        upload.path.clone(),
        staged.clone(),
        upload.content_type.clone(),
    );
    let scene = tokio::task::spawn_blocking(move || {
        prepare_scene(&up, ct.as_deref(), &work_dir, &sd, limits, &capture)
    })
    .await
    .map_err(|e| ApiError::internal(format!("import task failed: {e}")))??;

    if state.detector_needs_instances && !scene.frames.iter().any(|f| f.instance_path.is_some()) {
        return Err(ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "instance_masks_required", format!("the configured detector {:?} reads ground-truth instance masks (instance/<frame>.png + instance/labels.json) and this scene has none", state.cfg.detector)));
    }
    let detector = (state.cfg.detector != "none").then_some(state.cfg.detector.as_str());
    let status = if detector.is_some() && scene.frames.iter().any(|f| f.usable) {
        "indexing"
    } else {
        "ready"
    };
    if client_gone.is_cancelled() {
        return Err(gone());
    }
    state
        .store
        .insert_scene(
            &id,
            &scene,
            "importing",
            detector.filter(|_| status == "indexing"),
            owner,
            upload.bytes,
        )
        .await?;
    drop(upload);
    test_pause(&state).await;
    let scene_dir = state.jobs.scene_dir(&id);
    let placed = place(&staged, &scene_dir).await;
    test_pause(&state).await;
    // With a bucket, the files are uploaded before the row turns visible.
    let stored = match placed {
        Err(e) => Err(ApiError::internal(format!("cannot store the scene: {e}"))),
        Ok(()) => state
            .jobs
            .storage()
            .store_scene(&id)
            .await
            .map_err(|e| ApiError::internal(format!("cannot store the scene: {e}"))),
    };
    let placed = match stored {
        Err(e) => Err(e),
        Ok(_) if client_gone.is_cancelled() => Err(gone()),
        Ok(_pin) => match state.store.publish_scene(&id, status).await {
            Ok(true) => Ok(()),
            Ok(false) => Err(ApiError::internal("the scene was removed while importing")),
            Err(e) => Err(e.into()),
        },
    };
    if let Err(e) = placed {
        if let Err(u) =
            crate::jobs::sweep::finish_removal(&state.store, state.jobs.storage(), &id).await
        {
            tracing::error!(scene = %id, "cannot undo a failed import (the next start will): {u:#}");
        }
        return Err(e);
    }
    // Read the record before indexing starts, so the answer shows the scene as stored,
    // not a state a fast indexer reached meanwhile.
    let record = state.store.get_scene(&id).await;
    if status == "indexing" {
        (state.on_scene_stored)(id.clone(), 0);
    } else {
        state.jobs.wake();
        state.jobs.warm_scene_points(&id);
    }
    let record = record?.ok_or_else(|| ApiError::internal("scene vanished after insert"))?;
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, format!("/v1/scenes/{id}"))],
        axum::Json(record),
    )
        .into_response())
}

/// Fault injection for the crash tests (`test_step_pause_ms`; no pause in service).
pub(super) async fn test_pause(state: &AppState) {
    let ms = state.cfg.test_step_pause_ms;
    if ms > 0 {
        tokio::time::sleep(std::time::Duration::from_millis(ms)).await;
    }
}

/// Move a staged scene folder into place in one rename (a copy when a `file://` storage
/// is on another volume than the data dir's spool).
async fn place(staged: &std::path::Path, scene_dir: &std::path::Path) -> std::io::Result<()> {
    if let Some(parent) = scene_dir.parent() {
        tokio::fs::create_dir_all(parent).await?;
    }
    let (from, to) = (staged.to_path_buf(), scene_dir.to_path_buf());
    tokio::task::spawn_blocking(move || crate::storage::move_path(&from, &to))
        .await
        .map_err(std::io::Error::other)?
}

/// The answer nobody reads: the client disconnected before its scene was stored.
fn gone() -> ApiError {
    ApiError::bad_request(
        "client_gone",
        "the client disconnected before the scene was stored; nothing was kept",
    )
}

/// Suggested wait after a storage quota refusal.
const QUOTA_RETRY_SECS: u64 = 60;

/// A scene the caller may see (404 for other keys' scenes).
async fn visible_scene(
    state: &AppState,
    caller: &Caller,
    id: &str,
) -> Result<SceneRecord, ApiError> {
    state
        .store
        .get_scene(id)
        .await?
        .filter(|s| caller.sees(s.owner))
        .ok_or_else(|| ApiError::not_found("scene", id))
}

/// List scenes.
#[utoipa::path(get, path = "/v1/scenes", tag = "scenes", responses((status = 200, body = SceneList),
    (status = 401, body = super::Problem, content_type = "application/problem+json")), security((), ("bearer" = [])))]
pub async fn list(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
) -> Result<axum::Json<SceneList>, ApiError> {
    Ok(axum::Json(SceneList {
        scenes: state.store.list_scenes(caller.list_filter()).await?,
    }))
}

/// One scene.
#[utoipa::path(get, path = "/v1/scenes/{id}", tag = "scenes",
    params(("id" = String, Path), ("If-None-Match" = Option<String>, Header, description = "An ETag of this scene: 304 while it is current")),
    responses((status = 200, body = SceneRecord, headers(("ETag" = String))),
              (status = 304, description = "Not modified", headers(("ETag" = String))),
              (status = 401, body = super::Problem, content_type = "application/problem+json"),
              (status = 404, body = super::Problem, content_type = "application/problem+json")),
    security((), ("bearer" = [])))]
pub async fn get(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let scene = visible_scene(&state, &caller, &id).await?;
    let body = serde_json::to_vec(&scene)
        .map_err(|e| ApiError::internal(format!("cannot encode scene: {e}")))?;
    Ok(conditional::json_with_etag(&headers, body, None))
}

/// Delete a scene and its files (409 while a job on it runs; queued jobs are canceled).
#[utoipa::path(delete, path = "/v1/scenes/{id}", tag = "scenes", params(("id" = String, Path)),
    responses((status = 204), (status = 404, body = super::Problem, content_type = "application/problem+json"),
              (status = 409, body = super::Problem, content_type = "application/problem+json")))]
pub async fn delete(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    visible_scene(&state, &caller, &id).await?;
    if !state.store.delete_scene_if_idle(&id).await? {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "scene_busy",
            format!("scene {id} has a running job; cancel it or wait"),
        ));
    }
    state.jobs.forget_scene(&id);
    test_pause(&state).await;
    // The row is `deleting` (hidden); files go first, then the row. Should this stop
    // half-way, the start-up sweep finishes it.
    if let Err(e) =
        crate::jobs::sweep::finish_removal(&state.store, state.jobs.storage(), &id).await
    {
        tracing::error!(scene = %id, "the scene's files could not all be removed; the next start finishes: {e:#}");
    }
    Ok(StatusCode::NO_CONTENT)
}

/// Run the configured detector over the scene again (e.g. after changing detector); the
/// scene is `indexing` until done and jobs on it wait.
#[utoipa::path(post, path = "/v1/scenes/{id}/index", tag = "scenes", params(("id" = String, Path)),
    responses((status = 202, body = SceneRecord), (status = 404, body = super::Problem, content_type = "application/problem+json"),
              (status = 409, body = super::Problem, content_type = "application/problem+json"),
              (status = 503, body = super::Problem, content_type = "application/problem+json", description = "indexing_busy (max_queued_indexing)", headers(("Retry-After" = u64, description = "Seconds")))))]
pub async fn reindex(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<(StatusCode, axum::Json<SceneRecord>), ApiError> {
    let scene = visible_scene(&state, &caller, &id).await?;
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
    check_indexing_room(&state)?;
    let usable = scene.frames as usize - scene.unusable_frames.len();
    state
        .store
        .reset_index(&id, &state.cfg.detector, usable)
        .await?;
    (state.on_scene_stored)(id.clone(), 0);
    let record = state
        .store
        .get_scene(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("scene", &id))?;
    Ok((StatusCode::ACCEPTED, axum::Json(record)))
}

/// The unpacking limits of the configuration.
pub(super) fn limits(state: &AppState) -> Limits {
    Limits {
        max_bytes: state.cfg.max_unpacked_bytes,
        max_files: state.cfg.max_archive_files,
        max_image_pixels: state.cfg.max_image_pixels,
        max_scene_pixels: state.cfg.max_scene_pixels,
    }
}
