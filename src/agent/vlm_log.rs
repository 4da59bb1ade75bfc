//! Recording VLM exchanges in the trace: message text, images as artifact URLs (never
//! base64), the reply, usage and latency.

use serde_json::{json, Value};

use crate::vlm::{ChatReply, Message, Part};

/// Keeps the running VLM time and turns messages into trace JSON.
#[derive(Debug, Default)]
pub struct VlmLog {
    pub vlm_ms: f64,
    pub calls: usize,
}

impl VlmLog {
    /// Trace form of messages; `image_urls` names the images in order of appearance.
    pub fn messages_json(messages: &[Message], image_urls: &[String]) -> Value {
        let mut next = 0usize;
        let out: Vec<Value> = messages
            .iter()
            .map(|m| {
                let mut texts = Vec::new();
                let mut images = Vec::new();
                for p in &m.parts {
                    match p {
                        Part::Text(t) => texts.push(t.clone()),
                        Part::Image(_) => {
                            images.push(
                                image_urls
                                    .get(next)
                                    .cloned()
                                    .unwrap_or_else(|| "(image)".into()),
                            );
                            next += 1;
                        }
                    }
                }
                json!({"role": m.role.as_str(), "text": texts.join("\n"), "images": images})
            })
            .collect();
        Value::Array(out)
    }

    /// Record one reply; returns its trace form.
    pub fn reply(&mut self, r: &ChatReply) -> Value {
        self.vlm_ms += r.latency_ms as f64;
        self.calls += 1;
        json!({"text": r.text, "usage": r.usage, "attempts": r.attempts, "latency_ms": r.latency_ms})
    }
}
