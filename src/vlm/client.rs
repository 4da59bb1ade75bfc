//! Client for any OpenAI-compatible chat-completions endpoint, with retries, budgets and
//! cancellation.
//!
//! Retry policy: 429, 408, 5xx, timeouts and connection errors are retried up to
//! `max_retries` times, waiting `Retry-After` (or `retry-after-ms`) when the server sends
//! it, else `backoff_base_ms * 2^(n-1)` with jitter (50–100 %), capped at `backoff_max_ms`.
//! Every attempt takes one call from the job's [`CallBudget`]; no attempt starts (and no
//! wait runs) past the budget's deadline or after its cancellation token fires.

use crate::vlm::budget::{CallBudget, Usage};
use crate::vlm::config::{AuthStyle, VlmConfig, VlmStep};
use crate::vlm::error::{says_model_unknown, says_no_images, trim_message, VlmError};
use crate::vlm::message::{Message, Part, Role};
use crate::vlm::server_info::{models_url, props_url, ServerInfo};
pub use crate::vlm::wire::estimate_tokens;
use crate::vlm::wire::{
    error_message, fit_image, parse_completion, read_capped, retry_after, MAX_MESSAGE_CHARS,
};
use rand::Rng;
use serde_json::{json, Value};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Fewest reply tokens a request must leave room for in the model's context.
const MIN_REPLY_TOKENS: u64 = 16;
/// Time allowed to each request that asks the server about itself.
const PROBE_TIMEOUT: Duration = Duration::from_secs(5);

/// A successful reply.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ChatReply {
    /// The assistant's text.
    pub text: String,
    /// Token usage reported by the backend (zeros when it reports none).
    pub usage: Usage,
    /// HTTP attempts made (1 = no retry).
    pub attempts: u32,
    /// Wall time of the whole call including retries, milliseconds.
    pub latency_ms: u64,
}

/// A lasting problem of the VLM endpoint that a call has seen (the model cannot take
/// images, the model is not served): shown by `/readyz`.
#[derive(Debug, Default)]
pub struct VlmHealth {
    problem: Mutex<Option<String>>,
}

impl VlmHealth {
    /// The problem seen, if any.
    pub fn problem(&self) -> Option<String> {
        self.problem.lock().ok().and_then(|g| g.clone())
    }

    fn set(&self, problem: String) {
        if let Ok(mut g) = self.problem.lock() {
            *g = Some(problem);
        }
    }
}

/// The chat client. Cheap to share behind an `Arc`.
#[derive(Debug)]
pub struct VlmClient {
    cfg: VlmConfig,
    url: String,
    http: reqwest::Client,
    json_mode: AtomicBool,
    health: Arc<VlmHealth>,
    info: tokio::sync::Mutex<Option<ServerInfo>>,
}

/// Redirects are followed only to the same scheme, host and port (at most 5), so the key
/// never goes to another host.
fn redirect_policy() -> reqwest::redirect::Policy {
    reqwest::redirect::Policy::custom(|attempt| {
        let same_origin = attempt.previous().first().is_some_and(|first| {
            let next = attempt.url();
            first.scheme() == next.scheme()
                && first.host_str() == next.host_str()
                && first.port_or_known_default() == next.port_or_known_default()
        });
        if !same_origin {
            attempt.stop()
        } else if attempt.previous().len() > 5 {
            attempt.error("too many redirects")
        } else {
            attempt.follow()
        }
    })
}

enum Attempt {
    Done(ChatReply),
    Fatal(VlmError),
    Retry {
        err: VlmError,
        wait: Option<Duration>,
    },
    DropJsonMode,
}

