//! The chat client against a scripted fake OpenAI-compatible server on port 0.

use axum::extract::State;
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::post;
use axum::{Json, Router};
use grounder::vlm::{ApiKey, CallBudget, ImageData, Message, VlmClient, VlmConfig, VlmError};
use serde_json::{json, Value};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// One scripted response.
#[derive(Clone)]
enum Step {
    Ok(&'static str),
    Status(u16, Option<&'static str>),
    Sleep(u64),
}

#[derive(Default)]
struct Script {
    steps: Mutex<VecDeque<Step>>,
    seen: Mutex<Vec<(HeaderMap, Value, Instant)>>,
}

async fn handler(
    State(s): State<Arc<Script>>,
    headers: HeaderMap,
    Json(body): Json<Value>,
) -> Response {
    s.seen.lock().unwrap().push((headers, body, Instant::now()));
    let step = s
        .steps
        .lock()
        .unwrap()
        .pop_front()
        .unwrap_or(Step::Status(500, None));
    match step {
        Step::Ok(text) => Json(json!({
            "id": "chatcmpl-1", "object": "chat.completion", "created": 0, "model": "m",
            "choices": [{"index": 0, "message": {"role": "assistant", "content": text}, "finish_reason": "stop"}],
            "usage": {"prompt_tokens": 11, "completion_tokens": 5, "total_tokens": 16}
        }))
        .into_response(),
        Step::Status(code, retry_after) => {
            let mut r = (
                StatusCode::from_u16(code).unwrap(),
                Json(json!({"error": {"message": format!("scripted {code}"), "type": "x", "param": null, "code": null}})),
            )
                .into_response();
            if let Some(ra) = retry_after {
                r.headers_mut().insert("retry-after", ra.parse().unwrap());
            }
            r
        }
        Step::Sleep(ms) => {
            tokio::time::sleep(Duration::from_millis(ms)).await;
            Json(json!({"choices": [{"message": {"content": "late"}}]})).into_response()
        }
    }
}

async fn fake(steps: Vec<Step>) -> (Arc<Script>, String) {
    let script = Arc::new(Script {
        steps: Mutex::new(steps.into()),
        ..Default::default()
    });
    let app = Router::new()
        .route("/v1/chat/completions", post(handler))
        .with_state(script.clone());
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app).await.unwrap() });
    (script, format!("http://{addr}/v1"))
}

const KEY: &str = "sk-test-SECRET-0123456789";

fn config(base: &str) -> VlmConfig {
    VlmConfig {
        base_url: base.to_string(),
        model: "m".into(),
        api_key: ApiKey::new(KEY),
        timeout_ms: 300,
        max_retries: 3,
        backoff_base_ms: 10,
        backoff_max_ms: 5_000,
        ..VlmConfig::default()
    }
}

fn msgs() -> Vec<Message> {
    vec![Message::system("sys"), Message::user("hello")]
}

#[tokio::test]
async fn sends_openai_body_and_reads_reply() {
    let (script, base) = fake(vec![Step::Ok("{\"a\": 1}")]).await;
    let client = VlmClient::new(config(&base)).unwrap();
    let budget = CallBudget::new(10, None);
    let reply = client.chat(&msgs(), &budget).await.unwrap();
    assert_eq!(reply.text, "{\"a\": 1}");
    assert_eq!(reply.attempts, 1);
    assert_eq!(
        (
            reply.usage.prompt,
            reply.usage.completion,
            reply.usage.total
        ),
        (11, 5, 16)
    );
    assert_eq!(budget.total_usage().total, 16);
    let seen = script.seen.lock().unwrap();
    let (headers, body, _) = &seen[0];
    assert_eq!(headers["authorization"], format!("Bearer {KEY}").as_str());
    assert_eq!(body["model"], "m");
    assert!((body["temperature"].as_f64().unwrap() - 0.1).abs() < 1e-6);
    assert!((body["top_p"].as_f64().unwrap() - 0.3).abs() < 1e-6);
    assert_eq!(body["max_tokens"], 4095);
    assert_eq!(body["response_format"]["type"], "json_object");
    assert_eq!(body["messages"][0]["role"], "system");
    assert_eq!(body["messages"][1]["content"], "hello");
}

