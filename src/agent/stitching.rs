//! Stage 3: dynamic stitching of the pre-selected frames into grid images with id labels.
//! Frames are decoded once here (in parallel) and kept for the later stages.

use image::RgbImage;
use serde_json::json;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

use super::preselect::Preselection;
use super::{ms, step, VlmGrounder};
use crate::jobs::{JobContext, JobFailure};
use crate::scene::SceneData;
use crate::stitch::render::{load_frames, stitch_all, StitchedImage};

/// The stitched grids and the decoded frames.
pub struct Grids {
    pub images: Vec<StitchedImage>,
    pub urls: Vec<String>,
    pub decoded: HashMap<usize, Arc<RgbImage>>,
}

/// Decode the colour images of `frames` in parallel (off the async runtime).
pub async fn decode(scene: &Arc<SceneData>, frames: &[usize]) -> Result<HashMap<usize, Arc<RgbImage>>, JobFailure> {
    let paths: Vec<_> = frames.iter().map(|&i| scene.frames[i].color_path.clone()).collect();
    let imgs = tokio::task::spawn_blocking(move || load_frames(&paths))
        .await
        .map_err(|e| JobFailure::new("internal", format!("decoder task failed: {e}")))?
        .map_err(|e| JobFailure::new("storage_error", format!("cannot decode a stored frame: {e:#}")))?;
    Ok(frames.iter().copied().zip(imgs.into_iter().map(Arc::new)).collect())
}

pub async fn run(g: &VlmGrounder, ctx: &JobContext, pre: &Preselection) -> Result<Grids, JobFailure> {
    let t = Instant::now();
    let decoded = decode(&ctx.scene, &pre.frames).await?;
    let decode_ms = ms(t);
    let t_render = Instant::now();
    let limit = g.params.image_limit;
    let mut opts = g.params.stitch.clone();
    opts.max_side = opts.max_side.min(g.client.config().max_image_side);
    let frames: Vec<(String, Arc<RgbImage>)> = pre.frames.iter().map(|&i| (format!("{i:05}"), decoded[&i].clone())).collect();
    let images = tokio::task::spawn_blocking(move || {
        let refs: Vec<(String, &RgbImage)> = frames.iter().map(|(id, im)| (id.clone(), im.as_ref())).collect();
        stitch_all(&refs, limit, &opts)
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("stitching task failed: {e}")))?
    .map_err(|e| JobFailure::new("stitching_failed", format!("{e:#}")))?;
    let render_ms = ms(t_render);
    let mut urls = Vec::with_capacity(images.len());
    for (k, img) in images.iter().enumerate() {
        urls.push(ctx.trace.artifact(&format!("grid_{k}.jpg"), img.jpeg.clone()).await?);
    }
    let grids: Vec<_> = images
        .iter()
        .zip(&urls)
        .map(|(im, url)| json!({"url": url, "rows": im.spec.rows, "cols": im.spec.cols, "image_ids": im.image_ids, "width": im.width, "height": im.height, "jpeg_bytes": im.jpeg.len()}))
        .collect();
    step(ctx, "stitching", json!({"frames": pre.frames.len(), "limit": limit}), json!({"grids": grids, "decode_ms": decode_ms, "render_ms": render_ms}), t).await;
    Ok(Grids { images, urls, decoded })
}
