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

/// Decode JPEG `bytes` for a tile of `want` = (width, height) pixels: at the smallest DCT
/// scale (1/8, 1/4 or 1/2) whose output is still at least `want` in both dimensions, which
/// skips most of the inverse DCT, upsampling and colour conversion of a frame that is then
/// resized to a fraction of its size anyway. The caller resizes the result to `want`
/// exactly, as it would the full frame. Anything else (no reduced scale fits, a format the
/// scaled decoder does not give as 8-bit RGB or grey, an error or a panic in it) is decoded
/// at full size by [`decode_image`], whose result the tiles had before.
pub fn decode_at_least(bytes: &[u8], want: (u32, u32)) -> Result<RgbImage> {
    if bytes.starts_with(&[0xFF, 0xD8]) {
        // The scaled decoder is a second, independent JPEG parser of uploaded files: a
        // panic in it is a reason to use the full decoder, not to fail the job.
        let scaled = std::panic::catch_unwind(|| scaled_jpeg(bytes, want));
        if let Ok(Some(img)) = scaled {
            return Ok(img);
        }
    }
    decode_image(bytes)
}

/// Size of a `full` side decoded at `eighths` / 8 (the scaled IDCT rounds up).
fn scaled_side(full: u32, eighths: u32) -> u32 {
    (full * eighths).div_ceil(8)
}

