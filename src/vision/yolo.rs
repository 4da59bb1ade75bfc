//! Ultralytics YOLO detect exports (YOLOv8/11, YOLO-World with a fixed vocabulary).
//!
//! Input `images` float32 [1, 3, H, W]: the image letterboxed (aspect kept, centred, padded
//! with grey 114) and divided by 255. Output [1, 4 + nc, anchors]: cx, cy, w, h in input
//! pixels, then one score per class. Class names come from the `names` metadata entry.

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use image::RgbImage;
use ort::value::Tensor;

use super::common::{clamp_box, nms_per_class, resize_rgb};
use super::runtime::OrtModel;
use super::{DetectInput, Detection, Detector, VisionConfig};

const INPUT: &str = "images";
const PAD: u8 = 114;

/// How an image was placed into the network input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Letterbox {
    /// Scale from original to input pixels.
    pub scale: f32,
    /// Left and top padding in input pixels.
    pub pad_x: u32,
    pub pad_y: u32,
    /// Network input size.
    pub width: u32,
    pub height: u32,
}

impl Letterbox {
    /// Placement of a `w` x `h` image in a `net_w` x `net_h` input (Ultralytics rounding).
    pub fn fit(w: u32, h: u32, net_w: u32, net_h: u32) -> Self {
        let scale = (net_w as f32 / w as f32).min(net_h as f32 / h as f32);
        let new_w = ((w as f32 * scale).round() as u32).clamp(1, net_w);
        let new_h = ((h as f32 * scale).round() as u32).clamp(1, net_h);
        let dw = (net_w - new_w) as f32 / 2.0;
        let dh = (net_h - new_h) as f32 / 2.0;
        Self {
            scale,
            pad_x: (dw - 0.1).round().max(0.0) as u32,
            pad_y: (dh - 0.1).round().max(0.0) as u32,
            width: net_w,
            height: net_h,
        }
    }

    /// Scaled size of the image inside the input.
    pub fn inner_size(&self, w: u32, h: u32) -> (u32, u32) {
        (
            ((w as f32 * self.scale).round() as u32).clamp(1, self.width - self.pad_x),
            ((h as f32 * self.scale).round() as u32).clamp(1, self.height - self.pad_y),
        )
    }

    /// Input-pixel box → original-pixel box.
    pub fn to_original(&self, b: [f32; 4]) -> [f32; 4] {
        let (px, py) = (self.pad_x as f32, self.pad_y as f32);
        [
            (b[0] - px) / self.scale,
            (b[1] - py) / self.scale,
            (b[2] - px) / self.scale,
            (b[3] - py) / self.scale,
        ]
    }
}

/// Letterboxed NCHW tensor data (values /255) and the placement.
pub fn letterbox(img: &RgbImage, net_w: u32, net_h: u32) -> Result<(Vec<f32>, Letterbox)> {
    let (w, h) = img.dimensions();
    if w == 0 || h == 0 {
        bail!("empty image");
    }
    let lb = Letterbox::fit(w, h, net_w, net_h);
    let (iw, ih) = lb.inner_size(w, h);
    let resized = resize_rgb(img, iw, ih)?;
    let plane = (net_w * net_h) as usize;
    let mut data = vec![PAD as f32 / 255.0; 3 * plane];
    for (x, y, p) in resized.enumerate_pixels() {
        let (px, py) = (x + lb.pad_x, y + lb.pad_y);
        let i = (py * net_w + px) as usize;
        for c in 0..3 {
            data[c * plane + i] = p.0[c] as f32 / 255.0;
        }
    }
    Ok((data, lb))
}

/// Parse Ultralytics' `names` metadata (a Python dict literal like `{0: 'person', 1: "it's"}`)
/// into names ordered by index.
pub fn parse_names(meta: &str) -> Result<Vec<String>> {
    let s = meta.trim();
    let inner = s
        .strip_prefix('{')
        .and_then(|s| s.strip_suffix('}'))
        .ok_or_else(|| anyhow!("names metadata is not a {{...}} dict: {meta}"))?;
    let mut out: Vec<(usize, String)> = Vec::new();
    let chars: Vec<char> = inner.chars().collect();
    let mut i = 0;
    let skip_ws = |i: &mut usize| {
        while *i < chars.len() && (chars[*i].is_whitespace() || chars[*i] == ',') {
            *i += 1;
        }
    };
    loop {
        skip_ws(&mut i);
        if i >= chars.len() {
            break;
        }
        let start = i;
        while i < chars.len() && chars[i].is_ascii_digit() {
            i += 1;
        }
        let idx: usize = chars[start..i]
            .iter()
            .collect::<String>()
            .parse()
            .map_err(|_| anyhow!("bad class index in names metadata: {meta}"))?;
        while i < chars.len() && (chars[i].is_whitespace() || chars[i] == ':') {
            i += 1;
        }
        let quote = *chars
            .get(i)
            .ok_or_else(|| anyhow!("truncated names metadata: {meta}"))?;
        if quote != '\'' && quote != '"' {
            bail!("class names must be quoted in names metadata: {meta}");
        }
        i += 1;
        let mut name = String::new();
        while i < chars.len() && chars[i] != quote {
            if chars[i] == '\\' && i + 1 < chars.len() {
                i += 1;
            }
            name.push(chars[i]);
            i += 1;
        }
        if i >= chars.len() {
            bail!("unterminated class name in names metadata: {meta}");
        }
        i += 1;
        out.push((idx, name));
    }
    out.sort_by_key(|(k, _)| *k);
    if out.is_empty() || out.iter().enumerate().any(|(n, (k, _))| n != *k) {
        bail!("names metadata must list classes 0..n-1: {meta}");
    }
    Ok(out.into_iter().map(|(_, n)| n).collect())
}

