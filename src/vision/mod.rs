//! Local vision models (ONNX Runtime) and model-free adapters: detectors and segmenters.

use serde::{Deserialize, Serialize};

/// One 2D detection in the original image's pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    pub label: String,
    pub score: f32,
    /// [x1, y1, x2, y2] in pixels of the image the detector was given.
    #[serde(rename = "box")]
    pub bbox: [f32; 4],
}

pub mod cli;
pub mod index;
