//! Capture formats: each writer's output imports, grounds the same box as the
//! ScanNet-layout import (oracle VLM, oracle detector), and hostile inputs get a 4xx
//! problem+json with nothing left behind.

use crate::agent_fixture::vlm_config;
use crate::format_writers::{self as w, Files};
use crate::helpers::{files_under, tar_of, test_config, TestApp};
use grounder::eval::oracle_vlm::{router, OracleVlmArgs};
use grounder::synth::{generate_with, write_dataset, SynthParams, SynthScene};
use serde_json::Value;
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

/// A 12-frame 320x240 scene (depth at colour size), its tar, and its dataset folder.
fn scene() -> &'static (SynthScene, PathBuf) {
    static S: OnceLock<(SynthScene, PathBuf)> = OnceLock::new();
    S.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("format-tests");
        let _ = std::fs::remove_dir_all(&dir);
        let params = SynthParams {
            frames: 12,
            depth_size: (320, 240),
            frame_step: 1,
            ..SynthParams::small(5)
        };
        let s = generate_with(&params, &dir.join("scenes"), true).expect("synth");
        write_dataset(std::slice::from_ref(&s), &dir.join("ds")).expect("dataset");
        (s, dir)
    })
}

async fn post(app: &TestApp, query: &str, body: Vec<u8>, ct: &str) -> (u16, Value, String) {
    let r = app
        .client
        .post(app.url(&format!("/v1/scenes{query}")))
        .header("Content-Type", ct)
        .body(body)
        .send()
        .await
        .unwrap();
    let s = r.status().as_u16();
    let ct = r
        .headers()
        .get("content-type")
        .map(|v| v.to_str().unwrap_or("").to_string())
        .unwrap_or_default();
    (s, r.json().await.unwrap_or(Value::Null), ct)
}

async fn ground(app: &TestApp, id: &str, query: &str) -> [f64; 6] {
    let job = app.submit_job(id, query).await;
    let j = app.wait_job(&job, Duration::from_secs(120)).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    let b = &j["result"]["box"];
    let v = |k: &str, i: usize| b[k][i].as_f64().unwrap();
    [
        v("min", 0),
        v("min", 1),
        v("min", 2),
        v("max", 0),
        v("max", 1),
        v("max", 2),
    ]
}

/// Upload `body`; returns the scene record once indexed.
async fn import(app: &TestApp, query: &str, body: Vec<u8>, ct: &str) -> Value {
    let (s, rec, _) = post(app, query, body, ct).await;
    assert_eq!(s, 201, "{rec}");
    let id = rec["id"].as_str().unwrap();
    match app.wait_scene(id, "ready", Duration::from_secs(60)).await {
        Ok(s) => s,
        Err(s) if s["status"] == "indexing" => panic!("never indexed: {s}"),
        Err(s) => s,
    }
}

