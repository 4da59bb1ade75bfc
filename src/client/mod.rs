//! A small HTTP client of the service, used by `grounder ground` and `grounder demo`:
//! upload a scene, submit a job, follow it step by step (by polling `GET /v1/jobs/{id}`;
//! [`follow_job`] is the one place an events stream would plug in), print the box.

pub mod demo;
pub mod ground;

use anyhow::{bail, Context, Result};
use serde_json::{json, Value};
use std::path::Path;
use std::time::{Duration, Instant};

/// Base URL, optional key, HTTP client.
#[derive(Clone)]
pub struct Service {
    pub base: String,
    key: Option<String>,
    http: reqwest::Client,
}

/// A transport or protocol error (exit code 2), as opposed to a job that failed (exit 1).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Unreachable(pub String);

impl Service {
    pub fn new(base: &str, key: Option<String>) -> Self {
        Self {
            base: base.trim_end_matches('/').to_string(),
            key,
            http: reqwest::Client::new(),
        }
    }

    fn req(&self, m: reqwest::Method, path: &str) -> reqwest::RequestBuilder {
        let r = self.http.request(m, format!("{}{path}", self.base));
        match &self.key {
            Some(k) => r.bearer_auth(k),
            None => r,
        }
    }

    async fn json(&self, r: reqwest::RequestBuilder, what: &str) -> Result<Value> {
        let resp = r
            .send()
            .await
            .map_err(|e| Unreachable(format!("{what}: cannot reach {}: {e}", self.base)))?;
        let status = resp.status();
        let text = resp
            .text()
            .await
            .map_err(|e| Unreachable(format!("{what}: {e}")))?;
        if !status.is_success() {
            let detail = serde_json::from_str::<Value>(&text)
                .ok()
                .and_then(|v| v.get("detail").and_then(Value::as_str).map(str::to_string))
                .unwrap_or_else(|| text.chars().take(300).collect());
            return Err(Unreachable(format!("{what}: HTTP {status}: {detail}")).into());
        }
        serde_json::from_str(&text)
            .map_err(|_| Unreachable(format!("{what}: the answer is not JSON")).into())
    }

    pub async fn get(&self, path: &str) -> Result<Value> {
        self.json(self.req(reqwest::Method::GET, path), &format!("GET {path}"))
            .await
    }

