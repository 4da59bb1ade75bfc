//! `grounder oracle-vlm`: an OpenAI-compatible chat-completions server that answers the
//! agent's prompts from ground truth. It reads only the request (text and images) plus
//! the dataset annotations and the scenes' instance masks, never the service's database,
//! so the real client, prompts, parsing and feedback loop are exercised.

use super::oracle_vlm_answer::{answer, read_conversation, SeenMessage};
use super::oracle_vlm_truth::Truth;
use anyhow::{Context, Result};
use axum::body::Bytes;
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use base64::Engine;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Flags of `grounder oracle-vlm`.
#[derive(Debug, Clone, clap::Args)]
pub struct OracleVlmArgs {
    /// Address to listen on, e.g. 127.0.0.1:8011; port 0 picks a free port. The bound
    /// address is printed on stdout as `listening on http://ADDR`.
    #[arg(long)]
    pub addr: String,
    /// Annotation folder (objects/<scene>.json, queries.jsonl).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Folder with one ScanNet-layout scene folder per scene id (with instance/ masks).
    #[arg(long)]
    pub scenes: PathBuf,
    /// Seed of the error injection.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Probability of a fallible answer (wrong frame, invalid id or malformed JSON).
    #[arg(long, default_value_t = 0.0)]
    pub error_rate: f64,
}

/// Model name reported by `GET /v1/models`.
pub const ORACLE_MODEL: &str = "grounder-oracle";

struct OracleState {
    truth: Truth,
    rng: Mutex<ChaCha8Rng>,
    error_rate: f64,
    counter: AtomicU64,
}

/// Build the oracle's router (used by the CLI and by tests).
pub fn router(args: &OracleVlmArgs) -> Result<Router> {
    if !(0.0..=1.0).contains(&args.error_rate) {
        anyhow::bail!(
            "--error-rate must be within [0, 1], got {}",
            args.error_rate
        );
    }
    let truth = Truth::load(&args.dataset, &args.scenes)?;
    tracing::info!(queries = truth.len(), "oracle VLM ground truth loaded");
    let state = Arc::new(OracleState {
        truth,
        rng: Mutex::new(ChaCha8Rng::seed_from_u64(args.seed)),
        error_rate: args.error_rate,
        counter: AtomicU64::new(0),
    });
    Ok(Router::new()
        .route("/v1/chat/completions", post(chat))
        .route("/chat/completions", post(chat))
        .route("/v1/models", get(models))
        .fallback(not_found)
        .layer(axum::extract::DefaultBodyLimit::max(256 * 1024 * 1024))
        .with_state(state))
}

/// Run the server until interrupted.
pub async fn run(args: OracleVlmArgs) -> Result<()> {
    let app = router(&args)?;
    let listener = tokio::net::TcpListener::bind(&args.addr)
        .await
        .with_context(|| format!("cannot listen on {}", args.addr))?;
    // The real address (port 0 picks a free port); tests and scripts read this line.
    let local = listener
        .local_addr()
        .with_context(|| format!("cannot read the address bound for {}", args.addr))?;
    tracing::info!(addr = %local, "oracle VLM listening");
    println!("listening on http://{local}");
    axum::serve(listener, app)
        .with_graceful_shutdown(async {
            let _ = tokio::signal::ctrl_c().await;
        })
        .await
        .context("oracle VLM server failed")
}

/// An OpenAI-shaped error response.
fn api_error(
    status: StatusCode,
    kind: &str,
    message: impl Into<String>,
    param: Option<&str>,
) -> Response {
    let body =
        json!({"error": {"message": message.into(), "type": kind, "param": param, "code": null}});
    (status, Json(body)).into_response()
}

async fn not_found() -> Response {
    api_error(
        StatusCode::NOT_FOUND,
        "invalid_request_error",
        "Unknown request URL.",
        None,
    )
}

async fn models() -> Json<Value> {
    Json(json!({"object": "list", "data": [
        {"id": ORACLE_MODEL, "object": "model", "created": 0, "owned_by": "grounder"}
    ]}))
}

