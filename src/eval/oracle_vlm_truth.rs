//! Ground truth for the oracle VLM: annotated queries (FORMATS §2) and per-frame instance
//! statistics from the scenes' instance masks (FORMATS §1a). Scenes load lazily, once.

use anyhow::{bail, Context, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// One annotated query.
#[derive(Debug, Clone, serde::Deserialize)]
pub struct QueryRec {
    /// Scene id (folder name under the scenes dir).
    pub scene_id: String,
    /// Query id.
    #[serde(default)]
    pub query_id: String,
    /// The sentence.
    pub text: String,
    /// Target instance id.
    pub target_id: u32,
    /// Target label.
    pub target_label: String,
}

/// One instance's footprint in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceStat {
    /// Mask pixels of the instance.
    pub pixels: u64,
    /// Bounding box `[x1, y1, x2, y2]` in colour-image pixels (x2/y2 exclusive).
    pub bbox: [f32; 4],
}

/// One frame (position = image id).
#[derive(Debug, Clone)]
pub struct FrameTruth {
    /// Frame name (decimal).
    pub name: String,
    /// Colour image path, if present.
    pub color: Option<PathBuf>,
    /// Colour image size (mask size when there is no colour image).
    pub size: (u32, u32),
    /// Instances visible in the frame.
    pub instances: HashMap<u32, InstanceStat>,
    /// Pixels of the instance mask the counts come from (its width x height).
    pub mask_area: u64,
}

/// Share of a frame's pixels an object must cover to count as shown in it: the same rule
/// the evaluation's per-stage checks use (`eval::trace`), so the oracle never claims to see
/// the target where the scorer says it is not visible (a sliver at the border).
pub const MIN_VISIBLE_SHARE: f64 = 0.001;

/// All frames of one scene, ordered numerically.
#[derive(Debug, Clone)]
pub struct SceneTruth {
    /// Frames; index = image id.
    pub frames: Vec<FrameTruth>,
}

impl SceneTruth {
    /// Pixels of `instance` in frame `image_id` (0 when absent).
    pub fn pixels(&self, image_id: u32, instance: u32) -> u64 {
        self.frames
            .get(image_id as usize)
            .and_then(|f| f.instances.get(&instance))
            .map_or(0, |s| s.pixels)
    }

    /// Does frame `image_id` show `instance`: at least [`MIN_VISIBLE_SHARE`] of the mask's
    /// pixels (at least one)?
    pub fn shows(&self, image_id: u32, instance: u32) -> bool {
        let area = self
            .frames
            .get(image_id as usize)
            .map_or(1, |f| f.mask_area);
        let min = ((area as f64 * MIN_VISIBLE_SHARE) as u64).max(1);
        self.pixels(image_id, instance) >= min
    }

    /// Does the image border cut `instance` in frame `image_id` (its box reaches within
    /// 0.5 % of the image size of an edge)? False when absent.
    pub fn cut_by_border(&self, image_id: u32, instance: u32) -> bool {
        let Some(f) = self.frames.get(image_id as usize) else {
            return false;
        };
        let Some(s) = f.instances.get(&instance) else {
            return false;
        };
        let (w, h) = (f.size.0 as f32, f.size.1 as f32);
        let (mx, my) = ((0.005 * w).max(1.0), (0.005 * h).max(1.0));
        s.bbox[0] < mx || s.bbox[1] < my || s.bbox[2] > w - mx || s.bbox[3] > h - my
    }

    /// How well frame `image_id` shows `instance`: its pixels, halved when the image
    /// border cuts it (a close-up of part of a chair shows the chair less well than a
    /// slightly smaller view of all of it).
    pub fn visibility(&self, image_id: u32, instance: u32) -> u64 {
        let px = self.pixels(image_id, instance);
        if self.cut_by_border(image_id, instance) {
            px / 2
        } else {
            px
        }
    }
}

/// Queries plus lazily loaded scenes.
#[derive(Debug)]
pub struct Truth {
    queries: Vec<QueryRec>,
    by_text: HashMap<String, Vec<usize>>,
    scenes_dir: PathBuf,
    scenes: Mutex<HashMap<String, Arc<SceneTruth>>>,
}

/// Lowercase, whitespace collapsed: how query texts are matched.
pub fn normalize_text(s: &str) -> String {
    s.split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .to_lowercase()
}

