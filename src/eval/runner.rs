//! `grounder eval` against a running service: upload scenes, run every query as a job,
//! score it, append it to `results.jsonl`, then write the summary.

use super::dataset::{Dataset, Query, SceneObjects};
use super::metrics::{score, Observation, QueryRecord, Summary};
use super::report::{self, ResultsLog};
use super::trace::{stages_from_trace, TargetViews};
use crate::geometry::Aabb;
use anyhow::{anyhow, bail, Context, Result};
use futures::StreamExt;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::{json, Value};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Everything `grounder eval` needs.
#[derive(Debug, Clone)]
pub struct EvalConfig {
    /// FORMATS §2 dataset folder.
    pub dataset: PathBuf,
    /// Folder holding one scene directory per scene id.
    pub scenes: PathBuf,
    /// Base URL of the service (e.g. `http://127.0.0.1:8080`).
    pub server: String,
    /// Only the first N queries of the dataset.
    pub limit: Option<usize>,
    /// Concurrent jobs.
    pub jobs: usize,
    /// Report folder.
    pub out: PathBuf,
    /// Interval between status polls.
    pub poll: Duration,
    /// Give up on one job after this long.
    pub job_timeout: Duration,
    /// Give up waiting for a scene to become ready after this long.
    pub scene_timeout: Duration,
}

/// Result of a whole evaluation run.
#[derive(Debug, Clone)]
pub struct EvalOutcome {
    /// Summary over all records in the report (old and new).
    pub summary: Summary,
    /// Queries run in this invocation.
    pub ran: usize,
    /// Queries skipped because the report already had them.
    pub skipped: usize,
    /// Queries that could not be run (transport errors); not recorded, retried on resume.
    pub errors: Vec<String>,
}

/// Pack a scene directory into an in-memory tar with a single top-level folder.
pub fn tar_scene(dir: &Path, name: &str) -> Result<Vec<u8>> {
    let mut b = tar::Builder::new(Vec::new());
    b.follow_symlinks(true);
    b.append_dir_all(name, dir)
        .with_context(|| format!("cannot pack {}", dir.display()))?;
    b.into_inner()
        .with_context(|| format!("cannot pack {}", dir.display()))
}

async fn json_response(resp: reqwest::Response, what: &str) -> Result<Value> {
    let status = resp.status();
    let text = resp
        .text()
        .await
        .with_context(|| format!("{what}: cannot read the response"))?;
    if !status.is_success() {
        let snippet: String = text.chars().take(300).collect();
        bail!("{what}: HTTP {status}: {snippet}");
    }
    serde_json::from_str(&text).with_context(|| format!("{what}: the response is not JSON"))
}

fn id_of(v: &Value, what: &str) -> Result<String> {
    match v.get("id") {
        Some(Value::String(s)) => Ok(s.clone()),
        Some(Value::Number(n)) => Ok(n.to_string()),
        _ => bail!("{what}: the response has no \"id\""),
    }
}

/// Upload one scene and wait until the service reports it "ready"; returns its id.
pub async fn upload_scene(
    client: &reqwest::Client,
    cfg: &EvalConfig,
    scene_id: &str,
) -> Result<String> {
    let dir = cfg.scenes.join(scene_id);
    let d2 = dir.clone();
    let name = scene_id.to_string();
    let body = tokio::task::spawn_blocking(move || tar_scene(&d2, &name)).await??;
    let what = format!("uploading scene {scene_id}");
    let resp = client
        .post(format!("{}/v1/scenes", cfg.server))
        .header(reqwest::header::CONTENT_TYPE, "application/x-tar")
        .body(body)
        .send()
        .await
        .with_context(|| what.clone())?;
    let v = json_response(resp, &what).await?;
    let id = id_of(&v, &what)?;
    let start = Instant::now();
    let mut status = v
        .get("status")
        .and_then(|s| s.as_str())
        .unwrap_or_default()
        .to_string();
    loop {
        match status.as_str() {
            "ready" => return Ok(id),
            "failed" | "error" => bail!("scene {scene_id} failed to import on the server"),
            _ => {}
        }
        if start.elapsed() > cfg.scene_timeout {
            bail!(
                "scene {scene_id} was not ready after {:?} (status {status:?})",
                cfg.scene_timeout
            );
        }
        tokio::time::sleep(cfg.poll).await;
        let resp = client
            .get(format!("{}/v1/scenes/{id}", cfg.server))
            .send()
            .await
            .with_context(|| what.clone())?;
        let v = json_response(resp, &what).await?;
        status = v
            .get("status")
            .and_then(|s| s.as_str())
            .unwrap_or_default()
            .to_string();
    }
}

