//! The real service (pipeline "vlm", oracle detector, depth segmenter) on port 0, talking
//! to a fake VLM, with a small synthetic scene uploaded and indexed.

use crate::fake_vlm::{FakeVlm, Reply};
use crate::helpers::{test_config, TestApp};
use grounder::store::Store;
use grounder::synth::{generate_with, SynthParams, SynthScene};
use grounder::vision::Detection;
use grounder::vlm::{ApiKey, VlmConfig};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

pub const API_KEY: &str = "sk-agenttest-SECRET-42";
pub const SEED: u64 = 3;

/// The scene tar, generated once per test binary.
pub fn scene_tar() -> &'static (PathBuf, SynthScene) {
    static SCENE: OnceLock<(PathBuf, SynthScene)> = OnceLock::new();
    SCENE.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("agent-tests-scene");
        let _ = std::fs::remove_dir_all(&dir);
        let s = generate_with(&SynthParams::small(SEED), &dir, true).expect("synth scene");
        (s.tar.clone().expect("tar written"), s)
    })
}

/// The bytes of the shared scene's tar.
pub fn shared_tar() -> Vec<u8> {
    std::fs::read(&scene_tar().0).expect("the shared scene's tar")
}

/// The shared scene's tar with the left half of frame 0's depth emptied (no reading there,
/// as where the object stands beyond the sensor's range).
pub fn tar_without_depth_on_the_left_of_frame_0() -> Vec<u8> {
    let mut archive = tar::Archive::new(std::fs::File::open(&scene_tar().0).unwrap());
    let mut files = Vec::new();
    for e in archive.entries().unwrap() {
        let mut e = e.unwrap();
        if !e.header().entry_type().is_file() {
            continue;
        }
        let path = e.path().unwrap().to_string_lossy().to_string();
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut e, &mut bytes).unwrap();
        if path.ends_with("depth/0.png") {
            let mut d = image::load_from_memory(&bytes).unwrap().into_luma16();
            let w = d.width();
            for (x, _, p) in d.enumerate_pixels_mut() {
                if x < w / 2 {
                    p.0[0] = 0;
                }
            }
            let mut out = std::io::Cursor::new(Vec::new());
            image::DynamicImage::ImageLuma16(d)
                .write_to(&mut out, image::ImageFormat::Png)
                .unwrap();
            bytes = out.into_inner();
        }
        files.push((path, bytes));
    }
    crate::helpers::tar_of(&files, None)
}

/// A lamp job on a scene from [`tar_without_depth_on_the_left_of_frame_0`]: the VLM picks
/// frame 0, says no mark outlines the lamp and draws box `left` itself; asked again, it
/// picks frame 1 and its mark 0.
pub async fn run_left_box_then_frame_1(f: &Fixture, left: [f32; 4]) -> Value {
    let none = json!({"reasoning": "no outline", "object_id": null}).to_string();
    let boxed = json!({"reasoning": "on the left", "bbox_2d": left}).to_string();
    f.vlm.script_push(vec![
        analysis("lamp"),
        pick_image("00000"),
        Reply::ok(none),
        Reply::ok(boxed),
        pick_image("00001"),
        pick_object(0),
    ]);
    f.run_job(crate::agent_paths::QUERY).await
}

pub struct Fixture {
    pub app: TestApp,
    pub vlm: FakeVlm,
    pub scene_id: String,
    pub store: Store,
    /// Cached detections by frame index (what pre-selection reads).
    pub dets: BTreeMap<usize, Vec<Detection>>,
    /// The key the service caches its class-agnostic candidates under.
    pub candidates_key: String,
    _dir: tempfile::TempDir,
}

/// Client settings pointing at the fake: small backoff, `timeout_ms` per test.
pub fn vlm_config(base: &str, timeout_ms: u64) -> VlmConfig {
    VlmConfig {
        base_url: base.into(),
        model: "fake".into(),
        api_key: ApiKey::new(API_KEY),
        timeout_ms,
        max_retries: 2,
        backoff_base_ms: 5,
        backoff_max_ms: 50,
        ..VlmConfig::default()
    }
}

impl Fixture {
    /// The cached class-agnostic candidates of frame `idx` (none when it has none).
    pub async fn candidates(&self, idx: usize) -> Vec<Detection> {
        self.store
            .frame_candidates(&self.scene_id, &self.candidates_key, idx)
            .await
            .unwrap()
            .unwrap_or_default()
    }

