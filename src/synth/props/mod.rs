//! The `props` scene family: a second synthetic world, independent in its assumptions from
//! the `rooms` family's furniture of axis-aligned boxes.
//!
//! Objects are built from vertical cylinders and cones (lamp poles and shades, round table
//! tops and pedestals, bins, vases, pots), ellipsoids (foliage, pillows) and thin boxes
//! turned about the vertical (chair legs and open backs, shelf boards, curtain pleats).
//! Objects stand at any yaw; chairs are pushed under tables; shelves, tables and desks
//! carry small things; the camera walks the room and stops for close-ups. Ground-truth
//! boxes are the axis-aligned bounds of the turned geometry in the aligned frame, as
//! ScanNet's are. Only the output writer, the sensor-noise model and the query templates
//! are shared with `rooms`.

mod layout;
mod models;
mod path;
mod place;
mod prim;
mod render;

use super::{noise, output, queries, Noise, SynthFrame, SynthParams, SynthScene};
use anyhow::{Context, Result};
use rayon::prelude::*;
use std::path::Path;

/// Scene id of a props seed: `scene_props_0007`.
pub fn scene_id(seed: u64) -> String {
    format!("scene_props_{seed:04}")
}

/// Build, render and write one props scene into `<out_dir>/<scene_id>/` (and its tar when
/// `tar`). Output bytes depend only on `params`.
pub fn generate_with(params: &SynthParams, out_dir: &Path, tar: bool) -> Result<SynthScene> {
    params.validate()?;
    let world = layout::build(params.seed);
    let sid = scene_id(params.seed);
    let dir = out_dir.join(&sid);
    let color_k = super::color_intrinsics(params.color_size.0, params.color_size.1);
    let depth_k = color_k.scaled_to(params.depth_size.0, params.depth_size.1);
    let poses = path::camera_path(&world, params.frames, params.seed);
    let invalid = noise::invalid_pose_frames(params);
    let frames: Vec<SynthFrame> = poses
        .iter()
        .enumerate()
        .map(|(i, p)| SynthFrame {
            name: (i as u64 * params.frame_step as u64).to_string(),
            pose_aligned: *p,
            pose_valid: !invalid.contains(&i),
        })
        .collect();

    let writer = output::SceneWriter::create(&dir, params.layout)
        .with_context(|| format!("synth: cannot create scene directory {}", dir.display()))?;
    let labels: Vec<(u32, &str)> = world
        .objects
        .iter()
        .map(|o| (o.id, o.label.as_str()))
        .collect();
    writer.write_static(&world.align, &labels, &color_k, &depth_k)?;
    let renderer = render::Renderer::new(&world, params.seed);
    frames
        .par_iter()
        .enumerate()
        .try_for_each(|(i, f)| -> Result<()> {
            let color = renderer.render_color(&f.pose_aligned, &color_k);
            let mut depth = renderer.render_depth(&f.pose_aligned, &depth_k);
            let mut rgb = color.rgb;
            let mut pose_out = f.pose_aligned;
            if params.noise == Noise::Realistic {
                noise::depth_noise(&mut depth, params.seed, i);
                noise::color_noise(&mut rgb, params.seed, i);
                pose_out = noise::jitter_pose(&pose_out, params.seed, i);
            }
            let pose_world = world.align_inv * pose_out;
            writer.write_frame(
                &f.name,
                &rgb,
                &color_k,
                &depth.mm,
                &depth_k,
                &color.instance,
                f.pose_valid.then_some(&pose_world),
                params.jpeg_quality,
            )
        })?;

    let objects = world.output_objects();
    let queries = queries::make_queries(&sid, &objects);
    let tar_path = if tar {
        Some(output::write_tar(&dir, out_dir, &sid)?)
    } else {
        None
    };
    Ok(SynthScene {
        scene_id: sid,
        dir,
        tar: tar_path,
        room_size: world.size,
        objects,
        queries,
        frames,
        axis_align: world.align,
        color_intrinsics: color_k,
        depth_intrinsics: depth_k,
        params: params.clone(),
    })
}
