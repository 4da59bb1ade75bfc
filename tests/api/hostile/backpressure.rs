//! Back-pressure: an upload body that stalls is cut off (408) while it holds the only
//! upload slot, and another upload meanwhile is told to come back (503 + Retry-After);
//! scenes waiting to be indexed beyond the bound refuse more uploads the same way. The
//! server keeps answering `/healthz` throughout.

use super::{assert_peak_growth_under, vm_hwm_kb};
use crate::crash::scene_with_masks;
use crate::helpers::{tar_of, test_config, tiny_scene_files, TestApp};
use serde_json::Value;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

#[tokio::test]
async fn a_stalled_body_is_cut_off_with_408_and_a_full_house_answers_503() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.max_concurrent_uploads = 1;
    cfg.upload_idle_timeout_secs = 1;
    let app = TestApp::spawn_with(cfg).await;
    let before = vm_hwm_kb();
    // Headers promising 100 kB, then 512 bytes, then nothing.
    let mut slow = tokio::net::TcpStream::connect(app.addr)
        .await
        .expect("connect");
    slow.write_all(
        b"POST /v1/scenes HTTP/1.1\r\nHost: test\r\nContent-Type: application/x-tar\r\nContent-Length: 100000\r\n\r\n",
    )
    .await
    .expect("write");
    slow.write_all(&[0u8; 512]).await.expect("write");
    let started = Instant::now();
    tokio::time::sleep(Duration::from_millis(200)).await;

    // The only upload slot is taken: another upload is told to retry.
    let r = app
        .upload(tar_of(&tiny_scene_files(2), None), "application/x-tar")
        .await;
    assert_eq!(r.status().as_u16(), 503);
    let retry = r
        .headers()
        .get("retry-after")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    assert!(retry.is_some_and(|s| s > 0), "Retry-After: {retry:?}");
    let p: Value = r.json().await.expect("problem");
    assert_eq!(p["code"], "too_many_uploads", "{p}");
    assert!(
        p["detail"]
            .as_str()
            .is_some_and(|d| d.contains("max_concurrent_uploads")),
        "{p}"
    );
    assert_eq!(
        app.get_json("/healthz").await.0,
        200,
        "alive while a body stalls"
    );

    let mut answer = Vec::new();
    let read = tokio::time::timeout(Duration::from_secs(10), slow.read_to_end(&mut answer)).await;
    assert!(read.is_ok(), "the stalled upload is answered and closed");
    let text = String::from_utf8_lossy(&answer);
    assert!(text.starts_with("HTTP/1.1 408"), "{text}");
    assert!(text.contains("application/problem+json"), "{text}");
    assert!(
        text.contains("upload_timeout") && text.contains("upload_idle_timeout_secs"),
        "{text}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "cut off after the idle timeout"
    );

    // The slot is free again; nothing of the stalled body was kept.
    app.upload_tiny_scene(2).await;
    let leftovers: Vec<_> = std::fs::read_dir(app.data_dir.join("tmp"))
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    assert_peak_growth_under(before, 200_000);
    app.stop().await;
}

#[tokio::test]
async fn uploads_beyond_the_indexing_backlog_are_refused_with_503() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.detector = "oracle:delay_ms=300".into();
    cfg.max_concurrent_indexing = 1;
    cfg.max_queued_indexing = 1;
    let app = TestApp::spawn_with(cfg).await;
    let scene = scene_with_masks(8);
    let mut ids = Vec::new();
    for _ in 0..2 {
        let r = app.upload(scene.clone(), "application/x-tar").await;
        assert_eq!(r.status().as_u16(), 201);
        let s: Value = r.json().await.expect("json");
        ids.push(s["id"].as_str().expect("id").to_string());
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // One scene is indexed, one waits: the bound of one waiting scene is reached.
    let r = app.upload(scene.clone(), "application/x-tar").await;
    assert_eq!(r.status().as_u16(), 503);
    assert!(r.headers().get("retry-after").is_some());
    let p: Value = r.json().await.expect("problem");
    assert_eq!(p["code"], "indexing_busy", "{p}");
    assert_eq!(app.get_json("/healthz").await.0, 200);
    // Both end ready, one after the other; then uploads are taken again.
    let t = Instant::now();
    for id in &ids {
        loop {
            let (_, s) = app.get_json(&format!("/v1/scenes/{id}")).await;
            if s["status"] == "ready" {
                break;
            }
            assert!(t.elapsed() < Duration::from_secs(30), "{s}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
    let r = app.upload(scene, "application/x-tar").await;
    assert_eq!(r.status().as_u16(), 201);
    app.stop().await;
}
