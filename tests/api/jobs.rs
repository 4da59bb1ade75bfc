use crate::helpers::*;
use serde_json::Value;
use std::time::Duration;

#[tokio::test]
async fn a_job_runs_to_a_box_with_a_trace() {
    let app = TestApp::spawn().await;
    let sid = app.upload_tiny_scene(4).await;
    let r = app.create_job(&sid, "the chair by the window").await;
    assert_eq!(r.status().as_u16(), 202);
    let loc = r
        .headers()
        .get("location")
        .unwrap()
        .to_str()
        .unwrap()
        .to_string();
    let j: Value = r.json().await.unwrap();
    assert_eq!(loc, format!("/v1/jobs/{}", j["id"].as_str().unwrap()));
    assert_eq!(j["status"], "queued");
    let done = app
        .wait_job(j["id"].as_str().unwrap(), Duration::from_secs(10))
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    // The test pipeline boxes the usable camera centres, in the axis-aligned frame
    // (align adds (1, 2, 3)); frame 60's inf pose is skipped.
    let b = &done["result"]["box"];
    assert_eq!(b["min"], serde_json::json!([1.0, 2.0, 3.0]));
    assert_eq!(b["max"], serde_json::json!([2.0, 2.0, 3.0]));
    assert_eq!(b["center"], serde_json::json!([1.5, 2.0, 3.0]));
    assert_eq!(b["size"], serde_json::json!([1.0, 0.0, 0.0]));
    let steps: Vec<&str> = done["trace"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["step"].as_str().unwrap())
        .collect();
    assert_eq!(steps, vec!["start", "done"]);
    assert_eq!(done["trace"][0]["frames"], 4);
    for k in ["created_at", "started_at", "finished_at"] {
        assert!(done[k].is_string(), "{k}");
    }
    assert!(done["error"].is_null());
    app.stop().await;
}

#[tokio::test]
async fn failures_cancels_and_bad_requests() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    // Long enough that a loaded machine still catches the job running before it ends.
    cfg.pipeline = "test:delay_ms=1500".into();
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(4).await;
    // A failing pipeline gives a named reason.
    let id = app.submit_job(&sid, "[fail] the lamp").await;
    let done = app.wait_job(&id, Duration::from_secs(10)).await;
    assert_eq!(
        (done["status"].as_str(), done["error"]["code"].as_str()),
        (Some("failed"), Some("no_target_found"))
    );

    // Cancel while running.
    let id = app.submit_job(&sid, "the table").await;
    for _ in 0..200 {
        let (_, s) = app.get_json(&format!("/v1/jobs/{id}")).await;
        if s["status"] == "running" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    let r = app.post_empty(&format!("/v1/jobs/{id}/cancel")).await;
    assert_eq!(r.status().as_u16(), 200);
    let s = app.wait_job(&id, Duration::from_secs(10)).await;
    assert_eq!(
        s["status"], "canceled",
        "a cancel is never overwritten by the finishing worker: {s}"
    );
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (_, s) = app.get_json(&format!("/v1/jobs/{id}")).await;
    assert_eq!(s["status"], "canceled", "{s}");
    let r = app.post_empty(&format!("/v1/jobs/{id}/cancel")).await;
    assert_eq!(
        r.status().as_u16(),
        409,
        "cancelling a finished job is a conflict"
    );

    // Validation and 404s.
    let r = app.create_job(&sid, "   ").await;
    assert_eq!(r.status().as_u16(), 400);
    assert_eq!(r.json::<Value>().await.unwrap()["code"], "empty_query");
    let r = app.create_job("nope", "the chair").await;
    assert_eq!(r.status().as_u16(), 404);
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("content-type", "application/json")
        .body("{not json")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 400);
    assert_eq!(r.headers()["content-type"], "application/problem+json");
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("content-type", "application/json")
        .body("{\"scene_id\": 3}")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 422);
    assert_eq!(r.headers()["content-type"], "application/problem+json");
    let (s, p) = app.get_json("/v1/jobs/does-not-exist").await;
    assert_eq!((s, p["code"].as_str()), (404, Some("job_not_found")));
    let (s, _) = app.get_json("/v1/jobs?status=exploded").await;
    assert_eq!(s, 400);
    let (s, _) = app.get_json("/v1/jobs?cursor=garbage").await;
    assert_eq!(s, 400);
    app.stop().await;
}