impl Truth {
    /// Read `<dataset>/queries.jsonl`; scenes are read from `scenes_dir` on first use.
    pub fn load(dataset: &Path, scenes_dir: &Path) -> Result<Self> {
        let qpath = dataset.join("queries.jsonl");
        let text = std::fs::read_to_string(&qpath)
            .with_context(|| format!("cannot read {}", qpath.display()))?;
        let mut queries = Vec::new();
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let q: QueryRec = serde_json::from_str(line).with_context(|| {
                format!("{} line {}: not a query record", qpath.display(), i + 1)
            })?;
            queries.push(q);
        }
        if !scenes_dir.is_dir() {
            bail!("scenes dir {} is not a directory", scenes_dir.display());
        }
        let mut by_text: HashMap<String, Vec<usize>> = HashMap::new();
        for (i, q) in queries.iter().enumerate() {
            by_text.entry(normalize_text(&q.text)).or_default().push(i);
        }
        Ok(Self {
            queries,
            by_text,
            scenes_dir: scenes_dir.to_path_buf(),
            scenes: Mutex::new(HashMap::new()),
        })
    }

    /// Number of queries.
    pub fn len(&self) -> usize {
        self.queries.len()
    }

    /// Whether there are no queries.
    pub fn is_empty(&self) -> bool {
        self.queries.is_empty()
    }

    /// Queries whose text matches (normalised), distinct by (scene, target).
    pub fn find(&self, text: &str) -> Vec<&QueryRec> {
        let mut out: Vec<&QueryRec> = Vec::new();
        for &i in self
            .by_text
            .get(&normalize_text(text))
            .into_iter()
            .flatten()
        {
            let q = &self.queries[i];
            if !out
                .iter()
                .any(|o| o.scene_id == q.scene_id && o.target_id == q.target_id)
            {
                out.push(q);
            }
        }
        out
    }

    /// The scene's frame statistics (loaded on first use, then cached).
    pub fn scene(&self, scene_id: &str) -> Result<Arc<SceneTruth>> {
        if let Some(s) = self
            .scenes
            .lock()
            .ok()
            .and_then(|m| m.get(scene_id).cloned())
        {
            return Ok(s);
        }
        if scene_id.contains('/') || scene_id.contains('\\') || scene_id.starts_with('.') {
            bail!("scene id {scene_id:?} is not a plain folder name");
        }
        let loaded = Arc::new(load_scene(&self.scenes_dir.join(scene_id))?);
        if let Ok(mut m) = self.scenes.lock() {
            m.insert(scene_id.to_string(), loaded.clone());
        }
        Ok(loaded)
    }
}

/// Decimal-named files with extension `ext` in `dir`, ordered numerically.
fn numbered_files(dir: &Path, ext: &str) -> Result<Vec<(u64, String, PathBuf)>> {
    let mut out = Vec::new();
    if !dir.is_dir() {
        return Ok(out);
    }
    for e in std::fs::read_dir(dir).with_context(|| format!("cannot list {}", dir.display()))? {
        let path = e?.path();
        if path
            .extension()
            .and_then(|x| x.to_str())
            .map(|x| x.eq_ignore_ascii_case(ext))
            != Some(true)
        {
            continue;
        }
        let Some(stem) = path.file_stem().and_then(|s| s.to_str()) else {
            continue;
        };
        if let Ok(n) = stem.parse::<u64>() {
            out.push((n, stem.to_string(), path));
        }
    }
    out.sort_by_key(|(n, _, _)| *n);
    Ok(out)
}

fn load_scene(dir: &Path) -> Result<SceneTruth> {
    let colors = numbered_files(&dir.join("color"), "jpg")?;
    let masks = numbered_files(&dir.join("instance"), "png")?;
    let mask_by_num: HashMap<u64, &PathBuf> = masks.iter().map(|(n, _, p)| (*n, p)).collect();
    // Image ids follow the colour frames; without colour frames, the mask frames.
    let list: Vec<(u64, String, Option<PathBuf>)> = if colors.is_empty() {
        masks
            .iter()
            .map(|(n, s, _)| (*n, s.clone(), None))
            .collect()
    } else {
        colors
            .iter()
            .map(|(n, s, p)| (*n, s.clone(), Some(p.clone())))
            .collect()
    };
    if list.is_empty() {
        bail!(
            "scene {} has neither color/*.jpg nor instance/*.png frames",
            dir.display()
        );
    }
    let mut frames = Vec::with_capacity(list.len());
    for (num, name, color) in list {
        let color_size = match &color {
            Some(p) => Some(
                image::image_dimensions(p)
                    .with_context(|| format!("cannot read {}", p.display()))?,
            ),
            None => None,
        };
        let (instances, mask_size) = match mask_by_num.get(&num) {
            Some(p) => {
                let (stats, size) = mask_stats(p)?;
                (stats, Some(size))
            }
            None => (HashMap::new(), None),
        };
        let size = color_size.or(mask_size).unwrap_or((1, 1));
        // Masks may be at depth resolution: scale boxes into colour pixels.
        let instances = match mask_size {
            Some((mw, mh)) if (mw, mh) != size => {
                let (sx, sy) = (size.0 as f32 / mw as f32, size.1 as f32 / mh as f32);
                instances
                    .into_iter()
                    .map(|(id, s)| {
                        let b = s.bbox;
                        (
                            id,
                            InstanceStat {
                                pixels: s.pixels,
                                bbox: [b[0] * sx, b[1] * sy, b[2] * sx, b[3] * sy],
                            },
                        )
                    })
                    .collect()
            }
            _ => instances,
        };
        let mask_area = mask_size.map_or(u64::from(size.0) * u64::from(size.1), |(w, h)| {
            u64::from(w) * u64::from(h)
        });
        frames.push(FrameTruth {
            name,
            color,
            size,
            instances,
            mask_area,
        });
    }
    Ok(SceneTruth { frames })
}

