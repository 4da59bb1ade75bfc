//! What an OpenAI-compatible server says about itself: the models it serves
//! (`GET {base}/models`), their context size and input modalities (llama.cpp adds
//! `meta.n_ctx` and `architecture.input_modalities` there, and `n_ctx` / `modalities` at
//! `GET /props`). Servers that say nothing leave every field unknown.

use serde_json::Value;

/// Facts read from the server; `None` = the server did not say.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ServerInfo {
    /// Model ids and aliases listed by `/models` (None when the listing is unavailable).
    pub models: Option<Vec<String>>,
    /// Context window in tokens.
    pub n_ctx: Option<u64>,
    /// Whether the served model takes images.
    pub vision: Option<bool>,
}

impl ServerInfo {
    /// Read a `/models` body (OpenAI list, with llama.cpp's extras when present).
    pub fn from_models(body: &Value) -> Self {
        let Some(data) = body.get("data").and_then(Value::as_array) else {
            return Self::default();
        };
        let mut models = Vec::new();
        let mut n_ctx = None;
        let mut vision = None;
        for m in data {
            if let Some(id) = m.get("id").and_then(Value::as_str) {
                models.push(id.to_string());
            }
            if let Some(aliases) = m.get("aliases").and_then(Value::as_array) {
                models.extend(aliases.iter().filter_map(Value::as_str).map(String::from));
            }
            if let Some(n) = m.pointer("/meta/n_ctx").and_then(Value::as_u64) {
                n_ctx = Some(n);
            }
            if let Some(mods) = m
                .pointer("/architecture/input_modalities")
                .and_then(Value::as_array)
            {
                vision = Some(mods.iter().any(|v| v.as_str() == Some("image")));
            }
        }
        Self {
            models: (!models.is_empty()).then_some(models),
            n_ctx,
            vision,
        }
    }

    /// Fill what is still unknown from a llama.cpp `/props` body.
    pub fn merge_props(&mut self, body: &Value) {
        if self.n_ctx.is_none() {
            self.n_ctx = body
                .pointer("/default_generation_settings/n_ctx")
                .or_else(|| body.get("n_ctx"))
                .and_then(Value::as_u64);
        }
        if self.vision.is_none() {
            self.vision = body.pointer("/modalities/vision").and_then(Value::as_bool);
        }
    }

    /// Whether `model` is served: listed by id or alias, or by the file name of a listed
    /// path (llama.cpp lists the GGUF path), with or without its extension. True when the
    /// server lists nothing.
    pub fn serves(&self, model: &str) -> bool {
        let Some(models) = &self.models else {
            return true;
        };
        models.iter().any(|m| {
            let file = m.rsplit(['/', '\\']).next().unwrap_or(m);
            m == model || file == model || file.strip_suffix(".gguf") == Some(model)
        })
    }
}

/// The `/props` URL of a base URL ending in `/v1` (llama.cpp serves it at the root).
pub fn props_url(base_url: &str) -> Option<String> {
    let path = base_url.split('?').next().unwrap_or(base_url);
    path.trim_end_matches('/')
        .strip_suffix("/v1")
        .map(|root| format!("{root}/props"))
}

/// The `/models` URL of a base URL (before any query string).
pub fn models_url(base_url: &str) -> String {
    let (path, query) = match base_url.split_once('?') {
        Some((p, q)) => (p, Some(q)),
        None => (base_url, None),
    };
    let mut url = format!("{}/models", path.trim_end_matches('/'));
    if let Some(q) = query {
        url.push('?');
        url.push_str(q);
    }
    url
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn reads_llama_cpp_listing_and_props() {
        let body = json!({"object": "list", "data": [{
            "id": "/cache/gemma-3-270m-q4_k_m.gguf", "aliases": ["gemma"],
            "architecture": {"input_modalities": ["text"], "output_modalities": ["text"]},
            "meta": {"n_ctx": 2048, "n_ctx_train": 32768}
        }]});
        let mut info = ServerInfo::from_models(&body);
        assert_eq!(info.n_ctx, Some(2048));
        assert_eq!(info.vision, Some(false));
        assert!(info.serves("gemma"));
        assert!(info.serves("gemma-3-270m-q4_k_m"));
        assert!(info.serves("/cache/gemma-3-270m-q4_k_m.gguf"));
        assert!(!info.serves("gpt-4o"));
        info.merge_props(&json!({"default_generation_settings": {"n_ctx": 4096}, "modalities": {"vision": true}}));
        assert_eq!((info.n_ctx, info.vision), (Some(2048), Some(false)));
    }

    #[test]
    fn unknown_when_the_server_says_nothing() {
        let mut info = ServerInfo::from_models(&json!({"error": "no"}));
        assert!(info.serves("anything"));
        info.merge_props(&json!({"n_ctx": 8192, "modalities": {"vision": false}}));
        assert_eq!((info.n_ctx, info.vision), (Some(8192), Some(false)));
    }

    #[test]
    fn urls() {
        assert_eq!(
            props_url("http://h:1/v1/").as_deref(),
            Some("http://h:1/props")
        );
        assert_eq!(
            props_url("https://x/openai/deployments/d?api-version=1"),
            None
        );
        assert_eq!(
            models_url("https://x/d?api-version=1"),
            "https://x/d/models?api-version=1"
        );
    }
}