/// A YOLO detect model.
pub struct Yolo {
    model: OrtModel,
    names: Vec<String>,
    net_w: u32,
    net_h: u32,
    output: String,
    min_score: f32,
    nms_iou: f32,
}

impl Yolo {
    /// Load and check the model (input `images` [1,3,H,W], output [1, 4+nc, anchors], `names`).
    pub fn load(path: &Path, cfg: &VisionConfig) -> Result<Self> {
        let model = OrtModel::load(path, cfg.session_options())?;
        let input = model
            .check_io(false, INPUT, &[Some(1), Some(3), None, None])?
            .clone();
        let names_meta = model.metadata.get("names").ok_or_else(|| {
            anyhow!(
                "model {} has no `names` metadata (not an Ultralytics export?)",
                path.display()
            )
        })?;
        let names =
            parse_names(names_meta).map_err(|e| anyhow!("model {}: {e}", path.display()))?;
        let out = model
            .outputs
            .first()
            .ok_or_else(|| anyhow!("model {} has no outputs", path.display()))?
            .name
            .clone();
        let nc = names.len() as i64;
        model.check_io(true, &out, &[Some(1), Some(4 + nc), None])?;
        let imgsz: Vec<u32> = model
            .metadata
            .get("imgsz")
            .map(|s| {
                s.trim_matches(|c| c == '[' || c == ']')
                    .split(',')
                    .filter_map(|v| v.trim().parse().ok())
                    .collect()
            })
            .unwrap_or_default();
        let dim = |i: usize, fallback: u32| {
            if input.shape[i] > 0 {
                input.shape[i] as u32
            } else {
                fallback
            }
        };
        let net_h = dim(2, imgsz.first().copied().unwrap_or(640));
        let net_w = dim(3, imgsz.get(1).copied().unwrap_or(net_h));
        Ok(Self {
            model,
            names,
            net_w,
            net_h,
            output: out,
            min_score: cfg.min_score,
            nms_iou: cfg.nms_iou,
        })
    }

    /// Class-major output [4+nc, anchors] → detections in original pixels.
    pub fn postprocess(
        &self,
        out: &[f32],
        anchors: usize,
        lb: &Letterbox,
        w: u32,
        h: u32,
    ) -> Vec<Detection> {
        let nc = self.names.len();
        let mut dets = Vec::new();
        for a in 0..anchors {
            let at = |row: usize| out[row * anchors + a];
            let (best, score) = (0..nc)
                .map(|c| (c, at(4 + c)))
                .fold((0, f32::NEG_INFINITY), |m, x| if x.1 > m.1 { x } else { m });
            if score.is_nan() || score < self.min_score {
                continue;
            }
            let (cx, cy, bw, bh) = (at(0), at(1), at(2), at(3));
            let b = lb.to_original([cx - bw / 2.0, cy - bh / 2.0, cx + bw / 2.0, cy + bh / 2.0]);
            if let Some(bbox) = clamp_box(b, w, h) {
                dets.push(Detection {
                    label: self.names[best].clone(),
                    score,
                    bbox,
                });
            }
        }
        nms_per_class(dets, self.nms_iou)
    }
}

impl Detector for Yolo {
    fn name(&self) -> String {
        format!("yolo:{}", self.model.path().display())
    }

    fn vocabulary(&self) -> Vec<String> {
        self.names.clone()
    }

    fn detect(&self, input: &DetectInput<'_>) -> Result<Vec<Detection>> {
        let (w, h) = input.color.dimensions();
        let (data, lb) = letterbox(input.color, self.net_w, self.net_h)?;
        let (net_w, net_h) = (self.net_w as usize, self.net_h as usize);
        let (shape, values) = self.model.with_session(|s| {
            let t = Tensor::from_array(([1usize, 3, net_h, net_w], data))?;
            let out = s.run(ort::inputs![INPUT => t])?;
            let (shape, v) = out[self.output.as_str()].try_extract_tensor::<f32>()?;
            Ok((shape.to_vec(), v.to_vec()))
        })?;
        let nc = self.names.len();
        if shape.len() != 3 || shape[1] as usize != 4 + nc {
            bail!(
                "{}: output shape {shape:?} is not [1, {}, anchors]",
                self.model.path().display(),
                4 + nc
            );
        }
        Ok(self.postprocess(&values, shape[2] as usize, &lb, w, h))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_metadata_parses() {
        let n = parse_names("{0: 'person', 1: \"it's\", 2: 'dining table'}").unwrap();
        assert_eq!(n, vec!["person", "it's", "dining table"]);
        assert!(parse_names("[person]").is_err());
        assert!(parse_names("{1: 'a'}").is_err());
    }

    #[test]
    fn letterbox_places_wide_image_centred() {
        let lb = Letterbox::fit(1280, 720, 640, 640);
        assert_eq!(lb.scale, 0.5);
        assert_eq!((lb.pad_x, lb.pad_y), (0, 140));
        assert_eq!(
            lb.to_original([0.0, 140.0, 640.0, 500.0]),
            [0.0, 0.0, 1280.0, 720.0]
        );
    }
}
