//! Rendering stitched grids: tiles at their own aspect ratio in a rows x cols grid, an id
//! label per tile, the grid resized to the VLM's side limit and JPEG-encoded.

use super::label::{draw_label, LabelStyle};
use super::plan::{grid_starts, plan, GridSpec};
use anyhow::{bail, Context, Result};
use base64::Engine as _;
use fast_image_resize::images::CroppedImageMut;
use fast_image_resize::{FilterType, ResizeAlg, ResizeOptions, Resizer};
use image::RgbImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings for stitching and encoding (per VLM backend).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StitchOptions {
    /// Longer side of every stitched image after resizing, in pixels.
    pub max_side: u32,
    /// Scale grids smaller than `max_side` up as well (the reference does).
    pub upscale: bool,
    /// JPEG quality, 1..=100.
    pub jpeg_quality: u8,
    /// Height of the id text as a fraction of the tile height.
    pub label_height_frac: f32,
    /// Gap between the tile's top-left corner and the label, as a fraction of tile height.
    pub label_margin_frac: f32,
    /// Colour of the id text.
    pub label_color: [u8; 3],
    /// Colour of the box behind the id text (keeps it readable on any background).
    pub label_background: [u8; 3],
    /// Colour of grid cells that hold no frame.
    pub background: [u8; 3],
    /// Resampling filter (the reference uses Lanczos3).
    pub resize_filter: ResizeFilter,
}

/// Resampling filter used when scaling tiles and images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ResizeFilter {
    /// Lanczos, 3 lobes: sharpest, slowest (reference behaviour).
    #[default]
    Lanczos3,
    /// Catmull-Rom cubic: close to Lanczos3, fewer taps.
    CatmullRom,
    /// Triangle filter (bilinear with proper anti-aliasing): about 3x fewer taps.
    Bilinear,
}

impl ResizeFilter {
    pub(crate) fn options(self) -> ResizeOptions {
        let f = match self {
            ResizeFilter::Lanczos3 => FilterType::Lanczos3,
            ResizeFilter::CatmullRom => FilterType::CatmullRom,
            ResizeFilter::Bilinear => FilterType::Bilinear,
        };
        ResizeOptions::new().resize_alg(ResizeAlg::Convolution(f))
    }
}

impl Default for StitchOptions {
    fn default() -> Self {
        Self {
            max_side: 2048,
            upscale: true,
            jpeg_quality: 75,
            label_height_frac: 0.1,
            label_margin_frac: 0.005,
            label_color: [255, 0, 0],
            label_background: [255, 255, 255],
            background: [0, 0, 0],
            resize_filter: ResizeFilter::Lanczos3,
        }
    }
}

/// One encoded stitched image, ready to be sent to a VLM.
#[derive(Debug, Clone)]
pub struct StitchedImage {
    /// JPEG bytes.
    pub jpeg: Vec<u8>,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Ids of the frames it holds, row-major.
    pub image_ids: Vec<String>,
    /// The layout used.
    pub spec: GridSpec,
}

impl StitchedImage {
    /// `data:image/jpeg;base64,...` URL for an OpenAI-style image part.
    pub fn data_url(&self) -> String {
        jpeg_data_url(&self.jpeg)
    }
}

/// `data:image/jpeg;base64,...` URL of JPEG bytes.
pub fn jpeg_data_url(jpeg: &[u8]) -> String {
    format!(
        "data:image/jpeg;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(jpeg)
    )
}

/// Where a tile landed in a rendered grid (output pixel coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct TilePlacement {
    /// Frame id drawn on the tile.
    pub image_id: String,
    /// Left edge of the tile.
    pub x: u32,
    /// Top edge of the tile.
    pub y: u32,
    /// Tile width after resizing.
    pub w: u32,
    /// Tile height after resizing.
    pub h: u32,
}

/// Scale that makes the longer of (`w`, `h`) equal `max_side` (never above 1 unless `upscale`).
pub fn scale_to_limit(w: u32, h: u32, max_side: u32, upscale: bool) -> f64 {
    let long = w.max(h).max(1) as f64;
    let s = f64::from(max_side.max(1)) / long;
    if upscale {
        s
    } else {
        s.min(1.0)
    }
}

