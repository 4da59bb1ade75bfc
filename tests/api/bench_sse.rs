//! Benchmark (ignored by default): 1,000 concurrent SSE subscribers on one job.
//! `cargo test --test api bench_sse -- --ignored --nocapture`. Client and server share
//! this process (and the machine's cores). Every subscriber must receive the whole
//! stream; the figures are how long subscribing took and how late each got `done`.

use crate::helpers::*;
use serde_json::Value;
use std::time::{Duration, Instant};

fn rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|k| k.parse::<f64>().ok())
        })
        .unwrap_or(0.0)
        / 1024.0
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore]
async fn bench_sse_1000_subscribers_on_one_job() {
    let n: usize = std::env::var("SSE_SUBSCRIBERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1000);
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=6000".into();
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(3).await;
    let j: Value = app.create_job(&sid, "the lamp").await.json().await.unwrap();
    let url = app.url(&format!("/v1/jobs/{}/events", j["id"].as_str().unwrap()));
    let rss0 = rss_mb();
    let client = reqwest::Client::builder()
        .pool_max_idle_per_host(0)
        .build()
        .unwrap();
    let started = Instant::now();
    let (ready_tx, mut ready_rx) = tokio::sync::mpsc::channel::<()>(n);
    let mut tasks = Vec::with_capacity(n);
    for _ in 0..n {
        let (c, u, ready) = (client.clone(), url.clone(), ready_tx.clone());
        tasks.push(tokio::spawn(async move {
            let mut r = c.get(&u).send().await.expect("subscribe");
            assert_eq!(r.status().as_u16(), 200);
            let _ = ready.send(()).await;
            let mut text = String::new();
            while let Some(chunk) = r.chunk().await.expect("stream") {
                text.push_str(&String::from_utf8_lossy(&chunk));
                if text.contains("event: done") {
                    break;
                }
            }
            (
                time::OffsetDateTime::now_utc(),
                text.matches("event: ").count(),
            )
        }));
    }
    for _ in 0..n {
        ready_rx.recv().await.unwrap();
    }
    let subscribed = started.elapsed();
    let rss1 = rss_mb();
    let mut got = Vec::with_capacity(n);
    for t in tasks {
        got.push(t.await.unwrap());
    }
    let (_, job) = app
        .get_json(&format!("/v1/jobs/{}", j["id"].as_str().unwrap()))
        .await;
    assert_eq!(job["status"], "succeeded");
    let finished = time::OffsetDateTime::parse(
        job["finished_at"].as_str().unwrap(),
        &time::format_description::well_known::Rfc3339,
    )
    .unwrap();
    let mut lags: Vec<i128> = got
        .iter()
        .map(|(at, events)| {
            assert_eq!(*events, 6, "every subscriber gets all 6 events");
            (*at - finished).whole_milliseconds()
        })
        .collect();
    lags.sort();
    let pct = |p: f64| lags[((lags.len() - 1) as f64 * p) as usize];
    println!(
        "SSE bench: {n} subscribers connected in {:.0} ms; RSS {rss0:.0} -> {rss1:.0} MB while subscribed; \
         done received after the job ended: p50 {} ms, p99 {} ms, max {} ms",
        subscribed.as_secs_f64() * 1000.0,
        pct(0.5),
        pct(0.99),
        lags[lags.len() - 1]
    );
    assert!(
        subscribed < Duration::from_secs(6),
        "all subscribed while the job ran"
    );
    app.stop().await;
}
