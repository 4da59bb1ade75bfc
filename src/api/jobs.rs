//! `/v1/jobs`: create (one or many, idempotent), poll (conditional, long), list, cancel,
//! artifacts.

use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Extension;
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;
use serde_json::Value;
use sha2::{Digest, Sha256};

use super::auth::Caller;
use super::error::Query;
use super::{conditional, idempotency, ApiError, AppState};
use crate::jobs::webhooks::{check_url, UrlRefusal};
use crate::store::webhooks::Delivery;
use crate::store::{JobRecord, JobStatus, ListJobs, NewJobs};

/// `query` for one job, or `queries` for one job per query (answered as `{"jobs": [...]}`).
/// Its schema (`api::job_schema`, by hand) states that exactly one of the two is given.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreateJob {
    pub scene_id: String,
    pub query: Option<String>,
    pub queries: Option<Vec<String>>,
    pub webhook_url: Option<String>,
}

/// Webhook delivery of a job.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct WebhookInfo {
    pub url: String,
    /// `pending`, `delivered` or `failed` once the job has ended; absent before.
    pub state: Option<String>,
    /// Every attempt, oldest first.
    pub deliveries: Vec<Delivery>,
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
    /// Present when the job was created with a `webhook_url` (omitted in lists).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub webhook: Option<WebhookInfo>,
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
            webhook: r.webhook_url.map(|url| WebhookInfo {
                url,
                state: None,
                deliveries: Vec::new(),
            }),
        }
    }
}

/// The answer to a `queries` request.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct JobBatch {
    /// One job per query, in the order of `queries`.
    pub jobs: Vec<Job>,
}

/// What `POST /v1/jobs` answers: a job, or a batch for `queries`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
#[serde(untagged)]
pub enum Created {
    One(Box<Job>),
    Batch(JobBatch),
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
    /// queued | running | succeeded | failed | canceled (empty: any)
    #[param(pattern = "^(queued|running|succeeded|failed|canceled)?$")]
    pub status: Option<String>,
    /// Page size, 1..=500 (default 50).
    #[param(minimum = 1, maximum = 500)]
    pub limit: Option<i64>,
    pub cursor: Option<String>,
}

fn empty_trace() -> Box<RawValue> {
    RawValue::from_string("[]".to_owned()).unwrap_or_else(|_| unreachable!("\"[]\" is valid JSON"))
}

pub(super) const MAX_QUERY_CHARS: usize = 2000;
pub(super) const MAX_BATCH: usize = 100;
/// Suggested wait after a job quota refusal.
const QUOTA_RETRY_SECS: u64 = 10;

fn check_query(q: &str) -> Result<String, ApiError> {
    let query = q.trim();
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
    Ok(query.to_string())
}

/// Create a grounding job, or one per entry of `queries` (they wait queued while their
/// scene is still indexing). With `Idempotency-Key`, a retry with the same body replays
/// the first answer and creates nothing.
#[utoipa::path(post, path = "/v1/jobs", tag = "jobs", request_body = CreateJob,
    params(("Idempotency-Key" = Option<String>, Header, nullable = false, max_length = 255, pattern = "^[ -~]*[!-~][ -~]*$", description = "Makes retries safe: the same key and body within 24 h replay the first answer (1 to 255 printable ASCII characters, not all spaces)")),
    responses((status = 202, body = Created, description = "A Job for `query`, a JobBatch for `queries`", headers(("Location" = String, description = "The job (single query only)"))),
              (status = 400, body = super::Problem, content_type = "application/problem+json"),
              (status = 401, body = super::Problem, content_type = "application/problem+json"),
              (status = 404, body = super::Problem, content_type = "application/problem+json"),
              (status = 409, body = super::Problem, content_type = "application/problem+json", description = "scene_failed, or idempotency_key_in_use"),
              (status = 413, body = super::Problem, content_type = "application/problem+json", description = "The body is too large"),
              (status = 415, body = super::Problem, content_type = "application/problem+json", description = "The body is not application/json"),
              (status = 422, body = super::Problem, content_type = "application/problem+json", description = "The JSON does not match CreateJob, or idempotency_key_reused, invalid_webhook_url, webhook_url_not_allowed, webhook_requires_key"),
              (status = 429, body = super::Problem, content_type = "application/problem+json", headers(("Retry-After" = u64, description = "Seconds")))),
    security((), ("bearer" = [])))]