#[tokio::test]
async fn every_format_grounds_the_same_box_as_the_scannet_layout() {
    let (scene, dir) = scene();
    let oracle = router(&OracleVlmArgs {
        addr: "127.0.0.1:0".into(),
        dataset: dir.join("ds"),
        scenes: dir.join("scenes"),
        seed: 0,
        error_rate: 0.0,
    })
    .unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let oracle_addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, oracle).await.unwrap() });

    let data = tempfile::tempdir().unwrap();
    let mut cfg = test_config(data.path().to_path_buf());
    cfg.pipeline = "vlm".into();
    cfg.detector = "oracle".into();
    cfg.segmenter = "depth".into();
    cfg.model_dir = Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models"));
    let mut vc = vlm_config(&format!("http://{oracle_addr}/v1"), 30_000);
    vc.model = grounder::eval::oracle_vlm::ORACLE_MODEL.into();
    cfg.vlm = Some(vc);
    let app = TestApp::spawn_with(cfg).await;

    let query = scene
        .queries
        .iter()
        .find(|q| q.subset == "unique")
        .unwrap_or(&scene.queries[0])
        .text
        .clone();
    let tar = std::fs::read(scene.tar.as_ref().unwrap()).unwrap();
    let base = import(&app, "", tar, "application/x-tar").await;
    assert_eq!(base["layout"], "scannet");
    let want = ground(&app, base["id"].as_str().unwrap(), &query).await;

    let sens_files: Files = {
        let mut f = vec![("scene0000_00.sens".to_string(), w::sens(scene))];
        f.extend(
            w::tum(scene)
                .into_iter()
                .filter(|(p, _)| p.starts_with("instance/")),
        );
        f
    };
    let cases: Vec<(&str, &str, Vec<u8>, &str)> = vec![
        (
            "sens",
            "",
            tar_of(&sens_files, Some("scene0000_00")),
            "application/x-tar",
        ),
        (
            "tum",
            "",
            tar_of(&w::tum(scene), Some("rgbd_dataset_synth")),
            "application/x-tar",
        ),
        (
            "nerfstudio",
            "",
            tar_of(&w::nerfstudio_files(scene), None),
            "application/x-tar",
        ),
        (
            "arkitscenes",
            "",
            tar_of(&w::arkit(scene), None),
            "application/x-tar",
        ),
    ];
    for (format, q, body, ct) in cases {
        let rec = import(&app, q, body, ct).await;
        assert_eq!(rec["layout"], format, "{rec}");
        assert_eq!(rec["status"], "ready", "{rec}");
        assert_eq!(rec["frames"], 12, "{rec}");
        assert_eq!(rec["unusable_frames"], serde_json::json!([]), "{rec}");
        let got = ground(&app, rec["id"].as_str().unwrap(), &query).await;
        let err = want
            .iter()
            .zip(&got)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            err <= 0.01,
            "{format}: box {got:?} differs from the ScanNet-layout box {want:?} by {err:.4} m"
        );
    }
    app.stop().await;
}

#[tokio::test]
async fn raw_sens_body_keeps_every_nth_frame() {
    let (scene, _) = scene();
    let app = TestApp::spawn().await;
    let body = w::sens(scene);
    let (s, rec, _) = post(
        &app,
        "?format=sens&every=5",
        body.clone(),
        "application/octet-stream",
    )
    .await;
    assert_eq!(s, 201, "{rec}");
    assert_eq!(rec["layout"], "sens");
    assert_eq!(rec["frames"], 3, "frames 0, 5, 10 of 12: {rec}");
    assert_eq!(rec["color_size"], serde_json::json!([320, 240]));
    // Detected without ?format= too.
    let (s, rec, _) = post(&app, "", body, "application/octet-stream").await;
    assert_eq!(s, 201, "{rec}");
    assert_eq!(rec["frames"], 12);
    app.stop().await;
}

/// Every hostile upload: status, code, and no file left in the data dir.
async fn refused(app: &TestApp, query: &str, body: Vec<u8>, status: u16, needle: &str) {
    let (s, p, ct) = post(app, query, body, "application/x-tar").await;
    assert_eq!(s, status, "{query}: {p}");
    assert!(ct.starts_with("application/problem+json"), "{ct}");
    let detail = p["detail"].as_str().unwrap_or("");
    assert!(
        detail.contains(needle),
        "{query}: detail {detail:?} lacks {needle:?}"
    );
    let left: Vec<_> = files_under(&app.data_dir)
        .into_iter()
        .filter(|p| !p.to_string_lossy().contains("grounder.db"))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    let (_, list) = app.get_json("/v1/scenes").await;
    assert_eq!(list["scenes"], serde_json::json!([]));
}

fn edit(files: &Files, path: &str, f: impl Fn(&str) -> String) -> Files {
    files
        .iter()
        .map(|(p, b)| {
            if p == path {
                (p.clone(), f(std::str::from_utf8(b).unwrap()).into_bytes())
            } else {
                (p.clone(), b.clone())
            }
        })
        .collect()
}

