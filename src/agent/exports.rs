//! What a job leaves for people and robots beside its trace: each view's mask as a PNG and
//! the object's fused points as a coloured binary PLY (in the frame of the job's box).

use image::RgbImage;
use nalgebra::Point3;

use crate::geometry::export::{color_points, encode_ply};
use crate::geometry::{FrameCamera, Mask};
use crate::jobs::{mask_artifact, JobContext, JobFailure, OBJECT_PLY};

/// Colour of object points no kept view's image covers.
const UNSEEN: [u8; 3] = [255, 140, 0];

/// A mask as an 8-bit greyscale PNG: 255 inside, 0 outside.
pub fn mask_png(m: &Mask) -> anyhow::Result<Vec<u8>> {
    let data: Vec<u8> = m.data.iter().map(|&b| if b { 255 } else { 0 }).collect();
    let img = image::GrayImage::from_raw(m.width, m.height, data)
        .ok_or_else(|| anyhow::anyhow!("mask of {}x{} has the wrong size", m.width, m.height))?;
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)?;
    Ok(out)
}

/// The object's points coloured from the chosen view, as binary PLY.
pub fn object_ply(points: &[Point3<f64>], anchor: &FrameCamera, image: &RgbImage) -> Vec<u8> {
    let colored = color_points(points, anchor, image, UNSEEN);
    encode_ply(
        &colored,
        &["grounder: the object's fused points, in the frame of the job's box".into()],
    )
}

/// Files to store: the masks of the views used (by image index) and the object's points.
pub struct Exports {
    pub masks: Vec<(usize, anyhow::Result<Vec<u8>>)>,
    pub object: Vec<u8>,
}

/// Store the exports as artifacts; returns their URLs for the trace.
pub async fn store(ctx: &JobContext, e: Exports) -> Result<serde_json::Value, JobFailure> {
    let mut masks = serde_json::Map::new();
    for (idx, png) in e.masks {
        let png = png
            .map_err(|err| JobFailure::new("internal", format!("cannot encode a mask: {err:#}")))?;
        let id = format!("{idx:05}");
        ctx.trace.artifact(&mask_artifact(&id), png).await?;
        let url = format!("/v1/jobs/{}/masks/{id}.png", ctx.job_id);
        masks.insert(id, url.into());
    }
    ctx.trace.artifact(OBJECT_PLY, e.object).await?;
    let object = format!("/v1/jobs/{}/object.ply", ctx.job_id);
    Ok(serde_json::json!({"object_ply": object, "masks": masks}))
}