#[tokio::test]
async fn listing_pages_with_a_cursor_and_filters() {
    let app = TestApp::spawn().await;
    let a = app.upload_tiny_scene(4).await;
    let b = app.upload_tiny_scene(4).await;
    let mut ids = Vec::new();
    for i in 0..5 {
        let sid = if i % 2 == 0 { &a } else { &b };
        ids.push(app.submit_job(sid, &format!("object {i}")).await);
    }
    let mut seen = Vec::new();
    let mut cursor = String::new();
    loop {
        let (s, page) = app
            .get_json(&format!("/v1/jobs?limit=2&cursor={cursor}"))
            .await;
        assert_eq!(s, 200);
        for j in page["jobs"].as_array().unwrap() {
            assert!(j.get("trace").is_none(), "lists omit traces");
            seen.push(j["id"].as_str().unwrap().to_string());
        }
        match page["next_cursor"].as_str() {
            Some(c) => cursor = c.to_string(),
            None => break,
        }
    }
    let mut newest_first = ids.clone();
    newest_first.reverse();
    assert_eq!(seen, newest_first, "every job once, newest first");
    let (_, only_a) = app.get_json(&format!("/v1/jobs?scene_id={a}")).await;
    assert_eq!(only_a["jobs"].as_array().unwrap().len(), 3);
    for id in &ids {
        app.wait_job(id, Duration::from_secs(10)).await;
    }
    let (_, ok) = app.get_json("/v1/jobs?status=succeeded&limit=500").await;
    assert_eq!(ok["jobs"].as_array().unwrap().len(), 5);
    app.stop().await;
}

#[tokio::test]
async fn a_job_waits_while_its_scene_indexes_and_metrics_count_it() {
    let app = TestApp::spawn().await;
    let sid = app.upload_tiny_scene(4).await;
    let store = crate::helpers::open_store(&app.data_dir).await;
    store
        .set_scene_status(&sid, "indexing", None)
        .await
        .unwrap();
    let id = app.submit_job(&sid, "the sofa").await;
    tokio::time::sleep(Duration::from_millis(700)).await;
    let (_, s) = app.get_json(&format!("/v1/jobs/{id}")).await;
    assert_eq!(s["status"], "queued", "waits for the scene");
    let r = app.delete(&format!("/v1/scenes/{sid}")).await;
    assert_eq!(
        r.status().as_u16(),
        204,
        "a queued job does not block delete"
    );
    let (_, s) = app.get_json(&format!("/v1/jobs/{id}")).await;
    assert_eq!(
        (s["status"].as_str(), s["error"]["code"].as_str()),
        (Some("canceled"), Some("scene_deleted"))
    );

    let sid = app.upload_tiny_scene(4).await;
    let id = app.submit_job(&sid, "the sofa").await;
    app.wait_job(&id, Duration::from_secs(10)).await;
    let text = app
        .client
        .get(app.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        text.contains("grounder_jobs{state=\"succeeded\"} 1"),
        "{text}"
    );
    assert!(
        text.contains("grounder_jobs{state=\"canceled\"} 1"),
        "{text}"
    );
    assert!(
        text.contains("grounder_job_duration_seconds_count{outcome=\"succeeded\"} 1"),
        "{text}"
    );
    assert!(text.contains("grounder_http_request_duration_seconds_count{method=\"POST\",route=\"/v1/jobs\",status=\"202\"}"), "{text}");
    let (s, h) = app.get_json("/healthz").await;
    assert_eq!((s, h["status"].as_str()), (200, Some("ok")));
    let (s, _) = app.get_json("/readyz").await;
    assert_eq!(s, 200);
    let (s, p) = app.get_json("/no/such/route").await;
    assert_eq!((s, p["code"].as_str()), (404, Some("route_not_found")));
    app.stop().await;
}