    pub async fn start(replies: Vec<Reply>, timeout_ms: u64) -> Fixture {
        Self::start_with_detector(replies, timeout_ms, "oracle").await
    }

    /// As `start`, with another detector (e.g. the closed-vocabulary "centernet", which
    /// needs ONNX Runtime and the vendored model).
    pub async fn start_with_detector(
        replies: Vec<Reply>,
        timeout_ms: u64,
        detector: &str,
    ) -> Fixture {
        Self::start_with(replies, timeout_ms, detector, |_| {}).await
    }

    /// As `start_with_detector`, with the VLM client settings adjusted by `tweak`. These
    /// fixtures test the paper's detector path: class-agnostic candidates are off.
    pub async fn start_with(
        replies: Vec<Reply>,
        timeout_ms: u64,
        detector: &str,
        tweak: impl FnOnce(&mut VlmConfig),
    ) -> Fixture {
        Self::start_full(replies, timeout_ms, detector, tweak, false).await
    }

    /// As `start_with`, with the whole service configuration adjusted by `tweak` last.
    pub async fn start_with_config(
        timeout_ms: u64,
        detector: &str,
        tweak: impl FnOnce(&mut grounder::config::Config),
    ) -> Fixture {
        Self::start_with_tar(shared_tar(), timeout_ms, detector, tweak).await
    }

    /// With the class-agnostic candidates on (the default configuration).
    pub async fn start_with_candidates(
        replies: Vec<Reply>,
        timeout_ms: u64,
        detector: &str,
    ) -> Fixture {
        Self::start_full(replies, timeout_ms, detector, |_| {}, true).await
    }

    async fn start_full(
        replies: Vec<Reply>,
        timeout_ms: u64,
        detector: &str,
        tweak: impl FnOnce(&mut VlmConfig),
        candidates: bool,
    ) -> Fixture {
        let tar = shared_tar();
        Self::start_scene(
            tar,
            replies,
            timeout_ms,
            detector,
            tweak,
            candidates,
            |_| {},
        )
        .await
    }

    /// As `start_with_config`, uploading the scene tar `tar` instead of the shared one.
    pub async fn start_with_tar(
        tar: Vec<u8>,
        timeout_ms: u64,
        detector: &str,
        tweak_cfg: impl FnOnce(&mut grounder::config::Config),
    ) -> Fixture {
        Self::start_scene(tar, vec![], timeout_ms, detector, |_| {}, false, tweak_cfg).await
    }

    #[allow(clippy::too_many_arguments)]
    async fn start_scene(
        tar: Vec<u8>,
        replies: Vec<Reply>,
        timeout_ms: u64,
        detector: &str,
        tweak: impl FnOnce(&mut VlmConfig),
        candidates: bool,
        tweak_cfg: impl FnOnce(&mut grounder::config::Config),
    ) -> Fixture {
        let vlm = FakeVlm::start(replies).await;
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path().to_path_buf());
        cfg.pipeline = "vlm".into();
        cfg.detector = detector.into();
        cfg.model_dir = Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models"));
        cfg.segmenter = "depth".into();
        cfg.workers = 1;
        cfg.agent.candidates.enabled = candidates;
        let mut vc = vlm_config(&vlm.base, timeout_ms);
        tweak(&mut vc);
        cfg.vlm = Some(vc);
        tweak_cfg(&mut cfg);
        let candidates_key = cfg.agent.candidates.cache_key(&cfg.agent.geometry.layout);
        let app = TestApp::spawn_with(cfg).await;
        let r = app.upload(tar, "application/x-tar").await;
        assert_eq!(r.status().as_u16(), 201);
        let scene_id = r.json::<Value>().await.unwrap()["id"]
            .as_str()
            .unwrap()
            .to_string();
        let start = std::time::Instant::now();
        loop {
            let (_, s) = app.get_json(&format!("/v1/scenes/{scene_id}")).await;
            if s["status"] == "ready" {
                break;
            }
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "scene never became ready: {s}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let store = Store::open(dir.path()).await.unwrap();
        let dets = store.detections(&scene_id, detector).await.unwrap();
        if detector == "oracle" {
            assert!(!dets.is_empty(), "indexing cached no detections");
        }
        Fixture {
            app,
            vlm,
            scene_id,
            store,
            dets,
            candidates_key,
            _dir: dir,
        }
    }

