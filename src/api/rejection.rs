//! Every 4xx is problem+json: responses that axum's own extractors and router produce
//! (a malformed path or query, a wrong content type, a method not allowed, a body that
//! does not deserialize) come as plain text; this layer turns them into [`ApiError`]s.

use axum::extract::Request;
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::ApiError;

/// Largest plain-text body read into the problem's detail.
const MAX_DETAIL_BYTES: usize = 4096;

/// The problem code of an axum rejection by status.
fn code_for(status: StatusCode) -> &'static str {
    match status {
        StatusCode::BAD_REQUEST => "bad_request",
        StatusCode::NOT_FOUND => "not_found",
        StatusCode::METHOD_NOT_ALLOWED => "method_not_allowed",
        StatusCode::PAYLOAD_TOO_LARGE => "payload_too_large",
        StatusCode::UNSUPPORTED_MEDIA_TYPE => "unsupported_media_type",
        StatusCode::UNPROCESSABLE_ENTITY => "invalid_body",
        StatusCode::LENGTH_REQUIRED => "length_required",
        _ => "client_error",
    }
}

/// Rewrite a 4xx that is not already a problem (nor an empty 4xx such as 304's kin).
pub async fn problems_for_rejections(req: Request, next: Next) -> Response {
    let resp = next.run(req).await;
    let status = resp.status();
    if !status.is_client_error() {
        return resp;
    }
    let is_plain = resp
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_none_or(|ct| ct.starts_with("text/plain"));
    if !is_plain {
        return resp;
    }
    let (parts, body) = resp.into_parts();
    let detail = match axum::body::to_bytes(body, MAX_DETAIL_BYTES).await {
        Ok(b) if !b.is_empty() => String::from_utf8_lossy(&b).trim().to_string(),
        _ => status
            .canonical_reason()
            .unwrap_or("client error")
            .to_string(),
    };
    let mut out = ApiError::new(status, code_for(status), detail).into_response();
    // Keep headers such as Allow (405) that tell the client what to do.
    for (name, value) in parts.headers.iter() {
        if name != header::CONTENT_TYPE && name != header::CONTENT_LENGTH {
            out.headers_mut().insert(name.clone(), value.clone());
        }
    }
    out
}
