//! What artifacts are served with: browsers must not guess their type.

use crate::helpers::{tar_of, test_config, tiny_scene_files, TestApp};
use serde_json::Value;

#[tokio::test]
async fn artifacts_are_served_with_nosniff() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=10".into();
    let app = TestApp::spawn_with(cfg).await;
    let r = app
        .upload(tar_of(&tiny_scene_files(3), None), "application/x-tar")
        .await;
    let scene: Value = r.json().await.expect("json");
    let r = app
        .create_job(scene["id"].as_str().expect("id"), "<html>the chair")
        .await;
    let job: Value = r.json().await.expect("json");
    let id = job["id"].as_str().expect("id");
    let j = app.wait_job(id, std::time::Duration::from_secs(10)).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    let r = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/artifacts/test.txt")))
        .send()
        .await
        .expect("get");
    assert_eq!(r.status().as_u16(), 200);
    assert_eq!(
        r.headers()
            .get("x-content-type-options")
            .and_then(|v| v.to_str().ok()),
        Some("nosniff")
    );
    app.stop().await;
}