/// Resize `img` so its longer side is `max_side` (Lanczos3); smaller images are scaled up
/// only if `upscale`.
pub fn resize_to_limit(img: &RgbImage, max_side: u32, upscale: bool) -> Result<RgbImage> {
    resize_to_limit_with(img, max_side, upscale, ResizeFilter::Lanczos3)
}

/// [`resize_to_limit`] with a chosen filter.
pub fn resize_to_limit_with(
    img: &RgbImage,
    max_side: u32,
    upscale: bool,
    filter: ResizeFilter,
) -> Result<RgbImage> {
    let s = scale_to_limit(img.width(), img.height(), max_side, upscale);
    let w = ((f64::from(img.width()) * s).round() as u32).max(1);
    let h = ((f64::from(img.height()) * s).round() as u32).max(1);
    if (w, h) == img.dimensions() {
        return Ok(img.clone());
    }
    let mut dst = RgbImage::new(w, h);
    Resizer::new()
        .resize(img, &mut dst, &filter.options())
        .context("cannot resize image")?;
    Ok(dst)
}

/// The scale at which a `spec` grid of `cell_w` x `cell_h` cells is drawn: its longer side
/// becomes `opts.max_side` (never above 1 unless `opts.upscale`).
pub fn grid_scale(cell_w: u32, cell_h: u32, spec: &GridSpec, opts: &StitchOptions) -> f64 {
    let full_w = u64::from(cell_w) * u64::from(spec.cols);
    let full_h = u64::from(cell_h) * u64::from(spec.rows);
    let s = f64::from(opts.max_side.max(1)) / full_w.max(full_h).max(1) as f64;
    if opts.upscale {
        s
    } else {
        s.min(1.0)
    }
}

/// Render one grid: place `tiles` row-major in a `spec.rows` x `spec.cols` grid whose cells
/// are as large as the largest tile, scale it so the longer side is `opts.max_side`, and
/// draw each tile's id at its top-left corner.
///
/// Each tile is resized straight into its place in the output (equivalent to composing at
/// full resolution and resizing the whole grid, but much cheaper).
pub fn render_grid(
    tiles: &[(String, &RgbImage)],
    spec: &GridSpec,
    opts: &StitchOptions,
) -> Result<RgbImage> {
    Ok(render_grid_with_placements(tiles, spec, opts)?.0)
}

/// [`render_grid`], also returning where each tile was placed.
pub fn render_grid_with_placements(
    tiles: &[(String, &RgbImage)],
    spec: &GridSpec,
    opts: &StitchOptions,
) -> Result<(RgbImage, Vec<TilePlacement>)> {
    let dims: Vec<(u32, u32)> = tiles.iter().map(|t| t.1.dimensions()).collect();
    check_grid(&dims, spec)?;
    let (out_w, out_h, rects) = grid_layout(&dims, spec, opts);
    let mut out = RgbImage::from_pixel(out_w, out_h, image::Rgb(opts.background));

    let mut resizer = Resizer::new();
    let resize_opts = opts.resize_filter.options();
    let mut placements = Vec::with_capacity(tiles.len());
    for ((id, tile), [x, y, w, h]) in tiles.iter().zip(rects) {
        {
            let mut dst =
                CroppedImageMut::new(&mut out, x, y, w, h).context("tile does not fit the grid")?;
            resizer
                .resize(*tile, &mut dst, &resize_opts)
                .context("cannot resize a tile")?;
        }
        placements.push(TilePlacement {
            image_id: id.clone(),
            x,
            y,
            w,
            h,
        });
    }
    draw_labels(&mut out, &placements, opts);
    Ok((out, placements))
}

/// Tiles of sizes `dims` can be drawn in a `spec` grid: some, none empty, and they fit.
pub(crate) fn check_grid(dims: &[(u32, u32)], spec: &GridSpec) -> Result<()> {
    if dims.is_empty() {
        bail!("cannot stitch an empty grid");
    }
    if spec.rows == 0 || spec.cols == 0 {
        bail!("grid layout {}x{} has no cells", spec.rows, spec.cols);
    }
    if dims.len() > spec.capacity() as usize {
        bail!(
            "{} frames do not fit a {}x{} grid",
            dims.len(),
            spec.rows,
            spec.cols
        );
    }
    if dims.iter().any(|d| d.0 == 0 || d.1 == 0) {
        bail!("cannot stitch an empty frame");
    }
    Ok(())
}