#[tokio::test]
async fn images_become_data_urls_only_on_the_wire() {
    let (script, base) = fake(vec![Step::Ok("ok")]).await;
    let client = VlmClient::new(config(&base)).unwrap();
    let mut jpeg = Vec::new();
    let img = image::RgbImage::from_pixel(8, 4, image::Rgb([200, 10, 10]));
    image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
        .encode_image(&img)
        .unwrap();
    let m = Message::user_with_images("look", vec![ImageData::jpeg(jpeg)]);
    let dbg = format!("{m:?}");
    let ser = serde_json::to_string(&m).unwrap();
    assert!(
        !dbg.contains("base64") && !ser.contains("base64") && !ser.contains("/9j/"),
        "{dbg} {ser}"
    );
    client.chat(&[m], &CallBudget::unlimited()).await.unwrap();
    let seen = script.seen.lock().unwrap();
    let part = &seen[0].1["messages"][0]["content"][1];
    assert_eq!(part["type"], "image_url");
    assert!(part["image_url"]["url"]
        .as_str()
        .unwrap()
        .starts_with("data:image/jpeg;base64,/9j/"));
    assert_eq!(part["image_url"]["detail"], "high");
}

#[tokio::test]
async fn rate_limit_then_success_honours_retry_after() {
    let (script, base) = fake(vec![Step::Status(429, Some("1")), Step::Ok("fine")]).await;
    let client = VlmClient::new(config(&base)).unwrap();
    let reply = client
        .chat(&msgs(), &CallBudget::unlimited())
        .await
        .unwrap();
    assert_eq!(reply.text, "fine");
    assert_eq!(reply.attempts, 2);
    let seen = script.seen.lock().unwrap();
    let gap = seen[1].2.duration_since(seen[0].2);
    // Backoff alone would be ~10 ms; Retry-After says 1 s.
    assert!(gap >= Duration::from_millis(950), "gap {gap:?}");
}

/// A server asking to wait 1e20 seconds (past what a Duration holds) must not panic the
/// caller: the wait is clamped to the configured maximum.
#[tokio::test]
async fn absurd_retry_after_is_clamped_not_a_panic() {
    let (script, base) = fake(vec![
        Step::Status(429, Some("1e20")),
        Step::Status(503, Some("inf")),
        Step::Ok("fine"),
    ])
    .await;
    let cfg = VlmConfig {
        backoff_max_ms: 200,
        ..config(&base)
    };
    let client = VlmClient::new(cfg).unwrap();
    let t = Instant::now();
    let reply = client
        .chat(&msgs(), &CallBudget::unlimited())
        .await
        .unwrap();
    assert_eq!(reply.text, "fine");
    assert_eq!(script.seen.lock().unwrap().len(), 3);
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
}

#[tokio::test]
async fn timeout_then_success() {
    let (_s, base) = fake(vec![Step::Sleep(1_500), Step::Ok("second")]).await;
    let client = VlmClient::new(config(&base)).unwrap();
    let reply = client
        .chat(&msgs(), &CallBudget::unlimited())
        .await
        .unwrap();
    assert_eq!(reply.text, "second");
    assert_eq!(reply.attempts, 2);
}

#[tokio::test]
async fn server_errors_until_retry_cap() {
    let steps = vec![Step::Status(500, None); 10];
    let (script, base) = fake(steps).await;
    let client = VlmClient::new(config(&base)).unwrap();
    let err = client
        .chat(&msgs(), &CallBudget::unlimited())
        .await
        .unwrap_err();
    match err {
        VlmError::Server {
            status: 500,
            attempts: 4,
            ..
        } => {}
        other => panic!("unexpected {other:?}"),
    }
    assert_eq!(
        script.seen.lock().unwrap().len(),
        4,
        "1 attempt + max_retries 3"
    );
}

