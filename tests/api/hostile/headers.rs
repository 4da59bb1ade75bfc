//! What artifacts are served with: browsers must not guess their type.

use crate::helpers::{test_config, TestApp};

#[tokio::test]
async fn artifacts_are_served_with_nosniff() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=10".into();
    let app = TestApp::spawn_with(cfg).await;
    let scene = app.upload_tiny_scene(3).await;
    let id = app.submit_job(&scene, "<html>the chair").await;
    let j = app.wait_job(&id, std::time::Duration::from_secs(10)).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    let r = app.get(&format!("/v1/jobs/{id}/artifacts/test.txt")).await;
    assert_eq!(r.status().as_u16(), 200);
    // A text artifact is not served as an image.
    assert_eq!(
        r.headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok()),
        Some("text/plain; charset=utf-8")
    );
    assert_eq!(
        r.headers()
            .get("x-content-type-options")
            .and_then(|v| v.to_str().ok()),
        Some("nosniff")
    );
    app.stop().await;
}
