//! CenterNet (MobileNetV3, COCO-80): the vendored default detector.
//!
//! Input `tower_0/images:0` float32 [1, 512, 512, 3] NHWC RGB 0..255, the image resized (not
//! letterboxed); output `tower_0/detections` [1, 100, 6] = x1, y1, x2, y2 (input pixels),
//! score, class index. See models/PROVENANCE.md.

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use image::RgbImage;
use ort::value::Tensor;

use super::common::{clamp_box, nms_per_class, resize_rgb};
use super::runtime::OrtModel;
use super::{DetectInput, Detection, Detector, VisionConfig};

/// File name of the vendored model inside the model folder.
pub const MODEL_FILE: &str = "centernet-coco80.onnx";
/// File name of the class list next to it.
pub const CLASSES_FILE: &str = "coco80.txt";

/// The vendored model's bytes (8 MB), for [`CenterNet::embedded`].
static EMBEDDED_MODEL: &[u8] = include_bytes!("../../models/centernet-coco80.onnx");
const INPUT: &str = "tower_0/images:0";
const OUTPUT: &str = "tower_0/detections";
/// Network input side.
pub const SIZE: u32 = 512;

/// The CenterNet detector (one shared session pool).
pub struct CenterNet {
    model: OrtModel,
    classes: Vec<String>,
    min_score: f32,
    nms_iou: f32,
}

impl CenterNet {
    /// Load the model and its class list (`coco80.txt` beside the model, else the vendored copy).
    pub fn load(path: &Path, cfg: &VisionConfig) -> Result<Self> {
        let model = OrtModel::load(path, cfg.session_options())?;
        Self::with_model(model, path, cfg)
    }

    /// The vendored model and class list, embedded in the binary: the default detector
    /// works wherever the binary runs, whatever its working directory.
    pub fn embedded(cfg: &VisionConfig) -> Result<Self> {
        let label = Path::new("(embedded)").join(MODEL_FILE);
        let model = OrtModel::load_from_memory(&label, EMBEDDED_MODEL, cfg.session_options())?;
        Self::with_model(model, &label, cfg)
    }

    fn with_model(model: OrtModel, path: &Path, cfg: &VisionConfig) -> Result<Self> {
        model.check_io(
            false,
            INPUT,
            &[Some(1), Some(SIZE as i64), Some(SIZE as i64), Some(3)],
        )?;
        model.check_io(true, OUTPUT, &[Some(1), None, Some(6)])?;
        let classes_path = path.with_file_name(CLASSES_FILE);
        let text = match std::fs::read_to_string(&classes_path) {
            Ok(t) => t,
            Err(_) => include_str!("../../models/coco80.txt").to_string(),
        };
        let classes: Vec<String> = text
            .lines()
            .map(|l| l.trim().to_string())
            .filter(|l| !l.is_empty())
            .collect();
        if classes.len() != 80 {
            bail!(
                "class list {} has {} names, expected 80",
                classes_path.display(),
                classes.len()
            );
        }
        Ok(Self {
            model,
            classes,
            min_score: cfg.min_score,
            nms_iou: cfg.nms_iou,
        })
    }

    /// NHWC float tensor data of the resized image (raw 0..255).
    pub fn preprocess(img: &RgbImage) -> Result<Vec<f32>> {
        let resized = resize_rgb(img, SIZE, SIZE)?;
        Ok(resized.as_raw().iter().map(|&v| v as f32).collect())
    }

    /// Raw rows (x1, y1, x2, y2, score, class) → detections in original pixels.
    pub fn postprocess(&self, rows: &[f32], width: u32, height: u32) -> Vec<Detection> {
        let sx = width as f32 / SIZE as f32;
        let sy = height as f32 / SIZE as f32;
        let mut out = Vec::new();
        for r in rows.chunks_exact(6) {
            let score = r[4];
            if score.is_nan() || score < self.min_score {
                continue;
            }
            let cls = r[5];
            if cls.is_nan() || cls < 0.0 || cls as usize >= self.classes.len() {
                continue;
            }
            let b = [r[0] * sx, r[1] * sy, r[2] * sx, r[3] * sy];
            if let Some(bbox) = clamp_box(b, width, height) {
                out.push(Detection {
                    label: self.classes[cls as usize].clone(),
                    score,
                    bbox,
                });
            }
        }
        nms_per_class(out, self.nms_iou)
    }
}

impl Detector for CenterNet {
    fn name(&self) -> String {
        "centernet".into()
    }

    fn vocabulary(&self) -> Vec<String> {
        self.classes.clone()
    }

    fn detect(&self, input: &DetectInput<'_>) -> Result<Vec<Detection>> {
        let (w, h) = input.color.dimensions();
        let data = Self::preprocess(input.color)?;
        let rows = self.model.with_session(|s| {
            let t = Tensor::from_array(([1usize, SIZE as usize, SIZE as usize, 3], data))?;
            let out = s.run(ort::inputs![INPUT => t])?;
            let (_, rows) = out[OUTPUT].try_extract_tensor::<f32>()?;
            Ok(rows.to_vec())
        })?;
        if rows.len() % 6 != 0 {
            return Err(anyhow!(
                "{}: output has {} values, not rows of 6",
                self.model.path().display(),
                rows.len()
            ));
        }
        Ok(self.postprocess(&rows, w, h))
    }
}