pub async fn create(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    let key = idempotency::key_of(&headers)?;
    let json_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|m| {
            let m = m.trim();
            m == "application/json" || (m.starts_with("application/") && m.ends_with("+json"))
        });
    if !json_type {
        return Err(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "invalid_json",
            "expected Content-Type: application/json",
        ));
    }
    let req: CreateJob = serde_json::from_slice(&body).map_err(|e| {
        let status = if e.is_data() {
            StatusCode::UNPROCESSABLE_ENTITY
        } else {
            StatusCode::BAD_REQUEST
        };
        ApiError::new(status, "invalid_json", format!("invalid job request: {e}"))
    })?;
    let hash = hex::encode(Sha256::digest(&body));
    let st = state.clone();
    let c = caller.clone();
    idempotency::run(&state, &caller, "POST /v1/jobs", key, &hash, async move {
        create_now(st, c, req).await
    })
    .await
}

async fn create_now(state: AppState, caller: Caller, req: CreateJob) -> Result<Response, ApiError> {
    let (queries, batch) = match (req.query, req.queries) {
        (Some(q), None) => (vec![check_query(&q)?], false),
        (None, Some(qs)) => {
            if qs.is_empty() || qs.len() > MAX_BATCH {
                return Err(ApiError::bad_request(
                    "invalid_queries",
                    format!("queries must hold 1 to {MAX_BATCH} descriptions"),
                ));
            }
            (
                qs.iter()
                    .map(|q| check_query(q))
                    .collect::<Result<_, _>>()?,
                true,
            )
        }
        _ => {
            return Err(ApiError::bad_request(
                "query_or_queries",
                "give either query or queries",
            ))
        }
    };
    let scene = state
        .store
        .get_scene(&req.scene_id)
        .await?
        .filter(|s| caller.sees(s.owner))
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
    if let Some(url) = &req.webhook_url {
        if caller.key_id.is_none() {
            return Err(ApiError::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                "webhook_requires_key",
                "webhooks are signed with the caller's key secret: create a key with `grounder keys create`",
            ));
        }
        check_url(url, state.cfg.webhook_allow_private)
            .await
            .map_err(|e| match e {
                UrlRefusal::Invalid(_) => ApiError::new(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    "invalid_webhook_url",
                    e.to_string(),
                ),
                UrlRefusal::NotAllowed(_) => ApiError::new(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    "webhook_url_not_allowed",
                    e.to_string(),
                ),
            })?;
    }
    let jobs = queries
        .into_iter()
        .map(|q| (uuid::Uuid::now_v7().to_string(), q))
        .collect();
    let created = state
        .store
        .create_jobs(&NewJobs {
            jobs,
            scene_id: &scene.id,
            owner: caller.key_id,
            webhook_url: req.webhook_url.as_deref(),
            max_active: caller.max_running_jobs,
        })
        .await?
        .ok_or_else(|| {
            ApiError::too_many(
                "quota_exceeded",
                format!(
                    "this key may have at most {} queued or running jobs",
                    caller.max_running_jobs.unwrap_or(0)
                ),
                QUOTA_RETRY_SECS,
            )
        })?;
    state.jobs.wake();
    let mut jobs: Vec<Job> = created
        .into_iter()
        .map(|r| Job::from_record(r, Some(empty_trace())))
        .collect();
    if batch {
        return Ok((StatusCode::ACCEPTED, axum::Json(JobBatch { jobs })).into_response());
    }
    let job = jobs
        .pop()
        .ok_or_else(|| ApiError::internal("no job was created"))?;
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, format!("/v1/jobs/{}", job.id))],
        axum::Json(job),
    )
        .into_response())
}

/// A job visible to the caller, with its trace (404 for other keys' jobs).
pub(crate) async fn visible_job(
    state: &AppState,
    caller: &Caller,
    id: &str,
) -> Result<(JobRecord, Box<RawValue>), ApiError> {
    state
        .store
        .get_job_with_trace(id)
        .await?
        .filter(|(j, _)| caller.sees(j.owner))
        .ok_or_else(|| ApiError::not_found("job", id))
}

/// The JSON a poll answers: the job, its trace and its webhook deliveries.
pub(crate) async fn job_body(
    state: &AppState,
    job: JobRecord,
    trace: Box<RawValue>,
) -> Result<Vec<u8>, ApiError> {
    let id = job.id.clone();
    let mut j = Job::from_record(job, Some(trace));
    if let Some(w) = j.webhook.as_mut() {
        let (st, list) = state.store.webhook_deliveries(&id).await?;
        w.state = st;
        w.deliveries = list;
    }
    serde_json::to_vec(&j).map_err(|e| ApiError::internal(format!("cannot encode job: {e}")))
}

/// A job with its trace. `ETag` / `If-None-Match` answer 304 while nothing changed;
/// `Prefer: wait=N` (N ≤ 60) holds the answer until the job ends or N seconds pass.
#[utoipa::path(get, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = String, Path),
           ("If-None-Match" = Option<String>, Header, description = "An ETag of this job: 304 while it is current"),
           ("Prefer" = Option<String>, Header, description = "`wait=N` (seconds, at most 60): answer when the job ends or after N seconds")),
    responses((status = 200, body = Job, headers(("ETag" = String), ("Preference-Applied" = String, description = "`wait=N` when the wait was honoured"))),
              (status = 304, description = "Not modified", headers(("ETag" = String), ("Preference-Applied" = String))),
              (status = 401, body = super::Problem, content_type = "application/problem+json"),
              (status = 404, body = super::Problem, content_type = "application/problem+json")),
    security((), ("bearer" = [])))]
