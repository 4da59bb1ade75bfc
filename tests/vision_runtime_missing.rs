//! A missing runtime library is reported (status and build errors), never a panic.
//! Its own test binary: the library must not have been loaded in this process.

use std::path::PathBuf;

use grounder::vision::{build_detector, build_segmenter, runtime, VisionConfig};

#[test]
fn missing_library_is_reported_with_its_path() {
    runtime::set_configured_path(Some(PathBuf::from(
        "/nonexistent/ort/libonnxruntime.so.1.31.1",
    )));
    let st = runtime::status();
    let runtime::RuntimeStatus::Missing { message } = st else {
        panic!("runtime should be missing: {st:?}")
    };
    assert!(
        message.contains("/nonexistent/ort/libonnxruntime.so.1.31.1"),
        "{message}"
    );
    assert!(message.contains("setup-ort.sh"), "{message}");

    let cfg = VisionConfig {
        model_dir: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models"),
        ..Default::default()
    };
    let err = build_detector("centernet", &cfg)
        .err()
        .expect("no runtime, no detector");
    assert!(
        format!("{err:#}").contains("ONNX Runtime library not found"),
        "{err:#}"
    );
    // model-free components still work
    assert!(build_detector("oracle", &cfg).is_ok());
    assert!(build_segmenter("depth", &cfg).is_ok());
    assert!(build_segmenter("box", &cfg).is_ok());
}

/// The service still starts without the runtime library, stays live, and `/readyz` says
/// which file is missing (503 problem+json) instead of the process dying.
#[tokio::test]
async fn serve_without_runtime_is_live_but_not_ready() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};

    let dir = tempfile::tempdir().expect("tempdir");
    let missing = "/nonexistent/ort-for-readyz/libonnxruntime.so.1.31.1";
    let mut child = Command::new(env!("CARGO_BIN_EXE_grounder"))
        .args(["serve", "--addr", "127.0.0.1:0", "--data-dir"])
        .arg(dir.path().join("data"))
        .env("ORT_DYLIB_PATH", missing)
        .env("GROUNDER_DETECTOR", "centernet")
        .env("GROUNDER_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start grounder serve");
    let stdout = child.stdout.take().expect("piped stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if let Some(url) = line.strip_prefix("listening on ") {
                let _ = tx.send(url.trim().to_string());
            }
        }
    });
    let url = rx.recv_timeout(std::time::Duration::from_secs(60));
    let check = async {
        let url = url.expect("serve printed its address");
        let http = reqwest::Client::new();
        let live = http
            .get(format!("{url}/healthz"))
            .send()
            .await
            .expect("healthz");
        assert_eq!(live.status(), 200);
        let ready = http
            .get(format!("{url}/readyz"))
            .send()
            .await
            .expect("readyz");
        assert_eq!(ready.status(), 503);
        let ct = ready
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .unwrap_or_default()
            .to_string();
        assert!(ct.starts_with("application/problem+json"), "{ct}");
        let body: serde_json::Value = ready.json().await.expect("problem JSON");
        assert_eq!(body["code"], "not_ready", "{body}");
        let detail = body["detail"].as_str().unwrap_or_default();
        assert!(detail.contains(missing), "{detail}");
    };
    let outcome = futures::FutureExt::catch_unwind(std::panic::AssertUnwindSafe(check)).await;
    let _ = child.kill();
    let _ = child.wait();
    if let Err(p) = outcome {
        std::panic::resume_unwind(p);
    }
}
