//! Why a chat call failed, and the stable job failure code each reason maps to.

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
    /// The call (all its attempts and waits) took longer than `call_timeout_ms`.
    #[error("VLM call gave no answer within {ms} ms (all attempts)")]
    CallTimeout {
        /// The limit.
        ms: u64,
    },
    /// 401/403: key missing or wrong.
    #[error("VLM endpoint refused the credentials (HTTP {status}): {message}")]
    Auth {
        /// HTTP status.
        status: u16,
        /// Server message (key redacted).
        message: String,
    },
    /// Other 4xx: the request itself is wrong (payload size, context overflow...). Not
    /// retried: the same request would be refused again.
    #[error("VLM endpoint rejected the request (HTTP {status}): {message}")]
    BadRequest {
        /// HTTP status.
        status: u16,
        /// Server message (key redacted, trimmed).
        message: String,
    },
    /// The conversation does not fit the model's context window (checked before sending).
    #[error(
        "the request needs about {needed} tokens ({prompt} prompt + {reply} reply) but the model's context holds {n_ctx}"
    )]
    ContextOverflow {
        /// Estimated prompt plus reply tokens.
        needed: u64,
        /// Estimated prompt tokens.
        prompt: u64,
        /// Reply tokens asked for.
        reply: u64,
        /// The model's context size.
        n_ctx: u64,
    },
    /// The model takes text only.
    #[error("the VLM cannot take images: {message}")]
    CannotSeeImages {
        /// Server message or what the server's metadata says.
        message: String,
    },
    /// The endpoint does not serve the configured model.
    #[error("the VLM endpoint does not serve model {model:?} (it serves: {available})")]
    ModelNotFound {
        /// The configured model.
        model: String,
        /// What the server lists (or its message).
        available: String,
    },
    /// The endpoint redirected somewhere the client does not follow (another host).
    #[error("VLM endpoint redirected (HTTP {status}) to {location:?}; redirects to another host are not followed")]
    Redirected {
        /// HTTP status.
        status: u16,
        /// The `Location` header.
        location: String,
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
    /// The reply body is larger than `max_reply_bytes`.
    #[error("VLM reply exceeds {limit} bytes")]
    ReplyTooLarge {
        /// The limit.
        limit: usize,
    },
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

impl VlmError {
    /// The job failure code of this error (stable; documented in docs/vlm-backends.md).
    pub fn code(&self) -> &'static str {
        match self {
            VlmError::Cancelled => "canceled",
            VlmError::CallBudgetExhausted { .. } => "vlm_budget_exhausted",
            VlmError::DeadlineExceeded => "job_timeout",
            VlmError::Auth { .. } => "vlm_auth_failed",
            VlmError::BadRequest { .. }
            | VlmError::ContextOverflow { .. }
            | VlmError::TooManyImages { .. }
            | VlmError::Redirected { .. } => "vlm_request_rejected",
            VlmError::CannotSeeImages { .. } => "vlm_cannot_see_images",
            VlmError::ModelNotFound { .. } => "vlm_model_not_found",
            VlmError::InvalidResponse(_) | VlmError::ReplyTooLarge { .. } => "vlm_invalid_response",
            VlmError::RateLimited { .. } => "vlm_rate_limited",
            VlmError::CallTimeout { .. }
            | VlmError::Server { .. }
            | VlmError::Timeout { .. }
            | VlmError::Connection { .. } => "vlm_unavailable",
            VlmError::Image(_) => "image_encoding_failed",
            VlmError::Config(_) => "vlm_misconfigured",
        }
    }
}

/// At most `max` characters of a server's message, on one line.
pub fn trim_message(s: &str, max: usize) -> String {
    let one_line: String = s.split_whitespace().collect::<Vec<_>>().join(" ");
    if one_line.chars().count() <= max {
        return one_line;
    }
    let mut out: String = one_line.chars().take(max).collect();
    out.push('…');
    out
}

/// Whether a server's error message says the model cannot take image input.
pub fn says_no_images(message: &str) -> bool {
    let m = message.to_lowercase();
    [
        "image input is not supported",
        "does not support image",
        "doesn't support image",
        "image_url is not supported",
        "not a multimodal model",
        "vision is not supported",
        "images are not supported",
    ]
    .iter()
    .any(|p| m.contains(p))
}

/// Whether a server's 4xx message says the model name is unknown.
pub fn says_model_unknown(message: &str, code: Option<&str>) -> bool {
    if code == Some("model_not_found") {
        return true;
    }
    let m = message.to_lowercase();
    m.contains("model")
        && (m.contains("not found") || m.contains("does not exist") || m.contains("unknown"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trims_to_one_short_line() {
        assert_eq!(trim_message("a\n  b\tc", 10), "a b c");
        assert_eq!(trim_message(&"x".repeat(20), 5), "xxxxx…");
    }

    #[test]
    fn recognises_text_only_and_unknown_model_messages() {
        assert!(says_no_images(
            "image input is not supported - hint: you may need to provide the mmproj"
        ));
        assert!(!says_no_images(
            "request exceeds the available context size"
        ));
        assert!(says_model_unknown(
            "The model `gpt-5x` does not exist or you do not have access to it.",
            None
        ));
        assert!(says_model_unknown("whatever", Some("model_not_found")));
        assert!(!says_model_unknown("scripted 404", None));
    }

    #[test]
    fn each_kind_has_its_own_code() {
        let codes = [
            VlmError::BadRequest {
                status: 400,
                message: String::new(),
            }
            .code(),
            VlmError::CannotSeeImages {
                message: String::new(),
            }
            .code(),
            VlmError::ModelNotFound {
                model: String::new(),
                available: String::new(),
            }
            .code(),
            VlmError::Connection {
                attempts: 1,
                message: String::new(),
            }
            .code(),
            VlmError::RateLimited {
                attempts: 1,
                message: String::new(),
            }
            .code(),
        ];
        let unique: std::collections::BTreeSet<_> = codes.iter().collect();
        assert_eq!(unique.len(), codes.len(), "{codes:?}");
    }
}