/// [`decode_at_least`]'s reduced-scale decode; `None` where it does not apply or fails.
fn scaled_jpeg(bytes: &[u8], want: (u32, u32)) -> Option<RgbImage> {
    let mut dec = jpeg_decoder::Decoder::new(bytes);
    // The full size first (a request larger than any image selects the full scale).
    let (fw, fh) = dec.scale(u16::MAX, u16::MAX).ok()?;
    let (fw, fh) = (u32::from(fw), u32::from(fh));
    let eighths = [1, 2, 4]
        .into_iter()
        .find(|&e| scaled_side(fw, e) >= want.0 && scaled_side(fh, e) >= want.1)?;
    let (sw, sh) = (scaled_side(fw, eighths), scaled_side(fh, eighths));
    // `scale` takes the smallest scale that reaches the request in either dimension: asking
    // for exactly the chosen scale's size selects it; anything else is refused below.
    let got = dec
        .scale(u16::try_from(sw).ok()?, u16::try_from(sh).ok()?)
        .ok()?;
    if (u32::from(got.0), u32::from(got.1)) != (sw, sh) {
        return None;
    }
    let px = dec.decode().ok()?;
    let n = sw as usize * sh as usize;
    if px.len() == 3 * n {
        RgbImage::from_raw(sw, sh, px)
    } else if px.len() == n {
        // Grey (a 16-bit or CMYK image has other lengths and goes to the full decoder).
        let grey = image::GrayImage::from_raw(sw, sh, px)?;
        Some(image::DynamicImage::ImageLuma8(grey).into_rgb8())
    } else {
        None
    }
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

    /// A smooth picture (gradients and a wave of about 60 pixels), JPEG-encoded as asked.
    /// Hard edges would make the comparison below one of two downscalers at 1/8 (an 8x8
    /// block's mean against Lanczos3), not of the decoders.
    fn jpeg(w: u32, h: u32, progressive: bool, sampling: jpeg_encoder::SamplingFactor) -> Vec<u8> {
        let img = RgbImage::from_fn(w, h, |x, y| {
            let r = (x * 255 / w.max(1)) as u8;
            let g = (y * 255 / h.max(1)) as u8;
            let b = 128.0 + 60.0 * (f64::from(x + y) / 10.0).sin();
            image::Rgb([r, g, b as u8])
        });
        let mut buf = Vec::new();
        let mut enc = jpeg_encoder::Encoder::new(&mut buf, 90);
        enc.set_progressive(progressive);
        enc.set_sampling_factor(sampling);
        enc.encode(
            img.as_raw(),
            w as u16,
            h as u16,
            jpeg_encoder::ColorType::Rgb,
        )
        .unwrap();
        buf
    }

    /// Mean absolute difference per channel between `a` and `b` resized to `a`'s size.
    fn diff_to(a: &RgbImage, b: &RgbImage) -> f64 {
        let mut r = RgbImage::new(a.width(), a.height());
        fast_image_resize::Resizer::new()
            .resize(
                b,
                &mut r,
                &super::super::render::ResizeFilter::Lanczos3.options(),
            )
            .unwrap();
        let sum: u64 = a
            .as_raw()
            .iter()
            .zip(r.as_raw())
            .map(|(&x, &y)| u64::from(x.abs_diff(y)))
            .sum();
        sum as f64 / a.as_raw().len() as f64
    }

    #[test]
    fn scaled_decode_is_the_smallest_dct_scale_at_least_the_tile() {
        use jpeg_encoder::SamplingFactor::{F_1_1, F_2_2};
        // (frame, tile wanted, size decoded): odd sizes round up; a tile one pixel over a
        // scale takes the next one; one over half the frame decodes it whole.
        let cases = [
            ((160, 120), (75, 56), (80, 60)),
            ((160, 120), (80, 60), (80, 60)),
            ((160, 120), (81, 56), (160, 120)),
            ((160, 120), (20, 15), (20, 15)),
            ((160, 120), (21, 10), (40, 30)),
            ((121, 97), (30, 20), (31, 25)),
            ((121, 97), (16, 13), (16, 13)),
            ((648, 484), (305, 228), (324, 242)),
            ((7, 5), (1, 1), (1, 1)),
        ];
        for progressive in [false, true] {
            for sampling in [F_2_2, F_1_1] {
                for ((w, h), want, got) in cases {
                    let bytes = jpeg(w, h, progressive, sampling);
                    let full = decode_image(&bytes).unwrap();
                    let img = decode_at_least(&bytes, want).unwrap();
                    let what = format!("{w}x{h} for {want:?}, progressive {progressive}");
                    assert_eq!(img.dimensions(), got, "{what}");
                    assert!(img.width() >= want.0 && img.height() >= want.1, "{what}");
                    // The same picture as the full decode brought to that size (compared at
                    // tile sizes of 30 pixels or more: smaller outputs of these small test
                    // frames are mostly border, and the 4:2:0 chroma at 1/8 is 2 pixels).
                    if got.0 >= 30 {
                        let d = diff_to(&img, &full);
                        assert!(d < 8.0, "{what}: mean difference {d}");
                    }
                }
            }
        }
    }

    #[test]
    fn what_the_scaled_decoder_does_not_take_is_decoded_whole() {
        // Grey JPEG: decoded at the reduced scale too, as RGB.
        let grey = image::GrayImage::from_fn(64, 48, |x, _| image::Luma([(x * 4) as u8]));
        let mut bytes = Vec::new();
        jpeg_encoder::Encoder::new(&mut bytes, 90)
            .encode(grey.as_raw(), 64, 48, jpeg_encoder::ColorType::Luma)
            .unwrap();
        let img = decode_at_least(&bytes, (30, 20)).unwrap();
        assert_eq!(img.dimensions(), (32, 24));
        let p = img.get_pixel(20, 10);
        assert!(
            p[0] == p[1] && p[1] == p[2] && p[0].abs_diff(160) < 12,
            "{p:?}"
        );
        // PNG: the full decoder.
        let rgb = RgbImage::from_pixel(40, 30, image::Rgb([1, 2, 3]));
        let mut png = Vec::new();
        image::DynamicImage::ImageRgb8(rgb.clone())
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        assert_eq!(decode_at_least(&png, (5, 5)).unwrap(), rgb);
        // A truncated JPEG (cut mid-scan) gives an image or an error, never a panic; a JPEG
        // header over garbage is an error.
        let good = jpeg(160, 120, false, jpeg_encoder::SamplingFactor::F_2_2);
        if let Ok(img) = decode_at_least(&good[..good.len() / 2], (20, 15)) {
            assert!(img.width() >= 20 && img.height() >= 15);
        }
        let mut junk = vec![0xFF, 0xD8, 0xFF, 0xC0, 0x00, 0x11, 0x08];
        junk.extend((0..200u32).map(|i| (i * 37 % 251) as u8));
        assert!(decode_at_least(&junk, (10, 10)).is_err());
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
