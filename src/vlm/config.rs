//! VLM endpoint configuration (serde, defaults, environment).

use serde::{Deserialize, Serialize};

/// An API key that never shows up in Debug output or serialized traces.
#[derive(Clone, Default, PartialEq, Eq, Deserialize)]
#[serde(transparent)]
pub struct ApiKey(String);

impl ApiKey {
    /// Wrap a key.
    pub fn new(key: impl Into<String>) -> Self {
        Self(key.into())
    }
    /// The key, for the Authorization header only.
    pub fn expose(&self) -> &str {
        &self.0
    }
    /// Whether a key is set.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl std::fmt::Debug for ApiKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.0.is_empty() {
            f.write_str("ApiKey(none)")
        } else {
            f.write_str("ApiKey(<redacted>)")
        }
    }
}

impl Serialize for ApiKey {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(if self.0.is_empty() { "" } else { "<redacted>" })
    }
}

/// How the key is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AuthStyle {
    /// `Authorization: Bearer <key>` (OpenAI, vLLM, llama.cpp, Ollama).
    #[default]
    Bearer,
    /// `api-key: <key>` (Azure-style deployments).
    ApiKeyHeader,
}

/// Settings of the chat-completions client. Defaults follow REFERENCE-PARAMS.md.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VlmConfig {
    /// Base URL up to and including the API version path, e.g. `http://127.0.0.1:8000/v1`
    /// or an Azure deployment URL with `?api-version=...`; `/chat/completions` is appended
    /// before any query string.
    pub base_url: String,
    /// Model name sent in each request.
    pub model: String,
    /// API key (may be empty for local servers).
    pub api_key: ApiKey,
    /// How the key is sent.
    pub auth_style: AuthStyle,
    /// Sampling temperature.
    pub temperature: f32,
    /// Nucleus sampling.
    pub top_p: f32,
    /// Maximum completion tokens.
    pub max_tokens: u32,
    /// Ask for `response_format: json_object`. If the backend rejects it (HTTP 400 naming
    /// `response_format`), the client drops it for the rest of its life.
    pub json_mode: bool,
    /// Image detail hint ("high", "low", "auto").
    pub image_detail: String,
    /// Maximum images in one request (requests with more are refused locally).
    pub max_images_per_request: usize,
    /// Longer image side in pixels; larger images are downscaled before sending.
    pub max_image_side: u32,
    /// Timeout of one HTTP attempt, milliseconds.
    pub timeout_ms: u64,
    /// Retries after the first attempt on 429 / 5xx / timeouts / connection errors.
    pub max_retries: u32,
    /// First backoff delay, milliseconds (doubles per retry, with jitter).
    pub backoff_base_ms: u64,
    /// Largest backoff or Retry-After wait, milliseconds.
    pub backoff_max_ms: u64,
}

/// Default base URL when none is configured.
pub const DEFAULT_BASE_URL: &str = "https://api.openai.com/v1";

impl Default for VlmConfig {
    fn default() -> Self {
        Self {
            base_url: DEFAULT_BASE_URL.to_string(),
            model: "gpt-4o-2024-05-13".to_string(),
            api_key: ApiKey::default(),
            auth_style: AuthStyle::Bearer,
            temperature: 0.1,
            top_p: 0.3,
            max_tokens: 4095,
            json_mode: true,
            image_detail: "high".to_string(),
            max_images_per_request: 10,
            max_image_side: 2048,
            timeout_ms: 120_000,
            max_retries: 4,
            backoff_base_ms: 1_000,
            backoff_max_ms: 60_000,
        }
    }
}

impl VlmConfig {
    /// Apply environment-style overrides from any lookup function (testable).
    pub fn with_env(mut self, get: impl Fn(&str) -> Option<String>) -> Self {
        let nonempty = |k: &str| get(k).filter(|v| !v.trim().is_empty());
        if let Some(v) = nonempty("GROUNDER_VLM_BASE_URL") {
            self.base_url = v.trim().to_string();
        }
        if let Some(v) = nonempty("GROUNDER_VLM_MODEL") {
            self.model = v.trim().to_string();
        }
        if let Some(v) = nonempty("GROUNDER_VLM_API_KEY").or_else(|| nonempty("OPENAI_API_KEY")) {
            self.api_key = ApiKey::new(v.trim());
        }
        if self.base_url.contains(".openai.azure.com") {
            self.auth_style = AuthStyle::ApiKeyHeader;
        }
        self
    }

    /// The chat-completions URL: `/chat/completions` inserted before any query string.
    pub fn chat_url(&self) -> String {
        let (path, query) = match self.base_url.split_once('?') {
            Some((p, q)) => (p, Some(q)),
            None => (self.base_url.as_str(), None),
        };
        let mut url = format!("{}/chat/completions", path.trim_end_matches('/'));
        if let Some(q) = query {
            url.push('?');
            url.push_str(q);
        }
        url
    }
}
