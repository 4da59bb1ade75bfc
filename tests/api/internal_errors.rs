//! A server-side failure answers a generic 5xx with an id; the cause goes to the log with
//! the same id, never to the caller.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

#[tokio::test]
async fn a_failing_store_answers_a_generic_500_and_logs_the_cause_with_its_id() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data-dir-SECRETPATH");
    let log_path = dir.path().join("stderr.log");
    let log = std::fs::File::create(&log_path).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_grounder"))
        .args(["serve", "--addr", "127.0.0.1:0", "--data-dir"])
        .arg(&data)
        .env("GROUNDER_PIPELINE", "test:delay_ms=10")
        .env("GROUNDER_DETECTOR", "none")
        .env("GROUNDER_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::from(log))
        .spawn()
        .expect("start grounder serve");
    let stdout = child.stdout.take().expect("stdout");
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line).unwrap();
    let base = line.trim().trim_start_matches("listening on ").to_string();
    let check = async {
        // The scenes folder becomes a plain file: storing any scene now fails inside.
        let scenes = data.join("scenes");
        let _ = std::fs::remove_dir_all(&scenes);
        std::fs::write(&scenes, b"not a folder").unwrap();
        let (tar, _) = crate::agent_fixture::scene_tar();
        let r = crate::helpers::client()
            .post(format!("{base}/v1/scenes"))
            .header("Content-Type", "application/x-tar")
            .body(std::fs::read(tar).unwrap())
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 500);
        let body = r.text().await.unwrap();
        let v: serde_json::Value = serde_json::from_str(&body).unwrap();
        let detail = v["detail"].as_str().unwrap_or_default().to_string();
        let id = detail
            .strip_prefix("internal error, id ")
            .unwrap_or_else(|| panic!("not the generic detail: {body}"))
            .to_string();
        assert!(id.len() >= 16, "{body}");
        for leak in ["SECRETPATH", "os error", "scenes", "Io(", "::", "directory"] {
            assert!(!body.contains(leak), "{leak:?} in the body: {body}");
        }
        // The log has the cause, at error level, with the same id.
        let t = std::time::Instant::now();
        loop {
            let log = std::fs::read_to_string(&log_path).unwrap_or_default();
            if let Some(l) = log.lines().find(|l| l.contains(&id)) {
                assert!(l.contains("ERROR"), "{l}");
                assert!(l.contains("os error") || l.contains("SECRETPATH"), "{l}");
                break;
            }
            assert!(t.elapsed() < Duration::from_secs(10), "no log line: {log}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    };
    let outcome = futures::FutureExt::catch_unwind(std::panic::AssertUnwindSafe(check)).await;
    let _ = child.kill();
    let _ = child.wait();
    if let Err(p) = outcome {
        std::panic::resume_unwind(p);
    }
}