/// Submit one query and poll the job to a terminal status; returns the final job JSON and
/// the client-side wall time.
pub async fn run_job(
    client: &reqwest::Client,
    cfg: &EvalConfig,
    server_scene: &str,
    text: &str,
) -> Result<(Value, f64)> {
    let start = Instant::now();
    let resp = client
        .post(format!("{}/v1/jobs", cfg.server))
        .json(&json!({"scene_id": server_scene, "query": text}))
        .send()
        .await
        .context("submitting the job")?;
    let mut job = json_response(resp, "submitting the job").await?;
    let id = id_of(&job, "submitting the job")?;
    loop {
        let status = job
            .get("status")
            .and_then(|s| s.as_str())
            .unwrap_or_default();
        if matches!(status, "succeeded" | "failed" | "canceled") {
            return Ok((job, start.elapsed().as_secs_f64() * 1000.0));
        }
        if start.elapsed() > cfg.job_timeout {
            bail!("job {id} did not finish within {:?}", cfg.job_timeout);
        }
        tokio::time::sleep(cfg.poll).await;
        let resp = client
            .get(format!("{}/v1/jobs/{id}", cfg.server))
            .send()
            .await
            .context("polling the job")?;
        job = json_response(resp, "polling the job").await?;
    }
}

fn tokens_of(u: &Value) -> u64 {
    u.get("total_tokens")
        .and_then(|t| t.as_u64())
        .unwrap_or_else(|| {
            ["prompt_tokens", "completion_tokens"]
                .iter()
                .filter_map(|k| u.get(*k).and_then(|t| t.as_u64()))
                .sum()
        })
}

/// VLM calls and tokens: `usage` of the job (top level or in `result`, where the service
/// puts it) when present, else summed over trace steps carrying a `usage` object (each one
/// VLM call).
pub fn usage_of(job: &Value) -> (u32, u64) {
    let usage = job
        .get("usage")
        .or_else(|| job.get("result").and_then(|r| r.get("usage")))
        .filter(|u| u.is_object());
    if let Some(u) = usage {
        let calls = u.get("vlm_calls").and_then(|c| c.as_u64()).unwrap_or(0);
        return (u32::try_from(calls).unwrap_or(u32::MAX), tokens_of(u));
    }
    let (mut calls, mut tokens) = (0u32, 0u64);
    for step in job
        .get("trace")
        .and_then(|t| t.as_array())
        .into_iter()
        .flatten()
    {
        if let Some(u) = step
            .get("usage")
            .or_else(|| step.get("outputs").and_then(|o| o.get("usage")))
        {
            calls += 1;
            tokens += tokens_of(u);
        }
    }
    (calls, tokens)
}

/// The final box of a job (`result.box` with "min"/"max"), if any.
pub fn box_of(job: &Value) -> Option<Aabb> {
    let b = job.get("result")?.get("box")?;
    let a: Aabb = serde_json::from_value(b.clone()).ok()?;
    (0..3)
        .all(|i| a.min[i].is_finite() && a.max[i].is_finite())
        .then_some(a)
}

/// Score a finished job (reads instance masks for the stage outcomes; blocking I/O).
pub fn observe(job: &Value, wall_ms: f64, scene_dir: &Path, target_id: u32) -> Observation {
    let (vlm_calls, tokens) = usage_of(job);
    let stages = match (job.get("trace"), TargetViews::open(scene_dir, target_id)) {
        (Some(t), Ok(Some(mut views))) => stages_from_trace(t, &mut views),
        _ => Default::default(),
    };
    let latency_ms = ["latency_ms", "duration_ms"]
        .iter()
        .find_map(|k| job.get(*k).and_then(|v| v.as_f64()))
        .unwrap_or(wall_ms);
    let error = job.get("error").and_then(|e| match e {
        Value::Null => None,
        Value::String(s) => Some(s.clone()),
        other => Some(other.to_string()),
    });
    Observation {
        predicted: box_of(job),
        stages,
        vlm_calls,
        tokens,
        latency_ms,
        status: job
            .get("status")
            .and_then(|s| s.as_str())
            .unwrap_or("unknown")
            .to_string(),
        error,
    }
}

