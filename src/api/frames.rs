//! `/v1/scenes/{id}/frames`: scenes that grow. Frames are appended from an archive (or a
//! raw `.sens`) in any accepted layout or capture format, and removed one by one while no
//! job runs on the scene. A running job keeps the scene record it started with.

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, StatusCode};

use super::capture::CaptureParams;
use super::scenes::limits;
use super::spool::{check_indexing_room, spool};
use super::{ApiError, AppState};
use crate::jobs::ingest::{prepare_scene, Cleanup};
use crate::scene::import::ImportedScene;
use crate::store::frames::FrameRemoval;
use crate::store::SceneRecord;

/// Append frames to a scene. The body is an archive of more frames in any layout the
/// upload accepts (intrinsics included), or a raw `.sens`. Camera, image sizes and depth
/// intrinsics must match the scene's; frame names must come after its last frame
/// (captures are numbered from there). Only the new frames are indexed; `revision` is
/// bumped; jobs already running keep the frames they started with.
#[utoipa::path(post, path = "/v1/scenes/{id}/frames", tag = "scenes",
    params(("id" = String, Path), CaptureParams),
    request_body(content = Vec<u8>, description = "Archive of more frames, or a raw .sens", content_type = "application/x-tar"),
    responses(
        (status = 200, body = SceneRecord),
        (status = 400, body = super::Problem, content_type = "application/problem+json"),
        (status = 404, body = super::Problem, content_type = "application/problem+json"),
        (status = 408, body = super::Problem, content_type = "application/problem+json", description = "upload_timeout: the body stalled (upload_idle_timeout_secs) or took too long (upload_timeout_secs)"),
        (status = 409, body = super::Problem, content_type = "application/problem+json"),
        (status = 413, body = super::Problem, content_type = "application/problem+json", description = "body_too_large, archive_too_large, image_too_large or scene_too_large (max_scene_pixels, the scene's frames and the new ones)"),
        (status = 415, body = super::Problem, content_type = "application/problem+json"),
        (status = 422, body = super::Problem, content_type = "application/problem+json"),
        (status = 503, body = super::Problem, content_type = "application/problem+json", description = "too_many_uploads (max_concurrent_uploads) or indexing_busy (max_queued_indexing)", headers(("Retry-After" = u64, description = "Seconds"))),
        (status = 507, body = super::Problem, content_type = "application/problem+json", description = "insufficient_storage: the upload would cut into min_free_disk_mb")))]
pub async fn append(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(params): Query<CaptureParams>,
    headers: HeaderMap,
    body: Body,
) -> Result<axum::Json<SceneRecord>, ApiError> {
    let mut capture = params.to_capture()?;
    let record = state
        .store
        .get_scene(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("scene", &id))?;
    if record.status == "indexing" {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "scene_indexing",
            format!("scene {id} is being indexed; append once it is ready"),
        ));
    }
    let names = state.store.frame_names(&id).await?;
    let last: Option<u64> = names.iter().filter_map(|n| n.parse().ok()).max();
    capture.opts.first_name = last.map_or(0, |l| l + 1);
    check_indexing_room(&state)?;
    let part = uuid::Uuid::now_v7().to_string();
    let upload = spool(&state, &headers, body, &part, &|_| None).await?;
    let tmp = state.cfg.data_dir.join("tmp");
    let (work, staging) = (tmp.join(&part), tmp.join(format!("{part}.frames")));
    let staging_guard = Cleanup(Some(staging.clone()));
    let lim = limits(&state);
    let st = staging.clone();
    let (up, ct) = (upload.path.clone(), upload.content_type.clone());
    let frames = tokio::task::spawn_blocking(move || {
        prepare_scene(&up, ct.as_deref(), &work, &st, lim, &capture)
    })
    .await
    .map_err(|e| ApiError::internal(format!("import task failed: {e}")))??;
    drop(upload);
    check_fits(&state, &id, &frames, last).await?;
    // Its own task: a client going away never stops the files and rows half-way.
    tokio::spawn(store_frames(state, id, frames, staging_guard))
        .await
        .map_err(|e| ApiError::internal(format!("append task failed: {e}")))?
}

