//! `grounder demo`: the whole service with no VLM and no key. A small synthetic scene is
//! rendered, the oracle VLM (answers from the scene's ground truth) and the service run in
//! this process on loopback ports, three queries are grounded and their boxes printed with
//! their IoU against the truth and their viewer URLs.

use anyhow::{Context, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use super::ground::box_table;
use super::{step_line, Service};
use crate::eval::dataset::{load_scene_objects, parse_queries, Query};
use crate::geometry::Aabb;

/// Flags of `grounder demo`.
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Address of the service.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: String,
    /// Where the scene and the service's data go (default: a temporary folder, removed at
    /// exit).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Seed of the synthetic scene.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Frames of the synthetic scene (640x480).
    #[arg(long, default_value_t = 20)]
    pub frames: usize,
    /// Exit after the queries (0 when every box was found) instead of serving on.
    #[arg(long)]
    pub once: bool,
}

/// Three queries of different targets, preferring different kinds of sentence.
fn pick_queries(all: &[Query]) -> Vec<Query> {
    let mut out: Vec<Query> = Vec::new();
    for pass in 0..2 {
        for q in all {
            if out.len() == 3 {
                return out;
            }
            let kind = q.extra.get("kind").and_then(|k| k.as_str()).unwrap_or("");
            let new_target = out.iter().all(|o| o.target_id != q.target_id);
            let new_kind = out
                .iter()
                .all(|o| o.extra.get("kind").and_then(|k| k.as_str()).unwrap_or("") != kind);
            if new_target && (new_kind || pass == 1) {
                out.push(q.clone());
            }
        }
    }
    out
}

pub async fn run(a: DemoArgs) -> ExitCode {
    match go(a).await {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            let msg = e
                .chain()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(": ");
            eprintln!("error: {msg}");
            ExitCode::from(2)
        }
    }
}

async fn go(a: DemoArgs) -> Result<bool> {
    let tmp = match &a.data_dir {
        Some(_) => None,
        None => Some(tempfile::tempdir().context("cannot make a temporary folder")?),
    };
    let root = match (&a.data_dir, &tmp) {
        (Some(d), _) => d.clone(),
        (None, Some(t)) => t.path().to_path_buf(),
        (None, None) => unreachable!("one of the two is set"),
    };
    let (scenes, ds) = (root.join("scenes"), root.join("dataset"));
    println!(
        "rendering a synthetic scene ({} frames, 640x480) ...",
        a.frames
    );
    let params = crate::synth::SynthParams {
        frames: a.frames,
        color_size: (640, 480),
        depth_size: (320, 240),
        ..crate::synth::SynthParams::new(a.seed)
    };
    let (sc, ds2) = (scenes.clone(), ds.clone());
    let scene = tokio::task::spawn_blocking(move || -> Result<_> {
        let s = crate::synth::generate(&params, &sc)?;
        crate::synth::write_dataset(std::slice::from_ref(&s), &ds2)?;
        Ok(s)
    })
    .await??;

    // The oracle VLM on a loopback port.
    let oracle = crate::eval::oracle_vlm::router(&crate::eval::oracle_vlm::OracleVlmArgs {
        addr: "127.0.0.1:0".into(),
        dataset: ds.clone(),
        scenes: scenes.clone(),
        seed: 0,
        error_rate: 0.0,
    })?;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let oracle_url = format!("http://{}/v1", listener.local_addr()?);
    tokio::spawn(async move {
        let _ = axum::serve(listener, oracle).await;
    });

    // The service, configured as `serve` would be, with the oracle as its VLM.
    let cfg = crate::config::Config {
        addr: a.addr.clone(),
        data_dir: root.join("service"),
        detector: "oracle".into(),
        segmenter: "depth".into(),
        workers: 2,
        vlm: Some(crate::vlm::VlmConfig {
            base_url: oracle_url,
            model: crate::eval::oracle_vlm::ORACLE_MODEL.into(),
            api_key: crate::vlm::config::ApiKey::new("demo"),
            ..Default::default()
        }),
        ..Default::default()
    };
    let app = crate::startup::Application::build(cfg).await?;
    let base = format!("http://{}", app.local_addr()?);
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(app.run_until(async move {
        let _ = stop_rx.await;
    }));
    println!("listening on {base}");

    let svc = Service::new(&base, None);
    let scene_id = svc
        .upload(&scene.dir, Duration::from_secs(300))
        .await
        .context("uploading the demo scene")?;
    println!("scene: {base}/v1/scenes/{scene_id}/view");
    let queries = parse_queries(&std::fs::read_to_string(ds.join("queries.jsonl"))?)?;
    let truth = load_scene_objects(&ds.join("objects"), &scene.scene_id)?;
    let mut all_found = true;
    for q in pick_queries(&queries) {
        let id = svc.submit(&scene_id, &q.text).await?;
        println!("\n\"{}\"", q.text);
        let job = svc
            .follow_job(&id, Duration::from_secs(300), |s| {
                println!("{}", step_line(s))
            })
            .await?;
        let b = &job["result"]["box"];
        if job["status"] == "succeeded" {
            let pred: Option<Aabb> = serde_json::from_value(b.clone()).ok();
            let iou = match (pred, truth.get(q.target_id)) {
                (Some(p), Some(t)) => format!("{:.2}", p.iou(&t.aabb)),
                _ => "n/a".into(),
            };
            println!("{}  IoU with the truth: {iou}", box_table(b));
        } else {
            all_found = false;
            println!(
                "  {}: {}",
                job["error"]["code"].as_str().unwrap_or("failed"),
                job["error"]["detail"].as_str().unwrap_or("")
            );
        }
        println!("  view: {base}/v1/jobs/{id}/view");
    }
    if a.once {
        let _ = stop_tx.send(());
        let _ = server.await;
        return Ok(all_found);
    }
    println!("\nserving on {base} until Ctrl-C");
    let _ = tokio::signal::ctrl_c().await;
    let _ = stop_tx.send(());
    let _ = server.await;
    drop(tmp);
    Ok(all_found)
}