    /// Upload a scene folder (packed as tar here) or archive (.tar, .tar.gz/.tgz, .zip);
    /// returns the scene id once it is ready.
    pub async fn upload(&self, path: &Path, timeout: Duration) -> Result<String> {
        let (body, ct) = if path.is_dir() {
            let name = path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| "scene".into());
            let p = path.to_path_buf();
            let body =
                tokio::task::spawn_blocking(move || crate::eval::runner::tar_scene(&p, &name))
                    .await??;
            (body, "application/x-tar")
        } else {
            let n = path.to_string_lossy().to_lowercase();
            let ct = if n.ends_with(".zip") {
                "application/zip"
            } else if n.ends_with(".tar.gz") || n.ends_with(".tgz") {
                "application/gzip"
            } else if n.ends_with(".tar") {
                "application/x-tar"
            } else {
                bail!("{}: not a folder, .tar, .tar.gz or .zip", path.display());
            };
            let body = tokio::fs::read(path)
                .await
                .with_context(|| format!("cannot read {}", path.display()))?;
            (body, ct)
        };
        let v = self
            .json(
                self.req(reqwest::Method::POST, "/v1/scenes")
                    .header(reqwest::header::CONTENT_TYPE, ct)
                    .body(body),
                "uploading the scene",
            )
            .await?;
        let id = v["id"]
            .as_str()
            .ok_or_else(|| Unreachable("the upload's answer has no id".into()))?
            .to_string();
        let start = Instant::now();
        loop {
            let s = self.get(&format!("/v1/scenes/{id}")).await?;
            match s["status"].as_str() {
                Some("ready") => return Ok(id),
                Some("failed") => bail!(
                    "scene {id} failed to index: {}",
                    s["error"].as_str().unwrap_or("")
                ),
                _ if start.elapsed() > timeout => {
                    bail!("scene {id} was not ready after {timeout:?}")
                }
                _ => tokio::time::sleep(Duration::from_millis(200)).await,
            }
        }
    }

    /// Submit a job; returns its id.
    pub async fn submit(&self, scene: &str, query: &str) -> Result<String> {
        let v = self
            .json(
                self.req(reqwest::Method::POST, "/v1/jobs")
                    .json(&json!({"scene_id": scene, "query": query})),
                "submitting the job",
            )
            .await?;
        Ok(v["id"]
            .as_str()
            .ok_or_else(|| Unreachable("the job's answer has no id".into()))?
            .to_string())
    }

    /// Follow a job to a terminal status, calling `on_step` once per new trace step; returns
    /// the final job. Reads the job's events stream (`/v1/jobs/{id}/events`: a `step` event
    /// per trace step, `done` with the job); when the stream cannot be opened or breaks off
    /// before `done`, polls the job instead, skipping the steps already shown.
    pub async fn follow_job(
        &self,
        id: &str,
        timeout: Duration,
        mut on_step: impl FnMut(&Value),
    ) -> Result<Value> {
        let start = Instant::now();
        let mut seen = 0usize;
        let streamed = tokio::time::timeout(timeout, self.stream_job(id, &mut seen, &mut on_step))
            .await
            .map_err(|_| anyhow::anyhow!("job {id} did not finish within {timeout:?}"))?;
        if let Some(job) = streamed {
            return Ok(job);
        }
        loop {
            let job = self.get(&format!("/v1/jobs/{id}")).await?;
            if let Some(trace) = job["trace"].as_array() {
                for s in trace.iter().skip(seen) {
                    on_step(s);
                }
                seen = seen.max(trace.len());
            }
            if matches!(
                job["status"].as_str(),
                Some("succeeded" | "failed" | "canceled")
            ) {
                return Ok(job);
            }
            if start.elapsed() > timeout {
                bail!("job {id} did not finish within {timeout:?}");
            }
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
    }

    /// The job from its events stream's `done` event, `None` when the stream could not be
    /// opened or ended first. `seen` counts the steps passed to `on_step`.
    async fn stream_job(
        &self,
        id: &str,
        seen: &mut usize,
        on_step: &mut impl FnMut(&Value),
    ) -> Option<Value> {
        use futures::StreamExt;
        let resp = self
            .req(reqwest::Method::GET, &format!("/v1/jobs/{id}/events"))
            .header("Accept", "text/event-stream")
            .send()
            .await
            .ok()
            .filter(|r| r.status().is_success())?;
        let mut body = resp.bytes_stream();
        let mut buf: Vec<u8> = Vec::new();
        let (mut event, mut data) = (String::new(), String::new());
        while let Some(chunk) = body.next().await {
            buf.extend_from_slice(&chunk.ok()?);
            while let Some(end) = buf.iter().position(|&b| b == b'\n') {
                let line: Vec<u8> = buf.drain(..=end).collect();
                let line = String::from_utf8_lossy(&line);
                let line = line.trim_end_matches(['\n', '\r']);
                if line.is_empty() {
                    // One event complete.
                    let value: Option<Value> = serde_json::from_str(&data).ok();
                    match (event.as_str(), value) {
                        ("step", Some(v)) => {
                            on_step(&v);
                            *seen += 1;
                        }
                        ("done", Some(v)) => return Some(v),
                        _ => {}
                    }
                    event.clear();
                    data.clear();
                } else if let Some(v) = line.strip_prefix("event:") {
                    event = v.trim().to_string();
                } else if let Some(v) = line.strip_prefix("data:") {
                    if !data.is_empty() {
                        data.push('\n');
                    }
                    data.push_str(v.strip_prefix(' ').unwrap_or(v));
                }
            }
        }
        None
    }
}

/// One line for a trace step: its name, time and the most telling output.
pub fn step_line(s: &Value) -> String {
    let name = s["step"].as_str().unwrap_or("?");
    let o = &s["outputs"];
    let what = match name {
        "query_analysis" => o["analysis"]["target_class"]
            .as_str()
            .map(|c| format!("target class {c:?}")),
        "preselection" => o["image_ids"]
            .as_array()
            .map(|a| format!("{} frames offered", a.len())),
        "stitching" => o["grids"].as_array().map(|a| format!("{} grids", a.len())),
        "image_selection" | "segmentation" => o["image_id"].as_str().map(|i| format!("image {i}")),
        "detection" => o["detections"]
            .as_array()
            .map(|a| format!("{} candidates", a.len())),
        "projection" => o["views_used"].as_u64().map(|v| format!("{v} views fused")),
        "reselection" => s["inputs"]["image_id"].as_str().map(|i| {
            let why = s["inputs"]["failure"].as_str().unwrap_or("?");
            format!("image {i} left out ({why})")
        }),
        _ => None,
    };
    let ms = s["ms"].as_f64().unwrap_or(0.0);
    match what {
        Some(w) => format!("  {name:<18} {ms:>8.0} ms  {w}"),
        None => format!("  {name:<18} {ms:>8.0} ms"),
    }
}

#[cfg(test)]
mod tests {
    use super::step_line;
    use serde_json::json;

    #[test]
    fn a_step_line_names_the_steps_most_telling_output() {
        let left = json!({"step": "reselection", "ms": 0.5,
            "inputs": {"image_id": "00031", "failure": "projection_failed"},
            "outputs": {"left_out": ["00031"]}});
        let line = step_line(&left);
        assert!(
            line.contains("image 00031 left out (projection_failed)"),
            "{line}"
        );
        let chosen =
            json!({"step": "image_selection", "ms": 12.0, "outputs": {"image_id": "00007"}});
        assert!(
            step_line(&chosen).ends_with("image 00007"),
            "{}",
            step_line(&chosen)
        );
        let other = json!({"step": "summary", "ms": 3.0, "outputs": {}});
        assert!(
            step_line(&other).trim_end().ends_with("ms"),
            "{}",
            step_line(&other)
        );
    }
}
