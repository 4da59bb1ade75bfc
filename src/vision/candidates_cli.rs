//! `grounder candidates`: the class-agnostic candidates of a scene directory's frames,
//! drawn as the VLM would see them (one PNG per frame) and listed as JSON lines.

use std::path::PathBuf;

use anyhow::{Context, Result};

use super::candidates::{frame_candidates, CandidateParams};
use crate::geometry::{estimate_room, LayoutParams};
use crate::scene::{import, model::decompress_depth};
use crate::stitch::annotate::{annotate_instances, AnnotateOptions};

/// Arguments of `grounder candidates`.
#[derive(Debug, clap::Args)]
pub struct CandidatesArgs {
    /// A scene directory in either layout of FORMATS.md §1.
    pub scene: PathBuf,
    /// Frame names to draw (default: every tenth usable frame).
    #[arg(long, value_delimiter = ',')]
    pub frames: Vec<String>,
    /// Folder for the drawn frames (`<frame>.png`).
    #[arg(long)]
    pub out: PathBuf,
}

/// Run `grounder candidates`.
pub fn run(args: CandidatesArgs) -> Result<()> {
    let scene = import::import_dir(&args.scene).map_err(|e| anyhow::anyhow!("{e}"))?;
    let (dw, dh) = scene.depth_size;
    let mut frames = Vec::new();
    for f in scene.frames.iter().filter(|f| f.usable) {
        let depth = decompress_depth(&f.depth_blob, dw, dh)
            .with_context(|| format!("frame {}: depth", f.name))?;
        let cam = scene.camera(f);
        frames.push((f, cam, depth));
    }
    let lp = LayoutParams::default();
    let pairs: Vec<_> = frames.iter().map(|(_, c, d)| (c, d)).collect();
    let room = estimate_room(&pairs, &lp);
    eprintln!(
        "room layout: {}",
        serde_json::to_string(&room).unwrap_or_default()
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let params = CandidateParams::default();
    for (k, (f, cam, depth)) in frames.iter().enumerate() {
        let wanted = if args.frames.is_empty() {
            k % 10 == 0
        } else {
            args.frames.contains(&f.name)
        };
        if !wanted {
            continue;
        }
        let img = image::open(&f.color_path)
            .with_context(|| format!("frame {}: colour", f.name))?
            .to_rgb8();
        let cands = frame_candidates(cam, depth, &img, room.as_ref(), &lp, &params);
        let boxes: Vec<(String, [f32; 4])> = cands
            .iter()
            .enumerate()
            .map(|(i, c)| (i.to_string(), c.bbox))
            .collect();
        let opts = AnnotateOptions {
            draw_boxes: true,
            ..AnnotateOptions::default()
        };
        let drawn = annotate_instances(&img, &boxes, &opts)?;
        let path = args.out.join(format!("{}.png", f.name));
        drawn
            .save(&path)
            .with_context(|| format!("cannot write {}", path.display()))?;
        for (i, c) in cands.iter().enumerate() {
            println!(
                "{}",
                serde_json::json!({"frame": f.name, "id": i, "kind": c.kind, "box": c.bbox,
                    "cells": c.cells, "min": c.min, "max": c.max})
            );
        }
    }
    Ok(())
}
