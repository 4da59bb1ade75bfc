//! Turning a job's trace into per-stage outcomes ([`StageOutcome`]) using the scene's
//! ground-truth instance masks (`instance/<frame>.png`, FORMATS §1).
//!
//! The trace is an array of steps `{"step": name, "outputs": {...}}`; everything is
//! optional and unknown steps are ignored. Steps are recognised by name (lower case):
//!
//! | step name contains              | outputs read                                          |
//! |---------------------------------|-------------------------------------------------------|
//! | `preselect`                     | `frames` (frame names) or `image_ids` (indices)       |
//! | `image` + `select`/`choice`/`choose`/`ground` | `frame` or `image_id`                   |
//! | `detect`                        | `detections: [{"bbox"|"box": [x1,y1,x2,y2]}]`, optional `frame`/`image_id` |
//! | `instance`                      | `bbox`/`box`, or `index` into the detections          |
//! | `segment`                       | `mask: {"width","height","rle":[runs]}` (row-major runs, first run is background) |
//!
//! Boxes and masks are in colour-image pixels. An image id is the position of the frame
//! in the numerically sorted frame list. The detection and instance stages succeed when a
//! box has 2D IoU >= 0.5 with the bounding box of the target's ground-truth mask.

use super::metrics::StageOutcome;
use crate::geometry::Mask;
use anyhow::{Context, Result};
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// 2D IoU needed for a detection to count as the target.
pub const BOX2D_IOU: f64 = 0.5;

/// A target mask (instance-mask pixels) with the colour image size.
type LoadedMask = (Mask, (u32, u32));

/// Ground-truth view of one target in one scene, read lazily from instance masks.
pub struct TargetViews {
    instance_dir: PathBuf,
    color_dir: PathBuf,
    /// Frame names sorted by numeric value.
    frames: Vec<String>,
    target_id: u16,
    cache: HashMap<String, Option<LoadedMask>>,
}

/// Frame names of a scene directory (either layout), sorted numerically.
pub fn frame_names(scene_dir: &Path) -> Result<Vec<String>> {
    let color = scene_dir.join("color");
    let (dir, ext) = if color.is_dir() {
        (color, "jpg")
    } else {
        (scene_dir.to_path_buf(), "jpg")
    };
    let mut names: Vec<(f64, String)> = Vec::new();
    for e in std::fs::read_dir(&dir).with_context(|| format!("cannot list {}", dir.display()))? {
        let p = e?.path();
        if p.extension()
            .and_then(|x| x.to_str())
            .map(|x| x.eq_ignore_ascii_case(ext))
            != Some(true)
        {
            continue;
        }
        if let Some(stem) = p.file_stem().and_then(|s| s.to_str()) {
            if let Ok(v) = stem.parse::<f64>() {
                names.push((v, stem.to_string()));
            }
        }
    }
    names.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(names.into_iter().map(|n| n.1).collect())
}

impl TargetViews {
    /// Prepare for `scene_dir`; `None` when the scene has no `instance/` folder.
    pub fn open(scene_dir: &Path, target_id: u32) -> Result<Option<Self>> {
        let instance_dir = scene_dir.join("instance");
        if !instance_dir.is_dir() {
            return Ok(None);
        }
        let color = scene_dir.join("color");
        let color_dir = if color.is_dir() {
            color
        } else {
            scene_dir.to_path_buf()
        };
        let target_id =
            u16::try_from(target_id).context("target id does not fit a 16-bit instance mask")?;
        Ok(Some(Self {
            instance_dir,
            color_dir,
            frames: frame_names(scene_dir)?,
            target_id,
            cache: HashMap::new(),
        }))
    }

    /// Resolve a frame reference (name, or image id when `is_image_id`).
    fn frame_of(&self, v: &Value, is_image_id: bool) -> Option<String> {
        let s = match v {
            Value::String(s) => s.clone(),
            Value::Number(n) => n.to_string(),
            _ => return None,
        };
        if is_image_id {
            let i: usize = s.parse().ok()?;
            self.frames.get(i).cloned()
        } else {
            Some(s)
        }
    }

