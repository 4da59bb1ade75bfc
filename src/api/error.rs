//! RFC 9457 problem details: every error the API returns.

use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

use crate::scene::SceneError;
use crate::store::StoreError;

/// `application/problem+json` body.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Problem {
    /// URI reference naming the problem type (`/problems/<code>`).
    #[serde(rename = "type")]
    pub kind: String,
    pub title: String,
    pub status: u16,
    pub detail: String,
    /// Stable machine-readable code.
    pub code: String,
}

/// An error on its way to becoming a problem response.
#[derive(Debug, Clone)]
pub struct ApiError {
    pub status: StatusCode,
    pub code: &'static str,
    pub detail: String,
    /// Seconds for a `Retry-After` header (429, 503).
    pub retry_after: Option<u64>,
    /// Send `WWW-Authenticate: Bearer` (401).
    pub challenge: bool,
    /// A 5xx whose detail is written for the caller (readiness, overload) and holds no
    /// internal error text; any other 5xx answers a generic detail with an id.
    pub public: bool,
}

/// The `detail` every 5xx answers unless it is [`ApiError::public`]: the id is logged at
/// error level with the cause.
pub fn internal_detail(id: &str) -> String {
    format!("internal error, id {id}")
}

impl ApiError {
    pub fn new(status: StatusCode, code: &'static str, detail: impl Into<String>) -> Self {
        Self {
            status,
            code,
            detail: detail.into(),
            retry_after: None,
            challenge: false,
            public: false,
        }
    }
    /// 503 whose detail the caller may read (it must hold no internal error text).
    pub fn unavailable(code: &'static str, detail: impl Into<String>) -> Self {
        Self {
            public: true,
            ..Self::new(StatusCode::SERVICE_UNAVAILABLE, code, detail)
        }
    }
    /// 401 `unauthorized` with a `WWW-Authenticate: Bearer` challenge.
    pub fn unauthorized(detail: impl Into<String>) -> Self {
        Self {
            challenge: true,
            ..Self::new(StatusCode::UNAUTHORIZED, "unauthorized", detail)
        }
    }
    /// 429 with `Retry-After`.
    pub fn too_many(code: &'static str, detail: impl Into<String>, retry_after: u64) -> Self {
        Self {
            retry_after: Some(retry_after),
            ..Self::new(StatusCode::TOO_MANY_REQUESTS, code, detail)
        }
    }
    pub fn not_found(what: &str, id: &str) -> Self {
        Self::new(
            StatusCode::NOT_FOUND,
            if what == "scene" {
                "scene_not_found"
            } else {
                "job_not_found"
            },
            format!("no {what} with id {id:?}"),
        )
    }
    pub fn bad_request(code: &'static str, detail: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, code, detail)
    }
    pub fn internal(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", detail)
    }

    pub fn problem(&self) -> Problem {
        Problem {
            kind: format!("/problems/{}", self.code.replace('_', "-")),
            title: self
                .status
                .canonical_reason()
                .unwrap_or("Error")
                .to_string(),
            status: self.status.as_u16(),
            detail: self.detail.clone(),
            code: self.code.to_string(),
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(mut self) -> Response {
        // An overload answer (with Retry-After) says nothing internal either.
        if self.status.is_server_error() && !self.public && self.retry_after.is_none() {
            let id = uuid::Uuid::now_v7().simple().to_string();
            tracing::error!(error_id = %id, code = self.code, "{}", self.detail);
            self.detail = internal_detail(&id);
        } else if self.status.is_server_error() {
            tracing::warn!(code = self.code, "{}", self.detail);
        }
        let body = serde_json::to_vec(&self.problem()).unwrap_or_default();
        let mut resp = (
            self.status,
            [(header::CONTENT_TYPE, "application/problem+json")],
            body,
        )
            .into_response();
        if let Some(secs) = self.retry_after {
            resp.headers_mut()
                .insert(header::RETRY_AFTER, header::HeaderValue::from(secs));
        }
        if self.challenge {
            resp.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                header::HeaderValue::from_static("Bearer"),
            );
        }
        resp
    }
}

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        ApiError::internal(e.to_string())
    }
}

impl From<SceneError> for ApiError {
    fn from(e: SceneError) -> Self {
        let status = match &e {
            SceneError::TooLarge(_)
            | SceneError::ImageTooLarge(_)
            | SceneError::SceneTooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            SceneError::NotArchive(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            SceneError::Io(_) => StatusCode::INTERNAL_SERVER_ERROR,
            SceneError::BadImage(_)
            | SceneError::DepthSize(_)
            | SceneError::Malformed(_)
            | SceneError::NoFrames
            | SceneError::NoScene => StatusCode::UNPROCESSABLE_ENTITY,
            SceneError::Truncated(_) | SceneError::UnsafeArchive(_) => StatusCode::BAD_REQUEST,
        };
        ApiError::new(status, e.code(), e.to_string())
    }
}

/// JSON body extractor whose rejections are problems too.
pub struct Json<T>(pub T);

impl<S, T> axum::extract::FromRequest<S> for Json<T>
where
    T: serde::de::DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request(req: axum::extract::Request, state: &S) -> Result<Self, Self::Rejection> {
        match axum::Json::<T>::from_request(req, state).await {
            Ok(axum::Json(v)) => Ok(Json(v)),
            Err(rej) => Err(ApiError::new(rej.status(), "invalid_json", rej.body_text())),
        }
    }
}

/// Query-string extractor whose rejections are problems too.
pub struct Query<T>(pub T);

impl<S, T> axum::extract::FromRequestParts<S> for Query<T>
where
    T: serde::de::DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        state: &S,
    ) -> Result<Self, Self::Rejection> {
        match axum::extract::Query::<T>::from_request_parts(parts, state).await {
            Ok(axum::extract::Query(v)) => Ok(Query(v)),
            Err(rej) => Err(ApiError::bad_request(
                "invalid_query_string",
                rej.body_text(),
            )),
        }
    }
}
