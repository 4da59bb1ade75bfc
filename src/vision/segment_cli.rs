//! `grounder segment`: one box in one frame of a scene directory, segmented as the
//! pipeline's segmenter does it, written as an overlay PNG and described as one JSON line
//! (the mask's size and box, and the evidence that the view saw a part: see
//! `geometry::partial`). For finding out why a view's mask is what it is without a job.
//!
//! As the service does for the chosen view, the frame's missing depth readings inside the
//! box are first completed from the other frames and the room's box
//! (`agent.geometry.depth_fill`, default settings); `--depth-fill off` segments the frame's
//! own depth.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use image::Rgb;
use imageproc::drawing::draw_hollow_rect_mut;
use imageproc::rect::Rect;

use super::{build_segmenter, SegmentInput, VisionConfig};
use crate::geometry::morph::bounds;
use crate::geometry::{
    estimate_room, fill_depth, hidden_sides, partial_view, GeometryParams, PartialParams,
};
use crate::scene::{import, model::decompress_depth};

/// Arguments of `grounder segment`.
#[derive(Debug, clap::Args)]
pub struct SegmentArgs {
    /// A scene directory in either layout of FORMATS.md §1.
    pub scene: PathBuf,
    /// The frame's name (its colour file's stem).
    #[arg(long)]
    pub frame: String,
    /// The box in colour pixels: x0,y0,x1,y1.
    #[arg(long, value_delimiter = ',', required = true)]
    pub r#box: Vec<f32>,
    /// Segmenter spec, as the service's `segmenter` setting (`depth`, `depth:colour=off`,
    /// `box`, `sam:...`).
    #[arg(long, default_value = "depth")]
    pub segmenter: String,
    /// Where to write the frame with the mask and the box drawn on it (PNG).
    #[arg(long)]
    pub out: PathBuf,
    /// Complete the frame's missing depth inside the box from the other frames and the
    /// room's box first, as the service does for the chosen view (`on`), or not (`off`).
    #[arg(long, default_value = "on", value_parser = ["on", "off"])]
    pub depth_fill: String,
}

/// Run `grounder segment`.
pub fn run(args: SegmentArgs) -> Result<()> {
    let Ok(b) = <[f32; 4]>::try_from(args.r#box.as_slice()) else {
        bail!(
            "--box takes four numbers, x0,y0,x1,y1, not {}",
            args.r#box.len()
        );
    };
    if !b.iter().all(|v| v.is_finite()) || b[2] <= b[0] || b[3] <= b[1] {
        bail!("--box {b:?} has no area (x1 must exceed x0 and y1 y0)");
    }
    let scene = import::import_dir(&args.scene).map_err(|e| anyhow::anyhow!("{e}"))?;
    let Some(f) = scene.frames.iter().find(|f| f.name == args.frame) else {
        bail!("the scene has no frame named {:?}", args.frame);
    };
    if !f.usable {
        bail!("frame {:?} is not usable (no valid pose)", args.frame);
    }
    let (dw, dh) = scene.depth_size;
    let depth = decompress_depth(&f.depth_blob, dw, dh)
        .with_context(|| format!("frame {}: depth", f.name))?;
    let camera = scene.camera(f);
    let image = image::open(&f.color_path)
        .with_context(|| format!("frame {}: colour", f.name))?
        .to_rgb8();
    let (w, h) = image.dimensions();
    if b[0] >= w as f32 || b[1] >= h as f32 || b[2] <= 0.0 || b[3] <= 0.0 {
        bail!("--box {b:?} lies outside the {w}x{h} image");
    }
    let (depth, fill) = if args.depth_fill == "on" {
        let (depth, stats) = complete(&scene, f, &camera, depth, b)?;
        (depth, serde_json::json!(stats))
    } else {
        (depth, serde_json::Value::Null)
    };
    let seg = build_segmenter(&args.segmenter, &VisionConfig::default())?;
    let input = SegmentInput {
        color: &image,
        depth: &depth,
        camera: &camera,
    };
    let mask = seg.segment(&input, b)?;
    let rule = PartialParams::default();
    let partial = partial_view(&mask, &camera, &depth, &rule);
    let sides = hidden_sides(b, &mask, &camera, &depth, &rule);
    let mut drawn = image.clone();
    for (x, y, p) in drawn.enumerate_pixels_mut() {
        if mask.get(x, y) {
            let [r, g, b] = p.0;
            *p = Rgb([r / 2 + 127, g / 2, b / 2]);
        }
    }
    // The outline kept inside the image, so a box past its edge is drawn along it.
    let [x0, y0, x1, y1] = b.map(|v| v.round().max(0.0) as u32);
    let (x0, y0, x1, y1) = (x0.min(w - 1), y0.min(h - 1), x1.min(w), y1.min(h));
    let outline = Rect::at(x0 as i32, y0 as i32)
        .of_size(x1.saturating_sub(x0).max(1), y1.saturating_sub(y0).max(1));
    draw_hollow_rect_mut(&mut drawn, outline, Rgb([0, 255, 0]));
    drawn
        .save(&args.out)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!(
        "{}",
        serde_json::json!({"frame": f.name, "box": b, "segmenter": seg.name(),
            "pixels": mask.count(), "mask_box": bounds(&mask, 0),
            "partial": partial, "hidden_sides": sides, "depth_fill": fill})
    );
    Ok(())
}

/// `frame`'s `depth` with its missing readings inside `b` completed from the scene's other
/// usable frames and the room's box estimated from all of them, as the service completes
/// the chosen view's (`agent::view_clouds::complete_anchor_depth`), and what that did.
fn complete(
    scene: &import::ImportedScene,
    frame: &import::ImportedFrame,
    camera: &crate::geometry::FrameCamera,
    depth: crate::geometry::DepthMap,
    b: [f32; 4],
) -> Result<(crate::geometry::DepthMap, crate::geometry::DepthFillStats)> {
    let (dw, dh) = scene.depth_size;
    let mut others = Vec::new();
    for o in scene
        .frames
        .iter()
        .filter(|o| o.usable && o.name != frame.name)
    {
        let d = decompress_depth(&o.depth_blob, dw, dh)
            .with_context(|| format!("frame {}: depth", o.name))?;
        others.push((scene.camera(o), d));
    }
    let params = GeometryParams::default();
    let rest: Vec<_> = others.iter().map(|(c, d)| (c, d)).collect();
    let mut all = rest.clone();
    all.push((camera, &depth));
    let room = estimate_room(&all, &params.layout);
    fill_depth(camera, &depth, b, &rest, room.as_ref(), &params)
        .with_context(|| format!("frame {}: depth completion", frame.name))
}
