//! `grounder eval` runner against a small fake service (axum on port 0): scene upload,
//! job polling, scoring, concurrency, resume, report files.

use axum::extract::{Path as AxPath, State};
use axum::http::StatusCode;
use axum::routing::{get, post};
use axum::{Json, Router};
use grounder::eval::dataset::{write_dataset, Query, SceneObject, SceneObjects, Subset};
use grounder::eval::report::read_results;
use grounder::eval::runner::{run, EvalConfig};
use grounder::geometry::Aabb;
use serde_json::{json, Value};
use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

#[derive(Default)]
struct Fake {
    scenes: HashMap<String, (String, u32)>,
    jobs: HashMap<String, (String, u32)>,
    uploads: Vec<(String, usize)>,
    job_posts: usize,
    max_running: usize,
    running: usize,
}
type St = Arc<Mutex<Fake>>;

async fn post_scene(State(st): State<St>, body: axum::body::Bytes) -> (StatusCode, Json<Value>) {
    let mut ar = tar::Archive::new(&body[..]);
    let mut name = String::new();
    let mut files = 0;
    for e in ar.entries().unwrap() {
        let e = e.unwrap();
        let p = e.path().unwrap().into_owned();
        if name.is_empty() {
            name = p
                .components()
                .next()
                .unwrap()
                .as_os_str()
                .to_string_lossy()
                .into_owned();
        }
        files += e.header().entry_type().is_file() as usize;
    }
    let mut s = st.lock().unwrap();
    let id = format!("sc{}", s.scenes.len());
    s.uploads.push((name.clone(), files));
    s.scenes.insert(id.clone(), (name, 0));
    (
        StatusCode::CREATED,
        Json(json!({"id": id, "status": "importing"})),
    )
}

async fn get_scene(State(st): State<St>, AxPath(id): AxPath<String>) -> Json<Value> {
    let mut s = st.lock().unwrap();
    let e = s.scenes.get_mut(&id).unwrap();
    e.1 += 1;
    Json(json!({"id": id, "status": if e.1 >= 2 { "ready" } else { "importing" }}))
}

async fn post_job(State(st): State<St>, Json(b): Json<Value>) -> (StatusCode, Json<Value>) {
    let mut s = st.lock().unwrap();
    assert!(
        s.scenes.contains_key(b["scene_id"].as_str().unwrap()),
        "unknown scene"
    );
    s.job_posts += 1;
    s.running += 1;
    s.max_running = s.max_running.max(s.running);
    let id = format!("job{}", s.job_posts);
    s.jobs
        .insert(id.clone(), (b["query"].as_str().unwrap().to_string(), 0));
    (
        StatusCode::ACCEPTED,
        Json(json!({"id": id, "status": "queued"})),
    )
}

fn bx(min: [f64; 3], max: [f64; 3]) -> Value {
    json!({"min": min, "max": max, "center": [0, 0, 0], "size": [0, 0, 0]})
}

async fn get_job(State(st): State<St>, AxPath(id): AxPath<String>) -> Json<Value> {
    // Hold a job "running" for a few polls so concurrent jobs overlap.
    tokio::time::sleep(Duration::from_millis(5)).await;
    let mut s = st.lock().unwrap();
    let (text, polls) = {
        let e = s.jobs.get_mut(&id).unwrap();
        e.1 += 1;
        (e.0.clone(), e.1)
    };
    if polls < 3 {
        return Json(json!({"id": id, "status": "running"}));
    }
    if polls == 3 {
        s.running -= 1;
    }
    let usage = json!({"vlm_calls": 3, "total_tokens": 1200});
    Json(match text.as_str() {
        "the chair by the door" => json!({"id": id, "status": "succeeded", "usage": usage,
            "result": {"box": bx([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])},
            "trace": [{"step": "preselect", "outputs": {"frames": ["0", "20"]}},
                      {"step": "image_selection", "outputs": {"image_id": 1}}]}),
        "the other chair" => json!({"id": id, "status": "succeeded", "usage": usage,
            "result": {"box": bx([3.5, 0.0, 0.0], [4.5, 1.0, 1.0])},
            "trace": [{"step": "preselect", "outputs": {"frames": ["0"]}}]}),
        "the table" => json!({"id": id, "status": "failed", "error": "vlm timed out", "trace": []}),
        _ => json!({"id": id, "status": "succeeded", "result": null,
            "trace": [{"step": "vlm_image_choice", "outputs": {"frame": "0"}, "usage": {"prompt_tokens": 50, "completion_tokens": 7}}]}),
    })
}