#[tokio::test]
async fn auth_and_bad_request_are_not_retried() {
    let (script, base) = fake(vec![Step::Status(401, None), Step::Status(404, None)]).await;
    let client = VlmClient::new(config(&base)).unwrap();
    let e1 = client
        .chat(&msgs(), &CallBudget::unlimited())
        .await
        .unwrap_err();
    assert!(matches!(e1, VlmError::Auth { status: 401, .. }), "{e1:?}");
    let e2 = client
        .chat(&msgs(), &CallBudget::unlimited())
        .await
        .unwrap_err();
    assert!(
        matches!(e2, VlmError::BadRequest { status: 404, .. }),
        "{e2:?}"
    );
    assert_eq!(script.seen.lock().unwrap().len(), 2);
}

#[tokio::test]
async fn call_budget_is_shared_and_exhausts() {
    let (script, base) = fake(vec![Step::Status(503, None), Step::Ok("a"), Step::Ok("b")]).await;
    let client = VlmClient::new(config(&base)).unwrap();
    let budget = CallBudget::new(2, None);
    assert_eq!(client.chat(&msgs(), &budget).await.unwrap().text, "a");
    let err = client.chat(&msgs(), &budget).await.unwrap_err();
    assert!(
        matches!(err, VlmError::CallBudgetExhausted { max_calls: 2 }),
        "{err:?}"
    );
    assert_eq!(script.seen.lock().unwrap().len(), 2);
    assert_eq!(budget.calls_used(), 2);
}

#[tokio::test]
async fn wall_time_budget_stops_long_waits() {
    let (script, base) = fake(vec![Step::Status(429, Some("30")), Step::Ok("never")]).await;
    let mut cfg = config(&base);
    cfg.backoff_max_ms = 60_000;
    let client = VlmClient::new(cfg).unwrap();
    let budget = CallBudget::new(10, Some(Duration::from_millis(500)));
    let t = Instant::now();
    let err = client.chat(&msgs(), &budget).await.unwrap_err();
    assert!(matches!(err, VlmError::DeadlineExceeded), "{err:?}");
    assert!(t.elapsed() < Duration::from_secs(5));
    assert_eq!(script.seen.lock().unwrap().len(), 1);
}

#[tokio::test]
async fn cancellation_stops_further_calls() {
    let (script, base) = fake(vec![Step::Status(500, Some("1")); 10]).await;
    let client = Arc::new(VlmClient::new(config(&base)).unwrap());
    let budget = Arc::new(CallBudget::new(100, None));
    let (c, b) = (client.clone(), budget.clone());
    let task = tokio::spawn(async move { c.chat(&msgs(), &b).await });
    tokio::time::sleep(Duration::from_millis(300)).await;
    budget.cancel_token().cancel();
    let err = task.await.unwrap().unwrap_err();
    assert!(matches!(err, VlmError::Cancelled), "{err:?}");
    let n = script.seen.lock().unwrap().len();
    assert_eq!(n, 1, "cancelled during the Retry-After wait");
    let err = client.chat(&msgs(), &budget).await.unwrap_err();
    assert!(matches!(err, VlmError::Cancelled));
    assert_eq!(
        script.seen.lock().unwrap().len(),
        1,
        "no call after cancellation"
    );
}

#[tokio::test]
async fn json_mode_dropped_when_backend_rejects_it() {
    async fn picky(Json(body): Json<Value>) -> Response {
        if body.get("response_format").is_some() {
            return (
                StatusCode::BAD_REQUEST,
                Json(json!({"error": {"message": "unknown field response_format"}})),
            )
                .into_response();
        }
        Json(json!({"choices": [{"message": {"role": "assistant", "content": "plain"}}]}))
            .into_response()
    }
    let app = Router::new().route("/v1/chat/completions", post(picky));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app).await.unwrap() });
    let client = VlmClient::new(config(&format!("http://{addr}/v1"))).unwrap();
    let reply = client
        .chat(&msgs(), &CallBudget::unlimited())
        .await
        .unwrap();
    assert_eq!(reply.text, "plain");
    assert_eq!(reply.usage.total, 0);
}

