//! `.sens` import speed and memory (ignored by default; run with
//! `cargo test --test api sens_import_speed -- --ignored --nocapture`): ScanNet-sized
//! frames (colour 1296x968, depth 640x480), every 10th kept, uploaded as a raw body
//! streamed from disk. Two file sizes show memory flat in the file's size.

use crate::format_writers as w;
use crate::helpers::TestApp;
use grounder::synth::{generate_with, SynthParams};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

fn peak_rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

async fn upload_file(app: &TestApp, path: &Path) -> serde_json::Value {
    let file = tokio::fs::File::open(path).await.unwrap();
    let len = file.metadata().await.unwrap().len();
    let body = reqwest::Body::from(file);
    let r = app
        .client
        .post(app.url("/v1/scenes?format=sens&every=10"))
        .header("Content-Type", "application/octet-stream")
        .header("Content-Length", len)
        .body(body)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    r.json().await.unwrap()
}

#[tokio::test]
#[ignore = "benchmark: run on demand"]
async fn sens_import_speed() {
    let dir = tempfile::tempdir().unwrap();
    let params = SynthParams {
        frames: 10,
        ..SynthParams::new(9)
    };
    let scene = generate_with(&params, &dir.path().join("s"), false).unwrap();
    let chunks: Vec<Vec<u8>> = (0..10).map(|i| w::sens_frame(&scene, i)).collect();
    let app = TestApp::spawn().await;
    let mut rows = Vec::new();
    for frames in [500u64, 1500] {
        let path = dir.path().join(format!("{frames}.sens"));
        let mut f = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        f.write_all(&w::sens_header(&scene, frames)).unwrap();
        for i in 0..frames as usize {
            f.write_all(&chunks[i % 10]).unwrap();
        }
        f.write_all(&0u64.to_le_bytes()).unwrap();
        drop(f);
        let size = std::fs::metadata(&path).unwrap().len();
        let t = Instant::now();
        let rec = upload_file(&app, &path).await;
        let s = t.elapsed().as_secs_f64();
        assert_eq!(rec["frames"].as_u64(), Some(frames.div_ceil(10)));
        let rate = frames as f64 / s;
        let rss = peak_rss_kib();
        println!(
            "sens import: {frames} frames ({:.0} MB), every 10th: {s:.2} s, {rate:.0} file frames/s, {:.1} kept frames/s; peak RSS {} MiB",
            size as f64 / 1e6,
            frames.div_ceil(10) as f64 / s,
            rss / 1024
        );
        rows.push((rate, rss));
        std::fs::remove_file(&path).unwrap();
    }
    assert!(
        rows.iter().all(|r| r.0 >= 100.0),
        "below 100 frames/s: {rows:?}"
    );
    // Three times the file, peak memory grows by less than 64 MiB.
    assert!(
        rows[1].1 <= rows[0].1 + 64 * 1024,
        "memory grows with the file: {rows:?}"
    );
    app.stop().await;
}