/// Move the new colour images (and masks) in under their frame names, then commit their
/// rows. Files come first: a crash in between leaves files no row names, which the
/// start-up sweep removes (`jobs::sweep`); a failure here removes them at once.
async fn store_frames(
    state: AppState,
    id: String,
    frames: ImportedScene,
    _staging: Cleanup,
) -> Result<axum::Json<SceneRecord>, ApiError> {
    // The scene's files stay in this replica's cache meanwhile (fetched from the bucket
    // first when this replica lacks them).
    let _pin = state
        .jobs
        .acquire_scene(&id)
        .await
        .map_err(|f| ApiError::internal(f.detail))?;
    let scene_dir = state.jobs.scene_dir(&id);
    let mut moved = Vec::new();
    let res = move_in(&scene_dir, &frames, &mut moved);
    let undo = |moved: &[std::path::PathBuf]| {
        for p in moved {
            let _ = std::fs::remove_file(p);
        }
    };
    // With a bucket, the new files are uploaded before the rows name them.
    let res = match res {
        Ok(()) => state
            .jobs
            .storage()
            .sync_scene(&id)
            .await
            .map_err(|e| ApiError::internal(format!("cannot store the new frames: {e}"))),
        Err(e) => Err(e),
    };
    if let Err(e) = res {
        undo(&moved);
        return Err(e);
    }
    super::scenes::test_pause(&state).await;
    let detector = (state.cfg.detector != "none").then_some(state.cfg.detector.as_str());
    let first = match state.store.append_frames(&id, &frames, detector).await {
        Ok(f) => f,
        Err(e) => {
            undo(&moved);
            return Err(e.into());
        }
    };
    state.jobs.forget_scene(&id);
    let now = state
        .store
        .get_scene(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("scene", &id))?;
    if now.status == "indexing" {
        (state.on_scene_stored)(id.clone(), first);
    } else {
        state.jobs.wake();
    }
    Ok(axum::Json(now))
}

/// Rename the staged frames' files into the scene folder, recording each one moved.
fn move_in(
    scene_dir: &std::path::Path,
    frames: &ImportedScene,
    moved: &mut Vec<std::path::PathBuf>,
) -> Result<(), ApiError> {
    for f in &frames.frames {
        let dest = scene_dir.join("color").join(format!("{}.jpg", f.name));
        crate::storage::move_path(&f.color_path, &dest)
            .map_err(|e| ApiError::internal(format!("cannot store frame {}: {e}", f.name)))?;
        moved.push(dest);
        if let Some(inst) = &f.instance_path {
            let dest = scene_dir.join("instance").join(format!("{}.png", f.name));
            std::fs::create_dir_all(scene_dir.join("instance"))
                .and_then(|_| crate::storage::move_path(inst, &dest))
                .map_err(|e| ApiError::internal(format!("cannot store mask {}: {e}", f.name)))?;
            moved.push(dest);
        }
    }
    Ok(())
}

fn unfit(detail: String) -> ApiError {
    ApiError::new(
        StatusCode::UNPROCESSABLE_ENTITY,
        "frames_do_not_fit",
        detail,
    )
}

