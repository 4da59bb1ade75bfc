//! Limits on what is stored: a scene over the frames x pixels cap (at upload and at
//! append), a data dir short of free space, and finished jobs past their retention.

use super::{assert_peak_growth_under, vm_hwm_kb};
use crate::frames::more_frames;
use crate::helpers::{problem, tar_of, test_config, tiny_scene_files, TestApp};
use serde_json::Value;
use std::time::{Duration, Instant};

#[tokio::test]
async fn a_scene_over_the_frames_x_pixels_cap_is_refused_at_upload_and_at_append() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    // The tiny scene's frame: 64x48 colour + 32x24 depth = 3,840 pixels. Two fit, three not.
    cfg.max_scene_pixels = 3 * 3_840 - 1;
    let app = TestApp::spawn_with(cfg).await;
    let before = vm_hwm_kb();
    let r = app
        .upload(tar_of(&tiny_scene_files(3), None), "application/x-tar")
        .await;
    let (s, ct, p) = problem(r).await;
    assert_eq!(
        (s, p["code"].as_str()),
        (413, Some("scene_too_large")),
        "{p}"
    );
    assert_eq!(ct, "application/problem+json");
    let detail = p["detail"].as_str().unwrap_or("");
    assert!(
        detail.contains("max_scene_pixels")
            && detail.contains("3 frames")
            && detail.contains("11520"),
        "the detail names the setting and the count: {detail}"
    );
    assert_eq!(app.get_json("/healthz").await.0, 200);

    // Two frames fit.
    let id = app.upload_tiny_scene(2).await;
    let r = app
        .client
        .post(app.url(&format!("/v1/scenes/{id}/frames")))
        .header("content-type", "application/x-tar")
        .body(tar_of(&more_frames(&[1000], 0.3), None))
        .send()
        .await
        .expect("append");
    let (s, _, p) = problem(r).await;
    assert_eq!(
        (s, p["code"].as_str()),
        (413, Some("scene_too_large")),
        "{p}"
    );
    let (_, now) = app.get_json(&format!("/v1/scenes/{id}")).await;
    assert_eq!(now["frames"], 2, "nothing was appended: {now}");
    let colour = app.data_dir.join("scenes").join(id).join("color");
    assert_eq!(std::fs::read_dir(colour).map(|d| d.count()).ok(), Some(2));
    assert_peak_growth_under(before, 200_000);
    app.stop().await;
}

#[tokio::test]
async fn an_upload_that_would_eat_the_free_space_reserve_is_refused_with_507() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    // More than any disk holds: every upload would cut into the reserve.
    cfg.min_free_disk_mb = 1 << 40;
    let app = TestApp::spawn_with(cfg).await;
    let r = app
        .upload(tar_of(&tiny_scene_files(2), None), "application/x-tar")
        .await;
    let (s, ct, p) = problem(r).await;
    assert_eq!(
        (s, p["code"].as_str()),
        (507, Some("insufficient_storage")),
        "{p}"
    );
    assert_eq!(ct, "application/problem+json");
    let detail = p["detail"].as_str().unwrap_or("");
    assert!(detail.contains("min_free_disk_mb"), "{detail}");
    assert!(
        !detail.contains(&*dir.path().to_string_lossy()),
        "no path: {detail}"
    );
    let (_, list) = app.get_json("/v1/scenes").await;
    assert_eq!(list["scenes"].as_array().map(Vec::len), Some(0));
    assert_eq!(app.get_json("/healthz").await.0, 200);
    app.stop().await;
}

#[tokio::test]
async fn finished_jobs_and_their_artifacts_go_after_the_retention() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=10".into();
    cfg.job_retention_days = 1.5 / 86_400.0;
    let app = TestApp::spawn_with(cfg).await;
    let sid = app.upload_tiny_scene(3).await;
    let r = app.create_job(&sid, "the chair").await;
    let job: Value = r.json().await.expect("json");
    let id = job["id"].as_str().expect("id").to_string();
    let j = app.wait_job(&id, Duration::from_secs(10)).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    let artifacts = app.data_dir.join("artifacts").join(&id);
    assert!(
        artifacts.join("test.txt").is_file(),
        "the job wrote an artifact"
    );
    let t = Instant::now();
    let (status, _) = loop {
        let got = app.get_json(&format!("/v1/jobs/{id}")).await;
        if got.0 == 404 || t.elapsed() > Duration::from_secs(10) {
            break got;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(status, 404, "the job is deleted after its retention");
    assert!(!artifacts.exists(), "its artifacts went with it");
    let (s, _) = app.get_json(&format!("/v1/scenes/{sid}")).await;
    assert_eq!(s, 200, "the scene stays");
    app.stop().await;
}
