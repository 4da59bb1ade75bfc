//! `grounder detect`: run a detector over images and print one JSON line per detection.

use std::path::PathBuf;

use anyhow::{Context, Result};

use super::{build_detector, DetectInput, VisionConfig};

/// Arguments of `grounder detect`.
#[derive(Debug, clap::Args)]
pub struct DetectArgs {
    /// Images to run the detector on.
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// Detector spec: centernet, centernet:/path.onnx or yolo:/path.onnx.
    #[arg(long, env = "GROUNDER_DETECTOR", default_value = "centernet")]
    pub detector: String,
    /// Minimum score of a reported detection.
    #[arg(long, default_value_t = 0.3)]
    pub min_score: f32,
    /// Path of libonnxruntime (else ORT_DYLIB_PATH, else ./.ort/).
    #[arg(long)]
    pub ort_dylib: Option<PathBuf>,
    /// Folder with the vendored models.
    #[arg(long, env = "GROUNDER_MODEL_DIR", default_value = "models")]
    pub model_dir: PathBuf,
}

/// Run `grounder detect`.
pub fn run(args: DetectArgs) -> Result<()> {
    let cfg = VisionConfig {
        detector: args.detector.clone(),
        min_score: args.min_score,
        ort_dylib: args.ort_dylib.clone(),
        model_dir: args.model_dir.clone(),
        ..VisionConfig::default()
    };
    let detector = build_detector(&args.detector, &cfg)?;
    if detector.needs_instances() {
        anyhow::bail!(
            "the {} detector needs a scene's instance masks; it cannot run on plain images",
            detector.name()
        );
    }
    for path in &args.images {
        let img = image::open(path)
            .with_context(|| format!("cannot read image {}", path.display()))?
            .to_rgb8();
        for d in detector.detect(&DetectInput::image(&img))? {
            let line = serde_json::json!({
                "image": path.display().to_string(),
                "label": d.label,
                "score": d.score,
                "box": d.bbox,
            });
            println!("{line}");
        }
    }
    Ok(())
}