pub async fn get(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let wait = conditional::prefer_wait(&headers);
    // Subscribe before reading, so a change between the read and the wait is seen.
    let mut changes = wait.map(|_| state.store.events.subscribe(&id));
    let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs(wait.unwrap_or(0));
    let (job, trace) = loop {
        let (job, trace) = visible_job(&state, &caller, &id).await?;
        let Some(rx) = changes.as_mut() else {
            break (job, trace);
        };
        if job.status.is_terminal() {
            break (job, trace);
        }
        // A stopping service answers with the state it has: the graceful stop waits for
        // the requests in flight, and this one would otherwise hold it up to N seconds.
        tokio::select! {
            r = tokio::time::timeout_at(deadline, rx.changed()) => match r {
                Ok(Ok(())) => continue,
                _ => break (job, trace),
            },
            _ = state.store.events.closing.cancelled() => break (job, trace),
        }
    };
    let body = job_body(&state, job, trace).await?;
    Ok(conditional::json_with_etag(&headers, body, wait))
}

/// Jobs, newest first, with cursor pagination.
#[utoipa::path(get, path = "/v1/jobs", tag = "jobs", params(ListParams),
    responses((status = 200, body = JobList), (status = 400, body = super::Problem, content_type = "application/problem+json")))]
pub async fn list(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
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
            owner: caller.list_filter(),
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
            .map(|r| Job {
                webhook: None,
                ..Job::from_record(r, None)
            })
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
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let before = state
        .store
        .get_job(&id)
        .await?
        .filter(|j| caller.sees(j.owner))
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
    let (after, trace) = visible_job(&state, &caller, &id).await?;
    let body = job_body(&state, after, trace).await?;
    Ok(([(header::CONTENT_TYPE, "application/json")], body).into_response())
}

/// A file the pipeline produced (stitched grids and annotated frames as JPEG, masks as PNG,
/// records as JSON; the type follows the name's extension, see [`artifact_content_type`]).
#[utoipa::path(get, path = "/v1/jobs/{id}/artifacts/{name}", tag = "jobs",
    params(("id" = String, Path),
           ("name" = String, Path, pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]*$", description = "Artifact name, as the trace gives it")),
    responses((status = 200, content((Vec<u8> = "image/jpeg"), (Vec<u8> = "image/png"), (Object = "application/json"), (String = "text/plain"), (Vec<u8> = "application/octet-stream"))),
              (status = 404, body = super::Problem, content_type = "application/problem+json")))]
pub async fn artifact(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
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
    let visible = state
        .store
        .get_job(&id)
        .await?
        .is_some_and(|j| caller.sees(j.owner));
    if !visible {
        return Err(ApiError::not_found("job", &id));
    }
    let bytes = state
        .jobs
        .storage()
        .read_artifact(&id, &name)
        .await
        .map_err(|e| ApiError::internal(e.to_string()))?
        .ok_or_else(missing)?;
    let ct = artifact_content_type(&name);
    // Browsers must not guess another type from an artifact's bytes.
    Ok((
        [
            (header::CONTENT_TYPE, ct),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        ],
        bytes,
    ))
}

/// The type an artifact is served with, from its name's extension: JPEG, PNG, JSON and
/// plain text by name; anything else as bytes of no stated kind, never as an image.
pub fn artifact_content_type(name: &str) -> &'static str {
    let ext = name
        .rsplit_once('.')
        .map(|(_, e)| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "jpg" | "jpeg" => "image/jpeg",
        "png" => "image/png",
        "json" => "application/json",
        "txt" => "text/plain; charset=utf-8",
        _ => "application/octet-stream",
    }
}

#[cfg(test)]
mod artifact_type_tests {
    use super::artifact_content_type;

    #[test]
    fn artifacts_get_their_type_from_the_extension_and_unknown_ones_no_image_type() {
        assert_eq!(artifact_content_type("grid_0.jpg"), "image/jpeg");
        assert_eq!(artifact_content_type("marks.JPEG"), "image/jpeg");
        assert_eq!(artifact_content_type("mask_3.png"), "image/png");
        assert_eq!(artifact_content_type("trace.json"), "application/json");
        assert_eq!(
            artifact_content_type("test.txt"),
            "text/plain; charset=utf-8"
        );
        assert_eq!(
            artifact_content_type("object.ply"),
            "application/octet-stream"
        );
        assert_eq!(artifact_content_type("noext"), "application/octet-stream");
    }
}
