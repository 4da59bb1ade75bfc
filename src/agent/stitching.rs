//! Stage 3: dynamic stitching of the pre-selected frames into grid images with id labels.
//! Frames are decoded here in parallel, from the half-size previews indexing stored wherever
//! a grid shows them at half size or less, through the tile cache that later queries of the
//! scene share (`stitch::tiles`); the later stages decode the few frames they need at full
//! size.

use image::RgbImage;
use serde_json::json;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use super::preselect::Preselection;
use super::{step, VlmGrounder};
use crate::jobs::{JobContext, JobFailure};
use crate::scene::SceneData;
use crate::stitch::decode::{load_frames, tile_scales, use_previews};
use crate::stitch::plan::plan;
use crate::stitch::render::StitchedImage;
use crate::stitch::tiles::{stitch_files, UnreadableFile};

/// The stitched grids.
pub struct Grids {
    pub images: Vec<StitchedImage>,
    pub urls: Vec<String>,
}

/// Decode the colour images of `frames` at full size, in parallel (off the async runtime).
pub async fn decode(
    scene: &Arc<SceneData>,
    frames: &[usize],
) -> Result<HashMap<usize, Arc<RgbImage>>, JobFailure> {
    let paths: Vec<_> = frames
        .iter()
        .map(|&i| scene.frames[i].color_path.clone())
        .collect();
    let imgs = decode_paths(paths).await?;
    Ok(frames
        .iter()
        .copied()
        .zip(imgs.into_iter().map(Arc::new))
        .collect())
}

async fn decode_paths(paths: Vec<PathBuf>) -> Result<Vec<RgbImage>, JobFailure> {
    tokio::task::spawn_blocking(move || load_frames(&paths))
        .await
        .map_err(|e| JobFailure::new("internal", format!("decoder task failed: {e}")))?
        .map_err(|e| {
            JobFailure::new(
                "storage_error",
                format!("cannot decode a stored frame: {e:#}"),
            )
        })
}

pub async fn run(
    g: &VlmGrounder,
    ctx: &JobContext,
    pre: &Preselection,
) -> Result<Grids, JobFailure> {
    let t = Instant::now();
    let limit = g.params.image_limit;
    let mut opts = g.params.stitch.clone();
    opts.max_side = opts.max_side.min(g.client.config().max_image_side);
    let specs = plan(pre.frames.len(), limit);
    let dims: Vec<(u32, u32)> = pre
        .frames
        .iter()
        .map(|&i| {
            (
                ctx.scene.frames[i].camera.color.width,
                ctx.scene.frames[i].camera.color.height,
            )
        })
        .collect();
    let scales = tile_scales(&dims, &specs, &opts);
    let has_preview: Vec<bool> = pre
        .frames
        .iter()
        .map(|&i| ctx.scene.frames[i].preview_path().is_file())
        .collect();
    let from_preview = use_previews(&scales, &specs, &has_preview);
    let paths: Vec<PathBuf> = pre
        .frames
        .iter()
        .zip(&from_preview)
        .map(|(&i, &p)| {
            if p {
                ctx.scene.frames[i].preview_path()
            } else {
                ctx.scene.frames[i].color_path.clone()
            }
        })
        .collect();
    let ids: Vec<String> = pre.frames.iter().map(|i| format!("{i:05}")).collect();
    // Decoded and resized tiles, and whole grids, come from the tile cache when an earlier
    // query showed the same frame at the same size, or the same grid (the grids are the
    // same to the byte).
    let tiles = g.tiles.clone();
    let (images, stats) =
        tokio::task::spawn_blocking(move || stitch_files(&paths, &ids, &specs, &opts, &tiles))
            .await
            .map_err(|e| JobFailure::new("internal", format!("stitching task failed: {e}")))?
            .map_err(|e| {
                if e.downcast_ref::<UnreadableFile>().is_some() {
                    JobFailure::new(
                        "storage_error",
                        format!("cannot decode a stored frame: {e:#}"),
                    )
                } else {
                    JobFailure::new("stitching_failed", format!("{e:#}"))
                }
            })?;
    let mut urls = Vec::with_capacity(images.len());
    for (k, img) in images.iter().enumerate() {
        urls.push(
            ctx.trace
                .artifact(&grid_name(pre.round, k), img.jpeg.clone())
                .await?,
        );
    }
    let grids: Vec<_> = images
        .iter()
        .zip(&urls)
        .map(|(im, url)| json!({"url": url, "rows": im.spec.rows, "cols": im.spec.cols, "image_ids": im.image_ids, "width": im.width, "height": im.height, "jpeg_bytes": im.jpeg.len()}))
        .collect();
    let previews = from_preview.iter().filter(|&&p| p).count();
    step(ctx, "stitching", json!({"frames": pre.frames.len(), "limit": limit}), json!({"grids": grids, "decode_ms": stats.decode_ms, "render_ms": stats.render_ms, "tiles_cached": stats.tiles_cached, "grids_cached": stats.grids_cached, "from_previews": previews}), t).await;
    Ok(Grids { images, urls })
}

/// Artifact name of grid `k`; a widened offer ([`super::preselect::widened`]) keeps the
/// first offer's grids.
fn grid_name(round: usize, k: usize) -> String {
    if round == 0 {
        format!("grid_{k}.jpg")
    } else {
        format!("grid_r{round}_{k}.jpg")
    }
}
