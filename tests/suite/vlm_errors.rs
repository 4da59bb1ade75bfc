//! The chat client's caps and error kinds against a small fake server that can also
//! describe itself (`/v1/models`, `/props`) and redirect.

use axum::extract::State;
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use grounder::vlm::{ApiKey, CallBudget, ImageData, Message, VlmClient, VlmConfig, VlmError};
use serde_json::{json, Value};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

#[derive(Default)]
struct Fake {
    /// `/v1/models` body (404 when None).
    models: Option<Value>,
    /// Chat reply content; its length sets the body size.
    reply: String,
    /// Seconds each chat request sleeps.
    sleep_ms: u64,
    /// Redirect chat requests here (307) when set.
    redirect_to: Option<String>,
    seen: Mutex<Vec<(HeaderMap, Value)>>,
}

async fn chat(State(f): State<Arc<Fake>>, headers: HeaderMap, Json(body): Json<Value>) -> Response {
    f.seen.lock().unwrap().push((headers, body));
    if let Some(to) = &f.redirect_to {
        return (StatusCode::TEMPORARY_REDIRECT, [("location", to.clone())]).into_response();
    }
    if f.sleep_ms > 0 {
        tokio::time::sleep(Duration::from_millis(f.sleep_ms)).await;
    }
    Json(json!({"choices": [{"message": {"role": "assistant", "content": f.reply}}]}))
        .into_response()
}

async fn models(State(f): State<Arc<Fake>>) -> Response {
    match &f.models {
        Some(m) => Json(m.clone()).into_response(),
        None => StatusCode::NOT_FOUND.into_response(),
    }
}

async fn start(fake: Fake) -> (Arc<Fake>, String) {
    let fake = Arc::new(fake);
    let app = Router::new()
        .route("/v1/chat/completions", post(chat))
        .route("/v1/models", get(models))
        .with_state(fake.clone());
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app).await.unwrap() });
    (fake, format!("http://{addr}/v1"))
}

fn config(base: &str) -> VlmConfig {
    VlmConfig {
        base_url: base.to_string(),
        model: "gemma".into(),
        api_key: ApiKey::new("sk-secret-redirect-test"),
        timeout_ms: 2_000,
        max_retries: 2,
        backoff_base_ms: 5,
        backoff_max_ms: 20,
        ..VlmConfig::default()
    }
}

fn llama_listing(id: &str, n_ctx: u64, vision: bool) -> Value {
    let modalities = if vision {
        json!(["text", "image"])
    } else {
        json!(["text"])
    };
    json!({"object": "list", "data": [{"id": id, "aliases": [id],
        "architecture": {"input_modalities": modalities}, "meta": {"n_ctx": n_ctx}}]})
}

fn tiny_jpeg() -> ImageData {
    let img = image::RgbImage::from_pixel(8, 8, image::Rgb([1, 2, 3]));
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new(&mut out)
        .encode_image(&img)
        .unwrap();
    ImageData::jpeg(out)
}

#[tokio::test]
async fn a_model_the_server_does_not_list_fails_without_a_chat_request() {
    let (fake, base) = start(Fake {
        models: Some(llama_listing("/models/gemma-3-270m.gguf", 2048, false)),
        reply: "ok".into(),
        ..Fake::default()
    })
    .await;
    let client = VlmClient::new(VlmConfig {
        model: "gpt-4o".into(),
        ..config(&base)
    })
    .unwrap();
    let e = client
        .chat(&[Message::user("hi")], &CallBudget::unlimited())
        .await
        .unwrap_err();
    assert!(matches!(e, VlmError::ModelNotFound { .. }), "{e:?}");
    assert_eq!(e.code(), "vlm_model_not_found");
    assert!(e.to_string().contains("gemma-3-270m.gguf"), "{e}");
    assert!(fake.seen.lock().unwrap().is_empty());
    assert!(client.health().problem().unwrap().contains("gpt-4o"));
    // The file name of the listed path is accepted as the model's name.
    let ok = VlmClient::new(VlmConfig {
        model: "gemma-3-270m".into(),
        ..config(&base)
    })
    .unwrap();
    let r = ok
        .chat(&[Message::user("hi")], &CallBudget::unlimited())
        .await
        .unwrap();
    assert_eq!(r.text, "ok");
}

