//! A service stopped while a scene is being indexed ends the indexing between frames,
//! writes nothing after it stopped, frees the scene's lease without counting the stop as
//! an attempt, and the next start indexes the scene to the end.

use crate::helpers::*;
use serde_json::Value;
use std::time::{Duration, Instant};

/// Poll the scene until `until` holds of it: here its indexing progress, which
/// `TestApp::wait_scene` (a status) does not express.
async fn wait_index(app: &TestApp, id: &str, until: impl Fn(&Value) -> bool) -> Value {
    let t = Instant::now();
    loop {
        let (_, s) = app.get_json(&format!("/v1/scenes/{id}")).await;
        if until(&s) {
            return s;
        }
        assert!(t.elapsed() < Duration::from_secs(30), "scene stuck: {s}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test]
async fn a_stop_during_indexing_frees_the_scene_for_the_next_start() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.detector = "oracle:delay_ms=150".into();
    let app = TestApp::spawn_with(cfg.clone()).await;
    let r = app
        .upload(crate::crash::scene_with_masks(12), "application/x-tar")
        .await;
    assert_eq!(r.status().as_u16(), 201);
    let id = r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    // Some frames indexed, far from all of them.
    let s = wait_index(&app, &id, |s| s["index"]["done"].as_i64() >= Some(2)).await;
    assert_eq!(s["status"], "indexing", "{s}");
    let data_dir = app.data_dir.clone();
    app.stop().await;

    let scene_dir = data_dir.join("scenes").join(&id);
    let before = files_and_sizes(&scene_dir);
    tokio::time::sleep(Duration::from_millis(700)).await;
    assert_eq!(
        files_and_sizes(&scene_dir),
        before,
        "indexing went on writing after the service stopped"
    );
    let store = open_store(&data_dir).await;
    assert!(
        !store.indexing_held(&id).await.unwrap(),
        "the stopped indexer still holds the scene's lease"
    );
    assert_eq!(
        store.interrupted_indexing().await.unwrap(),
        vec![(id.clone(), 0)],
        "the scene stays indexing, and a stop is not counted as a failed attempt"
    );
    drop(store);

    // The next start indexes it to the end.
    let app = TestApp::spawn_with(cfg).await;
    // Stuck or failed, assert_indexed reports the scene as it was last seen.
    let s = app
        .wait_scene(&id, "ready", Duration::from_secs(30))
        .await
        .unwrap_or_else(|s| s);
    let unusable = s["unusable_frames"].as_array().map_or(0, Vec::len) as i64;
    let usable = 12 - unusable;
    assert_indexed(&s, usable);
    app.stop().await;
}