impl VlmClient {
    /// Build a client.
    pub fn new(cfg: VlmConfig) -> Result<Self, VlmError> {
        if !cfg.base_url.starts_with("http://") && !cfg.base_url.starts_with("https://") {
            return Err(VlmError::Config(
                "base URL must start with http:// or https://".into(),
            ));
        }
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_millis(cfg.timeout_ms.clamp(1, 10_000)))
            .redirect(redirect_policy())
            .build()
            .map_err(|e| VlmError::Config(e.to_string()))?;
        Ok(Self {
            url: cfg.chat_url(),
            json_mode: AtomicBool::new(cfg.json_mode),
            cfg,
            http,
            health: Arc::new(VlmHealth::default()),
            info: tokio::sync::Mutex::new(None),
        })
    }

    /// Lasting problems seen by calls (shared with readiness).
    pub fn health(&self) -> Arc<VlmHealth> {
        self.health.clone()
    }

    /// The completion-token cap of a step (never above `max_tokens`).
    pub fn step_cap(&self, step: VlmStep) -> u32 {
        self.cfg.step_max_tokens.get(step).min(self.cfg.max_tokens)
    }

    /// What the server says about itself, asked once (again after a probe that got no
    /// HTTP answer at all). Problems it reveals (model not served, model cannot take
    /// images) are recorded in [`VlmHealth`].
    pub async fn server_info(&self) -> ServerInfo {
        let mut guard = self.info.lock().await;
        if let Some(info) = guard.as_ref() {
            return info.clone();
        }
        let Some(mut info) = self.get_json(&models_url(&self.cfg.base_url)).await else {
            return ServerInfo::default();
        };
        let mut info_from = ServerInfo::from_models(&info.take());
        if let Some(props) = props_url(&self.cfg.base_url) {
            if let Some(body) = self.get_json(&props).await {
                info_from.merge_props(&body);
            }
        }
        if self.cfg.check_model && !info_from.serves(&self.cfg.model) {
            self.health.set(format!(
                "the VLM endpoint does not serve model {:?}",
                self.cfg.model
            ));
        } else if info_from.vision == Some(false) {
            self.health
                .set("the VLM endpoint's model cannot take images".to_string());
        }
        *guard = Some(info_from.clone());
        info_from
    }

    /// GET a JSON document: `Some(Value::Null)` for any HTTP answer that is not 2xx JSON,
    /// None when no HTTP answer came.
    async fn get_json(&self, url: &str) -> Option<Value> {
        let mut req = self.http.get(url).timeout(PROBE_TIMEOUT);
        req = self.authorize(req);
        let resp = req.send().await.ok()?;
        if !resp.status().is_success() {
            return Some(Value::Null);
        }
        let body = read_capped(resp, self.cfg.max_reply_bytes).await.ok()?;
        Some(
            body.and_then(|b| serde_json::from_str(&b).ok())
                .unwrap_or(Value::Null),
        )
    }

    fn authorize(&self, req: reqwest::RequestBuilder) -> reqwest::RequestBuilder {
        if self.cfg.api_key.is_empty() {
            return req;
        }
        match self.cfg.auth_style {
            AuthStyle::Bearer => req.bearer_auth(self.cfg.api_key.expose()),
            AuthStyle::ApiKeyHeader => req.header("api-key", self.cfg.api_key.expose()),
        }
    }

    /// Check a request against what the server said; returns the reply-token cap to send.
    fn admit(&self, info: &ServerInfo, messages: &[Message], cap: u32) -> Result<u32, VlmError> {
        if self.cfg.check_model && !info.serves(&self.cfg.model) {
            return Err(VlmError::ModelNotFound {
                model: self.cfg.model.clone(),
                available: trim_message(
                    &info.models.clone().unwrap_or_default().join(", "),
                    MAX_MESSAGE_CHARS,
                ),
            });
        }
        let images: usize = messages.iter().map(Message::image_count).sum();
        if images > 0 && info.vision == Some(false) {
            return Err(VlmError::CannotSeeImages {
                message: "the server says its model takes text only".into(),
            });
        }
        let n_ctx = match self.cfg.context_tokens {
            0 => info.n_ctx,
            n => Some(n),
        };
        let Some(n_ctx) = n_ctx else {
            return Ok(cap);
        };
        let prompt = estimate_tokens(messages, self.cfg.image_tokens);
        let room = n_ctx.saturating_sub(prompt);
        if room < MIN_REPLY_TOKENS.min(cap as u64) {
            return Err(VlmError::ContextOverflow {
                needed: prompt + cap as u64,
                prompt,
                reply: cap as u64,
                n_ctx,
            });
        }
        Ok(cap.min(room.min(u32::MAX as u64) as u32))
    }

    /// The configuration (its Debug form redacts the key).
    pub fn config(&self) -> &VlmConfig {
        &self.cfg
    }

    /// Send a conversation and return the assistant's reply (at most `max_tokens`).
    pub async fn chat(
        &self,
        messages: &[Message],
        budget: &CallBudget,
    ) -> Result<ChatReply, VlmError> {
        self.chat_capped(messages, budget, self.cfg.max_tokens)
            .await
    }

    /// Send the conversation of a pipeline step, with that step's reply cap.
    pub async fn chat_step(
        &self,
        step: VlmStep,
        messages: &[Message],
        budget: &CallBudget,
    ) -> Result<ChatReply, VlmError> {
        self.chat_capped(messages, budget, self.step_cap(step))
            .await
    }

    /// Send a conversation with a reply cap of `max_tokens`, the whole call (attempts and
    /// waits) bounded by `call_timeout_ms`.
    pub async fn chat_capped(
        &self,
        messages: &[Message],
        budget: &CallBudget,
        max_tokens: u32,
    ) -> Result<ChatReply, VlmError> {
        let ms = self.cfg.call_timeout_ms.max(1);
        tokio::time::timeout(
            Duration::from_millis(ms),
            self.chat_inner(messages, budget, max_tokens),
        )
        .await
        .unwrap_or(Err(VlmError::CallTimeout { ms }))
    }

    async fn chat_inner(
        &self,
        messages: &[Message],
        budget: &CallBudget,
        max_tokens: u32,
    ) -> Result<ChatReply, VlmError> {
        let count: usize = messages.iter().map(Message::image_count).sum();
        if count > self.cfg.max_images_per_request {
            return Err(VlmError::TooManyImages {
                count,
                max: self.cfg.max_images_per_request,
            });
        }
        let info = tokio::select! {
            _ = budget.cancel_token().cancelled() => return Err(VlmError::Cancelled),
            i = self.server_info() => i,
        };
        let max_tokens = self.admit(&info, messages, max_tokens).inspect_err(|e| {
            if let VlmError::CannotSeeImages { .. } = e {
                self.health.set(e.to_string());
            }
        })?;
        let wire = self.wire_messages(messages)?;
        let start = Instant::now();
        let mut attempts = 0u32;
        let mut retries = 0u32;
        loop {
            if budget.is_cancelled() {
                return Err(VlmError::Cancelled);
            }
            let remaining = budget.remaining();
            if remaining.is_some_and(|r| r.is_zero()) {
                return Err(VlmError::DeadlineExceeded);
            }
            if !budget.try_take() {
                return Err(VlmError::CallBudgetExhausted {
                    max_calls: budget.max_calls(),
                });
            }
            attempts += 1;
            let mut timeout = Duration::from_millis(self.cfg.timeout_ms.max(1));
            if let Some(r) = remaining {
                timeout = timeout.min(r);
            }
            let outcome = tokio::select! {
                _ = budget.cancel_token().cancelled() => return Err(VlmError::Cancelled),
                o = self.attempt(&wire, max_tokens, timeout, attempts, start) => o,
            };
            match outcome {
                Attempt::Done(reply) => {
                    budget.record_usage(reply.usage);
                    return Ok(reply);
                }
                Attempt::Fatal(e) => {
                    if matches!(
                        e,
                        VlmError::CannotSeeImages { .. } | VlmError::ModelNotFound { .. }
                    ) {
                        self.health.set(e.to_string());
                    }
                    return Err(e);
                }
                Attempt::DropJsonMode => {
                    tracing::info!(
                        "VLM endpoint does not accept JSON response mode; sending without it"
                    );
                    self.json_mode.store(false, Ordering::SeqCst);
                }
                Attempt::Retry { err, wait } => {
                    if retries >= self.cfg.max_retries {
                        return Err(err);
                    }
                    retries += 1;
                    let wait = wait.unwrap_or_else(|| self.backoff(retries));
                    let wait = wait.min(Duration::from_millis(self.cfg.backoff_max_ms));
                    if budget.remaining().is_some_and(|r| r < wait) {
                        return Err(VlmError::DeadlineExceeded);
                    }
                    tracing::warn!(attempt = attempts, wait_ms = wait.as_millis() as u64, error = %err, "VLM call failed; retrying");
                    tokio::select! {
                        _ = budget.cancel_token().cancelled() => return Err(VlmError::Cancelled),
                        _ = tokio::time::sleep(wait) => {}
                    }
                }
            }
        }
    }

    fn backoff(&self, retry: u32) -> Duration {
        let base =
            self.cfg.backoff_base_ms as f64 * 2f64.powi(retry.saturating_sub(1).min(30) as i32);
        let capped = base.min(self.cfg.backoff_max_ms as f64);
        let jitter: f64 = rand::thread_rng().gen_range(0.5..=1.0);
        Duration::from_millis((capped * jitter) as u64)
    }

    async fn attempt(
        &self,
        wire: &[Value],
        max_tokens: u32,
        timeout: Duration,
        attempts: u32,
        start: Instant,
    ) -> Attempt {
        let json_mode = self.json_mode.load(Ordering::SeqCst);
        let mut body = json!({
            "model": self.cfg.model,
            "messages": wire,
            "temperature": self.cfg.temperature,
            "top_p": self.cfg.top_p,
            "max_tokens": max_tokens,
        });
        if json_mode {
            body["response_format"] = json!({"type": "json_object"});
        }
        let req = self
            .authorize(self.http.post(&self.url).timeout(timeout))
            .json(&body);
        let resp = match req.send().await {
            Ok(r) => r,
            Err(e) => return self.transport_error(e, attempts),
        };
        let status = resp.status().as_u16();
        let wait = retry_after(resp.headers());
        let location = resp
            .headers()
            .get(reqwest::header::LOCATION)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string();
        let text = match read_capped(resp, self.cfg.max_reply_bytes).await {
            Ok(Some(t)) => t,
            Ok(None) => {
                return Attempt::Fatal(VlmError::ReplyTooLarge {
                    limit: self.cfg.max_reply_bytes,
                })
            }
            Err(e) => return self.transport_error(e, attempts),
        };
        tracing::debug!(
            status,
            attempt = attempts,
            bytes = text.len(),
            "VLM response"
        );
        if (200..300).contains(&status) {
            return match parse_completion(&text) {
                Ok((text, usage)) => Attempt::Done(ChatReply {
                    text,
                    usage,
                    attempts,
                    latency_ms: start.elapsed().as_millis() as u64,
                }),
                Err(m) => Attempt::Fatal(VlmError::InvalidResponse(self.redact(&m))),
            };
        }
        if (300..400).contains(&status) {
            return Attempt::Fatal(VlmError::Redirected {
                status,
                location: self.redact(&location),
            });
        }
        let (message, code) = error_message(&text);
        let message = trim_message(&self.redact(&message), MAX_MESSAGE_CHARS);
        if says_no_images(&message) {
            return Attempt::Fatal(VlmError::CannotSeeImages { message });
        }
        match status {
            401 | 403 => Attempt::Fatal(VlmError::Auth { status, message }),
            400..=499
                if status != 408
                    && status != 429
                    && says_model_unknown(&message, code.as_deref()) =>
            {
                Attempt::Fatal(VlmError::ModelNotFound {
                    model: self.cfg.model.clone(),
                    available: message,
                })
            }
            429 => Attempt::Retry {
                err: VlmError::RateLimited { attempts, message },
                wait,
            },
            408 => Attempt::Retry {
                err: VlmError::Timeout { attempts },
                wait,
            },
            500..=599 => Attempt::Retry {
                err: VlmError::Server {
                    status,
                    attempts,
                    message,
                },
                wait,
            },
            400 | 422 if json_mode && message.contains("response_format") => Attempt::DropJsonMode,
            _ => Attempt::Fatal(VlmError::BadRequest { status, message }),
        }
    }

    fn transport_error(&self, e: reqwest::Error, attempts: u32) -> Attempt {
        if e.is_timeout() {
            Attempt::Retry {
                err: VlmError::Timeout { attempts },
                wait: None,
            }
        } else if e.is_builder() {
            Attempt::Fatal(VlmError::Config(self.redact(&e.to_string())))
        } else {
            // Connection refused/reset, broken body: worth another try.
            let mut msg = e.to_string();
            let mut src = std::error::Error::source(&e);
            while let Some(s) = src {
                msg.push_str(": ");
                msg.push_str(&s.to_string());
                src = s.source();
            }
            Attempt::Retry {
                err: VlmError::Connection {
                    attempts,
                    message: self.redact(&msg),
                },
                wait: None,
            }
        }
    }

    /// Remove the key from any text that might be logged.
    fn redact(&self, s: &str) -> String {
        let key = self.cfg.api_key.expose();
        if key.len() >= 4 {
            s.replace(key, "<redacted>")
        } else {
            s.to_string()
        }
    }

    fn wire_messages(&self, messages: &[Message]) -> Result<Vec<Value>, VlmError> {
        messages
            .iter()
            .map(|m| {
                let only_text = m.parts.iter().all(|p| matches!(p, Part::Text(_)));
                // Plain strings for text-only messages: accepted by every backend.
                if only_text || m.role != Role::User {
                    return Ok(json!({"role": m.role.as_str(), "content": m.text()}));
                }
                let mut content = Vec::with_capacity(m.parts.len());
                for p in &m.parts {
                    match p {
                        Part::Text(t) => content.push(json!({"type": "text", "text": t})),
                        Part::Image(img) => {
                            let img = fit_image(img, self.cfg.max_image_side)?;
                            content.push(json!({
                                "type": "image_url",
                                "image_url": {"url": img.data_url(), "detail": self.cfg.image_detail},
                            }));
                        }
                    }
                }
                Ok(json!({"role": m.role.as_str(), "content": content}))
            })
            .collect()
    }
}