async fn serve() -> (String, St) {
    let st: St = Arc::default();
    let app = Router::new()
        .route("/v1/scenes", post(post_scene))
        .route("/v1/scenes/{id}", get(get_scene))
        .route("/v1/jobs", post(post_job))
        .route("/v1/jobs/{id}", get(get_job))
        .with_state(st.clone());
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(l, app).await.unwrap() });
    (format!("http://{addr}"), st)
}

/// Scene dir with frames 0 and 20; object 1 visible (instance id 1) only in frame 20.
fn make_scene(dir: &Path) {
    std::fs::create_dir_all(dir.join("color")).unwrap();
    std::fs::create_dir_all(dir.join("instance")).unwrap();
    for f in [0u32, 20] {
        image::RgbImage::new(8, 6)
            .save(dir.join(format!("color/{f}.jpg")))
            .unwrap();
        let mut m = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(8, 6);
        if f == 20 {
            for y in 1..4 {
                for x in 2..6 {
                    m.put_pixel(x, y, image::Luma([1]));
                }
            }
        }
        m.save(dir.join(format!("instance/{f}.png"))).unwrap();
    }
}

fn dataset(root: &Path) {
    let o = |id, label: &str, min: [f64; 3], max: [f64; 3]| SceneObject {
        id,
        label: label.into(),
        aabb: Aabb::new(min, max),
    };
    let a = SceneObjects {
        scene_id: "a".into(),
        objects: vec![
            o(1, "chair", [0.0; 3], [1.0; 3]),
            o(2, "chair", [3.0, 0.0, 0.0], [4.0, 1.0, 1.0]),
        ],
    };
    let b = SceneObjects {
        scene_id: "b".into(),
        objects: vec![
            o(1, "table", [0.0; 3], [2.0; 3]),
            o(2, "lamp", [5.0; 3], [6.0; 3]),
        ],
    };
    let q = |scene: &str, id: &str, text: &str, t: u32, label: &str, subset| Query {
        scene_id: scene.into(),
        query_id: id.into(),
        text: text.into(),
        target_id: t,
        target_label: label.into(),
        subset,
        extra: Default::default(),
    };
    write_dataset(
        &root.join("ds"),
        &[a, b],
        &[
            q(
                "a",
                "a1",
                "the chair by the door",
                1,
                "chair",
                Subset::Multiple,
            ),
            q("a", "a2", "the other chair", 2, "chair", Subset::Multiple),
            q("b", "b1", "the table", 1, "table", Subset::Unique),
            q("b", "b2", "the lamp", 2, "lamp", Subset::Unique),
        ],
    )
    .unwrap();
    make_scene(&root.join("scenes/a"));
    make_scene(&root.join("scenes/b"));
}

