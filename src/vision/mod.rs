//! Local vision models (ONNX Runtime) and model-free adapters: detectors and segmenters.
//!
//! Detectors: `centernet` (vendored COCO-80 model, default), `yolo` (Ultralytics detect
//! exports), `oracle` (boxes from ground-truth instance masks; evaluation only).
//! Segmenters: `depth` (default, model-free, for posed RGB-D), `box`, `sam` (encoder +
//! decoder ONNX pair). Build them with [`build_detector`] / [`build_segmenter`]; both are
//! `Send + Sync` and meant to be created once and shared (`Arc`).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{bail, Result};
use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::geometry::camera::{DepthMap, FrameCamera};
use crate::geometry::mask::Mask;

pub mod box_seg;
pub mod candidates;
pub mod candidates_cli;
pub mod centernet;
pub mod cli;
pub mod common;
pub mod depth_seg;
pub mod oracle;
pub mod runtime;
pub mod sam;
pub mod segment_cli;
pub mod synonyms;
pub mod yolo;

/// One 2D detection in the original image's pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    pub label: String,
    pub score: f32,
    /// [x1, y1, x2, y2] in pixels of the image the detector was given.
    #[serde(rename = "box")]
    pub bbox: [f32; 4],
}

/// Settings shared by every vision component (file section `[vision]`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VisionConfig {
    /// Detector spec (key `detector`), e.g. "centernet", "yolo:/m.onnx", "oracle".
    pub detector: String,
    /// Segmenter spec (key `segmenter`), e.g. "depth", "box", "sam:enc.onnx,dec.onnx".
    pub segmenter: String,
    /// Path of libonnxruntime (else `ORT_DYLIB_PATH`, else ./.ort/).
    pub ort_dylib: Option<PathBuf>,
    /// Folder holding the vendored models (centernet-coco80.onnx, coco80.txt).
    pub model_dir: PathBuf,
    /// Minimum detection score kept.
    pub min_score: f32,
    /// IoU above which a lower-scoring box of the same class is suppressed.
    pub nms_iou: f32,
    /// Threads one inference may use.
    pub intra_threads: usize,
    /// Sessions per model = inferences that may run at the same time.
    pub concurrency: usize,
}

impl Default for VisionConfig {
    fn default() -> Self {
        Self {
            detector: "centernet".into(),
            segmenter: "depth".into(),
            ort_dylib: None,
            model_dir: PathBuf::from("models"),
            min_score: 0.3,
            nms_iou: 0.5,
            intra_threads: 2,
            concurrency: 1,
        }
    }
}

impl VisionConfig {
    pub(crate) fn session_options(&self) -> runtime::SessionOptions {
        runtime::SessionOptions {
            intra_threads: self.intra_threads.max(1),
            sessions: self.concurrency.max(1),
        }
    }
}

/// Per-pixel ground-truth instance ids (FORMATS §1a `instance/<frame>.png`), colour- or
/// depth-sized; 0 = none.
#[derive(Debug, Clone, PartialEq)]
pub struct InstanceMask {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u16>,
}

/// What a detector gets for one frame.
#[derive(Debug, Clone, Copy)]
pub struct DetectInput<'a> {
    /// The decoded colour image; boxes come back in its pixels.
    pub color: &'a RgbImage,
    /// Ground-truth instance ids (oracle detector only).
    pub instances: Option<&'a InstanceMask>,
    /// Instance id → label (oracle detector only).
    pub labels: Option<&'a HashMap<u32, String>>,
    /// A stable number for this frame (e.g. its index); seeds the oracle's miss/jitter.
    pub frame_key: u64,
}

impl<'a> DetectInput<'a> {
    /// Input with just a colour image.
    pub fn image(color: &'a RgbImage) -> Self {
        Self {
            color,
            instances: None,
            labels: None,
            frame_key: 0,
        }
    }
}

