//! `Idempotency-Key` on creating requests: the first response is stored for 24 h (in the
//! database, so it survives restarts) and replayed for a retry with the same body.

use axum::body::Body;
use axum::http::{HeaderMap, HeaderName, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use std::future::Future;

use super::auth::Caller;
use super::{ApiError, AppState};
use crate::store::idempotency::{Begin, StoredResponse};

/// The request header.
pub const HEADER: &str = "idempotency-key";

/// Headers kept with a stored response.
const KEPT: [&str; 3] = ["content-type", "location", "etag"];

/// The key of a request, validated (1..=255 printable ASCII characters).
pub fn key_of(headers: &HeaderMap) -> Result<Option<String>, ApiError> {
    let Some(v) = headers.get(HEADER) else {
        return Ok(None);
    };
    let k = v.to_str().ok().map(str::trim).unwrap_or("");
    if k.is_empty() || k.len() > 255 || !k.bytes().all(|b| (0x20..0x7f).contains(&b)) {
        return Err(ApiError::bad_request(
            "invalid_idempotency_key",
            "Idempotency-Key must be 1 to 255 printable ASCII characters",
        ));
    }
    Ok(Some(k.to_string()))
}

/// Run `work` under the request's idempotency key, if any. `work` runs in its own task,
/// so a client that hangs up does not leave the key held: the response is stored and its
/// retry gets it.
pub async fn run<F>(
    state: &AppState,
    caller: &Caller,
    route: &'static str,
    key: Option<String>,
    body_sha256: &str,
    work: F,
) -> Result<Response, ApiError>
where
    F: Future<Output = Result<Response, ApiError>> + Send + 'static,
{
    let Some(key) = key else {
        return work.await;
    };
    let scope = caller.scope();
    match state
        .store
        .idempotency_begin(scope, route, &key, body_sha256)
        .await?
    {
        Begin::Proceed => {}
        Begin::Replay(r) => return Ok(replay(r)),
        Begin::Mismatch => {
            return Err(ApiError::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                "idempotency_key_reused",
                "this Idempotency-Key was used with a different request body",
            ))
        }
        Begin::InFlight => {
            return Err(ApiError::new(
                StatusCode::CONFLICT,
                "idempotency_key_in_use",
                "a request with this Idempotency-Key is still being processed; retry later",
            ))
        }
    }
    let store = state.store.clone();
    let task = tokio::spawn(async move {
        let resp = match work.await {
            Ok(r) => r,
            Err(e) => e.into_response(),
        };
        let status = resp.status();
        if status.is_server_error() || status == StatusCode::TOO_MANY_REQUESTS {
            // Worth retrying: the key is free again.
            if let Err(e) = store.idempotency_abandon(scope, route, &key).await {
                tracing::error!("cannot release idempotency key: {e}");
            }
            return Ok(resp);
        }
        let (parts, body) = resp.into_parts();
        let bytes = axum::body::to_bytes(body, usize::MAX)
            .await
            .map_err(|e| ApiError::internal(format!("cannot read the response: {e}")))?;
        let stored = StoredResponse {
            status: parts.status.as_u16(),
            headers: KEPT
                .iter()
                .filter_map(|h| {
                    let v = parts.headers.get(*h)?.to_str().ok()?;
                    Some((h.to_string(), v.to_string()))
                })
                .collect(),
            body: bytes.to_vec(),
        };
        if let Err(e) = store.idempotency_finish(scope, route, &key, &stored).await {
            tracing::error!("cannot store the idempotent response: {e}");
            let _ = store.idempotency_abandon(scope, route, &key).await;
        }
        Ok(Response::from_parts(parts, Body::from(bytes)))
    });
    task.await
        .map_err(|e| ApiError::internal(format!("request task failed: {e}")))?
}

fn replay(r: StoredResponse) -> Response {
    let mut resp = Response::new(Body::from(r.body));
    *resp.status_mut() = StatusCode::from_u16(r.status).unwrap_or(StatusCode::OK);
    let h = resp.headers_mut();
    for (k, v) in r.headers {
        if let (Ok(k), Ok(v)) = (HeaderName::try_from(k.as_str()), HeaderValue::from_str(&v)) {
            h.insert(k, v);
        }
    }
    h.insert("idempotent-replayed", HeaderValue::from_static("true"));
    resp
}
