//! Contact sheet of a generated scene (colour next to colourised depth) for a check by eye.

use super::{Layout, SynthScene};
use anyhow::{Context, Result};
use image::{imageops, ImageBuffer, Luma, Rgb, RgbImage};
use std::path::{Path, PathBuf};

/// Width of one tile in the sheet.
const TILE_W: u32 = 320;

fn frame_file(scene: &SynthScene, kind: &str, name: &str, ext: &str) -> PathBuf {
    match scene.params.layout {
        Layout::Scannet => scene.dir.join(kind).join(format!("{name}.{ext}")),
        Layout::PosedImages => scene.dir.join(format!("{name}.{ext}")),
    }
}

/// Colour for a depth in metres (0 = no reading → black): blue (near) to red (far, 6 m).
fn depth_colour(mm: u16) -> Rgb<u8> {
    if mm == 0 {
        return Rgb([0, 0, 0]);
    }
    let t = (mm as f64 / 6000.0).clamp(0.0, 1.0);
    let stops = [
        [48.0, 18.0, 59.0],
        [40.0, 140.0, 250.0],
        [60.0, 230.0, 120.0],
        [250.0, 220.0, 50.0],
        [220.0, 50.0, 20.0],
    ];
    let x = t * (stops.len() - 1) as f64;
    let i = (x.floor() as usize).min(stops.len() - 2);
    let f = x - i as f64;
    Rgb([0, 1, 2].map(|c| (stops[i][c] + (stops[i + 1][c] - stops[i][c]) * f) as u8))
}

/// Write a PNG with up to `max_frames` evenly spaced frames, two colour|depth pairs a row.
pub fn contact_sheet(scene: &SynthScene, out_png: &Path, max_frames: usize) -> Result<()> {
    let n = scene.frames.len().min(max_frames.max(1));
    let picks: Vec<usize> = (0..n).map(|k| k * scene.frames.len() / n).collect();
    let (cw, ch) = scene.params.color_size;
    let tile_h = (TILE_W as f64 * ch as f64 / cw as f64).round().max(1.0) as u32;
    let rows = n.div_ceil(2) as u32;
    let mut sheet =
        RgbImage::from_pixel(TILE_W * 4 + 10, rows * (tile_h + 4), Rgb([255, 255, 255]));
    for (k, &fi) in picks.iter().enumerate() {
        let name = &scene.frames[fi].name;
        let cpath = frame_file(scene, "color", name, "jpg");
        let color = image::open(&cpath)
            .with_context(|| format!("preview: cannot read {}", cpath.display()))?
            .to_rgb8();
        let color = imageops::resize(&color, TILE_W, tile_h, imageops::FilterType::Triangle);
        let dpath = frame_file(scene, "depth", name, "png");
        let depth: ImageBuffer<Luma<u16>, Vec<u16>> = image::open(&dpath)
            .with_context(|| format!("preview: cannot read {}", dpath.display()))?
            .to_luma16();
        let depth_rgb = RgbImage::from_fn(TILE_W, tile_h, |x, y| {
            let dx = (x * depth.width() / TILE_W).min(depth.width() - 1);
            let dy = (y * depth.height() / tile_h).min(depth.height() - 1);
            depth_colour(depth.get_pixel(dx, dy)[0])
        });
        let x0 = (k as u32 % 2) * (2 * TILE_W + 10);
        let y0 = (k as u32 / 2) * (tile_h + 4);
        imageops::overlay(&mut sheet, &color, x0 as i64, y0 as i64);
        imageops::overlay(&mut sheet, &depth_rgb, (x0 + TILE_W) as i64, y0 as i64);
    }
    sheet
        .save(out_png)
        .with_context(|| format!("preview: cannot write {}", out_png.display()))
}