/// The appended frames must come from the same camera and follow the scene's frames.
async fn check_fits(
    state: &AppState,
    id: &str,
    new: &ImportedScene,
    last: Option<u64>,
) -> Result<(), ApiError> {
    let scene = state
        .store
        .load_scene_camera(id)
        .await?
        .ok_or_else(|| ApiError::not_found("scene", id))?;
    let (color, depth, depth_size) = scene;
    let frames = state.store.frame_names(id).await?.len() + new.frames.len();
    if let Some(e) = crate::scene::import::scene_pixels_error(
        frames as u64,
        (new.color.width, new.color.height),
        new.depth_size,
        state.cfg.max_scene_pixels,
    ) {
        return Err(e.into());
    }
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-3 * a.abs().max(1.0);
    let same = |a: &crate::geometry::Intrinsics, b: &crate::geometry::Intrinsics| {
        a.width == b.width
            && a.height == b.height
            && close(a.fx, b.fx)
            && close(a.fy, b.fy)
            && close(a.cx, b.cx)
            && close(a.cy, b.cy)
    };
    if !same(&color, &new.color) {
        return Err(unfit(format!(
            "the new frames' colour camera ({}x{}, fx {:.2}, fy {:.2}, cx {:.2}, cy {:.2}) differs from the scene's ({}x{}, fx {:.2}, fy {:.2}, cx {:.2}, cy {:.2})",
            new.color.width, new.color.height, new.color.fx, new.color.fy, new.color.cx, new.color.cy,
            color.width, color.height, color.fx, color.fy, color.cx, color.cy
        )));
    }
    if new.depth_size != depth_size {
        return Err(unfit(format!(
            "the new depth images are {}x{} but the scene's are {}x{}",
            new.depth_size.0, new.depth_size.1, depth_size.0, depth_size.1
        )));
    }
    match (&depth, &new.depth) {
        (None, None) => {}
        (Some(a), Some(b)) if same(a, b) => {}
        _ => {
            return Err(unfit(
                "the new frames' depth intrinsics differ from the scene's".into(),
            ))
        }
    }
    if state.detector_needs_instances && new.frames.iter().any(|f| f.instance_path.is_none()) {
        return Err(unfit(format!(
            "the configured detector {:?} reads instance masks and some new frames have none",
            state.cfg.detector
        )));
    }
    for f in &new.frames {
        let n: Option<u64> = f.name.parse().ok();
        if let (Some(l), Some(n)) = (last, n) {
            if n <= l {
                return Err(unfit(format!(
                    "frame {} does not come after the scene's last frame {l}; appended frames must follow it",
                    f.name
                )));
            }
        }
    }
    Ok(())
}

/// Remove one frame by name (409 while a job on the scene runs or it is being indexed).
/// Later frames move up one image id; `revision` is bumped.
#[utoipa::path(delete, path = "/v1/scenes/{id}/frames/{name}", tag = "scenes",
    params(("id" = String, Path), ("name" = String, Path, description = "Frame name")),
    responses((status = 204),
              (status = 404, body = super::Problem, content_type = "application/problem+json"),
              (status = 409, body = super::Problem, content_type = "application/problem+json")))]
pub async fn remove(
    State(state): State<AppState>,
    Path((id, name)): Path<(String, String)>,
) -> Result<StatusCode, ApiError> {
    if state.store.get_scene(&id).await?.is_none() {
        return Err(ApiError::not_found("scene", &id));
    }
    // Forgotten before and after: no job can start from a cached copy that still holds
    // the frame once its files go.
    state.jobs.forget_scene(&id);
    match state.store.remove_frame_if_idle(&id, &name).await? {
        FrameRemoval::NoFrame => Err(ApiError::new(
            StatusCode::NOT_FOUND,
            "frame_not_found",
            format!("scene {id} has no frame {name:?}"),
        )),
        FrameRemoval::Busy(why) => Err(ApiError::new(
            StatusCode::CONFLICT,
            "scene_busy",
            format!("frames of scene {id} cannot be removed now: {why}"),
        )),
        FrameRemoval::LastFrame => Err(ApiError::new(
            StatusCode::CONFLICT,
            "last_frame",
            format!("{name} is the scene's only frame; delete the scene instead"),
        )),
        FrameRemoval::Removed { file } => {
            state.jobs.forget_scene(&id);
            let files = [
                format!("color/{file}.jpg"),
                format!("color/{file}.preview.jpg"),
                format!("instance/{file}.png"),
            ];
            if let Err(e) = state.jobs.storage().remove_scene_files(&id, &files).await {
                // The rows no longer name them; left objects are never read.
                tracing::warn!(scene = %id, "cannot remove a removed frame's objects: {e}");
            }
            Ok(StatusCode::NO_CONTENT)
        }
    }
}
