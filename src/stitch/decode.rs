//! Decoding frames for stitching. A grid shows each frame at a fraction of its size (a 9x3
//! grid of ScanNet frames under a 2048-pixel limit: about a quarter), so decoding a
//! 1296x968 JPEG only to resize most of its pixels away dominates stitching time. Scene
//! indexing therefore stores a half-size preview of every frame ([`make_preview`]), and
//! [`tile_scales`] tells which frames a plan can take from their previews.

use super::plan::{grid_starts, GridSpec};
use super::render::{encode_jpeg, grid_scale, resize_to_limit, StitchOptions};
use anyhow::{Context, Result};
use image::RgbImage;
use rayon::prelude::*;
use std::path::Path;

/// Size of a stored preview relative to its frame.
pub const PREVIEW_SCALE: f64 = 0.5;

/// JPEG quality of stored previews (grids are re-encoded at their own quality).
pub const PREVIEW_QUALITY: u8 = 90;

/// A tile may be drawn from a source this much smaller than it (the resizer scales it up by
/// at most 1/0.9): lets the 0.53 scale of a 4x1 grid of ScanNet frames use the preview.
pub const SCALE_SLACK: f64 = 0.9;

/// Decode JPEG (or PNG) bytes into RGB (moved, not copied, when the decoder gave RGB).
pub fn decode_image(bytes: &[u8]) -> Result<RgbImage> {
    Ok(image::load_from_memory(bytes)
        .context("cannot decode image")?
        .into_rgb8())
}

/// Read and decode image files in parallel.
pub fn load_frames<P: AsRef<Path> + Sync>(paths: &[P]) -> Result<Vec<RgbImage>> {
    paths
        .par_iter()
        .map(|p| {
            let p = p.as_ref();
            let bytes = std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?;
            decode_image(&bytes).with_context(|| format!("in {}", p.display()))
        })
        .collect()
}

/// The preview of a decoded frame: [`PREVIEW_SCALE`] of its size (Lanczos3), as JPEG.
pub fn make_preview(img: &RgbImage) -> Result<Vec<u8>> {
    let long = img.width().max(img.height());
    let side = ((f64::from(long) * PREVIEW_SCALE).round() as u32).max(1);
    encode_jpeg(&resize_to_limit(img, side, false)?, PREVIEW_QUALITY)
}

/// The scale each frame is drawn at when frames of sizes `dims` fill the grids `specs` in
/// order ([`grid_scale`], as [`super::render::render_grid`] draws them). Frames beyond
/// the plan get 1.
pub fn tile_scales(dims: &[(u32, u32)], specs: &[GridSpec], opts: &StitchOptions) -> Vec<f64> {
    let mut out = vec![1.0; dims.len()];
    for (spec, start) in specs.iter().zip(grid_starts(specs)) {
        let end = (start + spec.frames as usize).min(dims.len());
        if start >= end {
            continue;
        }
        let cell_w = dims[start..end].iter().map(|d| d.0).max().unwrap_or(1);
        let cell_h = dims[start..end].iter().map(|d| d.1).max().unwrap_or(1);
        out[start..end].fill(grid_scale(cell_w, cell_h, spec, opts));
    }
    out
}

/// Which frames to draw from their previews: those whose grid shows every frame at no more
/// than `PREVIEW_SCALE / SCALE_SLACK` of its size and whose grid's frames all have one
/// (`has_preview[i]`), so that a grid never mixes preview and full-size tiles.
pub fn use_previews(scales: &[f64], specs: &[GridSpec], has_preview: &[bool]) -> Vec<bool> {
    let mut out = vec![false; scales.len().min(has_preview.len())];
    for (spec, start) in specs.iter().zip(grid_starts(specs)) {
        let end = (start + spec.frames as usize).min(out.len());
        if start >= end {
            continue;
        }
        let ok = (start..end).all(|i| has_preview[i] && scales[i] * SCALE_SLACK <= PREVIEW_SCALE);
        out[start..end].fill(ok);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn previews_are_half_size_and_keep_the_content() {
        let img = RgbImage::from_fn(320, 240, |x, y| {
            image::Rgb([(x * 255 / 320) as u8, (y * 255 / 240) as u8, 128])
        });
        let p = decode_image(&make_preview(&img).unwrap()).unwrap();
        assert_eq!(p.dimensions(), (160, 120));
        assert!(
            p.get_pixel(5, 60)[0] < 25 && p.get_pixel(155, 60)[0] > 230,
            "{:?} {:?}",
            p.get_pixel(5, 60),
            p.get_pixel(155, 60)
        );
    }

    #[test]
    fn tile_scales_follow_each_grid_layout() {
        let opts = StitchOptions {
            max_side: 2048,
            ..StitchOptions::default()
        };
        let specs = [
            GridSpec {
                rows: 4,
                cols: 1,
                frames: 4,
            },
            GridSpec {
                rows: 9,
                cols: 3,
                frames: 2,
            },
        ];
        let s = tile_scales(&[(1296, 968); 6], &specs, &opts);
        let want = [2048.0 / (4.0 * 968.0), 2048.0 / (9.0 * 968.0)];
        for (i, v) in s.iter().enumerate() {
            assert!((v - want[usize::from(i >= 4)]).abs() < 1e-9, "{s:?}");
        }
        // Frames the plan does not cover are drawn whole.
        assert_eq!(tile_scales(&[(10, 10); 2], &[], &opts), vec![1.0, 1.0]);
    }

    #[test]
    fn previews_are_used_per_grid_and_only_where_they_are_sharp_enough() {
        let specs = [
            GridSpec {
                rows: 4,
                cols: 1,
                frames: 2,
            },
            GridSpec {
                rows: 2,
                cols: 4,
                frames: 3,
            },
        ];
        // The 4x1 grid at 0.53 may use previews; a grid at 0.6 may not.
        let scales = [0.53, 0.53, 0.6, 0.6, 0.6];
        assert_eq!(
            use_previews(&scales, &specs, &[true; 5]),
            vec![true, true, false, false, false]
        );
        // One frame of a grid has no preview: the whole grid is drawn from full frames.
        let scales = [0.25; 5];
        assert_eq!(
            use_previews(&scales, &specs, &[true, false, true, true, true]),
            vec![false, false, true, true, true]
        );
    }
}
