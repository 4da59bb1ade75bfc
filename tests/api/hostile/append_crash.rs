//! A frame append killed between moving its files into the scene and committing their
//! rows: the next start removes the files no row names, and the scene stays whole.

use crate::crash::{names, start};
use crate::frames::more_frames;
use crate::helpers::{client, tar_of, upload_tiny_scene_to};
use serde_json::Value;
use std::time::{Duration, Instant};

#[tokio::test]
async fn an_append_killed_between_files_and_rows_leaves_no_stray_files() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    // The pause widens the window between the files moved in and the rows committed.
    let env = [
        ("GROUNDER_DETECTOR", "none"),
        ("GROUNDER_TEST_STEP_PAUSE_MS", "1500"),
    ];
    let mut s = start(&data, &env);
    let c = client();
    let id = upload_tiny_scene_to(&c, &s.base, 3).await;
    let colour = data.join("scenes").join(&id).join("color");
    let before = names(&colour);
    assert_eq!(before.len(), 3, "{before:?}");

    let url = format!("{}/v1/scenes/{id}/frames", s.base);
    let body = tar_of(&more_frames(&[1000, 1020], 0.3), None);
    let pending = tokio::spawn(async move {
        let _ = client()
            .post(url)
            .header("content-type", "application/x-tar")
            .body(body)
            .send()
            .await;
    });
    let started = Instant::now();
    while !colour.join("1000.jpg").exists() {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "the append never moved its files in"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    s.signal("-KILL");
    let _ = pending.await;
    assert!(colour.join("1000.jpg").exists(), "killed inside the window");

    let mut s = start(&data, &[("GROUNDER_DETECTOR", "none")]);
    assert_eq!(names(&colour), before, "files no row names are gone");
    let r = c
        .get(format!("{}/v1/scenes/{id}", s.base))
        .send()
        .await
        .expect("get");
    let now: Value = r.json().await.expect("json");
    assert_eq!(now["frames"], 3, "{now}");
    // The same frames can be appended again, and then stay.
    let r = c
        .post(format!("{}/v1/scenes/{id}/frames", s.base))
        .header("content-type", "application/x-tar")
        .body(tar_of(&more_frames(&[1000, 1020], 0.3), None))
        .send()
        .await
        .expect("append");
    assert_eq!(r.status().as_u16(), 200);
    s.signal("-TERM");
    let mut s = start(&data, &[("GROUNDER_DETECTOR", "none")]);
    assert_eq!(names(&colour).len(), 5, "{:?}", names(&colour));
    s.signal("-TERM");
}
