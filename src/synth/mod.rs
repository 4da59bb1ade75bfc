//! Synthetic posed RGB-D scenes with exact ground truth (`grounder synth`).
//!
//! A room (floor, walls, ceiling) holds 8–20 pieces of furniture, each made of a few
//! axis-aligned boxes in the room's *aligned* frame. A camera walks a loop at head height;
//! every frame is ray-cast into a colour image, a depth image (u16 millimetres) and an
//! instance mask. Poses are written in an unaligned world frame together with
//! `axis_align_matrix.txt` (world -> aligned), so ground-truth boxes are axis-aligned in the
//! output frame of FORMATS.md §1 exactly as for ScanNet.
//!
//! A second family, [`props`], builds rooms from curved and thin parts instead
//! ([`Family`], [`generate_family`]).
//!
//! Library first: [`generate`] writes one scene and returns its ground truth;
//! [`write_dataset`] writes FORMATS §2 annotations for a set of scenes.

mod build;
mod catalog;
pub mod cli;
mod noise;
mod output;
mod path;
pub mod preview;
pub mod props;
mod queries;
mod render;
mod room;

use crate::geometry::{Aabb, Intrinsics};
use anyhow::{Context, Result};
use nalgebra::Matrix4;
use rayon::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};

pub use queries::write_dataset;

/// Sensor imperfections added to the rendered data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
pub enum Noise {
    /// Exact depth, exact poses.
    None,
    /// Distance-dependent depth noise, flying pixels, holes, a depth cut-off, pose jitter,
    /// a few frames with inf poses and colour sensor noise.
    Realistic,
}

/// Scene family: which generator builds the room.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
pub enum Family {
    /// Furniture of axis-aligned boxes, camera loop at head height (`scene_synth_<seed>`).
    #[default]
    Rooms,
    /// Cylinders, cones, ellipsoids and thin turned boxes; clutter; chairs under tables;
    /// close-ups as well as room-wide views (`scene_props_<seed>`).
    Props,
}

/// Build, render and write one scene of `family` (and its tar when `tar`).
pub fn generate_family(
    family: Family,
    params: &SynthParams,
    out_dir: &Path,
    tar: bool,
) -> Result<SynthScene> {
    match family {
        Family::Rooms => generate_with(params, out_dir, tar),
        Family::Props => props::generate_with(params, out_dir, tar),
    }
}

/// On-disk layout of the scene directory (FORMATS §1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
pub enum Layout {
    /// §1a: `color/`, `depth/`, `pose/`, `intrinsic/` sub-folders (ScanNet SensReader).
    Scannet,
    /// §1b: one folder of `<frame>.jpg/.png/.txt` plus `intrinsic.txt`.
    PosedImages,
}

/// Everything that determines a synthetic scene. Same parameters → same bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthParams {
    /// Seed of every random choice (room, objects, path, noise).
    pub seed: u64,
    /// Number of frames rendered.
    pub frames: usize,
    /// Sensor imperfections.
    pub noise: Noise,
    /// Colour image size (width, height); instance masks use this size too.
    pub color_size: (u32, u32),
    /// Depth image size (width, height).
    pub depth_size: (u32, u32),
    /// Directory layout.
    pub layout: Layout,
    /// Frame names are `i * frame_step` (ScanNet's every-20th sampling: 0, 20, 40, ...).
    pub frame_step: u32,
    /// JPEG quality of the colour images.
    pub jpeg_quality: u8,
}

impl SynthParams {
    /// ScanNet-sized scene: 60 frames, colour 1296x968, depth 640x480, no noise.
    pub fn new(seed: u64) -> Self {
        Self {
            seed,
            frames: 60,
            noise: Noise::None,
            color_size: (1296, 968),
            depth_size: (640, 480),
            layout: Layout::Scannet,
            frame_step: 20,
            jpeg_quality: 90,
        }
    }

