//! An object store that cannot be reached fails a request within the bounds the
//! `storage_*` settings give (connect and request timeouts, retries and their deadline),
//! not after the client's default minutes of retries: a job on a replica whose bucket
//! refuses connections fails `storage_error` within them, and a bucket endpoint that
//! accepts connections but never answers fails a listing within them.

use std::time::{Duration, Instant};

use grounder::config::Config;
use grounder::storage::{RemoteLimits, Storage};

use crate::helpers::{test_config, TestApp};
use crate::storage::{copy_db, Moto};

/// Short bounds: a failing request ends within 2 + 2 s.
fn limited(dir: &std::path::Path) -> Config {
    Config {
        storage: "s3://unreachable/p".into(),
        storage_connect_timeout_secs: 1,
        storage_request_timeout_secs: 2,
        storage_retries: 2,
        storage_retry_timeout_secs: 2,
        ..test_config(dir.to_path_buf())
    }
}

/// Slack for two loaded cores on top of a bound.
const SLACK: Duration = Duration::from_secs(3);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_fails_storage_error_within_the_bounds_when_the_bucket_refuses_connections() {
    let moto = Moto::start().await;
    moto.create_bucket("unreachable").await;
    let env = moto.env();
    let (dir_a, dir_b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    // Replica A stores a scene in the bucket; replica B (a copy of A's database, an empty
    // data dir) starts while the bucket is up, then the bucket goes away.
    let a = TestApp::spawn_with_env(limited(dir_a.path()), &env).await;
    let sid = a.upload_tiny_scene(3).await;
    a.stop().await;
    copy_db(dir_a.path(), dir_b.path());
    let cfg = limited(dir_b.path());
    let bound = cfg.remote_limits().worst_case();
    let b = TestApp::spawn_with_env(cfg, &env).await;
    let endpoint = env
        .iter()
        .find(|(k, _)| k == "AWS_ENDPOINT_URL")
        .map(|(_, v)| v.trim_start_matches("http://").to_string())
        .unwrap();
    drop(moto);
    assert!(
        std::net::TcpStream::connect(&endpoint).is_err(),
        "the endpoint still accepts connections"
    );

    let t = Instant::now();
    let id = b.submit_job(&sid, "the chair").await;
    let job = b.wait_job(&id, bound + SLACK * 4).await;
    let took = t.elapsed();
    assert_eq!(job["status"], "failed", "{job}");
    assert_eq!(job["error"]["code"], "storage_error", "{job}");
    let detail = job["error"]["detail"].as_str().unwrap_or("");
    assert!(detail.contains("object store"), "{detail}");
    assert!(
        took < bound + SLACK,
        "the job failed {took:?} after it was created (bound {bound:?})"
    );
    eprintln!("job failed storage_error {took:?} after creation (bound {bound:?})");
    b.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bucket_that_never_answers_fails_a_request_within_the_request_timeout() {
    // Accepts connections (the kernel's backlog) and never answers.
    let silent = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let env: Vec<(String, String)> = [
        (
            "AWS_ENDPOINT_URL",
            format!("http://{}", silent.local_addr().unwrap()),
        ),
        ("AWS_REGION", "us-east-1".into()),
        ("AWS_ACCESS_KEY_ID", "test".into()),
        ("AWS_SECRET_ACCESS_KEY", "test".into()),
        ("AWS_ALLOW_HTTP", "true".into()),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    let dir = tempfile::tempdir().unwrap();
    let limits = RemoteLimits {
        connect_timeout: Duration::from_secs(1),
        request_timeout: Duration::from_secs(1),
        retries: 1,
        retry_timeout: Duration::from_secs(1),
    };
    let storage = Storage::open_with("s3://silent/p", dir.path(), 1 << 20, &env, &limits)
        .await
        .expect("open storage");
    let t = Instant::now();
    let listed = storage.remote().expect("a bucket").list("scenes").await;
    let took = t.elapsed();
    let e = listed.expect_err("a listing from a silent endpoint succeeded");
    assert!(e.to_string().contains("cannot list"), "{e}");
    assert!(
        took >= limits.request_timeout && took < limits.worst_case() + SLACK,
        "the listing failed after {took:?} (timeout {:?}, bound {:?})",
        limits.request_timeout,
        limits.worst_case()
    );
    drop(silent);
}
