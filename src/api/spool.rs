//! Receiving an upload body: spooled to `<data>/tmp/<id>.upload`, counted against the
//! upload limit (and the caller's quota) and hashed, for `POST /v1/scenes` and
//! `POST /v1/scenes/{id}/frames` alike.

use axum::body::Body;
use axum::http::{header, HeaderMap, StatusCode};
use futures::StreamExt;
use sha2::{Digest, Sha256};
use tokio::io::AsyncWriteExt;

use super::{ApiError, AppState};
use crate::jobs::ingest::Cleanup;

/// Suggested wait after a refusal because uploads or indexing are at capacity, s.
const BUSY_RETRY_SECS: u64 = 5;

/// An upload spooled under `<data>/tmp` (removed when this is dropped). It holds one of
/// the `max_concurrent_uploads` slots until dropped.
pub(super) struct Spooled {
    pub _slot: tokio::sync::OwnedSemaphorePermit,
    pub path: std::path::PathBuf,
    pub _guard: Cleanup,
    pub content_type: Option<String>,
    pub bytes: u64,
    /// SHA-256 of the body, hex.
    pub hash: String,
}

/// A refusal for a body of this many bytes so far (a storage quota), or None.
pub(super) type Admit<'a> = &'a (dyn Fn(u64) -> Option<ApiError> + Send + Sync);

/// Spool a request body to `<data>/tmp/<id>.upload`, enforcing the upload limit and
/// `admit` on the declared length and on every chunk. The file goes when the result (or
/// the error) is dropped.
pub(super) async fn spool(
    state: &AppState,
    headers: &HeaderMap,
    body: Body,
    id: &str,
    admit: Admit<'_>,
) -> Result<Spooled, ApiError> {
    let slot = state.uploads.clone().try_acquire_owned().map_err(|_| {
        busy(
            "too_many_uploads",
            format!(
                "{} uploads are being received (max_concurrent_uploads); try again shortly",
                state.cfg.max_concurrent_uploads
            ),
        )
    })?;
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
        if let Some(e) = admit(len) {
            return Err(e);
        }
        check_free_space(state, len)?;
    } else {
        check_free_space(state, 0)?;
    }
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string);
    let tmp = state.cfg.data_dir.join("tmp");
    tokio::fs::create_dir_all(&tmp)
        .await
        .map_err(|e| ApiError::internal(format!("cannot create temp dir: {e}")))?;
    let path = tmp.join(format!("{id}.upload"));
    let guard = Cleanup(Some(path.clone()));

    let mut file = tokio::fs::File::create(&path)
        .await
        .map_err(|e| ApiError::internal(format!("cannot spool upload: {e}")))?;
    let mut stream = body.into_data_stream();
    let mut total: u64 = 0;
    let mut hasher = Sha256::new();
    let idle = std::time::Duration::from_secs(state.cfg.upload_idle_timeout_secs.max(1));
    let whole = std::time::Duration::from_secs(state.cfg.upload_timeout_secs.max(1));
    let deadline = tokio::time::Instant::now() + whole;
    let mut checked = 0u64;
    loop {
        let until = deadline.min(tokio::time::Instant::now() + idle);
        let chunk = match tokio::time::timeout_at(until, stream.next()).await {
            Ok(Some(c)) => c,
            Ok(None) => break,
            Err(_) if tokio::time::Instant::now() >= deadline => {
                return Err(timed_out(format!(
                    "the upload took longer than upload_timeout_secs = {} s; nothing was kept",
                    whole.as_secs()
                )))
            }
            Err(_) => {
                return Err(timed_out(format!(
                    "no part of the upload arrived for upload_idle_timeout_secs = {} s \
                     (after {total} bytes); nothing was kept",
                    idle.as_secs()
                )))
            }
        };
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
        if let Some(e) = admit(total) {
            return Err(e);
        }
        if total - checked >= FREE_SPACE_STEP {
            checked = total;
            check_free_space(state, 0)?;
        }
        hasher.update(&chunk);
        file.write_all(&chunk)
            .await
            .map_err(|e| ApiError::internal(format!("cannot spool upload: {e}")))?;
    }
    file.flush()
        .await
        .map_err(|e| ApiError::internal(format!("cannot spool upload: {e}")))?;
    drop(file);
    Ok(Spooled {
        _slot: slot,
        path,
        _guard: guard,
        content_type,
        bytes: total,
        hash: hex::encode(hasher.finalize()),
    })
}

/// Bytes received between two free-space checks during an upload.
const FREE_SPACE_STEP: u64 = 64 << 20;

/// 503 with Retry-After: a capacity is full now.
pub(super) fn busy(code: &'static str, detail: String) -> ApiError {
    ApiError {
        retry_after: Some(BUSY_RETRY_SECS),
        ..ApiError::unavailable(code, detail)
    }
}

fn timed_out(detail: String) -> ApiError {
    ApiError::new(StatusCode::REQUEST_TIMEOUT, "upload_timeout", detail)
}

/// Refuse (507) when storing `more` bytes would leave the data dir's file system with
/// less than `min_free_disk_mb` free. A file system that cannot be asked is not refused.
fn check_free_space(state: &AppState, more: u64) -> Result<(), ApiError> {
    let reserve = state.cfg.min_free_disk_mb.saturating_mul(1 << 20);
    if reserve == 0 {
        return Ok(());
    }
    let Some(free) = free_bytes(&state.cfg.data_dir) else {
        return Ok(());
    };
    if free.saturating_sub(more) < reserve {
        return Err(ApiError {
            public: true,
            ..ApiError::new(
                StatusCode::INSUFFICIENT_STORAGE,
                "insufficient_storage",
                format!(
                    "the server keeps min_free_disk_mb = {} MB free for its data and has {} MB left{}; \
                     try again once space is freed",
                    state.cfg.min_free_disk_mb,
                    free >> 20,
                    if more > 0 {
                        format!(" before this upload of {more} bytes")
                    } else {
                        String::new()
                    }
                ),
            )
        });
    }
    Ok(())
}

/// Bytes an unprivileged writer may still use on the file system holding `dir`.
fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    let st = rustix::fs::statvfs(dir).ok()?;
    Some(st.f_bavail.saturating_mul(st.f_frsize))
}

/// Refuse (503) when so many scenes wait for an indexing slot that another would wait
/// too long (only with a detector: without one nothing is indexed).
pub(super) fn check_indexing_room(state: &AppState) -> Result<(), ApiError> {
    let waiting = state.jobs.indexing_backlog();
    if state.cfg.detector != "none" && waiting >= state.cfg.max_queued_indexing {
        return Err(busy(
            "indexing_busy",
            format!("{waiting} scenes wait to be indexed (max_queued_indexing); try again shortly"),
        ));
    }
    Ok(())
}