    /// Small scene for tests: 8 frames, colour 320x240, depth 160x120, no noise.
    pub fn small(seed: u64) -> Self {
        Self {
            frames: 8,
            color_size: (320, 240),
            depth_size: (160, 120),
            ..Self::new(seed)
        }
    }

    pub(crate) fn validate(&self) -> Result<()> {
        let (cw, ch) = self.color_size;
        let (dw, dh) = self.depth_size;
        anyhow::ensure!(self.frames >= 1, "synth: at least one frame is needed");
        anyhow::ensure!(
            cw >= 8 && ch >= 8 && dw >= 8 && dh >= 8,
            "synth: image sizes must be at least 8x8"
        );
        anyhow::ensure!(
            cw <= 8192 && ch <= 8192 && dw <= 8192 && dh <= 8192,
            "synth: image sizes above 8192 are not supported"
        );
        anyhow::ensure!(self.frame_step >= 1, "synth: frame_step must be at least 1");
        Ok(())
    }
}

/// One ground-truth object. Boxes are in the OUTPUT frame (after `axis_align_matrix`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SynthObject {
    /// Instance id (equals the ids in `instance/*.png` and `objects/<scene>.json`).
    pub id: u32,
    /// Category, e.g. "chair".
    pub label: String,
    /// Colour name, e.g. "red".
    pub color: String,
    /// Tight axis-aligned box of the object's geometry.
    pub aabb: Aabb,
    /// The boxes the object is built from (their union's bounds are `aabb`).
    #[serde(skip)]
    pub parts: Vec<Aabb>,
    /// Linear RGB albedo used by the renderer.
    #[serde(skip)]
    pub rgb: [f64; 3],
}

/// One templated query whose target is unique by construction.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SynthQuery {
    pub scene_id: String,
    pub query_id: String,
    pub text: String,
    pub target_id: u32,
    pub target_label: String,
    /// "unique" or "multiple" (ScanRefer's definition, FORMATS §2).
    pub subset: String,
    /// Template family: "attribute", "relation", "support" or "extreme".
    pub kind: String,
}

/// One rendered frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthFrame {
    /// Decimal frame name (file stem).
    pub name: String,
    /// True camera-to-world pose in the OUTPUT (aligned) frame (used for rendering).
    pub pose_aligned: Matrix4<f64>,
    /// False when the pose file holds inf (unusable frame, FORMATS §1).
    pub pose_valid: bool,
}

/// A generated scene: where it was written and its exact ground truth.
#[derive(Debug, Clone)]
pub struct SynthScene {
    /// e.g. `scene_synth_0007`.
    pub scene_id: String,
    /// The scene directory (`<out_dir>/<scene_id>`).
    pub dir: PathBuf,
    /// The tar archive of the scene directory, when requested.
    pub tar: Option<PathBuf>,
    /// Room extent in the output frame: x in [0, size.0], y in [0, size.1], z in [0, size.2].
    pub room_size: (f64, f64, f64),
    pub objects: Vec<SynthObject>,
    pub queries: Vec<SynthQuery>,
    pub frames: Vec<SynthFrame>,
    /// World -> output frame, as written to `axis_align_matrix.txt`.
    pub axis_align: Matrix4<f64>,
    pub color_intrinsics: Intrinsics,
    pub depth_intrinsics: Intrinsics,
    pub params: SynthParams,
}

/// Scene id for a seed: `scene_synth_0007`.
pub fn scene_id(seed: u64) -> String {
    format!("scene_synth_{seed:04}")
}

/// Colour intrinsics of a synthetic camera (ScanNet-like field of view, square pixels).
pub fn color_intrinsics(width: u32, height: u32) -> Intrinsics {
    let f = 0.903 * width as f64; // 1170 px at 1296 wide, as ScanNet's colour camera
    Intrinsics {
        fx: f,
        fy: f,
        cx: (width as f64 - 1.0) / 2.0,
        cy: (height as f64 - 1.0) / 2.0,
        width,
        height,
    }
}

