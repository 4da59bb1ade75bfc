//! The scene-points export that a new scene warms in the background yields to the queries:
//! it is made while nothing runs, waits while a job runs, and is the same file a viewer's
//! request computes.

use super::helpers::*;
use std::path::PathBuf;
use std::time::{Duration, Instant};

fn points_file(app: &TestApp, sid: &str) -> PathBuf {
    app.data_dir
        .join("scenes")
        .join(sid)
        .join("points_50mm.ply")
}

async fn upload_tiny(app: &TestApp) -> String {
    let up = app
        .upload(tar_of(&tiny_scene_files(4), None), "application/x-tar")
        .await;
    assert_eq!(up.status(), 201);
    let scene: serde_json::Value = up.json().await.unwrap();
    scene["id"].as_str().unwrap().to_string()
}

async fn wait_file(p: &std::path::Path, within: Duration) -> bool {
    let t = Instant::now();
    while t.elapsed() < within {
        if p.is_file() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    p.is_file()
}

#[tokio::test]
async fn the_warmed_points_wait_for_a_running_job_and_equal_the_computed_ones() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    // Long enough that an upload and the 800 ms wait below end within it on a loaded runner.
    cfg.pipeline = "test:delay_ms=4000".into();
    let app = TestApp::spawn_with(cfg).await;

    // Nothing runs: the export of a new scene is made without being asked for.
    let a = upload_tiny(&app).await;
    assert!(
        wait_file(&points_file(&app, &a), Duration::from_secs(20)).await,
        "the points of an idle service's new scene were not made"
    );
    // Byte for byte what the export computes on request (frames in parallel).
    let store = open_store(&app.data_dir).await;
    let scene = store
        .load_scene(&a, &app.data_dir.join("scenes").join(&a))
        .await
        .unwrap()
        .unwrap();
    let want = grounder::jobs::exports::compute_scene_points(&scene, 50);
    assert_eq!(std::fs::read(points_file(&app, &a)).unwrap(), want);

    // A job runs: a scene uploaded meanwhile gets its points only once the job ended.
    let r = app.create_job(&a, "the box").await;
    let job: serde_json::Value = r.json().await.unwrap();
    let id = job["id"].as_str().unwrap().to_string();
    if let Err(j) = app
        .wait_status(&id, "running", Duration::from_secs(10))
        .await
    {
        panic!("job never ran: {j}");
    }
    let b = upload_tiny(&app).await;
    tokio::time::sleep(Duration::from_millis(800)).await;
    let (_, j) = app.get_json(&format!("/v1/jobs/{id}")).await;
    assert_eq!(
        j["status"], "running",
        "the job ended too early for the test"
    );
    assert!(
        !points_file(&app, &b).exists(),
        "the points export ran beside a running job"
    );
    let done = app.wait_job(&id, Duration::from_secs(20)).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert!(
        wait_file(&points_file(&app, &b), Duration::from_secs(20)).await,
        "the points were not made once the job ended"
    );
    app.stop().await;
}

#[tokio::test]
async fn a_stopping_service_ends_its_warming_and_writes_nothing_after() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.pipeline = "test:delay_ms=5000".into();
    let app = TestApp::spawn_with(cfg).await;
    let a = upload_tiny(&app).await;
    assert!(wait_file(&points_file(&app, &a), Duration::from_secs(20)).await);

    // A job runs, so the new scene's warming waits; then the service stops.
    let r = app.create_job(&a, "the box").await;
    let job: serde_json::Value = r.json().await.unwrap();
    let id = job["id"].as_str().unwrap().to_string();
    if let Err(j) = app
        .wait_status(&id, "running", Duration::from_secs(10))
        .await
    {
        panic!("job never ran: {j}");
    }
    let b = upload_tiny(&app).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let scene_b = app.data_dir.join("scenes").join(&b);
    let data_dir = app.data_dir.clone();
    let before = files_and_sizes(&scene_b);
    app.stop().await;

    // Once stop returned, nothing more is written into the scene's folder.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let after = files_and_sizes(&scene_b);
    assert_eq!(before, after, "files changed after the service stopped");
    assert!(!points_file_in(&data_dir, &b).exists());
}

fn points_file_in(data_dir: &std::path::Path, sid: &str) -> PathBuf {
    data_dir.join("scenes").join(sid).join("points_50mm.ply")
}
