//! Scenes that grow: frames appended while a job runs (the job keeps its frames), only
//! the new frames counted, frames removed when no job runs, `revision` on each change.

use crate::helpers::{tar_of, test_config, tiny_scene_files, TestApp};
use serde_json::Value;
use std::time::Duration;

/// Frames of the tiny scene renamed to `names`, their cameras moved to x = `x`.
pub fn more_frames(names: &[u64], x: f64) -> Vec<(String, Vec<u8>)> {
    let base = tiny_scene_files(2);
    let mut out = Vec::new();
    for n in names {
        for (p, b) in &base {
            if p.starts_with("color/0.") {
                out.push((format!("color/{n}.jpg"), b.clone()));
            } else if p.starts_with("depth/0.") {
                out.push((format!("depth/{n}.png"), b.clone()));
            }
        }
        out.push((
            format!("pose/{n}.txt"),
            format!("1 0 0 {x}\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").into_bytes(),
        ));
    }
    for (p, b) in &base {
        if p.starts_with("intrinsic/") {
            out.push((p.clone(), b.clone()));
        }
    }
    out
}

async fn append(app: &TestApp, id: &str, body: Vec<u8>) -> (u16, Value) {
    let r = app
        .client
        .post(app.url(&format!("/v1/scenes/{id}/frames")))
        .header("Content-Type", "application/x-tar")
        .body(body)
        .send()
        .await
        .unwrap();
    let s = r.status().as_u16();
    (s, r.json().await.unwrap_or(Value::Null))
}

async fn remove(app: &TestApp, id: &str, name: &str) -> (u16, Value) {
    let r = app.delete(&format!("/v1/scenes/{id}/frames/{name}")).await;
    let s = r.status().as_u16();
    (s, r.json().await.unwrap_or(Value::Null))
}

async fn start_job(app: &TestApp, id: &str) -> String {
    let job = app.submit_job(id, "the chair").await;
    match app
        .wait_status(&job, "running", Duration::from_secs(10))
        .await
    {
        Ok(_) => job,
        Err(j) => panic!("job never ran: {j}"),
    }
}

#[tokio::test]
async fn frames_appended_while_a_job_runs_do_not_reach_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=1500".into();
    // The frames below are appended after the job is claimed and before it loads its
    // scene (the race a loaded CI runner once hit): they must not reach it either.
    cfg.test_claim_pause_ms = 1500;
    let app = TestApp::spawn_with(cfg).await;
    // Frames 0, 20, 40 (cameras at x = 0, 0.5, 1) and 60 (inf pose).
    let r = app
        .upload(tar_of(&tiny_scene_files(4), None), "application/x-tar")
        .await;
    assert_eq!(r.status().as_u16(), 201);
    let rec: Value = r.json().await.unwrap();
    let id = rec["id"].as_str().unwrap().to_string();
    assert_eq!(
        (rec["frames"].as_i64(), rec["revision"].as_i64()),
        (Some(4), Some(0))
    );

    let job = start_job(&app, &id).await;
    let (s, grown) = append(&app, &id, tar_of(&more_frames(&[80, 100], 10.0), None)).await;
    assert_eq!(s, 200, "{grown}");
    assert_eq!(grown["frames"], 6);
    assert_eq!(grown["revision"], 1);
    assert_eq!(grown["unusable_frames"], serde_json::json!(["60"]));
    // No removal while the job runs.
    let (s, p) = remove(&app, &id, "20").await;
    assert_eq!((s, p["code"].as_str()), (409, Some("scene_busy")), "{p}");

    let done = app.wait_job(&job, Duration::from_secs(20)).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(
        done["trace"][0]["frames"], 4,
        "the job keeps the frames it started with"
    );
    // Box of the usable cameras: x within [0, 1] + axis alignment (x + 1).
    assert!(
        done["result"]["box"]["max"][0].as_f64().unwrap() < 3.0,
        "{done}"
    );

    let after = app
        .create_job(&id, "the chair")
        .await
        .json::<Value>()
        .await
        .unwrap();
    let after = app
        .wait_job(after["id"].as_str().unwrap(), Duration::from_secs(20))
        .await;
    assert_eq!(after["trace"][0]["frames"], 6, "{after}");
    assert!(
        after["result"]["box"]["max"][0].as_f64().unwrap() >= 11.0,
        "{after}"
    );

    // Removal once idle: later frames move up, revision bumps; the colour file goes.
    let (s, p) = remove(&app, &id, "80").await;
    assert_eq!(s, 204, "{p}");
    let (_, rec) = app.get_json(&format!("/v1/scenes/{id}")).await;
    assert_eq!(
        (rec["frames"].as_i64(), rec["revision"].as_i64()),
        (Some(5), Some(2))
    );
    let colour = dir
        .path()
        .join("scenes")
        .join(&id)
        .join("color")
        .join("80.jpg");
    assert!(!colour.exists(), "the removed frame's image is gone");
    let (s, p) = remove(&app, &id, "80").await;
    assert_eq!((s, p["code"].as_str()), (404, Some("frame_not_found")));
    let last = app
        .create_job(&id, "the chair")
        .await
        .json::<Value>()
        .await
        .unwrap();
    let last = app
        .wait_job(last["id"].as_str().unwrap(), Duration::from_secs(20))
        .await;
    assert_eq!(last["status"], "succeeded", "{last}");
    assert_eq!(last["trace"][0]["frames"], 5);

    // Frames that do not follow, or come from another camera, are refused.
    let (s, p) = append(&app, &id, tar_of(&more_frames(&[50], 2.0), None)).await;
    assert_eq!(
        (s, p["code"].as_str()),
        (422, Some("frames_do_not_fit")),
        "{p}"
    );
    let mut other = more_frames(&[200], 2.0);
    for (p, b) in &mut other {
        if p.starts_with("intrinsic/") {
            *b = b"60 0 32 0\n0 60 24 0\n0 0 1 0\n0 0 0 1\n".to_vec();
        }
    }
    let (s, p) = append(&app, &id, tar_of(&other, None)).await;
    assert_eq!(
        (s, p["code"].as_str()),
        (422, Some("frames_do_not_fit")),
        "{p}"
    );
    let (_, rec) = app.get_json(&format!("/v1/scenes/{id}")).await;
    assert_eq!(
        (rec["frames"].as_i64(), rec["revision"].as_i64()),
        (Some(5), Some(2))
    );
    let (s, _) = append(&app, "nope", tar_of(&more_frames(&[300], 2.0), None)).await;
    assert_eq!(s, 404);
    app.stop().await;
}
