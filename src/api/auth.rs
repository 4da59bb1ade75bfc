//! Bearer keys: who is calling, and what they may see.
//!
//! When at least one active key exists, every `/v1/` request needs
//! `Authorization: Bearer <secret>` and `/metrics` needs an admin key. Without keys, the
//! service answers anonymously (as an admin) only when it may: on a loopback address, or
//! when started with `--allow-anonymous`. Keys are created by `grounder keys` in another
//! process, so lookups are cached for [`TTL`] only: a new or revoked key takes effect
//! within that time.

use axum::extract::{Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use super::{ApiError, AppState};
use crate::store::keys::secret_hash;
use crate::store::{KeyRecord, Store, StoreError};

/// How long a key lookup is trusted.
pub const TTL: Duration = Duration::from_secs(1);

/// The caller of a request (in the request's extensions for every guarded route).
#[derive(Debug, Clone)]
pub struct Caller {
    /// The key's id; None for anonymous access (no keys exist).
    pub key_id: Option<i64>,
    pub admin: bool,
    pub max_running_jobs: Option<i64>,
    pub max_scene_bytes: Option<i64>,
}

impl Caller {
    pub fn anonymous() -> Self {
        Self {
            key_id: None,
            admin: true,
            max_running_jobs: None,
            max_scene_bytes: None,
        }
    }

    fn of_key(k: &KeyRecord) -> Self {
        Self {
            key_id: Some(k.id),
            admin: k.admin,
            max_running_jobs: k.max_running_jobs,
            max_scene_bytes: k.max_scene_bytes,
        }
    }

    /// May this caller see a row owned by `owner`?
    pub fn sees(&self, owner: Option<i64>) -> bool {
        self.admin || (self.key_id.is_some() && owner == self.key_id)
    }

    /// The owner filter for lists: None (everything) for admins.
    pub fn list_filter(&self) -> Option<i64> {
        if self.admin {
            None
        } else {
            self.key_id.or(Some(-1))
        }
    }

    /// Scope of idempotency keys (0 without keys).
    pub fn scope(&self) -> i64 {
        self.key_id.unwrap_or(0)
    }
}

#[derive(Default)]
struct Cache {
    any_keys: Option<(Instant, bool)>,
    by_hash: HashMap<String, (Instant, Option<KeyRecord>)>,
}

/// Key resolution with a short cache.
pub struct Auth {
    /// Anonymous access is allowed when no key exists (loopback or `--allow-anonymous`).
    pub anonymous_allowed: bool,
    cache: Mutex<Cache>,
}

impl Auth {
    pub fn new(anonymous_allowed: bool) -> Self {
        Self {
            anonymous_allowed,
            cache: Mutex::new(Cache::default()),
        }
    }

    async fn any_keys(&self, store: &Store) -> Result<bool, StoreError> {
        {
            let c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
            if let Some((at, v)) = c.any_keys {
                if at.elapsed() < TTL {
                    return Ok(v);
                }
            }
        }
        let v = store.any_active_key().await?;
        let mut c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        c.any_keys = Some((Instant::now(), v));
        Ok(v)
    }

    async fn key(&self, store: &Store, secret: &str) -> Result<Option<KeyRecord>, StoreError> {
        let hash = secret_hash(secret);
        {
            let c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
            if let Some((at, v)) = c.by_hash.get(&hash) {
                if at.elapsed() < TTL {
                    return Ok(v.clone());
                }
            }
        }
        let v = store.key_by_hash(&hash).await?;
        let mut c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if c.by_hash.len() > 10_000 {
            c.by_hash.clear();
        }
        c.by_hash.insert(hash, (Instant::now(), v.clone()));
        Ok(v)
    }

    /// Who is calling, from the `Authorization` header value. A presented key must be
    /// valid even when anonymous access is allowed.
    pub async fn resolve(
        &self,
        store: &Store,
        authorization: Option<&str>,
    ) -> Result<Caller, ApiError> {
        let Some(value) = authorization else {
            if !self.any_keys(store).await? {
                return if self.anonymous_allowed {
                    Ok(Caller::anonymous())
                } else {
                    Err(ApiError::unauthorized(
                        "no API key exists and anonymous access is off on this address: create one with `grounder keys create`",
                    ))
                };
            }
            return Err(ApiError::unauthorized(
                "this request needs an API key: Authorization: Bearer <key>",
            ));
        };
        let secret = value
            .strip_prefix("Bearer ")
            .or_else(|| value.strip_prefix("bearer "))
            .map(str::trim)
            .ok_or_else(|| {
                ApiError::unauthorized("the Authorization header must be `Bearer <key>`")
            })?;
        match self.key(store, secret).await? {
            Some(k) => Ok(Caller::of_key(&k)),
            None => Err(ApiError::unauthorized("unknown or revoked API key")),
        }
    }
}

/// A key a browser carries for the viewer pages (GET only): the `grounder_key` cookie the
/// pages set, or `?key=` on the first page load. Keys are URL-safe, so no decoding is needed.
fn browser_key(req: &Request) -> Option<String> {
    if req.method() != axum::http::Method::GET {
        return None;
    }
    let valid = |k: &str| {
        !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    };
    let from_cookie = req
        .headers()
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .find_map(|c| c.trim().strip_prefix("grounder_key="))
        .filter(|k| valid(k))
        .map(str::to_string);
    from_cookie.or_else(|| {
        req.uri()
            .query()?
            .split('&')
            .find_map(|kv| kv.strip_prefix("key="))
            .filter(|k| valid(k))
            .map(str::to_string)
    })
}

/// Middleware: resolve the caller of `/v1/` and `/metrics` requests.
pub async fn authenticate(State(state): State<AppState>, mut req: Request, next: Next) -> Response {
    let path = req.uri().path();
    let metrics = path == "/metrics";
    if !(path.starts_with("/v1/") || path == "/v1" || metrics) {
        return next.run(req).await;
    }
    let authorization = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string)
        .or_else(|| browser_key(&req).map(|k| format!("Bearer {k}")));
    let caller = match state
        .auth
        .resolve(&state.store, authorization.as_deref())
        .await
    {
        Ok(c) => c,
        Err(e) => return e.into_response(),
    };
    if metrics && !caller.admin {
        return ApiError::new(
            StatusCode::FORBIDDEN,
            "forbidden",
            "/metrics needs an admin key",
        )
        .into_response();
    }
    req.extensions_mut().insert(caller);
    next.run(req).await
}
