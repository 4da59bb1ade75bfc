//! SAM adapter on same-signature fixtures (encoder + decoder built by
//! scripts/make_vision_fixtures.py): preprocessing and box→mask mapping checked numerically.

use crate::vision_support;

use grounder::geometry::camera::{DepthMap, FrameCamera, Intrinsics};
use grounder::geometry::mask::Mask;
use grounder::vision::sam::{preprocess, Sam};
use grounder::vision::{build_segmenter, SegmentInput, VisionConfig};
use image::{Rgb, RgbImage};
use nalgebra::Matrix4;
use vision_support::{repo_path, require_runtime};

fn paths() -> (std::path::PathBuf, std::path::PathBuf) {
    (
        repo_path("tests/fixtures/vision/sam-encoder-signature.onnx"),
        repo_path("tests/fixtures/vision/sam-decoder-signature.onnx"),
    )
}

fn camera(w: u32, h: u32) -> FrameCamera {
    let k = Intrinsics {
        fx: 100.0,
        fy: 100.0,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        width: w,
        height: h,
    };
    FrameCamera {
        color: k,
        depth: None,
        depth_size: (w, h),
        pose: Matrix4::identity(),
        align: Matrix4::identity(),
    }
}

#[test]
fn preprocessing_resizes_long_side_normalises_and_pads() {
    let img = RgbImage::from_pixel(200, 100, Rgb([255, 255, 255]));
    let (data, sx, sy) = preprocess(&img).expect("preprocess");
    assert_eq!((sx, sy), (5.12, 5.12));
    let plane = 1024 * 1024;
    let at = |c: usize, y: usize, x: usize| data[c * plane + y * 1024 + x];
    assert!((at(0, 0, 0) - (255.0 - 123.675) / 58.395).abs() < 1e-5);
    assert!((at(1, 511, 1023) - (255.0 - 116.28) / 57.12).abs() < 1e-5);
    assert!((at(2, 300, 700) - (255.0 - 103.53) / 57.375).abs() < 1e-5);
    assert_eq!((at(0, 512, 0), at(2, 1023, 1023)), (0.0, 0.0));
}

#[test]
fn encoder_sees_the_normalised_padded_image() {
    require_runtime();
    let (enc, dec) = paths();
    let sam = Sam::load(&enc, &dec, &VisionConfig::default()).expect("load sam fixtures");
    let img = RgbImage::from_pixel(200, 100, Rgb([255, 255, 255]));
    let (emb, _, _) = sam.embed(&img).expect("embed");
    assert_eq!(emb.len(), 256 * 64 * 64);
    // fixture: channel k = 16x16 mean of input channel k % 3
    assert!((emb[0] - (255.0 - 123.675) / 58.395).abs() < 1e-4);
    assert!((emb[64 * 64 + 31 * 64 + 63] - (255.0 - 116.28) / 57.12).abs() < 1e-4);
    assert!(emb[32 * 64].abs() < 1e-6, "padding rows must be zero");
}

#[test]
fn box_prompt_gives_the_best_mask_in_original_pixels() {
    require_runtime();
    let (enc, dec) = paths();
    let seg = build_segmenter(
        &format!("sam:{},{}", enc.display(), dec.display()),
        &VisionConfig::default(),
    )
    .expect("load");
    for (w, h, bbox) in [
        (200u32, 100u32, [40.0f32, 20.0, 120.0, 80.0]),
        (60, 150, [10.0, 30.0, 50.0, 140.0]),
    ] {
        let img = RgbImage::from_pixel(w, h, Rgb([90, 120, 30]));
        let depth = DepthMap::new(w, h, vec![1000; (w * h) as usize]);
        let cam = camera(w, h);
        let mask = seg
            .segment(
                &SegmentInput {
                    color: &img,
                    depth: &depth,
                    camera: &cam,
                },
                bbox,
            )
            .expect("segment");
        // the fixture's "box" mask wins only with corner labels 2 and 3; the shrunk mask
        // (index 0) or everything (index 2) would differ
        let truth = Mask::from_box(w, h, bbox);
        assert_eq!((mask.width, mask.height), (w, h));
        assert_eq!(
            mask.iou(&truth),
            1.0,
            "{w}x{h} {bbox:?}: {} vs {} pixels",
            mask.count(),
            truth.count()
        );
    }
}

#[test]
fn swapped_or_missing_models_are_named_in_errors() {
    require_runtime();
    let (enc, dec) = paths();
    let err = Sam::load(&dec, &enc, &VisionConfig::default())
        .err()
        .expect("swapped pair must fail");
    let m = format!("{err:#}");
    assert!(
        m.contains("sam-decoder-signature.onnx") && m.contains("wrong signature"),
        "{m}"
    );
    let err = build_segmenter(
        "sam:/nope/enc.onnx,/nope/dec.onnx",
        &VisionConfig::default(),
    )
    .err()
    .expect("missing");
    assert!(format!("{err:#}").contains("/nope/enc.onnx"));
    assert!(build_segmenter("sam:only-one.onnx", &VisionConfig::default()).is_err());
}