/// Build, render and write one scene into `<out_dir>/<scene_id>/`.
///
/// Frames are rendered in parallel; output bytes depend only on `params`.
pub fn generate(params: &SynthParams, out_dir: &Path) -> Result<SynthScene> {
    generate_with(params, out_dir, false)
}

/// Like [`generate`], optionally also writing `<out_dir>/<scene_id>.tar`.
pub fn generate_with(params: &SynthParams, out_dir: &Path, tar: bool) -> Result<SynthScene> {
    params.validate()?;
    let world = room::build(params.seed);
    let poses = path::camera_path(&world, params.frames, params.seed);
    let head = SceneHead {
        scene_id: scene_id(params.seed),
        room_size: world.size,
        align: world.align,
        align_inv: world.align_inv,
        objects: world.output_objects(),
    };
    let renderer = render::Renderer::new(&world);
    write_scene(
        params,
        out_dir,
        tar,
        head,
        &poses,
        |i, pose, color_k, depth_k| {
            (
                renderer.render_color(pose, color_k, params, i),
                renderer.render_depth(pose, depth_k),
            )
        },
    )
}

/// What a scene family hands to [`write_scene`] about its world.
pub(crate) struct SceneHead {
    pub scene_id: String,
    pub room_size: (f64, f64, f64),
    /// Aligned frame from the world frame, and back.
    pub align: Matrix4<f64>,
    pub align_inv: Matrix4<f64>,
    /// Every object; their instance ids and labels go to `instance/labels.json`.
    pub objects: Vec<SynthObject>,
}

/// Render and write a scene of any family: the frames of the camera path `poses` (aligned
/// frame) in parallel through `render(i, pose, colour intrinsics, depth intrinsics)` ->
/// (colour and instance ids, depth), with the sensor noise of `params`, then the static
/// files, the queries and (when `tar`) the archive. Output bytes depend only on `params`.
pub(crate) fn write_scene<R>(
    params: &SynthParams,
    out_dir: &Path,
    tar: bool,
    head: SceneHead,
    poses: &[Matrix4<f64>],
    render: R,
) -> Result<SynthScene>
where
    R: Fn(
            usize,
            &Matrix4<f64>,
            &Intrinsics,
            &Intrinsics,
        ) -> (render::ColorFrame, render::DepthFrame)
        + Sync,
{
    let sid = head.scene_id;
    let dir = out_dir.join(&sid);
    let color_k = color_intrinsics(params.color_size.0, params.color_size.1);
    let depth_k = color_k.scaled_to(params.depth_size.0, params.depth_size.1);
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
    let labels: Vec<(u32, &str)> = head
        .objects
        .iter()
        .map(|o| (o.id, o.label.as_str()))
        .collect();
    writer.write_static(&head.align, &labels, &color_k, &depth_k)?;
    frames
        .par_iter()
        .enumerate()
        .try_for_each(|(i, f)| -> Result<()> {
            let (mut color, mut depth) = render(i, &f.pose_aligned, &color_k, &depth_k);
            let mut pose_out = f.pose_aligned;
            if params.noise == Noise::Realistic {
                noise::depth_noise(&mut depth, params.seed, i);
                noise::color_noise(&mut color.rgb, params.seed, i);
                pose_out = noise::jitter_pose(&pose_out, params.seed, i);
            }
            let pose_world = head.align_inv * pose_out;
            writer.write_frame(
                &f.name,
                &color.rgb,
                &color_k,
                &depth.mm,
                &depth_k,
                &color.instance,
                f.pose_valid.then_some(&pose_world),
                params.jpeg_quality,
            )
        })?;

    let objects = head.objects;
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
        room_size: head.room_size,
        objects,
        queries,
        frames,
        axis_align: head.align,
        color_intrinsics: color_k,
        depth_intrinsics: depth_k,
        params: params.clone(),
    })
}
