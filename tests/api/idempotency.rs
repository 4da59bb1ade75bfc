//! Issue 19: `Idempotency-Key` on POST /v1/jobs and POST /v1/scenes.

use crate::helpers::*;
use serde_json::{json, Value};
use sha2::{Digest, Sha256};

async fn post_job(app: &TestApp, key: &str, body: &Value) -> reqwest::Response {
    app.client
        .post(app.url("/v1/jobs"))
        .header("idempotency-key", key)
        .json(body)
        .send()
        .await
        .unwrap()
}

async fn post_scene(app: &TestApp, key: &str, body: Vec<u8>) -> reqwest::Response {
    app.client
        .post(app.url("/v1/scenes"))
        .header("idempotency-key", key)
        .header("content-type", "application/x-tar")
        .body(body)
        .send()
        .await
        .unwrap()
}

async fn count(app: &TestApp, path: &str, field: &str) -> usize {
    let (_, v) = app.get_json(path).await;
    v[field].as_array().unwrap().len()
}

#[tokio::test]
async fn a_retry_replays_the_first_answer_before_and_after_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let app = TestApp::spawn_with(test_config(dir.path().to_path_buf())).await;
    let tar = tar_of(&tiny_scene_files(3), None);
    let r1 = post_scene(&app, "scene-1", tar.clone()).await;
    assert_eq!(r1.status().as_u16(), 201);
    let loc1 = r1.headers()["location"].clone();
    let s1: Value = r1.json().await.unwrap();
    let r2 = post_scene(&app, "scene-1", tar.clone()).await;
    assert_eq!(r2.status().as_u16(), 201);
    assert_eq!(r2.headers()["location"], loc1);
    assert_eq!(r2.headers()["idempotent-replayed"], "true");
    assert_eq!(r2.json::<Value>().await.unwrap(), s1, "same body replayed");
    assert_eq!(count(&app, "/v1/scenes", "scenes").await, 1);

    let sid = s1["id"].as_str().unwrap();
    let body = json!({"scene_id": sid, "query": "the lamp"});
    let r1 = post_job(&app, "job-1", &body).await;
    assert_eq!(r1.status().as_u16(), 202);
    let (loc, j1) = (
        r1.headers()["location"].clone(),
        r1.json::<Value>().await.unwrap(),
    );
    let r2 = post_job(&app, "job-1", &body).await;
    assert_eq!(
        (r2.status().as_u16(), r2.headers()["location"].clone()),
        (202, loc.clone())
    );
    assert_eq!(r2.json::<Value>().await.unwrap(), j1);
    assert_eq!(count(&app, "/v1/jobs", "jobs").await, 1);

    // After a restart on the same data dir: still replayed, nothing created.
    app.stop().await;
    let app = TestApp::spawn_with(test_config(dir.path().to_path_buf())).await;
    let r3 = post_job(&app, "job-1", &body).await;
    assert_eq!(r3.status().as_u16(), 202);
    assert_eq!(r3.headers()["location"], loc);
    assert_eq!(r3.json::<Value>().await.unwrap(), j1);
    let r3 = post_scene(&app, "scene-1", tar).await;
    assert_eq!(r3.status().as_u16(), 201);
    assert_eq!(r3.json::<Value>().await.unwrap(), s1);
    assert_eq!(count(&app, "/v1/jobs", "jobs").await, 1);
    assert_eq!(count(&app, "/v1/scenes", "scenes").await, 1);
    // Another key is another request.
    let r4 = post_job(&app, "job-2", &body).await;
    assert_eq!(r4.status().as_u16(), 202);
    assert_ne!(r4.json::<Value>().await.unwrap()["id"], j1["id"]);
    app.stop().await;
}

#[tokio::test]
async fn a_different_body_is_422_and_a_request_in_flight_is_409() {
    let app = TestApp::spawn().await;
    let sid = app.upload_tiny_scene(3).await;
    let body = json!({"scene_id": sid, "query": "the lamp"});
    assert_eq!(post_job(&app, "k", &body).await.status().as_u16(), 202);
    let other = json!({"scene_id": sid, "query": "the sofa"});
    let r = post_job(&app, "k", &other).await;
    assert_eq!(r.status().as_u16(), 422);
    assert_eq!(
        r.json::<Value>().await.unwrap()["code"],
        "idempotency_key_reused"
    );

    // A first request still in flight holds its key (as the server does while it
    // processes one): the same key and body get 409, and nothing is created.
    let raw = serde_json::to_vec(&other).unwrap();
    let store = crate::helpers::open_store(&app.data_dir).await;
    let begun = store
        .idempotency_begin(
            0,
            "POST /v1/jobs",
            "busy",
            &hex::encode(Sha256::digest(&raw)),
        )
        .await
        .unwrap();
    assert_eq!(begun, grounder::store::idempotency::Begin::Proceed);
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("idempotency-key", "busy")
        .header("content-type", "application/json")
        .body(raw)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 409);
    assert_eq!(
        r.json::<Value>().await.unwrap()["code"],
        "idempotency_key_in_use"
    );
    assert_eq!(count(&app, "/v1/jobs", "jobs").await, 1);
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("idempotency-key", "")
        .json(&body)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 400);
    app.stop().await;
}
