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
    /// Maximum completion tokens of a call that names no step (and the upper bound of
    /// every step's cap).
    pub max_tokens: u32,
    /// Completion-token cap of each pipeline step (a reply is short JSON; a model that
    /// rambles is cut off here instead of filling its context).
    pub step_max_tokens: StepMaxTokens,
    /// Context window of the model in tokens; 0 = read it from the server (llama.cpp's
    /// `/v1/models` `meta.n_ctx` or `/props`), unchecked when the server does not say.
    pub context_tokens: u64,
    /// Tokens one image is assumed to take when a request is checked against the context.
    pub image_tokens: u64,
    /// Refuse to call a server whose `/models` listing does not name `model`.
    pub check_model: bool,
    /// Largest reply body read, bytes; a larger reply fails the call.
    pub max_reply_bytes: usize,
    /// Wall time of one call, all attempts and waits included, milliseconds.
    pub call_timeout_ms: u64,
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

/// The steps that call the VLM.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VlmStep {
    /// Query analysis (target class, attributes, conditions).
    QueryAnalysis,
    /// Choosing an image from the stitched grids.
    ImageSelection,
    /// Choosing a detection or a mark in the chosen image.
    ObjectSelection,
    /// The VLM's own box (`detector = "vlm"`).
    Box,
}

/// Completion-token cap per step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StepMaxTokens {
    /// Query analysis.
    pub query_analysis: u32,
    /// Image selection.
    pub image_selection: u32,
    /// Object (detection or mark) selection.
    pub object_selection: u32,
    /// The VLM's own box.
    #[serde(rename = "box")]
    pub bbox: u32,
}

impl Default for StepMaxTokens {
    fn default() -> Self {
        Self {
            query_analysis: 512,
            image_selection: 1024,
            object_selection: 512,
            bbox: 512,
        }
    }
}

impl StepMaxTokens {
    /// The cap of one step.
    pub fn get(&self, step: VlmStep) -> u32 {
        match step {
            VlmStep::QueryAnalysis => self.query_analysis,
            VlmStep::ImageSelection => self.image_selection,
            VlmStep::ObjectSelection => self.object_selection,
            VlmStep::Box => self.bbox,
        }
    }
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
            step_max_tokens: StepMaxTokens::default(),
            context_tokens: 0,
            image_tokens: 1_000,
            check_model: true,
            max_reply_bytes: 4 << 20,
            call_timeout_ms: 600_000,
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