/// Messages of a request body, images decoded from data URLs.
fn read_messages(body: &Value) -> Result<Vec<SeenMessage>, Box<Response>> {
    let bad = |m: &str, p: &str| {
        Box::new(api_error(
            StatusCode::BAD_REQUEST,
            "invalid_request_error",
            m,
            Some(p),
        ))
    };
    let msgs = body
        .get("messages")
        .and_then(Value::as_array)
        .ok_or_else(|| bad("'messages' is a required array", "messages"))?;
    if msgs.is_empty() {
        return Err(bad("'messages' must not be empty", "messages"));
    }
    let mut out = Vec::with_capacity(msgs.len());
    for (i, m) in msgs.iter().enumerate() {
        let role = m.get("role").and_then(Value::as_str).ok_or_else(|| {
            bad(
                "each message needs a 'role'",
                &format!("messages[{i}].role"),
            )
        })?;
        let mut seen = SeenMessage {
            role: role.to_string(),
            ..Default::default()
        };
        match m.get("content") {
            Some(Value::String(s)) => seen.text = s.clone(),
            Some(Value::Array(parts)) => {
                let mut texts = Vec::new();
                for p in parts {
                    match p.get("type").and_then(Value::as_str) {
                        Some("text") => texts.push(
                            p.get("text")
                                .and_then(Value::as_str)
                                .unwrap_or("")
                                .to_string(),
                        ),
                        Some("image_url") => {
                            let url = p
                                .pointer("/image_url/url")
                                .and_then(Value::as_str)
                                .unwrap_or("");
                            let Some((_, b64)) = url.split_once(";base64,") else {
                                return Err(bad(
                                    "only base64 data URLs are supported for images",
                                    &format!("messages[{i}].content"),
                                ));
                            };
                            let bytes = base64::engine::general_purpose::STANDARD
                                .decode(b64)
                                .map_err(|_| {
                                    bad(
                                        "invalid base64 image data",
                                        &format!("messages[{i}].content"),
                                    )
                                })?;
                            seen.images.push(bytes);
                        }
                        _ => {
                            return Err(bad(
                                "unsupported content part type",
                                &format!("messages[{i}].content"),
                            ))
                        }
                    }
                }
                seen.text = texts.join("\n");
            }
            Some(Value::Null) | None if role == "assistant" => {}
            _ => {
                return Err(bad(
                    "message content must be a string or an array of parts",
                    &format!("messages[{i}].content"),
                ))
            }
        }
        out.push(seen);
    }
    Ok(out)
}

async fn chat(State(st): State<Arc<OracleState>>, body: Bytes) -> Response {
    let body: Value = match serde_json::from_slice(&body) {
        Ok(v) => v,
        Err(e) => {
            return api_error(
                StatusCode::BAD_REQUEST,
                "invalid_request_error",
                format!("We could not parse the JSON body of your request: {e}"),
                None,
            )
        }
    };
    if body.get("stream").and_then(Value::as_bool) == Some(true) {
        return api_error(
            StatusCode::BAD_REQUEST,
            "invalid_request_error",
            "streaming is not supported by the oracle",
            Some("stream"),
        );
    }
    let model = body
        .get("model")
        .and_then(Value::as_str)
        .unwrap_or(ORACLE_MODEL)
        .to_string();
    let messages = match read_messages(&body) {
        Ok(m) => m,
        Err(r) => return *r,
    };
    let prompt_tokens: u64 = messages
        .iter()
        .map(|m| m.text.len() as u64 / 4 + 4 + 765 * m.images.len() as u64)
        .sum();
    let st2 = st.clone();
    let text = tokio::task::spawn_blocking(move || {
        let Some(conv) = read_conversation(&messages) else {
            return json!({"reasoning": "oracle: no task marker found in the conversation"})
                .to_string();
        };
        // One RNG draw sequence per request, in arrival order.
        let mut rng = match st2.rng.lock() {
            Ok(mut g) => {
                ChaCha8Rng::from_rng(&mut *g).unwrap_or_else(|_| ChaCha8Rng::seed_from_u64(0))
            }
            Err(_) => ChaCha8Rng::seed_from_u64(0),
        };
        answer(&st2.truth, &conv, st2.error_rate, &mut rng)
    })
    .await;
    let text = match text {
        Ok(t) => t,
        Err(e) => {
            return api_error(
                StatusCode::INTERNAL_SERVER_ERROR,
                "server_error",
                format!("oracle failed: {e}"),
                None,
            )
        }
    };
    let n = st.counter.fetch_add(1, Ordering::Relaxed);
    let completion_tokens = text.len() as u64 / 4 + 1;
    let created = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    Json(json!({
        "id": format!("chatcmpl-oracle-{n}"),
        "object": "chat.completion",
        "created": created,
        "model": model,
        "choices": [{"index": 0, "message": {"role": "assistant", "content": text, "refusal": null},
                     "logprobs": null, "finish_reason": "stop"}],
        "usage": {"prompt_tokens": prompt_tokens, "completion_tokens": completion_tokens,
                  "total_tokens": prompt_tokens + completion_tokens},
    }))
    .into_response()
}
