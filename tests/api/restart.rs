//! The real binary, killed and restarted: running jobs are resumed, never lost.

use crate::helpers::*;
use crate::spawned::{start_server, Server};
use serde_json::Value;
use std::time::{Duration, Instant};

fn start(data_dir: &std::path::Path, delay_ms: u64) -> Server {
    start_server(
        data_dir,
        &[("GROUNDER_PIPELINE", &format!("test:delay_ms={delay_ms}"))],
    )
}

async fn wait_status(c: &reqwest::Client, url: &str, want: &str) -> Value {
    let t = Instant::now();
    loop {
        let j: Value = get_json_at(c, url).await;
        if j["status"] == want || t.elapsed() > Duration::from_secs(20) {
            return j;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test]
async fn killed_and_terminated_servers_resume_running_jobs() {
    let dir = tempfile::tempdir().unwrap();
    let c = client();
    let mut s = start(dir.path(), 1500);
    let sid = upload_tiny_scene_to(&c, &s.base, 3).await;
    let jid = submit_job(&c, &s.base, &sid, "the bed").await;
    let qid = submit_job(&c, &s.base, &sid, "the desk").await;
    let j = wait_status(&c, &format!("{}/v1/jobs/{jid}", s.base), "running").await;
    assert_eq!(j["status"], "running");

    // SIGKILL mid-run: on restart the job runs again (attempt 2) and the queued one too.
    s.signal("-KILL");
    let mut s = start(dir.path(), 100);
    let j = wait_status(&c, &format!("{}/v1/jobs/{jid}", s.base), "succeeded").await;
    assert_eq!(
        (j["status"].as_str(), j["attempts"].as_i64()),
        (Some("succeeded"), Some(2)),
        "{j}"
    );
    let q = wait_status(&c, &format!("{}/v1/jobs/{qid}", s.base), "succeeded").await;
    assert_eq!(q["status"], "succeeded", "nothing queued is lost");
    assert!(q["result"]["box"]["min"].is_array());

    // SIGTERM mid-run: graceful; the job is left queued, not half-written, and the attempt
    // is not counted.
    s.signal("-KILL");
    let mut s = start(dir.path(), 3000);
    let tid = submit_job(&c, &s.base, &sid, "the lamp").await;
    wait_status(&c, &format!("{}/v1/jobs/{tid}", s.base), "running").await;
    s.signal("-TERM");
    let log = s.log_tail();
    assert!(
        log.contains("queued again"),
        "a graceful stop requeues: {log}"
    );
    let store = grounder::store::Store::open(dir.path()).await.unwrap();
    let rec = store.get_job(&tid).await.unwrap().unwrap();
    assert_eq!(
        (rec.status.as_str(), rec.attempts, rec.result.is_none()),
        ("queued", 0, true)
    );
    drop(store);

    // A job that keeps dying with the process is given up after 3 attempts, with a reason.
    for _ in 0..3 {
        s = start(dir.path(), 5000);
        let j = wait_status(&c, &format!("{}/v1/jobs/{tid}", s.base), "running").await;
        if j["status"] != "running" {
            break;
        }
        s.signal("-KILL");
    }
    let mut s = start(dir.path(), 100);
    let j = get_json_at(&c, &format!("{}/v1/jobs/{tid}", s.base)).await;
    assert_eq!(
        (j["status"].as_str(), j["error"]["code"].as_str()),
        (Some("failed"), Some("too_many_attempts")),
        "{j}"
    );
    s.signal("-TERM");
}

/// A stop that comes the moment the service has printed its address (an orchestrator
/// stopping a replica that has just started) is a graceful one: the process ends on its
/// own with status 0, not killed by the signal, and logs that it is shutting down.
#[test]
fn a_sigterm_as_soon_as_the_address_is_printed_is_a_graceful_stop() {
    for _ in 0..5 {
        let dir = tempfile::tempdir().unwrap();
        let mut s = start(dir.path(), 100);
        let status = s.signal("-TERM");
        let log = s.log_tail();
        assert!(status.success(), "{status}; log:\n{log}");
        assert!(log.contains("shutting down"), "{log}");
    }
}

/// A graceful stop waits for the requests in flight (here an upload whose body stalls); a
/// second SIGTERM does not: the process ends at once, with status 1.
#[tokio::test]
async fn a_second_sigterm_ends_a_stop_that_waits_for_a_request() {
    use tokio::io::AsyncWriteExt;
    let dir = tempfile::tempdir().unwrap();
    let mut s = start(dir.path(), 100);
    let addr = s.base.trim_start_matches("http://").to_string();
    let mut slow = tokio::net::TcpStream::connect(&addr).await.unwrap();
    slow.write_all(
        b"POST /v1/scenes HTTP/1.1\r\nHost: test\r\nContent-Type: application/x-tar\r\nContent-Length: 100000\r\n\r\n",
    )
    .await
    .unwrap();
    slow.write_all(&[0u8; 512]).await.unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    s.send("-TERM");
    tokio::time::sleep(Duration::from_millis(1000)).await;
    assert!(
        s.child.try_wait().unwrap().is_none(),
        "the graceful stop waits for the upload in flight"
    );
    let status = s.signal("-TERM");
    let log = s.log_tail();
    assert_eq!(status.code(), Some(1), "{status}; log:\n{log}");
    assert!(log.contains("a second stop signal"), "{log}");
    drop(slow);
}
