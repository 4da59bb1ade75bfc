//! Viewer pages, static files and exports over HTTP with the test pipeline (no VLM): what
//! is served, and the problems for what is not there.

use super::helpers::*;
use std::time::Duration;

#[tokio::test]
async fn pages_assets_and_exports_are_served_or_refused_clearly() {
    let app = TestApp::spawn().await;
    let sid = app.upload_tiny_scene(4).await;

    // Scene page: HTML naming the scene, with the import map of the vendored three.js.
    let r = app.get(&format!("/v1/scenes/{sid}/view")).await;
    assert_eq!(r.status(), 200);
    assert!(r.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/html"));
    let html = r.text().await.unwrap();
    assert!(html.contains(&format!("data-scene=\"{sid}\"")));
    assert!(html.contains("/v1/viewer/three.module.min.js"));
    for (file, ct) in [
        ("three.module.min.js", "text/javascript"),
        ("OrbitControls.js", "text/javascript"),
        ("job.js", "text/javascript"),
        ("viewer.css", "text/css"),
        ("three-LICENSE.txt", "text/plain"),
    ] {
        let r = app.get(&format!("/v1/viewer/{file}")).await;
        assert_eq!(r.status(), 200, "{file}");
        assert!(
            r.headers()["content-type"]
                .to_str()
                .unwrap()
                .starts_with(ct),
            "{file}"
        );
        assert!(!r.bytes().await.unwrap().is_empty());
    }
    let (s, p) = app.get_json("/v1/viewer/nope.js").await;
    assert_eq!((s, p["code"].as_str()), (404, Some("asset_not_found")));
    let (s, p) = app.get_json("/v1/scenes/0123-abc/view").await;
    assert_eq!((s, p["code"].as_str()), (404, Some("scene_not_found")));
    let (s, p) = app.get_json("/v1/jobs/0123-abc/view").await;
    assert_eq!((s, p["code"].as_str()), (404, Some("job_not_found")));

    // Frames: cameras in the output frame; the unusable last frame has none.
    let (s, f) = app.get_json(&format!("/v1/scenes/{sid}/frames")).await;
    assert_eq!(s, 200, "{f}");
    let frames = f["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 4);
    // Pose x = 0.5 i, axis alignment shifts by (1, 2, 3).
    assert_eq!(frames[1]["position"], serde_json::json!([1.5, 2.0, 3.0]));
    assert_eq!(frames[3]["usable"], false);
    assert!(frames[3]["position"].is_null());
    let r = app.get(&format!("/v1/scenes/{sid}/frames/00001.jpg")).await;
    assert_eq!(r.status(), 200);
    assert!(image::load_from_memory(&r.bytes().await.unwrap()).is_ok());
    let (s, _) = app
        .get_json(&format!("/v1/scenes/{sid}/frames/00009.jpg"))
        .await;
    assert_eq!(s, 404);

    // Scene points: a PLY whose header counts what the body holds; cached on disk.
    let r = app
        .get(&format!("/v1/scenes/{sid}/points.ply?voxel=0.05"))
        .await;
    assert_eq!(r.status(), 200);
    let ply = r.bytes().await.unwrap();
    let end = ply
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("header")
        + 11;
    let header = std::str::from_utf8(&ply[..end]).unwrap();
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .unwrap()
        .parse()
        .unwrap();
    assert!(n > 0);
    assert_eq!(ply.len() - end, n * 15);
    assert!(app
        .data_dir
        .join("scenes")
        .join(&sid)
        .join("points_50mm.ply")
        .is_file());
    for bad in ["0", "2", "abc", "NaN"] {
        let (s, p) = app
            .get_json(&format!("/v1/scenes/{sid}/points.ply?voxel={bad}"))
            .await;
        assert_eq!(s, 400, "voxel={bad}: {p}");
    }

    // A finished job of the test pipeline: box corners, the points of its box (camera
    // centres) and the mask of its first usable view, which the trace names.
    let r = app.create_job(&sid, "the chair").await;
    let job: serde_json::Value = r.json().await.unwrap();
    let jid = job["id"].as_str().unwrap().to_string();
    let done = app.wait_job(&jid, Duration::from_secs(10)).await;
    let corners = done["result"]["box"]["corners"]
        .as_array()
        .expect("corners");
    assert_eq!(corners.len(), 8);
    assert_eq!(corners[0], done["result"]["box"]["min"]);
    assert_eq!(corners[7], done["result"]["box"]["max"]);
    let r = app.get(&format!("/v1/jobs/{jid}/object.ply")).await;
    assert_eq!(r.status(), 200);
    let ply = r.bytes().await.unwrap();
    assert!(ply.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    let done_step = done["trace"]
        .as_array()
        .and_then(|s| s.iter().find(|s| s["step"] == "done"))
        .unwrap_or_else(|| panic!("no done step: {done}"));
    let cameras = done_step["cameras"].as_u64().expect("cameras");
    let text = String::from_utf8_lossy(&ply);
    assert!(
        text.contains(&format!("element vertex {cameras}\n")),
        "{text}"
    );
    let mask_of = done_step["mask_of"].as_str().expect("mask_of");
    let r = app
        .get(&format!("/v1/jobs/{jid}/masks/{mask_of}.png"))
        .await;
    assert_eq!(r.status(), 200);
    assert!(r.bytes().await.unwrap().starts_with(b"\x89PNG"));
    let (s, p) = app
        .get_json(&format!("/v1/jobs/{jid}/masks/99999.png"))
        .await;
    assert_eq!((s, p["code"].as_str()), (404, Some("export_not_found")));
    let (s, _) = app
        .get_json(&format!("/v1/jobs/{jid}/masks/..%2Fx.png"))
        .await;
    assert_eq!(s, 404);
    let (s, p) = app.get_json("/v1/jobs/0123-abc/object.ply").await;
    assert_eq!((s, p["code"].as_str()), (404, Some("job_not_found")));
    let r = app.get(&format!("/v1/jobs/{jid}/view")).await;
    assert_eq!(r.status(), 200);
    assert!(r
        .text()
        .await
        .unwrap()
        .contains(&format!("data-job=\"{jid}\"")));
    app.stop().await;
}
