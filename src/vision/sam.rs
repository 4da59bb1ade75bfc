//! Segment Anything as its standard ONNX pair: an image encoder (1x3x1024x1024, long side
//! resized to 1024, ImageNet-normalised, zero-padded bottom/right) producing
//! `image_embeddings`, and the prompt decoder of segment-anything's ONNX export (the box as
//! two corner points labelled 2 and 3). The highest-scoring mask is kept.

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use image::RgbImage;
use ort::value::Tensor;

use super::common::resize_rgb;
use super::runtime::OrtModel;
use super::{SegmentInput, Segmenter, VisionConfig};
use crate::geometry::mask::Mask;

/// Encoder input side.
pub const SIDE: u32 = 1024;
const MEAN: [f32; 3] = [123.675, 116.28, 103.53];
const STD: [f32; 3] = [58.395, 57.12, 57.375];

/// Encoder input tensor data (NCHW) and the per-axis scale (resized / original).
pub fn preprocess(img: &RgbImage) -> Result<(Vec<f32>, f32, f32)> {
    let (w, h) = img.dimensions();
    if w == 0 || h == 0 {
        bail!("empty image");
    }
    let s = SIDE as f32 / w.max(h) as f32;
    let nw = ((w as f32 * s + 0.5) as u32).clamp(1, SIDE);
    let nh = ((h as f32 * s + 0.5) as u32).clamp(1, SIDE);
    let resized = resize_rgb(img, nw, nh)?;
    let plane = (SIDE * SIDE) as usize;
    let mut data = vec![0.0f32; 3 * plane];
    for (x, y, p) in resized.enumerate_pixels() {
        let i = (y * SIDE + x) as usize;
        for c in 0..3 {
            data[c * plane + i] = (p.0[c] as f32 - MEAN[c]) / STD[c];
        }
    }
    Ok((data, nw as f32 / w as f32, nh as f32 / h as f32))
}

/// The SAM segmenter.
pub struct Sam {
    encoder: OrtModel,
    decoder: OrtModel,
    enc_input: String,
}

impl Sam {
    /// Load and check both models; errors name the offending file.
    pub fn load(encoder: &Path, decoder: &Path, cfg: &VisionConfig) -> Result<Self> {
        let enc = OrtModel::load(encoder, cfg.session_options())?;
        let enc_input = enc
            .inputs
            .first()
            .ok_or_else(|| anyhow!("model {} has no inputs", encoder.display()))?
            .name
            .clone();
        let side = Some(SIDE as i64);
        enc.check_io(false, &enc_input, &[Some(1), Some(3), side, side])?;
        enc.check_io(
            true,
            "image_embeddings",
            &[Some(1), Some(256), Some(64), Some(64)],
        )?;
        let dec = OrtModel::load(decoder, cfg.session_options())?;
        dec.check_io(
            false,
            "image_embeddings",
            &[Some(1), Some(256), Some(64), Some(64)],
        )?;
        dec.check_io(false, "point_coords", &[Some(1), None, Some(2)])?;
        dec.check_io(false, "point_labels", &[Some(1), None])?;
        dec.check_io(
            false,
            "mask_input",
            &[Some(1), Some(1), Some(256), Some(256)],
        )?;
        dec.check_io(false, "has_mask_input", &[Some(1)])?;
        dec.check_io(false, "orig_im_size", &[Some(2)])?;
        dec.check_io(true, "masks", &[Some(1), None, None, None])?;
        dec.check_io(true, "iou_predictions", &[Some(1), None])?;
        Ok(Self {
            encoder: enc,
            decoder: dec,
            enc_input,
        })
    }

    /// Image embeddings [1, 256, 64, 64] and the resize scales.
    pub fn embed(&self, img: &RgbImage) -> Result<(Vec<f32>, f32, f32)> {
        let (data, sx, sy) = preprocess(img)?;
        let emb = self.encoder.with_session(|s| {
            let t = Tensor::from_array(([1usize, 3, SIDE as usize, SIDE as usize], data))?;
            let out = s.run(ort::inputs![self.enc_input.as_str() => t])?;
            let (_, v) = out["image_embeddings"].try_extract_tensor::<f32>()?;
            Ok(v.to_vec())
        })?;
        Ok((emb, sx, sy))
    }

    /// Decode the best mask for `bbox` given embeddings of an image of size `w` x `h`.
    pub fn decode(
        &self,
        emb: Vec<f32>,
        sx: f32,
        sy: f32,
        w: u32,
        h: u32,
        bbox: [f32; 4],
    ) -> Result<Mask> {
        let coords = vec![bbox[0] * sx, bbox[1] * sy, bbox[2] * sx, bbox[3] * sy];
        let (shape, masks, ious) = self.decoder.with_session(|s| {
            let out = s.run(ort::inputs![
                "image_embeddings" => Tensor::from_array(([1usize, 256, 64, 64], emb))?,
                "point_coords" => Tensor::from_array(([1usize, 2, 2], coords))?,
                "point_labels" => Tensor::from_array(([1usize, 2], vec![2.0f32, 3.0]))?,
                "mask_input" => Tensor::from_array(([1usize, 1, 256, 256], vec![0.0f32; 256 * 256]))?,
                "has_mask_input" => Tensor::from_array(([1usize], vec![0.0f32]))?,
                "orig_im_size" => Tensor::from_array(([2usize], vec![h as f32, w as f32]))?,
            ])?;
            let (shape, m) = out["masks"].try_extract_tensor::<f32>()?;
            let (_, iou) = out["iou_predictions"].try_extract_tensor::<f32>()?;
            Ok((shape.to_vec(), m.to_vec(), iou.to_vec()))
        })?;
        if shape.len() != 4 || shape[1] < 1 || shape[1] as usize != ious.len() {
            bail!(
                "{}: masks shape {shape:?} does not match {} iou predictions",
                self.decoder.path().display(),
                ious.len()
            );
        }
        let (mh, mw) = (shape[2] as usize, shape[3] as usize);
        let best = ious
            .iter()
            .enumerate()
            .fold(0, |b, (i, v)| if *v > ious[b] { i } else { b });
        let plane = &masks[best * mh * mw..(best + 1) * mh * mw];
        let mut mask = Mask::new(w, h);
        for y in 0..h {
            let my = (y as usize * mh / h as usize).min(mh - 1);
            for x in 0..w {
                let mx = (x as usize * mw / w as usize).min(mw - 1);
                mask.set(x, y, plane[my * mw + mx] > 0.0);
            }
        }
        Ok(mask)
    }
}

impl Segmenter for Sam {
    fn name(&self) -> String {
        format!(
            "sam:{},{}",
            self.encoder.path().display(),
            self.decoder.path().display()
        )
    }

    fn segment(&self, input: &SegmentInput<'_>, bbox: [f32; 4]) -> Result<Mask> {
        let (w, h) = input.color.dimensions();
        let (emb, sx, sy) = self.embed(input.color)?;
        self.decode(emb, sx, sy, w, h, bbox)
    }
}
