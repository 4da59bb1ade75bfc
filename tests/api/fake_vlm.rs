//! A scripted fake OpenAI-compatible chat server on port 0: pops one scripted reply per
//! request and records every request body.

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::post;
use axum::{Json, Router};
use serde_json::{json, Value};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// One scripted reply.
#[derive(Clone, Debug)]
pub struct Reply {
    pub status: u16,
    pub headers: Vec<(&'static str, String)>,
    pub delay_ms: u64,
    /// Assistant content (status 200) or error message.
    pub content: String,
}

impl Reply {
    /// 200 with this assistant content.
    pub fn ok(content: impl Into<String>) -> Self {
        Self {
            status: 200,
            headers: Vec::new(),
            delay_ms: 0,
            content: content.into(),
        }
    }
    /// An error status, optionally with `Retry-After`.
    pub fn status(status: u16, retry_after: Option<&str>) -> Self {
        let headers = retry_after
            .map(|r| vec![("retry-after", r.to_string())])
            .unwrap_or_default();
        Self {
            status,
            headers,
            delay_ms: 0,
            content: format!("scripted {status}"),
        }
    }
    /// Answer only after `ms`.
    pub fn delayed(mut self, ms: u64) -> Self {
        self.delay_ms = ms;
        self
    }
}

#[derive(Default)]
pub struct Script {
    queue: Mutex<VecDeque<Reply>>,
    requests: Mutex<Vec<Value>>,
    in_flight: AtomicUsize,
    /// The most requests seen waiting for their answers at once.
    max_in_flight: AtomicUsize,
}

/// A request being answered; counted out when its answer is sent (or it is dropped).
struct InFlight(Arc<Script>);

impl InFlight {
    fn begin(s: &Arc<Script>) -> Self {
        let now = s.in_flight.fetch_add(1, Ordering::SeqCst) + 1;
        s.max_in_flight.fetch_max(now, Ordering::SeqCst);
        InFlight(s.clone())
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.in_flight.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Handle on a running fake server.
#[derive(Clone)]
pub struct FakeVlm {
    pub script: Arc<Script>,
    /// Base URL (`http://127.0.0.1:port/v1`).
    pub base: String,
}

async fn handler(State(s): State<Arc<Script>>, Json(body): Json<Value>) -> Response {
    let _counted = InFlight::begin(&s);
    s.requests.lock().unwrap().push(body);
    // Unscripted requests get a non-retryable 400, so a test sees them as a failure.
    let r = s
        .queue
        .lock()
        .unwrap()
        .pop_front()
        .unwrap_or_else(|| Reply::status(400, None));
    if r.delay_ms > 0 {
        tokio::time::sleep(Duration::from_millis(r.delay_ms)).await;
    }
    let mut resp = if r.status == 200 {
        Json(json!({
            "id": "chatcmpl-fake", "object": "chat.completion", "created": 0, "model": "fake",
            "choices": [{"index": 0, "message": {"role": "assistant", "content": r.content}, "finish_reason": "stop"}],
            "usage": {"prompt_tokens": 100, "completion_tokens": 10, "total_tokens": 110}
        }))
        .into_response()
    } else {
        (
            StatusCode::from_u16(r.status).unwrap(),
            Json(json!({"error": {"message": r.content, "type": "scripted"}})),
        )
            .into_response()
    };
    for (k, v) in r.headers {
        resp.headers_mut().insert(k, v.parse().unwrap());
    }
    resp
}

impl FakeVlm {
    pub async fn start(replies: Vec<Reply>) -> Self {
        let script = Arc::new(Script {
            queue: Mutex::new(replies.into()),
            ..Default::default()
        });
        let app = Router::new()
            .route("/v1/chat/completions", post(handler))
            .with_state(script.clone());
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        tokio::spawn(async move { axum::serve(listener, app).await.unwrap() });
        Self {
            script,
            base: format!("http://{addr}/v1"),
        }
    }

    /// Every request body received so far.
    pub fn requests(&self) -> Vec<Value> {
        self.script.requests.lock().unwrap().clone()
    }

    /// Append scripted replies.
    pub fn script_push(&self, replies: Vec<Reply>) {
        self.script.queue.lock().unwrap().extend(replies);
    }

    /// Drop the next scripted reply.
    #[allow(dead_code)]
    pub fn script_pop(&self) -> Option<Reply> {
        self.script.queue.lock().unwrap().pop_front()
    }

    /// The most requests that were being answered at once since the last call (which
    /// starts the count again).
    #[allow(dead_code)]
    pub fn take_max_in_flight(&self) -> usize {
        self.script.max_in_flight.swap(0, Ordering::SeqCst)
    }

    /// Replies not yet used.
    pub fn remaining(&self) -> usize {
        self.script.queue.lock().unwrap().len()
    }
}

/// The text of a wire message (a string, or the text parts of a parts array).
pub fn text_of(msg: &Value) -> String {
    match &msg["content"] {
        Value::String(s) => s.clone(),
        Value::Array(parts) => parts
            .iter()
            .filter(|p| p["type"] == "text")
            .filter_map(|p| p["text"].as_str())
            .collect::<Vec<_>>()
            .join("\n"),
        _ => String::new(),
    }
}

/// Number of images in a wire message.
pub fn images_in(msg: &Value) -> usize {
    msg["content"]
        .as_array()
        .map(|a| a.iter().filter(|p| p["type"] == "image_url").count())
        .unwrap_or(0)
}

/// The last message of a request body.
pub fn last_message(req: &Value) -> &Value {
    let m = req["messages"].as_array().expect("messages array");
    m.last().expect("at least one message")
}
