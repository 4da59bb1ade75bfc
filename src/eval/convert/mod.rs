//! `grounder convert`: ScanRefer JSON, Nr3D CSV and ScanNet ground truth into FORMATS §2.

pub mod nr3d;
pub mod scannet;
pub mod scanrefer;

use super::dataset::{write_dataset, Query, SceneObjects};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Which original format to convert.
#[derive(Debug, clap::Subcommand)]
pub enum ConvertCommand {
    /// ScanNet scans -> objects/<scene>.json (boxes = AABB of the axis-aligned vertices).
    ScannetGt {
        /// Folder holding one ScanNet scan folder per scene (<scans>/<scene>/<scene>_vh_clean_2.ply, ...).
        #[arg(long)]
        scans: PathBuf,
        /// Only these scenes (repeatable); default: every sub-folder of --scans.
        #[arg(long = "scene")]
        scenes: Vec<String>,
        /// Output dataset folder (objects/ is written there).
        #[arg(long)]
        out: PathBuf,
    },
    /// ScanRefer JSON -> queries.jsonl (needs the objects from `convert scannet-gt`).
    Scanrefer {
        /// ScanRefer JSON file (a list of annotations).
        #[arg(long)]
        input: PathBuf,
        /// Objects folder (or a dataset folder containing objects/).
        #[arg(long)]
        objects: PathBuf,
        /// Output dataset folder (queries.jsonl and objects/ of the scenes used).
        #[arg(long)]
        out: PathBuf,
    },
    /// Nr3D CSV -> queries.jsonl with "hard" and "view_dependent" flags.
    Nr3d {
        /// Nr3D CSV file.
        #[arg(long)]
        input: PathBuf,
        /// Objects folder (or a dataset folder containing objects/).
        #[arg(long)]
        objects: PathBuf,
        /// Output dataset folder.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Run one conversion and print what was written.
pub fn run(cmd: ConvertCommand) -> Result<()> {
    match cmd {
        ConvertCommand::ScannetGt { scans, scenes, out } => {
            let written = scannet::convert_scans(&scans, &scenes, &out)?;
            println!(
                "wrote objects for {written} scenes into {}",
                out.join("objects").display()
            );
        }
        ConvertCommand::Scanrefer {
            input,
            objects,
            out,
        } => {
            let objs = ObjectsSource::new(&objects);
            let (queries, skipped) = scanrefer::convert(&input, &objs)?;
            finish(&out, &objs, &queries, skipped)?;
        }
        ConvertCommand::Nr3d {
            input,
            objects,
            out,
        } => {
            let objs = ObjectsSource::new(&objects);
            let (queries, skipped) = nr3d::convert(&input, &objs)?;
            finish(&out, &objs, &queries, skipped)?;
        }
    }
    Ok(())
}

fn finish(out: &Path, objs: &ObjectsSource, queries: &[Query], skipped: usize) -> Result<()> {
    if queries.is_empty() {
        bail!("no query could be converted ({skipped} skipped: scene or object missing from the objects folder)");
    }
    let scenes: Vec<SceneObjects> = objs
        .cache
        .borrow()
        .values()
        .filter_map(|s| s.clone())
        .collect();
    write_dataset(out, &scenes, queries)?;
    println!(
        "wrote {} queries ({} skipped) for {} scenes into {}",
        queries.len(),
        skipped,
        scenes.len(),
        out.display()
    );
    Ok(())
}

/// Lazily loaded `objects/<scene>.json` files.
pub struct ObjectsSource {
    dir: PathBuf,
    cache: std::cell::RefCell<BTreeMap<String, Option<SceneObjects>>>,
}

impl ObjectsSource {
    /// `dir` is an objects folder or a dataset folder with `objects/` inside.
    pub fn new(dir: &Path) -> Self {
        let sub = dir.join("objects");
        let dir = if sub.is_dir() { sub } else { dir.to_path_buf() };
        Self {
            dir,
            cache: Default::default(),
        }
    }

    /// The scene's objects; `None` when the file does not exist. A broken file is an error.
    pub fn get(&self, scene_id: &str) -> Result<Option<SceneObjects>> {
        if let Some(s) = self.cache.borrow().get(scene_id) {
            return Ok(s.clone());
        }
        let path = self.dir.join(format!("{scene_id}.json"));
        let loaded = if path.is_file() {
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("cannot read {}", path.display()))?;
            Some(
                serde_json::from_str(&text)
                    .with_context(|| format!("{} is not a valid objects file", path.display()))?,
            )
        } else {
            None
        };
        self.cache
            .borrow_mut()
            .insert(scene_id.to_string(), loaded.clone());
        Ok(loaded)
    }
}
