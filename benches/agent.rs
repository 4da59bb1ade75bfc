//! Non-VLM time per query of the VLM-Grounder pipeline: the real service (oracle detector
//! with cached detections, depth segmenter, one worker) on a 100-frame synthetic scene,
//! with an instant scripted fake VLM. Reads `summary.outputs.non_vlm_ms` and the per-stage
//! `ms` of each job's trace. Target: non-VLM time ≤ 0.3 s per query on 2 cores.
//!
//! `cargo bench --bench agent` (AGENT_BENCH_QUERIES=N, default 12; AGENT_BENCH_FULL=1 adds
//! a 1296x968 run; AGENT_BENCH_SEGMENTER=SPEC another segmenter, default `depth`;
//! AGENT_BENCH_TILE_CACHE_MB=N the tile cache's bound, default the service's).
//!
//! `non_vlm_ms` is wall time: the job's total less the time spent waiting for the VLM.
//! The process's CPU time over the queries (user + system, the server's background work
//! included) is printed beside it, being less sensitive to other load on the machine.

#[allow(dead_code)]
#[path = "../tests/api/fake_vlm.rs"]
mod fake_vlm;
#[allow(dead_code)]
#[path = "../tests/api/helpers.rs"]
mod helpers;

use fake_vlm::{FakeVlm, Reply};
use grounder::synth::{generate_with, SynthParams};
use grounder::vlm::{ApiKey, VlmConfig};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

const STAGES: [&str; 11] = [
    "query_analysis",
    "preselection",
    "stitching",
    "image_selection",
    "detection",
    "candidates",
    "mark_selection",
    "instance_selection",
    "segmentation",
    "projection",
    "summary",
];