async fn eval_one(
    client: &reqwest::Client,
    cfg: &EvalConfig,
    server_scene: &str,
    q: Query,
    objects: SceneObjects,
) -> Result<QueryRecord> {
    let (job, wall) = run_job(client, cfg, server_scene, &q.text)
        .await
        .with_context(|| format!("query {}", q.query_id))?;
    let scene_dir = cfg.scenes.join(&q.scene_id);
    tokio::task::spawn_blocking(move || {
        let obs = observe(&job, wall, &scene_dir, q.target_id);
        score(&q, &objects, obs)
    })
    .await
    .map_err(|e| anyhow!("scoring failed: {e}"))
}

/// Run the evaluation: resumable, `cfg.jobs` concurrent jobs, progress bar on a terminal.
pub async fn run(cfg: &EvalConfig) -> Result<EvalOutcome> {
    let ds = Dataset::load(&cfg.dataset)?;
    let mut log = ResultsLog::open(&cfg.out)?;
    let selected: Vec<Query> = ds
        .queries
        .iter()
        .take(cfg.limit.unwrap_or(usize::MAX))
        .cloned()
        .collect();
    let pending: Vec<Query> = selected
        .iter()
        .filter(|q| !log.contains(&q.query_id))
        .cloned()
        .collect();
    let skipped = selected.len() - pending.len();
    let mut scene_ids: Vec<String> = Vec::new();
    for q in &pending {
        if !scene_ids.contains(&q.scene_id) {
            let dir = cfg.scenes.join(&q.scene_id);
            if !dir.is_dir() {
                bail!("scene directory {} does not exist", dir.display());
            }
            scene_ids.push(q.scene_id.clone());
        }
    }
    let client = reqwest::Client::builder()
        .build()
        .context("cannot build the HTTP client")?;
    let mut server_ids: HashMap<String, String> = HashMap::new();
    for s in &scene_ids {
        let id = upload_scene(&client, cfg, s).await?;
        server_ids.insert(s.clone(), id);
    }
    let bar = ProgressBar::new(pending.len() as u64);
    if let Ok(style) = ProgressStyle::with_template(
        "{bar:40} {pos}/{len} queries, {elapsed} elapsed, eta {eta} {msg}",
    ) {
        bar.set_style(style);
    }
    let ran = pending.len();
    let jobs = cfg.jobs.max(1);
    let mut stream = futures::stream::iter(pending.into_iter().map(|q| {
        let client = &client;
        let server_scene = server_ids.get(&q.scene_id).cloned().unwrap_or_default();
        let objects = ds
            .scenes
            .get(&q.scene_id)
            .cloned()
            .unwrap_or_else(|| SceneObjects {
                scene_id: q.scene_id.clone(),
                objects: vec![],
            });
        async move { eval_one(client, cfg, &server_scene, q, objects).await }
    }))
    .buffer_unordered(jobs);
    let mut errors = Vec::new();
    while let Some(res) = stream.next().await {
        match res {
            Ok(rec) => log.append(rec)?,
            Err(e) => {
                let msg = format!("{e:#}");
                bar.println(format!("error: {msg}"));
                errors.push(msg);
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    drop(stream);
    let selected_by_id: HashMap<&str, &Query> =
        selected.iter().map(|q| (q.query_id.as_str(), q)).collect();
    // Records resumed from older results name their target from the dataset.
    let records: Vec<QueryRecord> = log
        .records()
        .iter()
        .filter_map(|r| {
            let q = selected_by_id.get(r.query_id.as_str())?;
            let mut r = r.clone();
            r.target_id = r.target_id.or(Some(q.target_id));
            r.target_label = r.target_label.or_else(|| Some(q.target_label.clone()));
            Some(r)
        })
        .collect();
    let out = cfg.out.clone();
    let (summary, _) =
        tokio::task::spawn_blocking(move || report::write_summary(&out, &records)).await??;
    Ok(EvalOutcome {
        summary,
        ran: ran - errors.len(),
        skipped,
        errors,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn usage_is_read_from_the_result_as_the_service_reports_it() {
        let job = json!({"status": "succeeded",
            "result": {"usage": {"vlm_calls": 3, "prompt_tokens": 5296, "completion_tokens": 68, "total_tokens": 5364}}});
        assert_eq!(usage_of(&job), (3, 5364));
        let top = json!({"usage": {"vlm_calls": 2, "total_tokens": 10}});
        assert_eq!(usage_of(&top), (2, 10));
        assert_eq!(usage_of(&json!({"trace": []})), (0, 0));
    }
}
