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

/// Without the runtime library no detector can load: `serve` exits non-zero with the
/// reason (naming the missing file) instead of listening and failing every upload.
#[test]
fn serve_without_runtime_exits_with_the_reason() {
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = "/nonexistent/ort-for-serve/libonnxruntime.so.1.31.1";
    let out = Command::new(env!("CARGO_BIN_EXE_grounder"))
        .args(["serve", "--addr", "127.0.0.1:0", "--data-dir"])
        .arg(dir.path().join("data"))
        .env("ORT_DYLIB_PATH", missing)
        .env("GROUNDER_DETECTOR", "centernet")
        .env("GROUNDER_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("run grounder serve");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "serve must fail: {stdout} {stderr}");
    assert!(!stdout.contains("listening on"), "{stdout}");
    assert!(
        stderr.contains("detector \"centernet\" cannot be loaded") && stderr.contains(missing),
        "{stderr}"
    );
}
