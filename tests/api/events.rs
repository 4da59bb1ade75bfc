//! Issue 19: `GET /v1/jobs/{id}/events` (Server-Sent Events) with Last-Event-ID.

use crate::helpers::*;
use serde_json::Value;

async fn stream(app: &TestApp, job: &str, last: Option<&str>) -> Vec<Sse> {
    let mut req = app.client.get(app.url(&format!("/v1/jobs/{job}/events")));
    if let Some(l) = last {
        req = req.header("last-event-id", l);
    }
    let r = req.send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
    assert!(r.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/event-stream"));
    read_sse(r).await
}

#[tokio::test]
async fn the_stream_follows_the_trace_in_order_and_resumes_with_last_event_id() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=400".into();
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(3).await;
    let id = app.submit_job(&sid, "the lamp").await;

    // Subscribed while the job is queued or running: the live stream.
    let live = stream(&app, &id, None).await;
    let kinds: Vec<&str> = live.iter().map(|e| e.event.as_str()).collect();
    assert_eq!(
        kinds,
        ["status", "status", "step", "step", "status", "done"],
        "{live:?}"
    );
    let statuses: Vec<&str> = live
        .iter()
        .filter(|e| e.event == "status")
        .map(|e| e.data["status"].as_str().unwrap())
        .collect();
    assert_eq!(statuses, ["queued", "running", "succeeded"]);
    let done = &live.last().unwrap().data;
    assert_eq!(done["status"], "succeeded");
    // The step events are the trace, in the order it was written.
    let steps: Vec<Value> = live
        .iter()
        .filter(|e| e.event == "step")
        .map(|e| e.data.clone())
        .collect();
    assert_eq!(Value::Array(steps.clone()), done["trace"]);
    assert_eq!(steps[0]["step"], "start");
    // Ids increase strictly.
    let ids: Vec<i64> = live
        .iter()
        .filter_map(|e| e.id.as_ref())
        .map(|i| i.parse().unwrap())
        .collect();
    assert_eq!(ids.len(), 5);
    assert!(ids.windows(2).all(|w| w[0] < w[1]), "{ids:?}");

    // A finished job replays everything and closes.
    assert_eq!(stream(&app, &id, None).await, live);
    // Resumed after the first step: exactly the rest, no gap, no repeat.
    let cut = live[2].id.clone().unwrap();
    let rest = stream(&app, &id, Some(&cut)).await;
    assert_eq!(rest, live[3..].to_vec());
    // Resumed after the last event: only done.
    let last = live[4].id.clone().unwrap();
    assert_eq!(stream(&app, &id, Some(&last)).await, live[5..].to_vec());
    let r = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/events")))
        .header("last-event-id", "nope")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 400);
    let (s, _) = app.get_json("/v1/jobs/unknown/events").await;
    assert_eq!(s, 404);
    app.stop().await;
}