#[tokio::test]
async fn a_scene_with_a_running_job_cannot_be_deleted() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    // Long enough to be caught running, short enough to finish if the cancel is lost.
    cfg.pipeline = "test:delay_ms=3000".into();
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(4).await;
    let id = app.submit_job(&sid, "the sofa").await;
    if let Err(j) = app
        .wait_status(&id, "running", Duration::from_secs(10))
        .await
    {
        panic!("the job never started: {j}");
    }

    let r = app.delete(&format!("/v1/scenes/{sid}")).await;
    assert_eq!(r.status().as_u16(), 409);
    assert_eq!(r.headers()["content-type"], "application/problem+json");
    let p: Value = r.json().await.unwrap();
    assert_eq!(
        (p["status"].as_u64(), p["code"].as_str()),
        (Some(409), Some("scene_busy")),
        "{p}"
    );
    assert!(p["detail"].as_str().unwrap().contains(&sid), "{p}");
    // Nothing was lost: the scene, its files and the job are all still there.
    assert_eq!(app.get_json(&format!("/v1/scenes/{sid}")).await.0, 200);
    assert!(app.data_dir.join("scenes").join(&sid).exists());
    assert_eq!(
        app.get_json(&format!("/v1/jobs/{id}")).await.1["status"],
        "running"
    );

    // Once the job is canceled the scene can go.
    let r = app.post_empty(&format!("/v1/jobs/{id}/cancel")).await;
    assert_eq!(r.status().as_u16(), 200);
    let done = app.wait_job(&id, Duration::from_secs(10)).await;
    assert_eq!(done["status"], "canceled", "{done}");
    let r = app.delete(&format!("/v1/scenes/{sid}")).await;
    assert_eq!(r.status().as_u16(), 204);
    assert_eq!(app.get_json(&format!("/v1/scenes/{sid}")).await.0, 404);
    app.stop().await;
}

#[tokio::test]
async fn a_poll_returns_the_trace_in_step_order() {
    let app = TestApp::spawn().await;
    let sid = app.upload_tiny_scene(4).await;
    let j: Value = app.create_job(&sid, "the lamp").await.json().await.unwrap();
    assert_eq!(
        j["trace"],
        serde_json::json!([]),
        "a new job has an empty trace"
    );
    let done = app
        .wait_job(j["id"].as_str().unwrap(), Duration::from_secs(10))
        .await;
    let trace = done["trace"].as_array().unwrap();
    assert_eq!(trace.len(), 2, "{done}");
    assert_eq!(
        (trace[0]["step"].as_str(), trace[1]["step"].as_str()),
        (Some("start"), Some("done"))
    );
    assert_eq!(
        trace[0]["query"], "the lamp",
        "step data keeps its own fields beside `step`"
    );
    // Lists leave traces out.
    let (_, list) = app.get_json(&format!("/v1/jobs?scene_id={sid}")).await;
    assert!(list["jobs"][0].get("trace").is_none(), "{list}");
    app.stop().await;
}

/// A job is reported as created even when a worker claims it at once: the response to a
/// POST never shows a state the caller did not cause.
#[tokio::test]
async fn a_new_job_is_reported_queued_even_when_claimed_at_once() {
    let app = TestApp::spawn().await;
    let sid = app.upload_tiny_scene(4).await;
    let store = crate::helpers::open_store(&app.data_dir).await;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let claimer = {
        let (store, stop) = (store.clone(), stop.clone());
        tokio::spawn(async move {
            let mut claimed = 0;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if store.claim_next_job().await.unwrap().is_some() {
                    claimed += 1;
                }
                tokio::task::yield_now().await;
            }
            claimed
        })
    };
    for i in 0..200 {
        let rec = store
            .create_job(&format!("race-{i}"), &sid, "the chair")
            .await
            .unwrap();
        assert_eq!(
            (rec.status.as_str(), rec.attempts, rec.started_at.is_none()),
            ("queued", 0, true),
            "job {i}"
        );
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    assert!(
        claimer.await.unwrap() > 0,
        "the claimer ran beside the inserts"
    );
    app.stop().await;
}
