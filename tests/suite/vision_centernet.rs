//! The real CenterNet model on real photos, plus load-time error reporting.

use crate::vision_support;

use grounder::vision::{build_detector, DetectInput, VisionConfig};
use vision_support::{iou, repo_path, require_runtime};

fn cfg() -> VisionConfig {
    VisionConfig {
        model_dir: repo_path("models"),
        ..VisionConfig::default()
    }
}

fn detect(image: &str) -> Vec<grounder::vision::Detection> {
    require_runtime();
    let det = build_detector("centernet", &cfg()).expect("load centernet");
    let img = image::open(repo_path(image)).expect("read image").to_rgb8();
    det.detect(&DetectInput::image(&img)).expect("detect")
}

#[test]
fn coffee_has_a_cup_and_a_dining_table_where_they_are() {
    let dets = detect("tests/fixtures/vision/images/coffee.png");
    let cup = dets
        .iter()
        .find(|d| d.label == "cup")
        .expect("a cup is detected");
    // hand-labelled cup (with handle) in the 600x400 photo
    let cup_truth = [170.0, 18.0, 410.0, 290.0];
    assert!(iou(cup.bbox, cup_truth) > 0.6, "cup box {:?}", cup.bbox);
    assert!(cup.score >= 0.3);
    let table = dets
        .iter()
        .find(|d| d.label == "dining table")
        .expect("a dining table is detected");
    // the table is under the saucer: its box contains the cup's centre and is large
    let (cx, cy) = (290.0, 150.0);
    let b = table.bbox;
    assert!(
        b[0] < cx && cx < b[2] && b[1] < cy && cy < b[3],
        "table box {b:?}"
    );
    assert!(
        (b[2] - b[0]) * (b[3] - b[1]) > 0.25 * 600.0 * 400.0,
        "table box {b:?} too small"
    );
    // per-class NMS: no two boxes of one class overlap strongly
    for (i, a) in dets.iter().enumerate() {
        for c in &dets[i + 1..] {
            assert!(
                a.label != c.label || iou(a.bbox, c.bbox) <= 0.5,
                "duplicates {a:?} {c:?}"
            );
        }
    }
}

#[test]
fn astronaut_is_a_person() {
    let dets = detect("tests/fixtures/vision/images/astronaut.png");
    let best = dets.first().expect("something is detected");
    assert_eq!(best.label, "person");
    assert!(
        iou(best.bbox, [20.0, 14.0, 365.0, 512.0]) > 0.7,
        "person box {:?}",
        best.bbox
    );
}

#[test]
fn open_vocabulary_labels_map_to_coco_or_are_reported_unseen() {
    require_runtime();
    let det = build_detector("centernet", &cfg()).expect("load centernet");
    assert_eq!(det.vocabulary().len(), 80);
    assert_eq!(det.can_see("sofa").as_deref(), Some("couch"));
    assert_eq!(det.can_see("Monitor").as_deref(), Some("tv"));
    assert_eq!(det.can_see("table").as_deref(), Some("dining table"));
    assert_eq!(det.can_see("curtain"), None);
}

#[test]
fn bad_model_files_give_errors_naming_the_file() {
    require_runtime();
    let msg = |spec: &str| match build_detector(spec, &cfg()) {
        Ok(_) => panic!("{spec} should not load"),
        Err(e) => format!("{e:#}"),
    };
    let missing = msg("centernet:/nonexistent/model.onnx");
    assert!(
        missing.contains("/nonexistent/model.onnx") && missing.contains("not found"),
        "{missing}"
    );

    let dir = tempfile::tempdir().expect("tempdir");
    let broken = dir.path().join("broken.onnx");
    std::fs::write(&broken, b"this is not an onnx file").expect("write");
    let m = msg(&format!("centernet:{}", broken.display()));
    assert!(
        m.contains("broken.onnx") && m.contains("cannot load"),
        "{m}"
    );

    let yolo = repo_path("tests/fixtures/vision/yolo-signature.onnx");
    let m = msg(&format!("centernet:{}", yolo.display()));
    assert!(
        m.contains("yolo-signature.onnx") && m.contains("wrong signature"),
        "{m}"
    );

    let m = msg(&format!(
        "yolo:{}",
        repo_path("models/centernet-coco80.onnx").display()
    ));
    assert!(
        m.contains("centernet-coco80.onnx") && m.contains("wrong signature"),
        "{m}"
    );

    assert!(msg("nosuchdetector").contains("unknown detector"));
}
