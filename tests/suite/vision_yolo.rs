//! YOLO adapter on a same-signature fixture (tests/fixtures/vision/yolo-signature.onnx, built
//! by scripts/make_vision_fixtures.py): letterbox values and box mapping checked numerically.

use crate::vision_support;

use grounder::vision::yolo::letterbox;
use grounder::vision::{build_detector, DetectInput, Detection, VisionConfig};
use image::{Rgb, RgbImage};
use vision_support::{repo_path, require_runtime};

/// 128x64: left half red, right half blue.
fn test_image() -> RgbImage {
    RgbImage::from_fn(128, 64, |x, _| {
        if x < 64 {
            Rgb([255, 0, 0])
        } else {
            Rgb([0, 0, 255])
        }
    })
}

fn spec() -> String {
    format!(
        "yolo:{}",
        repo_path("tests/fixtures/vision/yolo-signature.onnx").display()
    )
}

#[test]
fn letterbox_scales_centres_and_pads_with_114() {
    let (data, lb) = letterbox(&test_image(), 64, 64).expect("letterbox");
    assert_eq!((lb.scale, lb.pad_x, lb.pad_y), (0.5, 0, 16));
    let at = |c: usize, y: usize, x: usize| data[c * 64 * 64 + y * 64 + x];
    let grey = 114.0 / 255.0;
    assert!(
        (at(1, 2, 10) - grey).abs() < 1e-6
            && (at(0, 15, 40) - grey).abs() < 1e-6
            && (at(2, 48, 5) - grey).abs() < 1e-6
    );
    assert_eq!(
        (at(0, 16, 10), at(1, 16, 10), at(2, 16, 10)),
        (1.0, 0.0, 0.0)
    );
    assert_eq!((at(0, 47, 50), at(2, 47, 50)), (0.0, 1.0));
    // input box back to original pixels
    assert_eq!(
        lb.to_original([16.0, 24.0, 48.0, 40.0]),
        [32.0, 16.0, 96.0, 48.0]
    );
}

fn close(d: &Detection, label: &str, score: f32, bbox: [f32; 4]) -> bool {
    d.label == label
        && (d.score - score).abs() < 1e-4
        && d.bbox.iter().zip(bbox).all(|(a, b)| (a - b).abs() < 1e-3)
}

#[test]
fn fixture_detections_come_back_in_original_pixels() {
    require_runtime();
    let cfg = VisionConfig {
        min_score: 0.3,
        ..VisionConfig::default()
    };
    let det = build_detector(&spec(), &cfg).expect("load yolo fixture");
    assert_eq!(det.vocabulary(), vec!["person", "chair", "sofa"]);
    assert_eq!(det.can_see("couch").as_deref(), Some("sofa"));
    assert_eq!(det.can_see("table"), None);
    let img = test_image();
    let dets = det.detect(&DetectInput::image(&img)).expect("detect");
    assert_eq!(dets.len(), 3, "{dets:?}");
    // scores are the fixture's readings of letterboxed pixels: red/blue = 1.0, padding = 114/255
    assert!(
        close(&dets[0], "person", 1.0, [32.0, 16.0, 96.0, 48.0]),
        "{:?}",
        dets[0]
    );
    assert!(
        close(&dets[1], "chair", 1.0, [8.0, 8.0, 40.0, 56.0]),
        "{:?}",
        dets[1]
    );
    assert!(
        close(&dets[2], "sofa", 114.0 / 255.0, [80.0, 4.0, 120.0, 28.0]),
        "{:?}",
        dets[2]
    );
    // anchor 3 (a lower-scoring near-duplicate person) was removed by NMS

    let strict = build_detector(
        &spec(),
        &VisionConfig {
            min_score: 0.5,
            ..VisionConfig::default()
        },
    )
    .expect("load");
    let dets = strict.detect(&DetectInput::image(&img)).expect("detect");
    assert_eq!(
        dets.iter().map(|d| d.label.as_str()).collect::<Vec<_>>(),
        vec!["person", "chair"]
    );
}