fn cfg(root: &Path, server: &str, out: &str, limit: Option<usize>) -> EvalConfig {
    EvalConfig {
        dataset: root.join("ds"),
        scenes: root.join("scenes"),
        server: server.into(),
        limit,
        jobs: 2,
        out: root.join(out),
        poll: Duration::from_millis(5),
        job_timeout: Duration::from_secs(20),
        scene_timeout: Duration::from_secs(20),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn runs_scores_and_resumes() {
    let root = tempfile::tempdir().unwrap();
    dataset(root.path());
    let (url, st) = serve().await;
    let c = cfg(root.path(), &url, "report", None);

    let o = run(&c).await.unwrap();
    assert_eq!((o.ran, o.skipped, o.errors.len()), (4, 0, 0));
    {
        let s = st.lock().unwrap();
        assert_eq!(s.job_posts, 4);
        let mut up = s.uploads.clone();
        up.sort();
        assert_eq!(up, vec![("a".to_string(), 4), ("b".to_string(), 4)]);
        assert_eq!(s.max_running, 2, "two jobs should overlap with --jobs 2");
    }
    let sm = &o.summary;
    assert_eq!(sm.n_queries, 4);
    assert_eq!(sm.scanrefer.overall.acc_025, 0.5);
    assert_eq!(sm.scanrefer.overall.acc_05, 0.25);
    assert_eq!(sm.scanrefer.multiple.acc_025, 1.0);
    assert_eq!(sm.scanrefer.unique.acc_025, 0.0);
    assert_eq!(sm.nr3d.overall.k, 2);
    // a1: target visible in frame 20 -> preselection {0,20} true, image id 1 = frame 20 true.
    // a2: target 2 has no pixels anywhere -> preselection false. b2: frame 0 -> image choice false.
    assert_eq!(
        (
            sm.stages.preselection_contains_target.n,
            sm.stages.preselection_contains_target.k
        ),
        (2, 1)
    );
    assert_eq!(
        (
            sm.stages.image_choice_correct.n,
            sm.stages.image_choice_correct.k
        ),
        (2, 1)
    );
    // Per class, the most queries lost first: lamp and table lose theirs at 0.25, the
    // chairs one at 0.5.
    let classes: Vec<&str> = sm.by_class.iter().map(|c| c.label.as_str()).collect();
    assert_eq!(classes, ["lamp", "table", "chair"]);
    assert_eq!(sm.mean_vlm_calls, (3.0 + 3.0 + 0.0 + 1.0) / 4.0);
    assert_eq!(sm.mean_tokens, (1200.0 + 1200.0 + 0.0 + 57.0) / 4.0);
    let recs = read_results(&c.out.join("results.jsonl")).unwrap();
    let by: HashMap<_, _> = recs.iter().map(|r| (r.query_id.as_str(), r)).collect();
    assert_eq!(by["a2"].failure_stage.as_deref(), Some("preselection"));
    assert_eq!(by["b1"].failure_stage.as_deref(), Some("job_failed"));
    assert_eq!(by["b1"].error.as_deref(), Some("vlm timed out"));
    assert_eq!(by["b2"].predicted, None);
    assert!(by["a1"].latency_ms > 0.0);
    for f in ["summary.json", "summary.md", "iou_hist.png"] {
        assert!(c.out.join(f).is_file(), "{f}");
    }

    // Resume: nothing left to do, nothing posted or uploaded.
    let o = run(&c).await.unwrap();
    assert_eq!((o.ran, o.skipped), (0, 4));
    assert_eq!(st.lock().unwrap().job_posts, 4);
    assert_eq!(st.lock().unwrap().uploads.len(), 2);
    assert_eq!(o.summary.n_queries, 4);

    // Records of an older report (no target id or class) take them from the dataset.
    let path = c.out.join("results.jsonl");
    let older: Vec<String> = std::fs::read_to_string(&path)
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            let m = v.as_object_mut().unwrap();
            assert!(m.remove("target_id").is_some() && m.remove("target_label").is_some());
            format!("{v}\n")
        })
        .collect();
    std::fs::write(&path, older.concat()).unwrap();
    let o = run(&c).await.unwrap();
    assert_eq!((o.ran, o.skipped), (0, 4));
    assert_eq!(o.summary.by_class, sm.by_class);

    // Drop one record: only that query runs again, only its scene is uploaded.
    let path = c.out.join("results.jsonl");
    let kept: Vec<String> = std::fs::read_to_string(&path)
        .unwrap()
        .lines()
        .filter(|l| !l.contains("\"query_id\":\"a2\""))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&path, kept.concat()).unwrap();
    let o = run(&c).await.unwrap();
    assert_eq!((o.ran, o.skipped), (1, 3));
    assert_eq!(st.lock().unwrap().job_posts, 5);
    assert_eq!(st.lock().unwrap().uploads.last().unwrap().0, "a");
    assert_eq!(read_results(&path).unwrap().len(), 4);

    // --limit 1 on a fresh report.
    let o = run(&cfg(root.path(), &url, "report2", Some(1)))
        .await
        .unwrap();
    assert_eq!((o.ran, o.summary.n_queries), (1, 1));
    assert_eq!(o.summary.scanrefer.overall.acc_05, 1.0);
}

