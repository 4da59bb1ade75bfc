//! `/v1/jobs`: create, poll, list, cancel, artifacts.

use axum::extract::{Path, Query, State};
use axum::http::{header, StatusCode};
use axum::response::IntoResponse;
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;
use serde_json::Value;

use super::error::Json;
use super::{ApiError, AppState};
use crate::store::{JobRecord, JobStatus, ListJobs};

#[derive(Debug, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CreateJob {
    pub scene_id: String,
    /// The description of the object, e.g. "the black chair next to the window".
    pub query: String,
}

/// A grounding job.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct Job {
    pub id: String,
    pub scene_id: String,
    pub query: String,
    pub status: JobStatus,
    pub attempts: i64,
    pub created_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
    /// `{code, detail}` when the job failed or was canceled.
    #[schema(value_type = Option<Object>)]
    pub error: Option<Value>,
    /// `{box: {min, max, center, size}, ...}` when the job succeeded.
    #[schema(value_type = Option<Object>)]
    pub result: Option<Value>,
    /// Steps of the pipeline in order (omitted in lists).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Vec<Object>>)]
    pub trace: Option<Box<RawValue>>,
}

impl Job {
    fn from_record(r: JobRecord, trace: Option<Box<RawValue>>) -> Self {
        Job {
            id: r.id,
            scene_id: r.scene_id,
            query: r.query,
            status: r.status,
            attempts: r.attempts,
            created_at: r.created_at,
            started_at: r.started_at,
            finished_at: r.finished_at,
            error: r.error,
            result: r.result,
            trace,
        }
    }
}

#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct JobList {
    pub jobs: Vec<Job>,
    /// Pass as `cursor` to get the next page; absent on the last page.
    pub next_cursor: Option<String>,
}

#[derive(Debug, Deserialize, utoipa::IntoParams)]
pub struct ListParams {
    pub scene_id: Option<String>,
    /// queued | running | succeeded | failed | canceled
    pub status: Option<String>,
    /// Page size, 1..=500 (default 50).
    pub limit: Option<i64>,
    pub cursor: Option<String>,
}

fn empty_trace() -> Box<RawValue> {
    RawValue::from_string("[]".to_owned()).unwrap_or_else(|_| unreachable!("\"[]\" is valid JSON"))
}

const MAX_QUERY_CHARS: usize = 2000;

/// Create a grounding job (it waits queued while its scene is still indexing).
#[utoipa::path(post, path = "/v1/jobs", tag = "jobs", request_body = CreateJob,
    responses((status = 202, body = Job, headers(("Location" = String))),
              (status = 400, body = super::Problem, content_type = "application/problem+json"),
              (status = 404, body = super::Problem, content_type = "application/problem+json"),
              (status = 409, body = super::Problem, content_type = "application/problem+json")))]
pub async fn create(
    State(state): State<AppState>,
    Json(req): Json<CreateJob>,
) -> Result<impl IntoResponse, ApiError> {
    let query = req.query.trim();
    if query.is_empty() {
        return Err(ApiError::bad_request(
            "empty_query",
            "query must describe the object to find",
        ));
    }
    if query.chars().count() > MAX_QUERY_CHARS {
        return Err(ApiError::bad_request(
            "query_too_long",
            format!("query is longer than {MAX_QUERY_CHARS} characters"),
        ));
    }
    let scene = state
        .store
        .get_scene(&req.scene_id)
        .await?
        .ok_or_else(|| ApiError::not_found("scene", &req.scene_id))?;
    if scene.status == "failed" {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "scene_failed",
            format!(
                "scene {} failed to index: {}",
                scene.id,
                scene.error.unwrap_or_default()
            ),
        ));
    }
    let id = uuid::Uuid::now_v7().to_string();
    let job = state.store.create_job(&id, &scene.id, query).await?;
    state.jobs.wake();
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, format!("/v1/jobs/{id}"))],
        axum::Json(Job::from_record(job, Some(empty_trace()))),
    ))
}