#[tokio::test]
async fn context_size_read_from_the_server_caps_replies_and_refuses_overflow() {
    let (fake, base) = start(Fake {
        models: Some(llama_listing("gemma", 600, true)),
        reply: "ok".into(),
        ..Fake::default()
    })
    .await;
    let client = VlmClient::new(config(&base)).unwrap();
    let budget = CallBudget::unlimited();
    // ~100 prompt tokens: the reply cap shrinks to what is left of 600.
    client
        .chat(&[Message::user("x".repeat(300))], &budget)
        .await
        .unwrap();
    let sent = fake.seen.lock().unwrap()[0].1["max_tokens"]
        .as_u64()
        .unwrap();
    assert!(sent < 600 && sent > 400, "max_tokens {sent}");
    // An image is counted at image_tokens (1000): over the context, refused locally.
    let e = client
        .chat(
            &[Message::user_with_images("look", vec![tiny_jpeg()])],
            &budget,
        )
        .await
        .unwrap_err();
    assert!(
        matches!(e, VlmError::ContextOverflow { n_ctx: 600, .. }),
        "{e:?}"
    );
    assert_eq!(e.code(), "vlm_request_rejected");
    assert_eq!(fake.seen.lock().unwrap().len(), 1, "not sent");
}

#[tokio::test]
async fn a_server_that_says_text_only_gets_no_image() {
    let (fake, base) = start(Fake {
        models: Some(llama_listing("gemma", 8192, false)),
        reply: "ok".into(),
        ..Fake::default()
    })
    .await;
    let client = VlmClient::new(config(&base)).unwrap();
    let e = client
        .chat(
            &[Message::user_with_images("look", vec![tiny_jpeg()])],
            &CallBudget::unlimited(),
        )
        .await
        .unwrap_err();
    assert_eq!(e.code(), "vlm_cannot_see_images", "{e}");
    assert!(fake.seen.lock().unwrap().is_empty());
    assert!(client.health().problem().is_some());
}

#[tokio::test]
async fn reply_body_is_capped() {
    let (_fake, base) = start(Fake {
        reply: "y".repeat(64 * 1024),
        ..Fake::default()
    })
    .await;
    let client = VlmClient::new(VlmConfig {
        max_reply_bytes: 16 * 1024,
        ..config(&base)
    })
    .unwrap();
    let e = client
        .chat(&[Message::user("hi")], &CallBudget::unlimited())
        .await
        .unwrap_err();
    assert!(
        matches!(e, VlmError::ReplyTooLarge { limit: 16384 }),
        "{e:?}"
    );
}

#[tokio::test]
async fn the_whole_call_is_bounded_by_call_timeout() {
    let (fake, base) = start(Fake {
        reply: "late".into(),
        sleep_ms: 400,
        ..Fake::default()
    })
    .await;
    let client = VlmClient::new(VlmConfig {
        timeout_ms: 300,
        max_retries: 10,
        call_timeout_ms: 700,
        ..config(&base)
    })
    .unwrap();
    let t = Instant::now();
    let e = client
        .chat(&[Message::user("hi")], &CallBudget::unlimited())
        .await
        .unwrap_err();
    assert!(matches!(e, VlmError::CallTimeout { ms: 700 }), "{e:?}");
    assert!(
        t.elapsed() < Duration::from_millis(1_500),
        "{:?}",
        t.elapsed()
    );
    assert!(fake.seen.lock().unwrap().len() < 4);
}

#[tokio::test]
async fn redirects_to_another_host_are_not_followed_with_the_key() {
    // The other "host": a listener on another address that records what reaches it.
    let (other, other_base) = start(Fake {
        reply: "stolen".into(),
        ..Fake::default()
    })
    .await;
    let other_url = other_base.replace("127.0.0.1", "localhost") + "/chat/completions";
    let (_fake, base) = start(Fake {
        redirect_to: Some(other_url.clone()),
        ..Fake::default()
    })
    .await;
    let client = VlmClient::new(config(&base)).unwrap();
    let e = client
        .chat(&[Message::user("hi")], &CallBudget::unlimited())
        .await
        .unwrap_err();
    assert!(
        matches!(e, VlmError::Redirected { status: 307, .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains(&other_url), "{e}");
    assert!(
        other.seen.lock().unwrap().is_empty(),
        "nothing reached the other host"
    );
}

#[tokio::test]
async fn per_step_caps_are_sent() {
    let (fake, base) = start(Fake {
        reply: "ok".into(),
        ..Fake::default()
    })
    .await;
    let mut cfg = config(&base);
    cfg.step_max_tokens.query_analysis = 77;
    let client = VlmClient::new(cfg).unwrap();
    let budget = CallBudget::unlimited();
    client
        .chat_step(
            grounder::vlm::VlmStep::QueryAnalysis,
            &[Message::user("hi")],
            &budget,
        )
        .await
        .unwrap();
    client
        .chat_step(
            grounder::vlm::VlmStep::ImageSelection,
            &[Message::user("hi")],
            &budget,
        )
        .await
        .unwrap();
    let seen = fake.seen.lock().unwrap();
    assert_eq!(seen[0].1["max_tokens"], 77);
    assert_eq!(seen[1].1["max_tokens"], 1024);
}
