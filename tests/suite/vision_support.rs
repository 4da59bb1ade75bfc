//! Shared helpers of the vision tests.
#![allow(dead_code)]

use std::path::PathBuf;

use grounder::vision::runtime;

/// Load ONNX Runtime the way the service does, failing (not skipping) when it is missing.
pub fn require_runtime() {
    if let Err(e) = runtime::environment() {
        panic!(
            "ONNX Runtime is needed by this test: {e:#}\nRun scripts/setup-ort.sh first (CI does)."
        );
    }
}

/// A file of the repo.
pub fn repo_path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// Intersection over union of two boxes.
pub fn iou(a: [f32; 4], b: [f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let i = iw * ih;
    i / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - i)
}
