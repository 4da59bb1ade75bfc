//! `max_memory_mb`: beyond the bound, jobs wait in the queue instead of starting.

use crate::helpers::*;
use serde_json::Value;
use std::time::Duration;
use time::format_description::well_known::Rfc3339;
use time::OffsetDateTime;

fn at(job: &Value, field: &str) -> OffsetDateTime {
    let s = job[field]
        .as_str()
        .unwrap_or_else(|| panic!("{field} in {job}"));
    OffsetDateTime::parse(s, &Rfc3339).unwrap()
}

/// Two jobs on a server with two workers and `max_memory_mb`; the jobs' records once
/// both ended, and whether the second was ever seen queued while the first ran.
async fn two_jobs(max_memory_mb: u64) -> (Value, Value, bool) {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.workers = 2;
    cfg.pipeline = "test:delay_ms=700".into();
    cfg.max_memory_mb = max_memory_mb;
    let app = TestApp::spawn_with(cfg).await;
    let scene = app.upload_tiny_scene(3).await;
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .json(&serde_json::json!({"scene_id": scene, "queries": ["the chair", "the table"]}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let b: Value = r.json().await.unwrap();
    let ids: Vec<String> = b["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["id"].as_str().unwrap().to_string())
        .collect();
    let mut waited = false;
    let start = std::time::Instant::now();
    loop {
        let (_, a) = app.get_json(&format!("/v1/jobs/{}", ids[0])).await;
        let (_, b) = app.get_json(&format!("/v1/jobs/{}", ids[1])).await;
        let (sa, sb) = (a["status"].as_str().unwrap(), b["status"].as_str().unwrap());
        if (sa == "running" && sb == "queued") || (sb == "running" && sa == "queued") {
            waited = true;
        }
        if sa == "succeeded" && sb == "succeeded" {
            app.stop().await;
            return (a, b, waited);
        }
        assert!(
            !matches!(sa, "failed" | "canceled") && !matches!(sb, "failed" | "canceled"),
            "{a}\n{b}"
        );
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "jobs never ended"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test]
async fn under_a_tiny_memory_bound_the_second_job_waits_until_the_first_ends() {
    let (a, b, waited) = two_jobs(1).await;
    let (first, second) = if at(&a, "started_at") <= at(&b, "started_at") {
        (a, b)
    } else {
        (b, a)
    };
    assert!(
        waited,
        "the second job was never seen queued beside a running one"
    );
    assert!(
        at(&second, "started_at") >= at(&first, "finished_at"),
        "the second job started before the first ended:\n{first}\n{second}"
    );
}

#[tokio::test]
async fn without_a_memory_bound_two_workers_run_two_jobs_at_once() {
    // The control: the same two jobs overlap when nothing bounds memory.
    let (a, b, _) = two_jobs(0).await;
    let overlap = at(&a, "started_at") < at(&b, "finished_at")
        && at(&b, "started_at") < at(&a, "finished_at");
    assert!(overlap, "the jobs did not run together:\n{a}\n{b}");
}