/// A 2D object detector.
pub trait Detector: Send + Sync {
    /// Short name with its model, for traces and the database (e.g. "centernet").
    fn name(&self) -> String;
    /// The classes it can report; empty when open (oracle: whatever the scene labels say).
    fn vocabulary(&self) -> Vec<String>;
    /// The detector class for an open-vocabulary label; `None` = "detector cannot see
    /// this class".
    fn can_see(&self, label: &str) -> Option<String> {
        synonyms::map_to_vocabulary(label, &self.vocabulary())
    }
    /// Detections above the configured score, after per-class NMS, in `input.color` pixels.
    fn detect(&self, input: &DetectInput<'_>) -> Result<Vec<Detection>>;
    /// True when it needs ground-truth instance masks (the API refuses such a detector for
    /// scenes without them).
    fn needs_instances(&self) -> bool {
        false
    }
}

/// `detector = "vlm"`: no local detector. Indexing finds no detections (pre-selection
/// samples frames evenly) and the pipeline asks the VLM for the target's box in the image
/// it chose.
pub struct VlmBoxes;

impl Detector for VlmBoxes {
    fn name(&self) -> String {
        "vlm".into()
    }
    fn vocabulary(&self) -> Vec<String> {
        Vec::new()
    }
    fn can_see(&self, _label: &str) -> Option<String> {
        None
    }
    fn detect(&self, _input: &DetectInput<'_>) -> Result<Vec<Detection>> {
        Ok(Vec::new())
    }
}

/// What a segmenter gets for one frame.
#[derive(Debug, Clone, Copy)]
pub struct SegmentInput<'a> {
    pub color: &'a RgbImage,
    pub depth: &'a DepthMap,
    pub camera: &'a FrameCamera,
}

/// Box → mask at colour resolution.
pub trait Segmenter: Send + Sync {
    /// Short name (e.g. "depth").
    fn name(&self) -> String;
    /// Mask of the object inside `bbox` ([x1, y1, x2, y2], colour pixels).
    fn segment(&self, input: &SegmentInput<'_>, bbox: [f32; 4]) -> Result<Mask>;
}

fn split_spec(spec: &str) -> (&str, &str) {
    match spec.split_once(':') {
        Some((k, rest)) => (k.trim(), rest.trim()),
        None => (spec.trim(), ""),
    }
}

/// Build a detector from a spec: "centernet", "centernet:/path.onnx", "yolo:/path.onnx",
/// "oracle", "oracle:miss=0.1,jitter=0.05,seed=1". Model errors name the file.
pub fn build_detector(spec: &str, cfg: &VisionConfig) -> Result<Arc<dyn Detector>> {
    let (kind, arg) = split_spec(spec);
    if let Some(p) = &cfg.ort_dylib {
        runtime::set_configured_path(Some(p.clone()));
    }
    Ok(match kind {
        "centernet" => {
            if arg.is_empty() {
                // The configured folder's copy when it has one, else the copy in the binary.
                let model = cfg.model_dir.join(centernet::MODEL_FILE);
                if model.is_file() {
                    Arc::new(centernet::CenterNet::load(&model, cfg)?)
                } else {
                    tracing::info!(
                        "{} not found; using the detector model embedded in the binary",
                        model.display()
                    );
                    Arc::new(centernet::CenterNet::embedded(cfg)?)
                }
            } else {
                Arc::new(centernet::CenterNet::load(&PathBuf::from(arg), cfg)?)
            }
        }
        "yolo" => {
            if arg.is_empty() {
                bail!("the yolo detector needs a model path: yolo:/path/to/model.onnx");
            }
            Arc::new(yolo::Yolo::load(&PathBuf::from(arg), cfg)?)
        }
        "oracle" => Arc::new(oracle::OracleDetector::from_spec(arg)?),
        "vlm" => Arc::new(VlmBoxes),
        other => bail!("unknown detector `{other}` (expected centernet, yolo, oracle or vlm)"),
    })
}

/// Build a segmenter from a spec: "depth" (options: "depth:edges=on"), "box",
/// "sam:encoder.onnx,decoder.onnx".
pub fn build_segmenter(spec: &str, cfg: &VisionConfig) -> Result<Arc<dyn Segmenter>> {
    let (kind, arg) = split_spec(spec);
    if let Some(p) = &cfg.ort_dylib {
        runtime::set_configured_path(Some(p.clone()));
    }
    Ok(match kind {
        "depth" => Arc::new(depth_seg::DepthSegmenter::from_spec(arg)?),
        "box" => Arc::new(box_seg::BoxSegmenter),
        "sam" => {
            let Some((enc, dec)) = arg.split_once(',') else {
                bail!("the sam segmenter needs two model paths: sam:encoder.onnx,decoder.onnx");
            };
            Arc::new(sam::Sam::load(
                &PathBuf::from(enc.trim()),
                &PathBuf::from(dec.trim()),
                cfg,
            )?)
        }
        other => bail!("unknown segmenter `{other}` (expected depth, box or sam)"),
    })
}
