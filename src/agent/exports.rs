//! What a job leaves for people and robots beside its trace: each view's mask as a PNG and
//! the object's fused points as a coloured binary PLY (in the frame of the job's box),
//! encoded straight into their artifact files.

use image::RgbImage;
use nalgebra::Point3;

use std::io::Write;

use crate::geometry::export::{color_points, write_ply};
use crate::geometry::{FrameCamera, Mask};
use crate::jobs::{mask_artifact, JobFailure, TraceSink, OBJECT_PLY};

/// Colour of object points no kept view's image covers.
const UNSEEN: [u8; 3] = [255, 140, 0];

/// A mask as an 8-bit greyscale PNG (255 inside, 0 outside), into `out`.
pub fn write_mask_png(out: &mut dyn Write, m: &Mask) -> std::io::Result<()> {
    use image::ImageEncoder;
    let data: Vec<u8> = m.data.iter().map(|&b| if b { 255 } else { 0 }).collect();
    if data.len() != m.width as usize * m.height as usize {
        return Err(std::io::Error::other(format!(
            "mask of {}x{} has the wrong size",
            m.width, m.height
        )));
    }
    image::codecs::png::PngEncoder::new(out)
        .write_image(&data, m.width, m.height, image::ExtendedColorType::L8)
        .map_err(std::io::Error::other)
}

/// The object's points coloured from the chosen view, as binary PLY, into `out`.
pub fn write_object_ply(
    out: &mut dyn Write,
    points: &[Point3<f64>],
    anchor: &FrameCamera,
    image: &RgbImage,
) -> std::io::Result<()> {
    let colored = color_points(points, anchor, image, UNSEEN);
    write_ply(
        out,
        &colored,
        &["grounder: the object's fused points, in the frame of the job's box".into()],
    )
}

/// Write the exports as artifacts as they are encoded, straight to their files (blocking:
/// call from blocking code): the masks of the views used (by image index) and the object's
/// points coloured from the chosen view. Returns their URLs for the trace.
pub fn write(
    trace: &TraceSink,
    masks: &[(usize, &Mask)],
    points: &[Point3<f64>],
    anchor: &FrameCamera,
    image: &RgbImage,
) -> Result<serde_json::Value, JobFailure> {
    let job = trace.job_id();
    let mut urls = serde_json::Map::new();
    for (idx, m) in masks {
        let id = format!("{idx:05}");
        trace.write_artifact(&mask_artifact(&id), |w| write_mask_png(w, m))?;
        urls.insert(id.clone(), format!("/v1/jobs/{job}/masks/{id}.png").into());
    }
    trace.write_artifact(OBJECT_PLY, |w| write_object_ply(w, points, anchor, image))?;
    let object = format!("/v1/jobs/{job}/object.ply");
    Ok(serde_json::json!({"object_ply": object, "masks": urls}))
}
