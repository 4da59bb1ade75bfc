//! Issue 19: ETag / If-None-Match, `Prefer: wait=N`, and batches of queries.

use crate::helpers::*;
use serde_json::{json, Value};
use std::time::{Duration, Instant};

async fn cond_get(app: &TestApp, path: &str, etag: &str) -> reqwest::Response {
    app.client
        .get(app.url(path))
        .header("if-none-match", etag)
        .send()
        .await
        .unwrap()
}

#[tokio::test]
async fn etags_answer_304_until_the_job_or_scene_changes() {
    let app = TestApp::spawn().await;
    let sid = app.upload_tiny_scene(3).await;
    let r = app.get(&format!("/v1/scenes/{sid}")).await;
    let tag = r.headers()["etag"].to_str().unwrap().to_string();
    let r = cond_get(&app, &format!("/v1/scenes/{sid}"), &tag).await;
    assert_eq!(r.status().as_u16(), 304);
    assert_eq!(r.headers()["etag"].to_str().unwrap(), tag);
    assert!(r.bytes().await.unwrap().is_empty(), "304 has no body");
    let r = cond_get(&app, &format!("/v1/scenes/{sid}"), "\"stale\"").await;
    assert_eq!(r.status().as_u16(), 200);

    let id = app.submit_job(&sid, "the lamp").await;
    let path = format!("/v1/jobs/{id}");
    let r = app.client.get(app.url(&path)).send().await.unwrap();
    let tag = r.headers()["etag"].to_str().unwrap().to_string();
    let first: Value = r.json().await.unwrap();
    let done = app.wait_job(&id, Duration::from_secs(10)).await;
    assert_eq!(done["status"], "succeeded");
    // Changed since: 200 with a new tag; then 304 with that tag.
    let r = cond_get(&app, &path, &tag).await;
    assert_eq!(r.status().as_u16(), 200, "first seen {first}");
    let tag2 = r.headers()["etag"].to_str().unwrap().to_string();
    assert_ne!(tag, tag2);
    let r = cond_get(&app, &path, &tag2).await;
    assert_eq!(r.status().as_u16(), 304);
    let r = cond_get(&app, &path, &format!("\"x\", W/{tag2}")).await;
    assert_eq!(r.status().as_u16(), 304, "weak comparison, lists");
    app.stop().await;
}

#[tokio::test]
async fn prefer_wait_returns_within_100ms_of_the_job_ending() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=1500".into();
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(3).await;
    let id = app.submit_job(&sid, "the lamp").await;
    let path = format!("/v1/jobs/{id}");
    let started = Instant::now();
    let r = app
        .client
        .get(app.url(&path))
        .header("prefer", "wait=30")
        .send()
        .await
        .unwrap();
    let answered = time::OffsetDateTime::now_utc();
    let took = started.elapsed();
    assert_eq!(r.status().as_u16(), 200);
    assert_eq!(r.headers()["preference-applied"], "wait=30");
    let job: Value = r.json().await.unwrap();
    assert_eq!(job["status"], "succeeded", "returned when the job ended");
    let finished = time::OffsetDateTime::parse(
        job["finished_at"].as_str().unwrap(),
        &time::format_description::well_known::Rfc3339,
    )
    .unwrap();
    let lag = (answered - finished).whole_milliseconds();
    assert!(
        (0..100).contains(&lag),
        "answered {lag} ms after the job ended"
    );
    assert!(took >= Duration::from_millis(1000), "it did wait: {took:?}");

    // A running job past N seconds comes back with its current state.
    let id = app.submit_job(&sid, "the sofa").await;
    let path = format!("/v1/jobs/{id}");
    let started = Instant::now();
    let r = app
        .client
        .get(app.url(&path))
        .header("prefer", "wait=1")
        .send()
        .await
        .unwrap();
    let took = started.elapsed();
    assert_eq!(r.headers()["preference-applied"], "wait=1");
    let v: Value = r.json().await.unwrap();
    assert!(
        matches!(v["status"].as_str(), Some("queued" | "running")),
        "{v}"
    );
    assert!(
        (Duration::from_millis(950)..Duration::from_millis(1400)).contains(&took),
        "{took:?}"
    );
    // Without the preference, no header and no wait.
    let r = app.client.get(app.url(&path)).send().await.unwrap();
    assert!(!r.headers().contains_key("preference-applied"));
    app.stop().await;
}

#[tokio::test]
async fn a_batch_of_queries_makes_one_job_each_in_order() {
    let app = TestApp::spawn().await;
    let sid = app.upload_tiny_scene(3).await;
    let queries = ["the lamp", "the sofa", "the chair", "[fail] the bed"];
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .json(&json!({"scene_id": sid, "queries": queries}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let v: Value = r.json().await.unwrap();
    let jobs = v["jobs"].as_array().unwrap();
    let got: Vec<&str> = jobs.iter().map(|j| j["query"].as_str().unwrap()).collect();
    assert_eq!(got, queries);
    for j in jobs {
        assert_eq!(j["status"], "queued");
        let done = app
            .wait_job(j["id"].as_str().unwrap(), Duration::from_secs(10))
            .await;
        let want = if j["query"].as_str().unwrap().contains("[fail]") {
            "failed"
        } else {
            "succeeded"
        };
        assert_eq!(done["status"], want);
    }
    for bad in [
        json!({"scene_id": sid, "queries": []}),
        json!({"scene_id": sid, "queries": ["a", " "]}),
        json!({"scene_id": sid, "query": "a", "queries": ["b"]}),
        json!({"scene_id": sid}),
    ] {
        let r = app
            .client
            .post(app.url("/v1/jobs"))
            .json(&bad)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 400, "{bad}");
    }
    let (_, l) = app.get_json("/v1/jobs").await;
    assert_eq!(
        l["jobs"].as_array().unwrap().len(),
        4,
        "refused batches made nothing"
    );
    app.stop().await;
}

/// A `Prefer: wait` in flight when the service stops gracefully is answered at once with the
/// job as it stands, rather than holding the stop until the job ends or N seconds pass.
#[tokio::test]
async fn a_graceful_stop_answers_a_waiting_poll_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=10000".into();
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(3).await;
    let id = app.submit_job(&sid, "the lamp").await;
    app.wait_status(&id, "running", Duration::from_secs(10))
        .await
        .expect("the job runs");
    let poll = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}")))
        .header("prefer", "wait=30")
        .send();
    let poll = tokio::spawn(poll);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let stopping = Instant::now();
    app.stop().await;
    let stopped = stopping.elapsed();
    let r = poll.await.unwrap().expect("an answer");
    assert_eq!(r.status().as_u16(), 200);
    let job: Value = r.json().await.unwrap();
    assert_eq!(job["status"], "running", "the job as it stood: {job}");
    assert!(
        stopped < Duration::from_secs(5),
        "the stop took {stopped:?}"
    );
}
