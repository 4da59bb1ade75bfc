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

use super::{write_scene, SceneHead, SynthParams, SynthScene};
use anyhow::Result;
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
    let poses = path::camera_path(&world, params.frames, params.seed);
    let head = SceneHead {
        scene_id: scene_id(params.seed),
        room_size: world.size,
        align: world.align,
        align_inv: world.align_inv,
        objects: world.output_objects(),
    };
    let renderer = render::Renderer::new(&world, params.seed);
    write_scene(
        params,
        out_dir,
        tar,
        head,
        &poses,
        |_, pose, color_k, depth_k| {
            (
                renderer.render_color(pose, color_k),
                renderer.render_depth(pose, depth_k),
            )
        },
    )
}
