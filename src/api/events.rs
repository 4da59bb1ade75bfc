//! `GET /v1/jobs/{id}/events`: Server-Sent Events of a job. One `step` event per trace
//! step and one `status` event per state change, in the order they were written, each
//! with its event id; then `done` with the job, and the stream ends. `Last-Event-ID`
//! resumes after that event.

use axum::extract::{Path, State};
use axum::http::HeaderMap;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Extension;
use std::convert::Infallible;
use tokio::sync::mpsc;

use super::auth::Caller;
use super::jobs::{job_body, visible_job};
use super::{ApiError, AppState};

/// One event of the stream (a Server-Sent Event: its `event`, `data` and `id` fields).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)] // Only documents the stream; events are built by `Event`.
pub struct JobEvent {
    /// `step`, `status`, or `done` (the last event).
    #[schema(pattern = "^(step|status|done)$")]
    event: String,
    /// JSON: the trace step, `{status, attempts}`, or the job (`done`).
    data: String,
    /// The event id to resume after (`Last-Event-ID`); `done` has none.
    #[schema(pattern = "^[0-9]+$")]
    id: Option<String>,
}

/// A job's events as a stream.
#[utoipa::path(get, path = "/v1/jobs/{id}/events", tag = "jobs",
    params(("id" = String, Path),
           ("Last-Event-ID" = Option<i64>, Header, minimum = 0, nullable = false,
            description = "Resume after this event id (an `id` of this stream; none: from the start)")),
    responses((status = 200, content_type = "text/event-stream", body = JobEvent,
               description = "`event: step` (data: the trace step), `event: status` (data: {status, attempts}), each with an `id`; finally `event: done` (data: the job). The schema is that of one event."),
              (status = 400, body = super::Problem, content_type = "application/problem+json"),
              (status = 401, body = super::Problem, content_type = "application/problem+json"),
              (status = 404, body = super::Problem, content_type = "application/problem+json")),
    security((), ("bearer" = [])))]
pub async fn events(
    State(state): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let after = match headers.get("last-event-id") {
        None => 0,
        Some(v) => v
            .to_str()
            .ok()
            .and_then(|s| s.trim().parse::<i64>().ok())
            .filter(|n| *n >= 0)
            .ok_or_else(|| {
                ApiError::bad_request(
                    "invalid_last_event_id",
                    "Last-Event-ID must be an event id this stream sent",
                )
            })?,
    };
    visible_job(&state, &caller, &id).await?;
    // Subscribe before the first read: nothing written after it is missed.
    let changes = state.store.events.subscribe(&id);
    let (tx, rx) = mpsc::channel::<Event>(32);
    tokio::spawn(pump(state, caller, id, after, changes, tx));
    let stream = futures::stream::unfold(rx, |mut rx| async move {
        rx.recv().await.map(|e| (Ok::<_, Infallible>(e), rx))
    });
    Ok(Sse::new(stream)
        .keep_alive(KeepAlive::default())
        .into_response())
}

/// Send the job's events after `last` as they are written, then `done`.
async fn pump(
    state: AppState,
    caller: Caller,
    id: String,
    mut last: i64,
    mut changes: tokio::sync::watch::Receiver<u64>,
    tx: mpsc::Sender<Event>,
) {
    loop {
        // The job's state is read before its events: a terminal state seen here has its
        // status event among those read next.
        let job = match visible_job(&state, &caller, &id).await {
            Ok(j) => j,
            Err(_) => return,
        };
        let events = match state.store.job_events_after(&id, last).await {
            Ok(e) => e,
            Err(e) => {
                tracing::warn!(job = %id, "event stream: {e}");
                return;
            }
        };
        for e in events {
            let ev = Event::default()
                .id(e.id.to_string())
                .event(e.kind.as_str())
                .data(e.data.get());
            if tx.send(ev).await.is_err() {
                return;
            }
            last = e.id;
        }
        let (job, trace) = job;
        if job.status.is_terminal() {
            if let Ok(body) = job_body(&state, job, trace).await {
                let text = String::from_utf8_lossy(&body).into_owned();
                let _ = tx.send(Event::default().event("done").data(text)).await;
            }
            return;
        }
        tokio::select! {
            r = changes.changed() => if r.is_err() { return },
            _ = tx.closed() => return,
            _ = state.store.events.closing.cancelled() => return,
        }
    }
}
