//! The watchdog: a worker that dies half-way through a job leaves no row `running`, the
//! live-worker gauge counts it out, and `/readyz` is not ready once no worker is left.

use crate::helpers::{client, submit_job, test_config, upload_tiny_scene_to};
use grounder::startup::Application;
use serde_json::Value;
use std::time::{Duration, Instant};

fn gauge(metrics: &str, name: &str) -> Option<f64> {
    metrics
        .lines()
        .find(|l| l.starts_with(name) && !l.starts_with('#'))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
}

#[tokio::test]
async fn a_dead_worker_fails_its_job_and_makes_the_service_not_ready() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.workers = 1;
    cfg.pipeline = "test:delay_ms=30000".into();
    let app = Application::build(cfg).await.expect("build");
    let jobs = app.jobs();
    let base = format!("http://{}", app.local_addr().expect("addr"));
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(async move {
        let _ = app
            .run_until(async move {
                let _ = stopped.await;
            })
            .await;
    });
    let c = client();
    let text = |p: &'static str| {
        let c = c.clone();
        let url = format!("{base}{p}");
        async move {
            let r = c.get(url).send().await.expect("get");
            (r.status().as_u16(), r.text().await.unwrap_or_default())
        }
    };
    let (s, m) = text("/metrics").await;
    assert_eq!(s, 200);
    assert_eq!(gauge(&m, "grounder_workers_alive"), Some(1.0), "{m}");
    assert_eq!(text("/readyz").await.0, 200);

    let scene = upload_tiny_scene_to(&c, &base, 3).await;
    let job = submit_job(&c, &base, &scene, "the chair").await;
    let job_url = format!("{base}/v1/jobs/{job}");
    let get_job = || {
        let (c, u) = (c.clone(), job_url.clone());
        async move {
            let r = c.get(u).send().await.expect("get");
            r.json::<Value>().await.expect("json")
        }
    };
    let t = Instant::now();
    while get_job().await["status"] != "running" {
        assert!(t.elapsed() < Duration::from_secs(10), "the job never ran");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(jobs.abort_worker_for_test(), "a worker to stop");

    // The watchdog fails the job whose worker is gone, within seconds.
    let t = Instant::now();
    let j = loop {
        let j = get_job().await;
        if j["status"] != "running" || t.elapsed() > Duration::from_secs(10) {
            break j;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(j["status"], "failed", "{j}");
    assert_eq!(j["error"]["code"], "internal", "{j}");
    let (_, m) = text("/metrics").await;
    assert_eq!(gauge(&m, "grounder_workers_alive"), Some(0.0), "{m}");
    let (s, body) = text("/readyz").await;
    assert_eq!(s, 503, "{body}");
    assert!(body.contains("worker"), "{body}");
    assert_eq!(text("/healthz").await.0, 200, "the process itself lives");
    let _ = stop.send(());
    let _ = server.await;
}
