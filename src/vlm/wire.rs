//! The OpenAI-compatible wire format around [`super::client::VlmClient`]: images fitted
//! to the model's size, completion bodies and error bodies parsed, `Retry-After` read, and
//! the token estimate a request is admitted by.

use crate::vlm::budget::Usage;
use crate::vlm::error::VlmError;
use crate::vlm::message::{ImageData, Message, Part};
use serde_json::Value;
use std::time::Duration;

/// Longest server message kept in an error.
pub(crate) const MAX_MESSAGE_CHARS: usize = 300;

/// Downscale an image whose longer side exceeds `max_side` (Lanczos, JPEG quality 90).
pub(crate) fn fit_image(img: &ImageData, max_side: u32) -> Result<ImageData, VlmError> {
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
pub(crate) fn retry_after(h: &reqwest::header::HeaderMap) -> Option<Duration> {
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

/// The `error.message` (and `error.code`) of an OpenAI-style error body, else the start
/// of the body.
pub(crate) fn error_message(body: &str) -> (String, Option<String>) {
    if let Ok(v) = serde_json::from_str::<Value>(body) {
        let code = v
            .pointer("/error/code")
            .and_then(Value::as_str)
            .map(String::from);
        if let Some(m) = v.pointer("/error/message").and_then(Value::as_str) {
            return (m.to_string(), code);
        }
        if let Some(m) = v.get("error").and_then(Value::as_str) {
            return (m.to_string(), code);
        }
    }
    (body.chars().take(MAX_MESSAGE_CHARS).collect(), None)
}

/// The body as text, or None when it exceeds `limit` bytes (read no further).
pub(crate) async fn read_capped(
    mut resp: reqwest::Response,
    limit: usize,
) -> Result<Option<String>, reqwest::Error> {
    if resp.content_length().is_some_and(|n| n > limit as u64) {
        return Ok(None);
    }
    let mut buf = Vec::new();
    while let Some(chunk) = resp.chunk().await? {
        if buf.len() + chunk.len() > limit {
            return Ok(None);
        }
        buf.extend_from_slice(&chunk);
    }
    Ok(Some(String::from_utf8_lossy(&buf).into_owned()))
}

/// Rough prompt size in tokens: a token per 3 bytes of text (English is nearer 4, so
/// this errs on the safe side), a few per message, `image_tokens` per image.
pub fn estimate_tokens(messages: &[Message], image_tokens: u64) -> u64 {
    messages
        .iter()
        .map(|m| {
            let text: u64 = m
                .parts
                .iter()
                .map(|p| match p {
                    Part::Text(t) => (t.len() as u64).div_ceil(3),
                    Part::Image(_) => image_tokens,
                })
                .sum();
            text + 4
        })
        .sum()
}

/// Text and usage of a chat completion body.
pub(crate) fn parse_completion(body: &str) -> Result<(String, Usage), String> {
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