/// Per-instance pixel counts and boxes of one 16-bit (or 8-bit) instance mask.
fn mask_stats(path: &Path) -> Result<(HashMap<u32, InstanceStat>, (u32, u32))> {
    let img = image::open(path)
        .with_context(|| format!("cannot read instance mask {}", path.display()))?;
    let (w, h) = (img.width(), img.height());
    let ids: Vec<u32> = match img {
        image::DynamicImage::ImageLuma16(b) => b.into_raw().into_iter().map(u32::from).collect(),
        image::DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(u32::from).collect(),
        _ => bail!("instance mask {} is not a one-channel PNG", path.display()),
    };
    let mut acc: HashMap<u32, (u64, [u32; 4])> = HashMap::new();
    for (i, &id) in ids.iter().enumerate() {
        if id == 0 {
            continue;
        }
        let (x, y) = ((i as u32) % w, (i as u32) / w);
        let e = acc.entry(id).or_insert((0, [x, y, x, y]));
        e.0 += 1;
        e.1 = [e.1[0].min(x), e.1[1].min(y), e.1[2].max(x), e.1[3].max(y)];
    }
    let stats = acc
        .into_iter()
        .map(|(id, (n, b))| {
            let bbox = [
                b[0] as f32,
                b[1] as f32,
                (b[2] + 1) as f32,
                (b[3] + 1) as f32,
            ];
            (id, InstanceStat { pixels: n, bbox })
        })
        .collect();
    Ok((stats, (w, h)))
}

/// Normalised 4×4×4 RGB histogram of an encoded image (used to tell scenes apart).
pub fn color_histogram_bytes(bytes: &[u8]) -> Option<[f32; 64]> {
    let img = image::load_from_memory(bytes).ok()?;
    Some(histogram(&img))
}

/// Normalised 4×4×4 RGB histogram of an image file.
pub fn color_histogram_file(path: &Path) -> Option<[f32; 64]> {
    let img = image::open(path).ok()?;
    Some(histogram(&img))
}

fn histogram(img: &image::DynamicImage) -> [f32; 64] {
    let small = img.thumbnail(128, 128).to_rgb8();
    let mut h = [0f32; 64];
    for p in small.pixels() {
        let bin = (p[0] as usize >> 6) * 16 + (p[1] as usize >> 6) * 4 + (p[2] as usize >> 6);
        h[bin] += 1.0;
    }
    let n: f32 = h.iter().sum::<f32>().max(1.0);
    h.iter_mut().for_each(|v| *v /= n);
    h
}

/// L1 distance of two histograms, both taken without their darkest bin and renormalised.
/// A stitched grid with fewer frames than tiles is mostly black padding; with that bin in,
/// the padding outweighs what the frames show and any scene can come out closest.
pub fn hist_distance(a: &[f32; 64], b: &[f32; 64]) -> f32 {
    let rest = |h: &[f32; 64]| h[1..].iter().sum::<f32>().max(1e-6);
    let (na, nb) = (rest(a), rest(b));
    a[1..]
        .iter()
        .zip(&b[1..])
        .map(|(x, y)| (x / na - y / nb).abs())
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hist_of(tiles: &[[u8; 3]]) -> [f32; 64] {
        // One 8x8 tile per colour, side by side.
        let mut img = image::RgbImage::new(8 * tiles.len() as u32, 8);
        for (x, y, p) in img.enumerate_pixels_mut() {
            *p = image::Rgb(tiles[(x / 8) as usize]);
            let _ = y;
        }
        histogram(&image::DynamicImage::ImageRgb8(img))
    }

    #[test]
    fn grid_padding_does_not_decide_the_scene() {
        let red = [200, 40, 40];
        let blue = [40, 40, 200];
        let black = [0, 0, 0];
        // Scene A's frames are red; scene B's are dark with some blue.
        let a = hist_of(&[red]);
        let b = hist_of(&[black, black, black, blue, blue]);
        // A grid of one red frame and three padding tiles.
        let grid = hist_of(&[red, black, black, black]);
        assert!(hist_distance(&grid, &a) < hist_distance(&grid, &b));
        assert!(hist_distance(&a, &a).abs() < 1e-6);
        // All black on both sides: no information, no panic, finite.
        assert!(hist_distance(&hist_of(&[black]), &hist_of(&[black])).is_finite());
    }
}