fn main() -> anyhow::Result<()> {
    let n: usize = std::env::var("AGENT_BENCH_QUERIES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(12);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(run(n, (640, 480)))?;
    if std::env::var("AGENT_BENCH_FULL").is_ok_and(|v| v == "1") {
        rt.block_on(run(n, (1296, 968)))?;
    }
    Ok(())
}

async fn run(n: usize, color: (u32, u32)) -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let t = Instant::now();
    let params = SynthParams {
        frames: 100,
        color_size: color,
        depth_size: (640, 480),
        ..SynthParams::new(11)
    };
    let scene = tokio::task::spawn_blocking({
        let out = dir.path().join("synth");
        move || generate_with(&params, &out, true)
    })
    .await??;
    eprintln!(
        "scene {}x{} x100 generated in {:.1} s",
        color.0,
        color.1,
        t.elapsed().as_secs_f64()
    );

    let vlm = FakeVlm::start(vec![]).await;
    let mut cfg = helpers::test_config(dir.path().join("data"));
    cfg.pipeline = "vlm".into();
    cfg.detector = "oracle".into();
    cfg.segmenter = std::env::var("AGENT_BENCH_SEGMENTER").unwrap_or_else(|_| "depth".into());
    cfg.workers = 1;
    if let Some(mb) = std::env::var("AGENT_BENCH_TILE_CACHE_MB")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        cfg.tile_cache_mb = mb;
    }
    cfg.vlm = Some(VlmConfig {
        base_url: vlm.base.clone(),
        api_key: ApiKey::new("bench"),
        timeout_ms: 30_000,
        ..VlmConfig::default()
    });
    let app = helpers::TestApp::spawn_with(cfg).await;
    let tar = scene.tar.clone().ok_or_else(|| anyhow::anyhow!("no tar"))?;
    let r = app.upload(std::fs::read(tar)?, "application/x-tar").await;
    anyhow::ensure!(r.status().as_u16() == 201, "upload failed: {}", r.status());
    let sid = r.json::<Value>().await?["id"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    let t = Instant::now();
    loop {
        let (_, s) = app.get_json(&format!("/v1/scenes/{sid}")).await;
        if s["status"] == "ready" {
            break;
        }
        anyhow::ensure!(
            t.elapsed() < Duration::from_secs(600),
            "scene not ready: {s}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    eprintln!("indexed (oracle) in {:.1} s", t.elapsed().as_secs_f64());
    let store = grounder::store::Store::open(&app.data_dir).await?;
    let dets = store.detections(&sid, "oracle").await?;

    let mut non_vlm = Vec::new();
    let mut per_stage: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    let mut extra: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    let mut failed = 0;
    let cpu0 = cpu_seconds();
    let wall0 = Instant::now();
    for k in 0..n {
        let q = &scene.queries[k % scene.queries.len()];
        let class = q.target_label.as_str();
        // The "VLM" picks the frame where the class's largest box is.
        let area = |b: &[f32; 4]| (b[2] - b[0]) * (b[3] - b[1]);
        let best = dets
            .iter()
            .flat_map(|(i, d)| {
                d.iter()
                    .filter(|d| d.label == class)
                    .map(move |d| (*i, area(&d.bbox)))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let Some((frame, _)) = best else { continue };
        // With candidates beside the detections (the default since #18), the VLM always
        // picks among the marks; mark 0 is the first detection.
        let many = dets[&frame].iter().filter(|d| d.label == class).count() > 1
            || grounder::vision::candidates::CandidateParams::default().beside_detections;
        let mut replies = vec![
            Reply::ok(
                json!({"target_class": class, "attributes": [], "conditions": []}).to_string(),
            ),
            Reply::ok(
                json!({"reasoning": "", "target_image_id": frame, "reference_image_ids": []})
                    .to_string(),
            ),
        ];
        if many {
            replies.push(Reply::ok(
                json!({"reasoning": "", "object_id": 0}).to_string(),
            ));
        }
        vlm.script_push(replies);
        let r = app.create_job(&sid, &format!("{} (run {k})", q.text)).await;
        let id = r.json::<Value>().await?["id"]
            .as_str()
            .unwrap_or_default()
            .to_string();
        let job = app.wait_job(&id, Duration::from_secs(120)).await;
        if job["status"] != "succeeded" {
            failed += 1;
            eprintln!("query {k} ({class}): {} {}", job["status"], job["error"]);
            while vlm.remaining() > 0 {
                vlm.script_pop();
            }
            continue;
        }
        for s in job["trace"].as_array().into_iter().flatten() {
            let name = s["step"].as_str().unwrap_or("");
            if let Some(st) = STAGES.iter().find(|x| **x == name) {
                per_stage
                    .entry(st)
                    .or_default()
                    .push(s["ms"].as_f64().unwrap_or(0.0));
            }
            if name == "summary" {
                let ms = s["outputs"]["non_vlm_ms"].as_f64().unwrap_or(f64::NAN);
                let stages: Vec<String> = job["trace"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .filter(|s| s["ms"].as_f64().unwrap_or(0.0) >= 10.0)
                    .map(|s| {
                        format!(
                            "{} {:.0}",
                            s["step"].as_str().unwrap_or("?"),
                            s["ms"].as_f64().unwrap_or(0.0)
                        )
                    })
                    .collect();
                let proj = job["trace"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .find(|s| s["step"] == "projection")
                    .map(|s| s["outputs"]["timings_ms"].to_string())
                    .unwrap_or_default();
                eprintln!(
                    "query {k} ({class}, frame {frame}): non-VLM {ms:.1} ms; {}; projection {proj}",
                    stages.join(", ")
                );
                non_vlm.push(ms);
            }
            if name == "stitching" {
                extra
                    .entry("stitching.decode")
                    .or_default()
                    .push(s["outputs"]["decode_ms"].as_f64().unwrap_or(0.0));
                extra
                    .entry("stitching.render")
                    .or_default()
                    .push(s["outputs"]["render_ms"].as_f64().unwrap_or(0.0));
                extra
                    .entry("stitching.frames")
                    .or_default()
                    .push(s["inputs"]["frames"].as_f64().unwrap_or(0.0));
                extra
                    .entry("stitching.tiles_cached")
                    .or_default()
                    .push(s["outputs"]["tiles_cached"].as_f64().unwrap_or(0.0));
                extra
                    .entry("stitching.grids_cached")
                    .or_default()
                    .push(s["outputs"]["grids_cached"].as_f64().unwrap_or(0.0));
                extra
                    .entry("stitching.from_previews")
                    .or_default()
                    .push(s["outputs"]["from_previews"].as_f64().unwrap_or(0.0));
            }
            if name == "projection" {
                for (key, part) in [
                    ("projection.find_views", "find_views"),
                    ("projection.decode", "decode"),
                    ("projection.segment", "segment"),
                    ("projection.fuse", "fuse"),
                    ("projection.support", "support"),
                ] {
                    extra
                        .entry(key)
                        .or_default()
                        .push(s["outputs"]["timings_ms"][part].as_f64().unwrap_or(0.0));
                }
                extra
                    .entry("projection.views_decoded")
                    .or_default()
                    .push(s["outputs"]["views_decoded"].as_f64().unwrap_or(0.0));
                extra
                    .entry("projection.candidate_views")
                    .or_default()
                    .push(s["inputs"]["candidate_views"].as_f64().unwrap_or(0.0));
            }
        }
    }
    let (cpu, wall) = (cpu_seconds() - cpu0, wall0.elapsed().as_secs_f64());
    let stat = |v: &[f64]| {
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        let max = v.iter().cloned().fold(f64::NAN, f64::max);
        (mean, max)
    };
    let (mean, max) = stat(&non_vlm);
    println!("agent/{}x{}: {} queries ok, {failed} failed; non-VLM ms per query: mean {mean:.1}, max {max:.1} (target <= 300)", color.0, color.1, non_vlm.len());
    println!(
        "  queries' wall {wall:.2} s, process CPU {cpu:.2} s ({:.0} ms CPU per query)",
        cpu * 1e3 / n.max(1) as f64
    );
    for (k, v) in per_stage.iter().chain(extra.iter()) {
        let (m, x) = stat(v);
        println!("  {k:<28} mean {m:>8.1}  max {x:>8.1}");
    }
    app.stop().await;
    Ok(())
}

/// User + system CPU seconds of this process so far (Linux: /proc/self/stat; 0 elsewhere).
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the command name, which is in parentheses and may hold spaces.
    let rest = stat.rsplit_once(')').map_or("", |r| r.1);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // utime and stime are fields 14 and 15 of the line: indices 11 and 12 after the name
    // (field 3 is index 0); the kernel counts them in USER_HZ, 100 on Linux.
    (ticks(11) + ticks(12)) / 100.0
}
