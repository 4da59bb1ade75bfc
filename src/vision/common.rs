//! Shared pre/post-processing: resizing, box IoU, per-class non-maximum suppression, and
//! the 4-neighbours of a cell of a row-major grid.

use anyhow::{anyhow, Result};
use fast_image_resize::{images::Image, FilterType, PixelType, ResizeAlg, ResizeOptions, Resizer};
use image::RgbImage;

use super::Detection;

/// Bilinear resize of an RGB image to exactly `w` x `h`.
pub fn resize_rgb(img: &RgbImage, w: u32, h: u32) -> Result<RgbImage> {
    if img.width() == w && img.height() == h {
        return Ok(img.clone());
    }
    if img.width() == 0 || img.height() == 0 || w == 0 || h == 0 {
        return Err(anyhow!(
            "cannot resize an empty image ({}x{} -> {w}x{h})",
            img.width(),
            img.height()
        ));
    }
    let mut dst = Image::new(w, h, PixelType::U8x3);
    let opts = ResizeOptions::new().resize_alg(ResizeAlg::Convolution(FilterType::Bilinear));
    Resizer::new()
        .resize(img, &mut dst, &opts)
        .map_err(|e| anyhow!("image resize failed: {e}"))?;
    RgbImage::from_raw(w, h, dst.into_vec())
        .ok_or_else(|| anyhow!("resize produced a wrong-sized buffer"))
}

/// Intersection over union of two [x1, y1, x2, y2] boxes.
pub fn box_iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let area = |r: &[f32; 4]| (r[2] - r[0]).max(0.0) * (r[3] - r[1]).max(0.0);
    let union = area(a) + area(b) - inter;
    if union <= 0.0 {
        0.0
    } else {
        inter / union
    }
}

/// Greedy non-maximum suppression within each label; result sorted by descending score.
pub fn nms_per_class(mut dets: Vec<Detection>, iou_threshold: f32) -> Vec<Detection> {
    dets.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut keep: Vec<Detection> = Vec::with_capacity(dets.len());
    for d in dets {
        if keep
            .iter()
            .all(|k| k.label != d.label || box_iou(&k.bbox, &d.bbox) <= iou_threshold)
        {
            keep.push(d);
        }
    }
    keep
}

/// Clamp a box to the image and drop it when it has no area left.
pub fn clamp_box(b: [f32; 4], w: u32, h: u32) -> Option<[f32; 4]> {
    if b.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let (w, h) = (w as f32, h as f32);
    let r = [
        b[0].clamp(0.0, w),
        b[1].clamp(0.0, h),
        b[2].clamp(0.0, w),
        b[3].clamp(0.0, h),
    ];
    (r[2] > r[0] && r[3] > r[1]).then_some(r)
}

/// The 4-neighbours of cell `i` of a row-major grid `w` cells wide and `h` high (left,
/// right, above, below; `None` past the grid's edge).
pub fn grid_neighbours(i: usize, w: usize, h: usize) -> [Option<usize>; 4] {
    let (x, y) = (i % w, i / w);
    [
        (x > 0).then(|| i - 1),
        (x + 1 < w).then(|| i + 1),
        (y > 0).then(|| i - w),
        (y + 1 < h).then(|| i + w),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(label: &str, score: f32, bbox: [f32; 4]) -> Detection {
        Detection {
            label: label.into(),
            score,
            bbox,
        }
    }

    #[test]
    fn nms_keeps_best_per_class_and_other_classes() {
        let out = nms_per_class(
            vec![
                det("cup", 0.5, [0.0, 0.0, 10.0, 10.0]),
                det("cup", 0.9, [1.0, 1.0, 11.0, 11.0]),
                det("bowl", 0.4, [0.0, 0.0, 10.0, 10.0]),
                det("cup", 0.3, [50.0, 50.0, 60.0, 60.0]),
            ],
            0.5,
        );
        let labels: Vec<(&str, f32)> = out.iter().map(|d| (d.label.as_str(), d.score)).collect();
        assert_eq!(labels, vec![("cup", 0.9), ("bowl", 0.4), ("cup", 0.3)]);
    }

    #[test]
    fn iou_of_half_overlap() {
        let v = box_iou(&[0.0, 0.0, 2.0, 1.0], &[1.0, 0.0, 3.0, 1.0]);
        assert!((v - 1.0 / 3.0).abs() < 1e-6);
        assert_eq!(clamp_box([-5.0, 2.0, 3.0, 2.0], 10, 10), None);
        assert_eq!(
            clamp_box([-5.0, 2.0, 30.0, 4.0], 10, 10),
            Some([0.0, 2.0, 10.0, 4.0])
        );
    }
}