#[tokio::test]
async fn key_never_in_debug_serialize_or_errors() {
    let (_s, base) = fake(vec![Step::Status(400, None)]).await;
    let cfg = config(&base);
    assert!(!format!("{cfg:?}").contains("SECRET"));
    assert!(!serde_json::to_string(&cfg).unwrap().contains("SECRET"));
    let client = VlmClient::new(cfg).unwrap();
    assert!(!format!("{client:?}").contains("SECRET"));
    let err = client
        .chat(&msgs(), &CallBudget::unlimited())
        .await
        .unwrap_err();
    assert!(!format!("{err:?} {err}").contains("SECRET"));
}

#[tokio::test]
async fn connection_refused_is_retried_then_reported() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    drop(listener);
    let client = VlmClient::new(config(&format!("http://{addr}/v1"))).unwrap();
    let budget = CallBudget::unlimited();
    let err = client.chat(&msgs(), &budget).await.unwrap_err();
    assert!(
        matches!(err, VlmError::Connection { attempts: 4, .. }),
        "{err:?}"
    );
    assert_eq!(budget.calls_used(), 4);
}

#[test]
fn env_overrides_and_azure_urls() {
    let env = |k: &str| match k {
        "GROUNDER_VLM_BASE_URL" => {
            Some("https://x.openai.azure.com/openai/deployments/d?api-version=1".to_string())
        }
        "OPENAI_API_KEY" => Some("k2".to_string()),
        _ => None,
    };
    let cfg = VlmConfig::default().with_env(env);
    assert_eq!(cfg.api_key.expose(), "k2");
    assert_eq!(
        cfg.chat_url(),
        "https://x.openai.azure.com/openai/deployments/d/chat/completions?api-version=1"
    );
    assert_eq!(cfg.auth_style, grounder::vlm::AuthStyle::ApiKeyHeader);
    let env2 = |k: &str| match k {
        "GROUNDER_VLM_API_KEY" => Some("k1".to_string()),
        "OPENAI_API_KEY" => Some("k2".to_string()),
        "GROUNDER_VLM_MODEL" => Some("qwen".to_string()),
        _ => None,
    };
    let cfg = VlmConfig::default().with_env(env2);
    assert_eq!((cfg.api_key.expose(), cfg.model.as_str()), ("k1", "qwen"));
    assert!(cfg.chat_url().ends_with("/v1/chat/completions"));
}

#[tokio::test]
async fn large_images_are_downscaled_and_image_count_is_capped() {
    use base64::Engine;
    let (script, base) = fake(vec![Step::Ok("ok")]).await;
    let mut cfg = config(&base);
    cfg.max_image_side = 32;
    cfg.max_images_per_request = 2;
    let client = VlmClient::new(cfg).unwrap();
    let mut jpeg = Vec::new();
    let img = image::RgbImage::from_pixel(128, 32, image::Rgb([10, 200, 10]));
    image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
        .encode_image(&img)
        .unwrap();
    let m = Message::user_with_images("look", vec![ImageData::jpeg(jpeg.clone())]);
    client.chat(&[m], &CallBudget::unlimited()).await.unwrap();
    let url = script.seen.lock().unwrap()[0].1["messages"][0]["content"][1]["image_url"]["url"]
        .as_str()
        .unwrap()
        .to_string();
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(url.split_once(',').unwrap().1)
        .unwrap();
    let sent = image::load_from_memory(&bytes).unwrap();
    assert_eq!((sent.width(), sent.height()), (32, 8));

    let three = Message::user_with_images("x", vec![ImageData::jpeg(jpeg.clone()); 3]);
    let budget = CallBudget::unlimited();
    let err = client.chat(&[three], &budget).await.unwrap_err();
    assert!(
        matches!(err, VlmError::TooManyImages { count: 3, max: 2 }),
        "{err:?}"
    );
    assert_eq!(budget.calls_used(), 0);
}
