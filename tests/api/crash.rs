//! The real binary SIGKILLed at random points while scenes are uploaded, indexed and
//! deleted and jobs run; restarted each time. Afterwards nothing is orphaned (no folder
//! without its row, no hidden row, no spooled upload, no artifact without its job), no job
//! is lost or left queued/running, and SQLite's integrity check passes.
//!
//! The randomness is seeded (printed; `GROUNDER_CRASH_SEED=N` replays a run).

use crate::helpers::*;
use crate::spawned::{start_server, Server};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Start `grounder serve` on a data dir with the test pipeline and a slow oracle detector
/// (so that indexing lasts long enough to be interrupted). `env` adds settings.
pub fn start(data_dir: &Path, env: &[(&str, &str)]) -> Server {
    let mut all = vec![
        ("GROUNDER_DETECTOR", "oracle:delay_ms=40"),
        // Widen the windows between an import's or a delete's steps, so kills land there.
        ("GROUNDER_TEST_STEP_PAUSE_MS", "60"),
    ];
    all.extend_from_slice(env);
    start_server(data_dir, &all)
}

/// A tiny scene with 16-bit instance masks and labels (the oracle detector needs them).
pub fn scene_with_masks(frames: usize) -> Vec<u8> {
    let mut files = tiny_scene_files(frames);
    for i in 0..frames {
        let mask = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(64, 48, |x, y| {
            image::Luma([u16::from((10..30).contains(&x) && (10..30).contains(&y))])
        });
        let mut png = Vec::new();
        mask.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .expect("png");
        files.push((format!("instance/{}.png", i * 20), png));
    }
    files.push(("instance/labels.json".into(), br#"{"1": "bed"}"#.to_vec()));
    tar_of(&files, Some("scene"))
}

/// What the clients were told: scenes stored (201), deleted (204), jobs accepted (202).
#[derive(Default)]
struct Acked {
    scenes: BTreeSet<String>,
    deleted: BTreeSet<String>,
    /// Deletes sent (a kill may come before the answer: either outcome is right).
    delete_sent: BTreeSet<String>,
    jobs: BTreeSet<String>,
}

/// Random traffic until aborted: uploads, jobs, deletes.
async fn traffic(base: String, seed: u64, acked: Arc<Mutex<Acked>>, scene: Arc<Vec<u8>>) {
    let c = client();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    loop {
        let known: Vec<String> = {
            let a = acked.lock().unwrap();
            a.scenes.difference(&a.deleted).cloned().collect()
        };
        let roll = rng.gen_range(0..10);
        if roll < 4 || known.is_empty() {
            let r = c
                .post(format!("{base}/v1/scenes"))
                .header("content-type", "application/x-tar")
                .body(scene.as_ref().clone())
                .send()
                .await;
            if let Ok(r) = r {
                if r.status().as_u16() == 201 {
                    if let Ok(j) = r.json::<Value>().await {
                        let id = j["id"].as_str().unwrap_or_default().to_string();
                        acked.lock().unwrap().scenes.insert(id);
                    }
                }
            }
        } else if roll < 9 {
            let sid = &known[rng.gen_range(0..known.len())];
            let r = c
                .post(format!("{base}/v1/jobs"))
                .json(&serde_json::json!({"scene_id": sid, "query": "the bed"}))
                .send()
                .await;
            if let Ok(r) = r {
                if r.status().as_u16() == 202 {
                    if let Ok(j) = r.json::<Value>().await {
                        let id = j["id"].as_str().unwrap_or_default().to_string();
                        acked.lock().unwrap().jobs.insert(id);
                    }
                }
            }
        } else {
            let sid = known[rng.gen_range(0..known.len())].clone();
            acked.lock().unwrap().delete_sent.insert(sid.clone());
            let r = c.delete(format!("{base}/v1/scenes/{sid}")).send().await;
            if let Ok(r) = r {
                if r.status().as_u16() == 204 {
                    acked.lock().unwrap().deleted.insert(sid);
                }
            }
        }
        tokio::time::sleep(Duration::from_millis(rng.gen_range(0..60))).await;
    }
}

/// Wait until no job is queued or running and no scene is indexing.
async fn settle(base: &str) {
    let c = client();
    let t = Instant::now();
    loop {
        let mut busy = false;
        for st in ["queued", "running"] {
            let j: Value = get_json_at(&c, &format!("{base}/v1/jobs?status={st}&limit=1")).await;
            busy |= j["jobs"].as_array().is_some_and(|a| !a.is_empty());
        }
        let s: Value = get_json_at(&c, &format!("{base}/v1/scenes")).await;
        busy |= s["scenes"]
            .as_array()
            .is_some_and(|a| a.iter().any(|x| x["status"] == "indexing"));
        if !busy {
            return;
        }
        assert!(
            t.elapsed() < Duration::from_secs(40),
            "jobs or indexing still busy after 40 s: a stuck job or scene"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// The names in `dir`, sorted; empty when it does not exist.
pub fn names(dir: &Path) -> BTreeSet<String> {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default()
}

#[tokio::test]
async fn sigkill_at_random_points_leaves_nothing_orphaned_lost_or_stuck() {
    let seed: u64 = std::env::var("GROUNDER_CRASH_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| rand::thread_rng().gen());
    println!("crash test seed: {seed} (GROUNDER_CRASH_SEED={seed} replays it)");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let acked = Arc::new(Mutex::new(Acked::default()));
    let scene = Arc::new(scene_with_masks(8));
    let rounds = 7;
    for round in 0..rounds {
        let mut s = start(&data, &[]);
        let t = tokio::spawn(traffic(
            s.base.clone(),
            rng.gen(),
            acked.clone(),
            scene.clone(),
        ));
        let wait = rng.gen_range(150..1500);
        tokio::time::sleep(Duration::from_millis(wait)).await;
        s.signal("-KILL");
        t.abort();
        let _ = t.await;
        println!("round {round}: SIGKILL after {wait} ms");
    }
    let mut s = start(&data, &[]);
    settle(&s.base).await;
    s.signal("-TERM");

    let store = grounder::store::Store::open(&data).await.unwrap();
    let ok: String = sqlx::query_scalar("PRAGMA integrity_check")
        .fetch_one(&store.pool)
        .await
        .unwrap();
    assert_eq!(ok, "ok");
    let rows: Vec<(String, String, i64)> =
        sqlx::query_as("SELECT id, status, frame_count FROM scenes")
            .fetch_all(&store.pool)
            .await
            .unwrap();
    let row_ids: BTreeSet<String> = rows.iter().map(|r| r.0.clone()).collect();
    for (id, status, frames) in &rows {
        assert!(
            matches!(status.as_str(), "ready" | "failed"),
            "scene {id} is left {status}"
        );
        let colour = names(&data.join("scenes").join(id).join("color"));
        let stray: Vec<_> = colour.iter().filter(|n| n.ends_with(".tmp")).collect();
        assert!(
            stray.is_empty(),
            "scene {id} keeps half-written files {stray:?}"
        );
        let frames_kept = colour
            .iter()
            .filter(|n| n.ends_with(".jpg") && !n.ends_with(".preview.jpg"))
            .count();
        assert_eq!(frames_kept as i64, *frames, "scene {id} lacks files");
    }
    assert_eq!(
        names(&data.join("scenes")),
        row_ids,
        "every scene folder has its row and every row its folder"
    );
    assert!(names(&data.join("tmp")).is_empty(), "spooled uploads left");
    let acked = std::mem::take(&mut *acked.lock().unwrap());
    for id in &acked.scenes {
        if row_ids.contains(id) {
            assert!(!acked.deleted.contains(id), "scene {id} was deleted (204)");
        } else {
            assert!(
                acked.delete_sent.contains(id),
                "scene {id} was stored (201) and is lost"
            );
        }
    }
    let jobs: Vec<(String, String, String)> =
        sqlx::query_as("SELECT id, status, scene_id FROM jobs")
            .fetch_all(&store.pool)
            .await
            .unwrap();
    let job_ids: BTreeSet<String> = jobs.iter().map(|j| j.0.clone()).collect();
    for id in &acked.jobs {
        assert!(job_ids.contains(id), "job {id} was accepted and is lost");
    }
    for (id, status, _) in &jobs {
        assert!(
            matches!(status.as_str(), "succeeded" | "failed" | "canceled"),
            "job {id} is left {status}"
        );
    }
    for a in names(&data.join("artifacts")) {
        let (_, _, scene) = jobs
            .iter()
            .find(|j| j.0 == a)
            .unwrap_or_else(|| panic!("artifacts of job {a}, which does not exist"));
        assert!(
            row_ids.contains(scene),
            "artifacts of job {a} survive its deleted scene {scene}"
        );
    }
    println!(
        "crash test: {} scenes acknowledged, {} deleted, {} jobs accepted, {} kept",
        acked.scenes.len(),
        acked.deleted.len(),
        acked.jobs.len(),
        rows.len()
    );
    assert!(
        !acked.scenes.is_empty() && !acked.jobs.is_empty(),
        "the traffic reached the server"
    );
}

/// A scene whose indexing dies with the process every time ends `failed` with the reason
/// after `max_index_attempts` (3) instead of being resumed forever; a job queued on it fails.
#[tokio::test]
async fn a_scene_whose_indexing_keeps_killing_the_process_ends_failed() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let slow = [("GROUNDER_DETECTOR", "oracle:delay_ms=400")];
    let c = client();
    let mut s = start(&data, &slow);
    let id = upload_scene_to(&c, &s.base, scene_with_masks(8)).await;
    let jid = submit_job(&c, &s.base, &id, "the bed").await;
    for attempt in 1..=3 {
        if attempt > 1 {
            s = start(&data, &slow);
        }
        // Killed while indexing (each frame takes 400 ms; 7 usable frames).
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (st, j) = {
            let r = c
                .get(format!("{}/v1/scenes/{id}", s.base))
                .send()
                .await
                .unwrap();
            (r.status().as_u16(), r.json::<Value>().await.unwrap())
        };
        assert_eq!((st, j["status"].as_str()), (200, Some("indexing")), "{j}");
        s.signal("-KILL");
    }
    let mut s = start(&data, &slow);
    let j: Value = get_json_at(&c, &format!("{}/v1/scenes/{id}", s.base)).await;
    assert_eq!(j["status"], "failed", "{j}");
    let why = j["error"].as_str().unwrap_or_default();
    assert!(why.contains("interrupted 3 times"), "{why}");
    let job: Value = get_json_at(&c, &format!("{}/v1/jobs/{jid}", s.base)).await;
    assert_eq!(
        (job["status"].as_str(), job["error"]["code"].as_str()),
        (Some("failed"), Some("scene_failed")),
        "{job}"
    );
    s.signal("-TERM");
}