    /// Frames where `class` has exactly `n` cached detections (n = 2 means "two or more").
    pub fn frames_with(&self, class: &str, n: usize) -> Vec<usize> {
        self.dets
            .iter()
            .filter(|(_, d)| {
                let k = d
                    .iter()
                    .filter(|d| d.label == class && d.score > 0.2)
                    .count();
                if n >= 2 {
                    k >= 2
                } else {
                    k == n
                }
            })
            .map(|(i, _)| *i)
            .collect()
    }

    /// Frames that hold any detection of `class` (the pre-selection).
    pub fn offered(&self, class: &str) -> Vec<u32> {
        self.dets
            .iter()
            .filter(|(_, d)| d.iter().any(|d| d.label == class && d.score > 0.2))
            .map(|(i, _)| *i as u32)
            .collect()
    }

    /// A job the VLM answers with a whiteboard in image 00000, picking mark (or object) 0;
    /// it must succeed.
    pub async fn run_whiteboard_mark_0(&self) -> Value {
        self.vlm.script_push(vec![
            analysis("whiteboard"),
            pick_image("00000"),
            pick_object(0),
        ]);
        let job = self.run_job(crate::agent_paths::QUERY).await;
        assert_eq!(job["status"], "succeeded", "{job:#}");
        job
    }

    /// Submit a job and wait until it ends.
    pub async fn run_job(&self, query: &str) -> Value {
        let id = self.submit(query).await;
        self.app.wait_job(&id, Duration::from_secs(60)).await
    }

    pub async fn submit(&self, query: &str) -> String {
        self.app.submit_job(&self.scene_id, query).await
    }
}

/// Query analysis reply naming `class`.
pub fn analysis(class: &str) -> Reply {
    Reply::ok(json!({"target_class": class, "attributes": [], "conditions": []}).to_string())
}

/// Grounding reply choosing `image_id`.
pub fn pick_image(image_id: impl Into<Value>) -> Reply {
    Reply::ok(json!({"reasoning": "it matches", "target_image_id": image_id.into(), "reference_image_ids": []}).to_string())
}

/// Instance reply choosing `object_id`.
pub fn pick_object(object_id: u32) -> Reply {
    Reply::ok(json!({"reasoning": "that one", "object_id": object_id}).to_string())
}

/// The first class (by name) with a frame holding `n` instances (as
/// [`Fixture::frames_with`] counts them), and that frame.
fn class_with(f: &Fixture, n: usize) -> Option<(String, usize)> {
    let mut labels: Vec<&str> = f
        .dets
        .values()
        .flatten()
        .map(|d| d.label.as_str())
        .collect();
    labels.sort();
    labels.dedup();
    labels
        .into_iter()
        .find_map(|l| f.frames_with(l, n).first().map(|&i| (l.to_string(), i)))
}

/// A class with a frame holding exactly one instance, and that frame.
pub fn class_with_single(f: &Fixture) -> (String, usize) {
    class_with(f, 1).unwrap_or_else(|| {
        panic!(
            "no class has a frame with exactly one instance: {:?}",
            f.dets
        )
    })
}

/// A class with a frame holding two or more instances, and that frame.
pub fn class_with_several(f: &Fixture) -> (String, usize) {
    class_with(f, 2).unwrap_or_else(|| {
        panic!(
            "no class has a frame with several instances (seed {SEED}): {:?}",
            f.dets
        )
    })
}

/// Step names of a finished job's trace.
pub fn step_names(job: &Value) -> Vec<String> {
    job["trace"]
        .as_array()
        .expect("trace")
        .iter()
        .map(|s| s["step"].as_str().unwrap_or("").to_string())
        .collect()
}

/// All trace steps called `name`.
pub fn steps<'a>(job: &'a Value, name: &str) -> Vec<&'a Value> {
    job["trace"]
        .as_array()
        .expect("trace")
        .iter()
        .filter(|s| s["step"] == name)
        .collect()
}

/// The trace must not leak image bytes or the key.
pub fn assert_trace_clean(job: &Value) {
    let t = job["trace"].to_string();
    assert!(!t.contains("base64"), "trace holds base64");
    assert!(!t.contains("data:image"), "trace holds a data URL");
    assert!(!t.contains(API_KEY), "trace holds the API key");
    assert!(!job.to_string().contains(API_KEY), "job holds the API key");
}