#[tokio::test]
async fn hostile_captures_get_problems_and_leave_nothing() {
    let (scene, _) = scene();
    let app = TestApp::spawn().await;
    // .sens cut in the middle of a frame, as a raw body and inside an archive.
    let sens = w::sens(scene);
    let cut = sens[..sens.len() / 2].to_vec();
    let (s, p, _) = post(
        &app,
        "?format=sens",
        cut.clone(),
        "application/octet-stream",
    )
    .await;
    assert_eq!(s, 400, "{p}");
    assert_eq!(p["code"], "corrupt_archive");
    assert!(p["detail"].as_str().unwrap().contains("truncated"), "{p}");
    refused(
        &app,
        "",
        tar_of(&[("a.sens".into(), cut)], None),
        400,
        "a.sens: truncated",
    )
    .await;

    // TUM: timestamps out of order; NaN in the ground truth; a missing depth image.
    let tum = w::tum(scene);
    let swapped = edit(&tum, "rgb.txt", |t| {
        let mut lines: Vec<&str> = t.lines().collect();
        lines.swap(4, 5);
        lines.join("\n")
    });
    refused(&app, "", tar_of(&swapped, None), 422, "rgb.txt line 6").await;
    let nan = edit(&tum, "groundtruth.txt", |t| {
        let mut l: Vec<String> = t.lines().map(str::to_string).collect();
        let mut toks: Vec<&str> = l[3].split(' ').collect();
        toks[1] = "nan";
        l[3] = toks.join(" ");
        l.join("\n")
    });
    refused(&app, "", tar_of(&nan, None), 422, "groundtruth.txt line 4").await;
    let first_depth = tum
        .iter()
        .find(|(p, _)| p.starts_with("depth/"))
        .unwrap()
        .0
        .clone();
    let no_depth: Files = tum
        .iter()
        .filter(|(p, _)| *p != first_depth)
        .cloned()
        .collect();
    refused(
        &app,
        "",
        tar_of(&no_depth, None),
        422,
        "depth image is missing",
    )
    .await;

    // nerfstudio: a path out of the archive, a NaN pose, a frame without depth.
    let (t, files) = w::nerfstudio(scene);
    let with = |t: &Value| {
        let mut f = files.clone();
        f.push(("transforms.json".into(), serde_json::to_vec(t).unwrap()));
        tar_of(&f, None)
    };
    let mut out = t.clone();
    out["frames"][2]["depth_file_path"] = "../../etc/passwd".into();
    refused(&app, "", with(&out), 422, "points outside the archive").await;
    let mut nanpose = t.clone();
    nanpose["frames"][1]["transform_matrix"][0][3] = "NaN".into();
    refused(&app, "", with(&nanpose), 422, "finite number").await;
    let mut nodepth = t.clone();
    nodepth["frames"][3]
        .as_object_mut()
        .unwrap()
        .remove("depth_file_path");
    refused(&app, "", with(&nodepth), 422, "no depth_file_path").await;

    // ARKitScenes: a frame without depth; a NaN in the trajectory.
    let ark = w::arkit(scene);
    let d = ark
        .iter()
        .find(|(p, _)| p.contains("lowres_depth/"))
        .unwrap()
        .0
        .clone();
    let nod: Files = ark.iter().filter(|(p, _)| *p != d).cloned().collect();
    refused(
        &app,
        "",
        tar_of(&nod, None),
        422,
        "is missing; every lowres_wide frame",
    )
    .await;
    let traj = ark
        .iter()
        .find(|(p, _)| p.ends_with(".traj"))
        .unwrap()
        .0
        .clone();
    let nantraj = edit(&ark, &traj, |t| {
        let mut l: Vec<String> = t.lines().map(str::to_string).collect();
        let mut toks: Vec<&str> = l[2].split(' ').collect();
        toks[3] = "nan";
        l[2] = toks.join(" ");
        l.join("\n")
    });
    refused(
        &app,
        "",
        tar_of(&nantraj, None),
        422,
        "lowres_wide.traj line 3",
    )
    .await;
    // A named format that is not there.
    refused(
        &app,
        "?format=tum",
        tar_of(&w::nerfstudio_files(scene), None),
        422,
        "rgb.txt",
    )
    .await;
    let (s, p, _) = post(&app, "?every=0", Vec::new(), "application/x-tar").await;
    assert_eq!(
        (s, p["code"].as_str()),
        (400, Some("invalid_parameter")),
        "{p}"
    );
    app.stop().await;
}