/// A job with its trace.
#[utoipa::path(get, path = "/v1/jobs/{id}", tag = "jobs", params(("id" = String, Path)),
    responses((status = 200, body = Job), (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn get(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<axum::Json<Job>, ApiError> {
    let (job, trace) = state
        .store
        .get_job_with_trace(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("job", &id))?;
    Ok(axum::Json(Job::from_record(job, Some(trace))))
}

/// Jobs, newest first, with cursor pagination.
#[utoipa::path(get, path = "/v1/jobs", tag = "jobs", params(ListParams),
    responses((status = 200, body = JobList), (status = 400, body = super::Problem, content_type = "application/problem+json")))]
pub async fn list(
    State(state): State<AppState>,
    Query(p): Query<ListParams>,
) -> Result<axum::Json<JobList>, ApiError> {
    let limit = p.limit.unwrap_or(50);
    if !(1..=500).contains(&limit) {
        return Err(ApiError::bad_request(
            "invalid_limit",
            "limit must be between 1 and 500",
        ));
    }
    let status = match p.status.as_deref() {
        None | Some("") => None,
        Some(s) => Some(JobStatus::parse(s).ok_or_else(|| {
            ApiError::bad_request("invalid_status", format!("unknown status {s:?}"))
        })?),
    };
    let before_seq = match p.cursor.as_deref() {
        None | Some("") => None,
        Some(c) => Some(
            c.strip_prefix('j')
                .and_then(|n| n.parse::<i64>().ok())
                .ok_or_else(|| {
                    ApiError::bad_request("invalid_cursor", "cursor is not one this service issued")
                })?,
        ),
    };
    let rows = state
        .store
        .list_jobs(&ListJobs {
            scene_id: p.scene_id,
            status,
            limit: limit + 1,
            before_seq,
        })
        .await?;
    let more = rows.len() as i64 > limit;
    let rows: Vec<JobRecord> = rows.into_iter().take(limit as usize).collect();
    let next_cursor = if more {
        rows.last().map(|r| format!("j{}", r.seq))
    } else {
        None
    };
    Ok(axum::Json(JobList {
        jobs: rows
            .into_iter()
            .map(|r| Job::from_record(r, None))
            .collect(),
        next_cursor,
    }))
}

/// Cancel a queued or running job.
#[utoipa::path(post, path = "/v1/jobs/{id}/cancel", tag = "jobs", params(("id" = String, Path)),
    responses((status = 200, body = Job), (status = 404, body = super::Problem, content_type = "application/problem+json"),
              (status = 409, body = super::Problem, content_type = "application/problem+json")))]
pub async fn cancel(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<axum::Json<Job>, ApiError> {
    let before = state
        .store
        .get_job(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("job", &id))?;
    if before.status.is_terminal() {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "job_finished",
            format!("job {id} is already {}", before.status.as_str()),
        ));
    }
    state
        .store
        .cancel_job(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("job", &id))?;
    state.jobs.interrupt(&id);
    let (after, trace) = state
        .store
        .get_job_with_trace(&id)
        .await?
        .ok_or_else(|| ApiError::not_found("job", &id))?;
    Ok(axum::Json(Job::from_record(after, Some(trace))))
}

/// An image the pipeline produced (stitched grids, annotated frames).
#[utoipa::path(get, path = "/v1/jobs/{id}/artifacts/{name}", tag = "jobs", params(("id" = String, Path), ("name" = String, Path)),
    responses((status = 200, content_type = "image/jpeg", body = Vec<u8>), (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn artifact(
    State(state): State<AppState>,
    Path((id, name)): Path<(String, String)>,
) -> Result<impl IntoResponse, ApiError> {
    let valid = !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    let valid_id = id.chars().all(|c| c.is_ascii_hexdigit() || c == '-');
    let missing = || {
        ApiError::new(
            StatusCode::NOT_FOUND,
            "artifact_not_found",
            format!("job {id} has no artifact {name:?}"),
        )
    };
    if !valid || !valid_id {
        return Err(missing());
    }
    let path = state.jobs.artifact_dir(&id).join(&name);
    let bytes = tokio::fs::read(&path).await.map_err(|_| missing())?;
    let ct = if name.ends_with(".png") {
        "image/png"
    } else if name.ends_with(".json") {
        "application/json"
    } else {
        "image/jpeg"
    };
    Ok(([(header::CONTENT_TYPE, ct)], bytes))
}