    /// Target mask in instance-mask pixels and the colour image size, if readable.
    fn target_mask(&mut self, frame: &str) -> Option<&LoadedMask> {
        if !self.cache.contains_key(frame) {
            let loaded = self.load(frame);
            self.cache.insert(frame.to_string(), loaded);
        }
        self.cache.get(frame).and_then(|m| m.as_ref())
    }

    fn load(&self, frame: &str) -> Option<LoadedMask> {
        let img = image::open(self.instance_dir.join(format!("{frame}.png")))
            .ok()?
            .into_luma16();
        let color = image::image_dimensions(self.color_dir.join(format!("{frame}.jpg")))
            .unwrap_or(img.dimensions());
        let mut m = Mask::new(img.width(), img.height());
        for (x, y, p) in img.enumerate_pixels() {
            if p.0[0] == self.target_id {
                m.set(x, y, true);
            }
        }
        Some((m, color))
    }

    /// Whether the target is visible in the frame (at least 0.1 % of the pixels, min 1).
    pub fn visible(&mut self, frame: &str) -> Option<bool> {
        let (m, _) = self.target_mask(frame)?;
        let min = ((m.width as f64 * m.height as f64) * super::oracle_vlm_truth::MIN_VISIBLE_SHARE)
            .max(1.0) as usize;
        Some(m.count() >= min)
    }

    /// Target's 2D bounding box in colour pixels [x1, y1, x2, y2), if visible.
    pub fn target_box(&mut self, frame: &str) -> Option<[f64; 4]> {
        let (m, (cw, ch)) = self.target_mask(frame)?;
        let (sx, sy) = (*cw as f64 / m.width as f64, *ch as f64 / m.height as f64);
        let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
        for y in 0..m.height {
            for x in 0..m.width {
                if m.get(x, y) {
                    b = [
                        b[0].min(x as f64),
                        b[1].min(y as f64),
                        b[2].max(x as f64 + 1.0),
                        b[3].max(y as f64 + 1.0),
                    ];
                }
            }
        }
        (b[0] <= b[2]).then(|| [b[0] * sx, b[1] * sy, b[2] * sx, b[3] * sy])
    }

    /// IoU of a predicted colour-pixel mask with the target mask (resampled to the mask grid).
    pub fn mask_iou(&mut self, frame: &str, pred: &Mask) -> Option<f64> {
        let (gt, _) = self.target_mask(frame)?;
        let mut resampled = Mask::new(gt.width, gt.height);
        for y in 0..gt.height {
            for x in 0..gt.width {
                let px = ((x as f64 + 0.5) * pred.width as f64 / gt.width as f64) as u32;
                let py = ((y as f64 + 0.5) * pred.height as f64 / gt.height as f64) as u32;
                resampled.set(x, y, pred.get(px, py));
            }
        }
        Some(gt.iou(&resampled))
    }
}

/// 2D IoU of two [x1, y1, x2, y2] boxes.
pub fn box2d_iou(a: [f64; 4], b: [f64; 4]) -> f64 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let area = |r: [f64; 4]| (r[2] - r[0]).max(0.0) * (r[3] - r[1]).max(0.0);
    let union = area(a) + area(b) - inter;
    if union <= 0.0 {
        0.0
    } else {
        inter / union
    }
}

fn as_box(v: &Value) -> Option<[f64; 4]> {
    let a = v.as_array()?;
    if a.len() != 4 {
        return None;
    }
    let mut b = [0.0; 4];
    for (i, x) in a.iter().enumerate() {
        b[i] = x.as_f64()?;
    }
    Some(b)
}

fn det_box(d: &Value) -> Option<[f64; 4]> {
    d.get("bbox").or_else(|| d.get("box")).and_then(as_box)
}

/// Run lengths of a mask, row-major, alternating background/foreground, starting with
/// background (possibly 0): the `rle` field the segment step should report.
pub fn encode_rle(mask: &Mask) -> Vec<u64> {
    let mut runs = vec![0u64];
    let mut cur = false;
    for &b in &mask.data {
        if b != cur {
            runs.push(0);
            cur = b;
        }
        if let Some(last) = runs.last_mut() {
            *last += 1;
        }
    }
    runs
}