#[tokio::test]
async fn unreachable_server_is_an_error() {
    let root = tempfile::tempdir().unwrap();
    dataset(root.path());
    let c = cfg(root.path(), "http://127.0.0.1:9", "r", None);
    let err = run(&c).await.unwrap_err();
    assert!(format!("{err:#}").contains("uploading scene a"), "{err:#}");
}

#[test]
fn cli_in_process_mode_reports_a_bad_dataset_in_one_line() {
    let root = tempfile::tempdir().unwrap();
    let out = root.path().join("report");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_grounder"))
        .args([
            "eval",
            "--dataset",
            "no-such-dataset",
            "--scenes",
            "y",
            "--out",
        ])
        .arg(&out)
        .env("GROUNDER_PIPELINE", "test")
        .env("GROUNDER_DETECTOR", "none")
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    let last = err.lines().last().unwrap_or("");
    assert!(
        last.starts_with("error: ") && last.contains("no-such-dataset"),
        "{err}"
    );
}

#[test]
fn cli_compare_pairs_two_reports_by_query_and_object() {
    use grounder::eval::metrics::{QueryRecord, StageOutcome};
    let root = tempfile::tempdir().unwrap();
    dataset(root.path());
    let rec = |id: &str, scene: &str, target: Option<u32>, iou: f64| QueryRecord {
        query_id: id.into(),
        scene_id: scene.into(),
        target_id: target,
        target_label: None,
        subset: Subset::Unique,
        predicted: Some(Aabb::new([0.0; 3], [1.0; 3])),
        iou,
        nr3d_correct: false,
        failure_stage: None,
        vlm_calls: 1,
        tokens: 1,
        latency_ms: 1.0,
        stages: StageOutcome::default(),
        hard: None,
        view_dependent: None,
        status: "succeeded".into(),
        error: None,
    };
    let write = |dir: &str, recs: &[QueryRecord]| {
        let d = root.path().join(dir);
        std::fs::create_dir_all(&d).unwrap();
        let lines: Vec<String> = recs
            .iter()
            .map(|r| serde_json::to_string(r).unwrap() + "\n")
            .collect();
        std::fs::write(d.join("results.jsonl"), lines.concat()).unwrap();
        d
    };
    // The base names no targets (an older report); the run loses "a1" and names its target.
    let base = write(
        "base",
        &[
            rec("a1", "a", None, 0.9),
            rec("a2", "a", None, 0.9),
            rec("b1", "b", None, 0.9),
            rec("b2", "b", None, 0.3),
        ],
    );
    let run = write(
        "run",
        &[
            rec("a1", "a", Some(1), 0.0),
            rec("a2", "a", Some(2), 0.9),
            rec("b1", "b", Some(1), 0.9),
        ],
    );
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_grounder"))
        .arg("compare")
        .args([&base, &run])
        .arg("--dataset")
        .arg(root.path().join("ds"))
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        out.contains(
            "3 queries in both reports (1 only in the base, 0 only in the run), 3 target objects"
        ),
        "{out}"
    );
    assert!(
        out.contains("Acc@0.25: base 100.0 %, run 66.7 %, difference -33.3 points"),
        "{out}"
    );
    assert!(out.contains("  a#1: -1 of 1 queries"), "{out}");
    // The same as JSON, for scripts: shares, the interval, the changed objects.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_grounder"))
        .arg("compare")
        .args([&base, &run])
        .arg("--dataset")
        .arg(root.path().join("ds"))
        .arg("--json")
        .output()
        .unwrap();
    assert!(o.status.success());
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (j["matched"].as_u64(), j["objects"].as_u64()),
        (Some(3), Some(3))
    );
    let d25 = &j["deltas"][0];
    assert_eq!(d25["threshold"], json!(0.25));
    assert!(
        (d25["difference"].as_f64().unwrap() + 1.0 / 3.0).abs() < 1e-9,
        "{j}"
    );
    assert!(d25["interval"]["lo"].as_f64().unwrap() <= d25["difference"].as_f64().unwrap());
    assert_eq!(
        d25["changed"],
        json!([{"object": "a#1", "net": -1, "queries": 1}])
    );
    // A folder without results: one line on stderr, a failing exit.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_grounder"))
        .arg("compare")
        .arg(&base)
        .arg(root.path().join("scenes"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.trim_end().ends_with("no results.jsonl there"), "{err}");
}
