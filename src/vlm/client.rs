//! Client for any OpenAI-compatible chat-completions endpoint, with retries, budgets and
//! cancellation.
//!
//! Retry policy: 429, 408, 5xx, timeouts and connection errors are retried up to
//! `max_retries` times, waiting `Retry-After` (or `retry-after-ms`) when the server sends
//! it, else `backoff_base_ms * 2^(n-1)` with jitter (50–100 %), capped at `backoff_max_ms`.
//! Every attempt takes one call from the job's [`CallBudget`]; no attempt starts (and no
//! wait runs) past the budget's deadline or after its cancellation token fires.

use crate::vlm::budget::{CallBudget, Usage};
use crate::vlm::config::{AuthStyle, VlmConfig};
use crate::vlm::message::{ImageData, Message, Part, Role};
use rand::Rng;
use serde_json::{json, Value};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

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

/// Why a chat call failed.
#[derive(Debug, thiserror::Error)]
pub enum VlmError {
    /// The job's cancellation token fired.
    #[error("VLM call cancelled")]
    Cancelled,
    /// The job's call budget is spent.
    #[error("VLM call budget of {max_calls} calls exhausted")]
    CallBudgetExhausted {
        /// The budget.
        max_calls: u32,
    },
    /// The job's wall-time budget is spent (or a wait would exceed it).
    #[error("VLM wall-time budget exhausted")]
    DeadlineExceeded,
    /// 401/403: key missing or wrong.
    #[error("VLM endpoint refused the credentials (HTTP {status}): {message}")]
    Auth {
        /// HTTP status.
        status: u16,
        /// Server message (key redacted).
        message: String,
    },
    /// Other 4xx: the request itself is wrong (model name, payload size...).
    #[error("VLM endpoint rejected the request (HTTP {status}): {message}")]
    BadRequest {
        /// HTTP status.
        status: u16,
        /// Server message (key redacted).
        message: String,
    },
    /// Still rate-limited after all retries.
    #[error("VLM endpoint still rate-limited after {attempts} attempts: {message}")]
    RateLimited {
        /// Attempts made.
        attempts: u32,
        /// Last server message.
        message: String,
    },
    /// Still failing with 5xx after all retries.
    #[error("VLM endpoint failed with HTTP {status} after {attempts} attempts: {message}")]
    Server {
        /// Last HTTP status.
        status: u16,
        /// Attempts made.
        attempts: u32,
        /// Last server message.
        message: String,
    },
    /// Still timing out after all retries.
    #[error("VLM request timed out {attempts} times")]
    Timeout {
        /// Attempts made.
        attempts: u32,
    },
    /// Still unable to connect after all retries.
    #[error("cannot reach the VLM endpoint after {attempts} attempts: {message}")]
    Connection {
        /// Attempts made.
        attempts: u32,
        /// Last error.
        message: String,
    },
    /// 2xx with a body that is not a chat completion.
    #[error("VLM endpoint sent an unusable response: {0}")]
    InvalidResponse(String),
    /// More images than `max_images_per_request`.
    #[error("{count} images in one request exceed the limit of {max}")]
    TooManyImages {
        /// Images in the request.
        count: usize,
        /// Configured limit.
        max: usize,
    },
    /// An attached image cannot be read or re-encoded.
    #[error("cannot prepare an image for the VLM: {0}")]
    Image(String),
    /// The client cannot be built from the configuration.
    #[error("invalid VLM configuration: {0}")]
    Config(String),
}