/// Decode `{"width","height","rle":[runs]}` (runs alternate background/foreground).
pub fn decode_rle(v: &Value) -> Option<Mask> {
    let w = u32::try_from(v.get("width")?.as_u64()?).ok()?;
    let h = u32::try_from(v.get("height")?.as_u64()?).ok()?;
    let mut m = Mask::new(w, h);
    let total = m.data.len();
    let mut pos = 0usize;
    for (i, run) in v.get("rle")?.as_array()?.iter().enumerate() {
        let n = usize::try_from(run.as_u64()?).ok()?;
        let end = pos.checked_add(n)?.min(total);
        if i % 2 == 1 {
            m.data[pos..end].iter_mut().for_each(|b| *b = true);
        }
        pos = end;
    }
    Some(m)
}

fn frame_ref(views: &TargetViews, o: &Value, one: (&str, &str)) -> Option<String> {
    o.get(one.0)
        .and_then(|v| views.frame_of(v, false))
        .or_else(|| o.get(one.1).and_then(|v| views.frame_of(v, true)))
}

/// Read the stage outcomes a trace allows (the box stage is filled by scoring).
pub fn stages_from_trace(trace: &Value, views: &mut TargetViews) -> StageOutcome {
    let mut st = StageOutcome::default();
    let Some(steps) = trace.as_array() else {
        return st;
    };
    let mut chosen: Option<String> = None;
    let mut detections: Vec<[f64; 4]> = Vec::new();
    for step in steps {
        let name = step
            .get("step")
            .and_then(|s| s.as_str())
            .unwrap_or_default()
            .to_lowercase();
        let null = Value::Null;
        let o = step.get("outputs").unwrap_or(&null);
        if name.contains("preselect") {
            let list = o
                .get("frames")
                .and_then(|a| a.as_array())
                .map(|a| {
                    a.iter()
                        .filter_map(|v| views.frame_of(v, false))
                        .collect::<Vec<_>>()
                })
                .or_else(|| {
                    o.get("image_ids")
                        .and_then(|a| a.as_array())
                        .map(|a| a.iter().filter_map(|v| views.frame_of(v, true)).collect())
                });
            if let Some(list) = list {
                st.preselection_contains_target =
                    Some(list.iter().any(|f| views.visible(f) == Some(true)));
            }
        } else if name.contains("image")
            && ["select", "choice", "choose", "ground"]
                .iter()
                .any(|k| name.contains(k))
        {
            if let Some(f) = frame_ref(views, o, ("frame", "image_id")) {
                st.image_choice_correct = views.visible(&f);
                chosen = Some(f);
            }
        } else if name.contains("detect") {
            let frame = frame_ref(views, o, ("frame", "image_id")).or_else(|| chosen.clone());
            if let (Some(f), Some(list)) = (frame, o.get("detections").and_then(|d| d.as_array())) {
                detections = list.iter().filter_map(det_box).collect();
                chosen = Some(f.clone());
                st.detection_present = Some(match views.target_box(&f) {
                    Some(t) => detections.iter().any(|d| box2d_iou(*d, t) >= BOX2D_IOU),
                    None => false,
                });
            }
        } else if name.contains("instance") {
            let b = det_box(o).or_else(|| {
                o.get("index")
                    .and_then(|i| i.as_u64())
                    .and_then(|i| detections.get(i as usize).copied())
            });
            if let (Some(b), Some(f)) = (b, chosen.clone()) {
                st.instance_choice_correct = Some(
                    views
                        .target_box(&f)
                        .is_some_and(|t| box2d_iou(b, t) >= BOX2D_IOU),
                );
            }
        } else if name.contains("segment") {
            let frame = frame_ref(views, o, ("frame", "image_id")).or_else(|| chosen.clone());
            if let (Some(f), Some(m)) = (frame, o.get("mask").and_then(decode_rle)) {
                st.mask_iou = views.mask_iou(&f, &m);
            }
        }
    }
    st
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// Scene with frames 0, 20, 40 (colour 16x12, instance masks 8x6 = half size).
    /// Target 5 occupies mask pixels x 2..6, y 1..4 in frame 20 only; object 9 in frame 40.
    fn scene() -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(d.path().join("color")).unwrap();
        std::fs::create_dir_all(d.path().join("instance")).unwrap();
        for f in [0u32, 20, 40] {
            image::RgbImage::new(16, 12)
                .save(d.path().join(format!("color/{f}.jpg")))
                .unwrap();
            let mut m = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(8, 6);
            for y in 1..4 {
                for x in 2..6 {
                    if f == 20 {
                        m.put_pixel(x, y, image::Luma([5]));
                    } else if f == 40 {
                        m.put_pixel(x, y, image::Luma([9]));
                    }
                }
            }
            m.save(d.path().join(format!("instance/{f}.png"))).unwrap();
        }
        d
    }

    #[test]
    fn good_trace_all_stages_succeed() {
        let d = scene();
        let mut v = TargetViews::open(d.path(), 5).unwrap().unwrap();
        // Target box in colour pixels: [4, 2, 12, 8].
        assert_eq!(v.target_box("20"), Some([4.0, 2.0, 12.0, 8.0]));
        // Predicted mask in colour pixels covering exactly the target (x 4..12, y 2..8) -> IoU 1.
        let pred = Mask::from_box(16, 12, [4.0, 2.0, 12.0, 8.0]);
        let rle = encode_rle(&pred);
        assert_eq!(
            decode_rle(&json!({"width": 16, "height": 12, "rle": rle.clone()})),
            Some(pred)
        );
        let trace = json!([
            {"step": "preselect_views", "outputs": {"frames": ["0", 20]}},
            {"step": "vlm_image_selection", "outputs": {"image_id": 1}},
            {"step": "detect", "outputs": {"detections": [{"bbox": [0, 0, 3, 3]}, {"box": [4, 2, 12, 9]}]}},
            {"step": "vlm_instance_selection", "outputs": {"index": 1}},
            {"step": "segment", "outputs": {"mask": {"width": 16, "height": 12, "rle": rle}}},
        ]);
        let st = stages_from_trace(&trace, &mut v);
        assert_eq!(st.preselection_contains_target, Some(true));
        assert_eq!(st.image_choice_correct, Some(true));
        assert_eq!(st.detection_present, Some(true));
        assert_eq!(st.instance_choice_correct, Some(true));
        assert!(
            (st.mask_iou.unwrap() - 1.0).abs() < 1e-9,
            "{:?}",
            st.mask_iou
        );
    }

    #[test]
    fn bad_trace_fails_stages_and_tolerates_junk() {
        let d = scene();
        let mut v = TargetViews::open(d.path(), 5).unwrap().unwrap();
        let trace = json!([
            {"step": "preselect", "outputs": {"frames": ["0", "40"]}},
            {"step": "image_choice", "outputs": {"frame": "40"}},
            {"step": "detect", "outputs": {"frame": "20", "detections": [{"bbox": [0, 0, 4, 4]}]}},
            {"step": "select_instance", "outputs": {"bbox": [0, 0, 4, 4]}},
            {"step": "segment", "outputs": {"mask": {"width": 2, "height": 2, "rle": [4]}}},
            {"step": "weird", "outputs": 3},
            {"nothing": true}
        ]);
        let st = stages_from_trace(&trace, &mut v);
        assert_eq!(st.preselection_contains_target, Some(false));
        assert_eq!(st.image_choice_correct, Some(false));
        assert_eq!(st.detection_present, Some(false));
        assert_eq!(st.instance_choice_correct, Some(false));
        assert_eq!(st.mask_iou, Some(0.0));
        assert_eq!(
            stages_from_trace(&json!({"not": "a list"}), &mut v),
            StageOutcome::default()
        );
    }

    #[test]
    fn no_instance_folder_means_no_views() {
        let d = tempfile::tempdir().unwrap();
        assert!(TargetViews::open(d.path(), 1).unwrap().is_none());
        assert!((box2d_iou([0.0, 0.0, 2.0, 2.0], [1.0, 0.0, 3.0, 2.0]) - 1.0 / 3.0).abs() < 1e-12);
    }
}
