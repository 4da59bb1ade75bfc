//! `grounder synth`: generate synthetic posed RGB-D scenes with exact ground truth.

use super::{generate_family, preview, write_dataset, Family, Layout, Noise, SynthParams};
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Arguments of `grounder synth`.
#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Output directory; each scene goes to `<out>/<scene_id>/`.
    #[arg(long)]
    pub out: PathBuf,
    /// Scene family: `rooms` (boxes) or `props` (curved and thin parts, close-ups).
    #[arg(long, value_enum, default_value_t = Family::Rooms)]
    pub family: Family,
    /// Seed of the (first) scene; the scene id is `scene_synth_<seed>` (rooms) or
    /// `scene_props_<seed>` (props).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Number of scenes (seeds seed, seed+1, ...).
    #[arg(long, default_value_t = 1)]
    pub scenes: u64,
    /// Frames per scene.
    #[arg(long, default_value_t = 60)]
    pub frames: usize,
    /// Sensor noise.
    #[arg(long, value_enum, default_value_t = Noise::None)]
    pub noise: Noise,
    /// Directory layout (FORMATS §1a `scannet` or §1b `posed-images`).
    #[arg(long, value_enum, default_value_t = Layout::Scannet)]
    pub layout: Layout,
    /// Colour image size WxH.
    #[arg(long, default_value = "1296x968", value_parser = parse_size)]
    pub color_size: (u32, u32),
    /// Depth image size WxH.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub depth_size: (u32, u32),
    /// Also write `<out>/<scene_id>.tar`.
    #[arg(long)]
    pub tar: bool,
    /// Write FORMATS §2 annotations (objects/<scene>.json, queries.jsonl) into this directory.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Write a contact sheet `<out>/<scene_id>_preview.png` (colour + depth).
    #[arg(long)]
    pub preview: bool,
}

fn parse_size(s: &str) -> std::result::Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WxH, got {s:?}"))?;
    let w = w
        .trim()
        .parse()
        .map_err(|_| format!("bad width in {s:?}"))?;
    let h = h
        .trim()
        .parse()
        .map_err(|_| format!("bad height in {s:?}"))?;
    Ok((w, h))
}

/// Run `grounder synth`.
pub fn run(args: SynthArgs) -> Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("synth: cannot create {}", args.out.display()))?;
    let mut scenes = Vec::new();
    for k in 0..args.scenes.max(1) {
        let params = SynthParams {
            seed: args.seed + k,
            frames: args.frames,
            noise: args.noise,
            color_size: args.color_size,
            depth_size: args.depth_size,
            layout: args.layout,
            ..SynthParams::new(args.seed + k)
        };
        let start = std::time::Instant::now();
        let scene = generate_family(args.family, &params, &args.out, args.tar)?;
        eprintln!(
            "{}: {} objects, {} queries, {} frames in {:.1} s -> {}",
            scene.scene_id,
            scene.objects.len(),
            scene.queries.len(),
            scene.frames.len(),
            start.elapsed().as_secs_f64(),
            scene.dir.display()
        );
        if args.preview {
            let png = args.out.join(format!("{}_preview.png", scene.scene_id));
            preview::contact_sheet(&scene, &png, 8)?;
            eprintln!("preview: {}", png.display());
        }
        scenes.push(scene);
    }
    if let Some(d) = &args.dataset {
        write_dataset(&scenes, d)?;
        eprintln!("annotations: {}", d.display());
    }
    Ok(())
}