/// The chat client. Cheap to share behind an `Arc`.
#[derive(Debug)]
pub struct VlmClient {
    cfg: VlmConfig,
    url: String,
    http: reqwest::Client,
    json_mode: AtomicBool,
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
            .build()
            .map_err(|e| VlmError::Config(e.to_string()))?;
        Ok(Self {
            url: cfg.chat_url(),
            json_mode: AtomicBool::new(cfg.json_mode),
            cfg,
            http,
        })
    }

    /// The configuration (its Debug form redacts the key).
    pub fn config(&self) -> &VlmConfig {
        &self.cfg
    }

    /// Send a conversation and return the assistant's reply.
    pub async fn chat(
        &self,
        messages: &[Message],
        budget: &CallBudget,
    ) -> Result<ChatReply, VlmError> {
        let count: usize = messages.iter().map(Message::image_count).sum();
        if count > self.cfg.max_images_per_request {
            return Err(VlmError::TooManyImages {
                count,
                max: self.cfg.max_images_per_request,
            });
        }
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
                o = self.attempt(&wire, timeout, attempts, start) => o,
            };
            match outcome {
                Attempt::Done(reply) => {
                    budget.record_usage(reply.usage);
                    return Ok(reply);
                }
                Attempt::Fatal(e) => return Err(e),
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
            "max_tokens": self.cfg.max_tokens,
        });
        if json_mode {
            body["response_format"] = json!({"type": "json_object"});
        }
        let mut req = self.http.post(&self.url).timeout(timeout).json(&body);
        if !self.cfg.api_key.is_empty() {
            req = match self.cfg.auth_style {
                AuthStyle::Bearer => req.bearer_auth(self.cfg.api_key.expose()),
                AuthStyle::ApiKeyHeader => req.header("api-key", self.cfg.api_key.expose()),
            };
        }
        let resp = match req.send().await {
            Ok(r) => r,
            Err(e) => return self.transport_error(e, attempts),
        };
        let status = resp.status().as_u16();
        let wait = retry_after(resp.headers());
        let text = match resp.text().await {
            Ok(t) => t,
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
        let message = self.redact(&error_message(&text));
        match status {
            401 | 403 => Attempt::Fatal(VlmError::Auth { status, message }),
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

/// Downscale an image whose longer side exceeds `max_side` (Lanczos, JPEG quality 90).
fn fit_image(img: &ImageData, max_side: u32) -> Result<ImageData, VlmError> {
    use image::ImageReader;
    use std::io::Cursor;
    let reader = ImageReader::new(Cursor::new(&img.jpeg[..]))
        .with_guessed_format()
        .map_err(|e| VlmError::Image(e.to_string()))?;
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| VlmError::Image(e.to_string()))?;
    if max_side == 0 || w.max(h) <= max_side {
        return Ok(img.clone());
    }
    let decoded = image::load_from_memory(&img.jpeg).map_err(|e| VlmError::Image(e.to_string()))?;
    let resized = decoded
        .resize(max_side, max_side, image::imageops::FilterType::Lanczos3)
        .to_rgb8();
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
        .encode_image(&resized)
        .map_err(|e| VlmError::Image(e.to_string()))?;
    Ok(ImageData::jpeg(out))
}

/// `retry-after-ms` or `Retry-After` (seconds) as a duration.
fn retry_after(h: &reqwest::header::HeaderMap) -> Option<Duration> {
    let read = |name: &str| {
        h.get(name)
            .and_then(|v| v.to_str().ok())
            .and_then(|s| s.trim().parse::<f64>().ok())
    };
    // A server's number is clamped to a day before it becomes a duration (1e20 seconds
    // would overflow it); the caller caps the wait further at its own maximum.
    const DAY: f64 = 86_400.0;
    if let Some(ms) = read("retry-after-ms").filter(|v| v.is_finite() && *v >= 0.0) {
        return Some(Duration::from_secs_f64((ms / 1000.0).min(DAY)));
    }
    read("retry-after")
        .filter(|v| v.is_finite() && *v >= 0.0)
        .map(|s| Duration::from_secs_f64(s.min(DAY)))
}

/// The `error.message` of an OpenAI-style error body, else the start of the body.
fn error_message(body: &str) -> String {
    if let Ok(v) = serde_json::from_str::<Value>(body) {
        if let Some(m) = v.pointer("/error/message").and_then(Value::as_str) {
            return m.to_string();
        }
        if let Some(m) = v.get("error").and_then(Value::as_str) {
            return m.to_string();
        }
    }
    body.chars().take(300).collect()
}

/// Text and usage of a chat completion body.
fn parse_completion(body: &str) -> Result<(String, Usage), String> {
    let v: Value = serde_json::from_str(body).map_err(|e| format!("body is not JSON: {e}"))?;
    let msg = v
        .pointer("/choices/0/message")
        .ok_or("no choices[0].message in the body")?;
    let text = match msg.get("content") {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Array(parts)) => parts
            .iter()
            .filter_map(|p| p.get("text").and_then(Value::as_str))
            .collect::<Vec<_>>()
            .join(""),
        _ => {
            let refusal = msg
                .get("refusal")
                .and_then(Value::as_str)
                .unwrap_or("no content");
            return Err(format!("reply has no text content ({refusal})"));
        }
    };
    let n = |k: &str| {
        v.pointer(&format!("/usage/{k}"))
            .and_then(Value::as_u64)
            .unwrap_or(0)
    };
    let (prompt, completion) = (n("prompt_tokens"), n("completion_tokens"));
    let total = match n("total_tokens") {
        0 => prompt + completion,
        t => t,
    };
    Ok((
        text,
        Usage {
            prompt,
            completion,
            total,
        },
    ))
}