/// The size of a `spec` grid of tiles of sizes `dims` (row-major, cells as large as the
/// largest tile, scaled by [`grid_scale`]) and each tile's place in it, `[x, y, w, h]`.
/// `dims` must be non-empty, without zero sides, and fit the grid.
pub fn grid_layout(
    dims: &[(u32, u32)],
    spec: &GridSpec,
    opts: &StitchOptions,
) -> (u32, u32, Vec<[u32; 4]>) {
    let cell_w = dims.iter().map(|d| d.0).max().unwrap_or(0);
    let cell_h = dims.iter().map(|d| d.1).max().unwrap_or(0);
    let cols = spec.cols.max(1);
    let full_w = u64::from(cell_w) * u64::from(cols);
    let full_h = u64::from(cell_h) * u64::from(spec.rows);
    let s = grid_scale(cell_w, cell_h, spec, opts);
    let out_w = ((full_w as f64 * s).round() as u32).max(1);
    let out_h = ((full_h as f64 * s).round() as u32).max(1);
    let rects = dims
        .iter()
        .enumerate()
        .map(|(i, &(tw, th))| {
            let (r, c) = (i as u32 / cols, i as u32 % cols);
            let x = ((f64::from(c) * f64::from(cell_w) * s).round() as u32).min(out_w - 1);
            let y = ((f64::from(r) * f64::from(cell_h) * s).round() as u32).min(out_h - 1);
            let w = ((f64::from(tw) * s).round() as u32).clamp(1, out_w - x);
            let h = ((f64::from(th) * s).round() as u32).clamp(1, out_h - y);
            [x, y, w, h]
        })
        .collect();
    (out_w, out_h, rects)
}

/// Draw each placed tile's id at its top-left corner.
pub fn draw_labels(out: &mut RgbImage, placements: &[TilePlacement], opts: &StitchOptions) {
    for p in placements {
        let style = LabelStyle {
            text: opts.label_color,
            background: Some(opts.label_background),
            ink_height: (opts.label_height_frac * p.h as f32).max(4.0),
        };
        let m = ((opts.label_margin_frac * p.h as f32).round() as i32).max(1);
        draw_label(out, &p.image_id, p.x as i32 + m, p.y as i32 + m, &style);
    }
}

/// Encode an RGB image as baseline JPEG at `quality` (1..=100).
pub fn encode_jpeg(img: &RgbImage, quality: u8) -> Result<Vec<u8>> {
    let (w, h) = img.dimensions();
    if w > u32::from(u16::MAX) || h > u32::from(u16::MAX) {
        bail!("image {w}x{h} is too large for JPEG");
    }
    let mut buf = Vec::with_capacity((w * h / 4) as usize);
    let enc = jpeg_encoder::Encoder::new(&mut buf, quality.clamp(1, 100));
    enc.encode(
        img.as_raw(),
        w as u16,
        h as u16,
        jpeg_encoder::ColorType::Rgb,
    )
    .context("cannot encode JPEG")?;
    Ok(buf)
}

/// Plan, render and encode all `frames` (id, image) under soft limit `limit`, grids in
/// parallel. The result keeps the plan's order.
pub fn stitch_all(
    frames: &[(String, &RgbImage)],
    limit: usize,
    opts: &StitchOptions,
) -> Result<Vec<StitchedImage>> {
    let specs = plan(frames.len(), limit);
    stitch_with_specs(frames, &specs, opts)
}

/// Render and encode `frames` into the given grids (in order), in parallel.
pub fn stitch_with_specs(
    frames: &[(String, &RgbImage)],
    specs: &[GridSpec],
    opts: &StitchOptions,
) -> Result<Vec<StitchedImage>> {
    let starts = grid_starts(specs);
    let needed: usize = specs.iter().map(|s| s.frames as usize).sum();
    if needed != frames.len() {
        bail!(
            "the plan holds {needed} frames but {} were given",
            frames.len()
        );
    }
    specs
        .par_iter()
        .zip(starts)
        .map(|(spec, start)| {
            let tiles = &frames[start..start + spec.frames as usize];
            let img = render_grid(tiles, spec, opts)?;
            let jpeg = encode_jpeg(&img, opts.jpeg_quality)?;
            Ok(StitchedImage {
                jpeg,
                width: img.width(),
                height: img.height(),
                image_ids: tiles.iter().map(|t| t.0.clone()).collect(),
                spec: *spec,
            })
        })
        .collect()
}
