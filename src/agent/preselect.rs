//! Stage 2: view pre-selection from the scene's cached detections. A usable frame is
//! offered when it holds a detection of the target class above the score threshold, or
//! (ours) when it sees by depth and pose what such a detection shows in another frame; when
//! the detector cannot see the class or finds nothing, evenly sampled usable frames are
//! offered instead, and the trace says why.

use serde_json::json;
use std::time::Instant;

use super::{step, VlmGrounder};
use crate::geometry::{reseen, GeometryParams, LayoutParams, RoomLayout};
use crate::jobs::{JobContext, JobFailure};
use crate::scene::SceneData;
use crate::vlm::json::QueryAnalysis;

/// The frames offered to the VLM.
#[derive(Debug, Clone)]
pub struct Preselection {
    /// Frame indices (= image ids), ascending.
    pub frames: Vec<usize>,
    /// The detector's class for the target (None: it cannot see it).
    pub detector_class: Option<String>,
    /// Why the fallback was used, if it was.
    pub fallback: Option<String>,
    /// 0 for the first offer, 1 once widened ([`widened`]): names the grids apart.
    pub round: usize,
}

/// Does a detection label name the detector class (compared in normalised form)?
pub fn same_class(label: &str, class: &str) -> bool {
    label == class
        || crate::vision::synonyms::normalize(label) == crate::vision::synonyms::normalize(class)
}

/// `n` indices spread evenly over `items` (all of them when there are fewer).
pub fn evenly_sampled(items: &[usize], n: usize) -> Vec<usize> {
    if items.len() <= n || n == 0 {
        return items.to_vec();
    }
    (0..n).map(|i| items[i * items.len() / n]).collect()
}

/// The frames' file names and five-digit image ids, for the `preselection` trace step.
fn trace_ids<'a>(ctx: &'a JobContext, frames: &[usize]) -> (Vec<&'a str>, Vec<String>) {
    let names = frames
        .iter()
        .map(|&i| ctx.scene.frames[i].name.as_str())
        .collect();
    let image_ids = frames.iter().map(|i| format!("{i:05}")).collect();
    (names, image_ids)
}

/// After the VLM saw the target in none of `previous`'s frames, which the detector chose
/// (a detector's false detections of the class in other frames, or its misses of the
/// target itself, leave the target out): the usable frames not offered yet, evenly sampled
/// as in the class-agnostic fallback. `None` when the detector did not choose the frames
/// (they already were the fallback) or none is left.
pub async fn widened(
    g: &VlmGrounder,
    ctx: &JobContext,
    analysis: &QueryAnalysis,
    previous: &Preselection,
) -> Option<Preselection> {
    if previous.fallback.is_some() {
        return None;
    }
    let t = Instant::now();
    let rest: Vec<usize> = ctx
        .scene
        .usable_frames()
        .map(|f| f.idx)
        .filter(|i| !previous.frames.contains(i))
        .collect();
    if rest.is_empty() {
        return None;
    }
    let frames = evenly_sampled(&rest, g.params.fallback_frames);
    let fallback = format!(
        "the VLM saw the target in none of the {} frames with a {:?} detection; offering frames without one",
        previous.frames.len(),
        previous.detector_class.as_deref().unwrap_or_default()
    );
    let (names, image_ids) = trace_ids(ctx, &frames);
    step(
        ctx,
        "preselection",
        json!({"target_class": analysis.target_class, "widened_from": previous.frames.len()}),
        json!({"detector_class": previous.detector_class, "image_ids": image_ids, "frames": names, "fallback": fallback}),
        t,
    )
    .await;
    Some(Preselection {
        frames,
        detector_class: previous.detector_class.clone(),
        fallback: Some(fallback),
        round: previous.round + 1,
    })
}

/// `layout`: the room's box when the target is flat against a wall; then a detection's
/// pixels without depth whose ray leaves the room beyond the sensor's range count as
/// measured (projection ends them on the wall).
pub async fn run(
    g: &VlmGrounder,
    ctx: &JobContext,
    analysis: &QueryAnalysis,
    layout: Option<&RoomLayout>,
) -> Result<Preselection, JobFailure> {
    let t = Instant::now();
    let usable: Vec<usize> = ctx.scene.usable_frames().map(|f| f.idx).collect();
    if usable.is_empty() {
        return Err(JobFailure::new(
            "no_usable_frames",
            "every frame of the scene has an invalid pose",
        ));
    }
    let class = g.detector.can_see(&analysis.target_class);
    let mut no_depth: Vec<usize> = Vec::new();
    let mut depth_tier: Option<f64> = None;
    let mut reseen: Vec<usize> = Vec::new();
    let (frames, fallback) = match &class {
        None => (
            evenly_sampled(&usable, g.params.fallback_frames),
            Some(format!(
                "detector cannot see this class: {:?}",
                analysis.target_class
            )),
        ),
        Some(c) => {
            let dets = ctx
                .store
                .detections(&ctx.scene.id, &g.detector_key)
                .await
                .map_err(|e| JobFailure::new("storage_error", e.to_string()))?;
            // The target class's detections above the score, per usable frame that has
            // any: the frames they are in and their boxes serve every rule below.
            let found: Vec<(usize, Vec<[f32; 4]>)> = usable
                .iter()
                .filter_map(|i| {
                    let boxes: Vec<[f32; 4]> = dets
                        .get(i)?
                        .iter()
                        .filter(|d| same_class(&d.label, c) && d.score > g.params.preselect_score)
                        .map(|d| d.bbox)
                        .collect();
                    (!boxes.is_empty()).then_some((*i, boxes))
                })
                .collect();
            let hits: Vec<usize> = found.iter().map(|(i, _)| *i).collect();
            if hits.is_empty() {
                (
                    evenly_sampled(&usable, g.params.fallback_frames),
                    Some(format!(
                        "no frame has a {c:?} detection above {}",
                        g.params.preselect_score
                    )),
                )
            } else {
                // A frame whose every detection of the class lies where the sensor read no
                // depth (too far, glass, a dark surface) cannot give a 3D box, and one where
                // it is mostly unread gives a poor one. Offered: the frames with a
                // well-measured detection if there are any, else those with some depth,
                // else all.
                let best: Vec<f64> = found
                    .iter()
                    .map(|(i, boxes)| {
                        let f = &ctx.scene.frames[*i];
                        boxes
                            .iter()
                            .map(|b| depth_fraction(f, *b, layout, &g.params.geometry.layout))
                            .fold(0.0, f64::max)
                    })
                    .collect();
                let (keep, dropped, tier) = split_by_depth(
                    &hits,
                    &best,
                    g.params.good_depth_fraction,
                    g.params.min_depth_fraction,
                );
                no_depth = dropped;
                depth_tier = tier;
                if g.params.preselect_reseen {
                    let (scene, params) = (ctx.scene.clone(), g.params.geometry.clone());
                    reseen =
                        tokio::task::spawn_blocking(move || reseen_frames(&scene, &found, &params))
                            .await
                            .map_err(|e| {
                                JobFailure::new("internal", format!("pre-selection failed: {e}"))
                            })?;
                }
                let mut frames = keep;
                frames.extend(&reseen);
                frames.sort_unstable();
                (frames, None)
            }
        }
    };
    let (names, image_ids) = trace_ids(ctx, &frames);
    step(
        ctx,
        "preselection",
        json!({"target_class": analysis.target_class, "usable_frames": usable.len()}),
        json!({"detector_class": class, "image_ids": image_ids, "frames": names, "fallback": fallback, "dropped_without_depth": no_depth.iter().map(|i| format!("{i:05}")).collect::<Vec<_>>(), "depth_fraction_required": depth_tier, "reseen": reseen.iter().map(|i| format!("{i:05}")).collect::<Vec<_>>(), "room_layout": layout}),
        t,
    )
    .await;
    Ok(Preselection {
        frames,
        detector_class: class,
        fallback,
        round: 0,
    })
}

/// The usable frames without one of the detections `found` (frame, its boxes) that see, by depth
/// and pose, what one of them shows (`geometry::reseen`): the detector missed the object
/// there. Ascending.
fn reseen_frames(
    scene: &SceneData,
    found: &[(usize, Vec<[f32; 4]>)],
    params: &GeometryParams,
) -> Vec<usize> {
    let probes: Vec<reseen::Probe> = found
        .iter()
        .filter_map(|(i, boxes)| Some((scene.frames.get(*i)?, boxes)))
        .flat_map(|(f, boxes)| {
            boxes
                .iter()
                .filter_map(|b| reseen::box_probe(&f.camera, &f.depth, *b))
        })
        .collect();
    scene
        .usable_frames()
        .filter(|f| !found.iter().any(|(i, _)| *i == f.idx))
        .filter(|f| {
            probes
                .iter()
                .any(|p| reseen::sees_probe(p, &f.camera, &f.depth, params))
        })
        .map(|f| f.idx)
        .collect()
}

/// The frames to offer given each frame's best depth fraction of a target detection
/// (`best[k]` for `hits[k]`): those at `good` or above when any are, else those at `min`
/// or above when any are, else all. Also the frames dropped and the fraction applied.
pub fn split_by_depth(
    hits: &[usize],
    best: &[f64],
    good: f64,
    min: f64,
) -> (Vec<usize>, Vec<usize>, Option<f64>) {
    let Some(t) = [good, min]
        .into_iter()
        .find(|&t| best.iter().any(|&b| b >= t))
    else {
        return (hits.to_vec(), Vec::new(), None);
    };
    let (keep, drop): (Vec<_>, Vec<_>) = hits
        .iter()
        .copied()
        .zip(best.iter().copied())
        .partition(|(_, b)| *b >= t);
    (
        keep.into_iter().map(|(i, _)| i).collect(),
        drop.into_iter().map(|(i, _)| i).collect(),
        Some(t),
    )
}

/// Share of the depth pixels under colour box `b` of frame `f` that hold a reading
/// (sampled on a grid of at most 32 x 32); with a `layout`, an empty pixel whose ray leaves
/// the room beyond the sensor's range counts as read.
pub fn depth_fraction(
    f: &crate::scene::FrameData,
    b: [f32; 4],
    layout: Option<&RoomLayout>,
    lp: &LayoutParams,
) -> f64 {
    let (w, h) = (f.camera.color.width as f32, f.camera.color.height as f32);
    let (x0, y0, x1, y1) = (
        b[0].clamp(0.0, w),
        b[1].clamp(0.0, h),
        b[2].clamp(0.0, w),
        b[3].clamp(0.0, h),
    );
    if x1 <= x0 || y1 <= y0 {
        return 0.0;
    }
    const N: usize = 32;
    let cam_to_out = f.camera.cam_to_out();
    let (mut seen, mut valid) = (0usize, 0usize);
    for j in 0..N {
        for i in 0..N {
            let u = x0 + (x1 - x0) * (i as f32 + 0.5) / N as f32;
            let v = y0 + (y1 - y0) * (j as f32 + 0.5) / N as f32;
            let (du, dv) = f.camera.depth_pixel_for_color(f64::from(u), f64::from(v));
            seen += 1;
            let placeable = || {
                layout.is_some_and(|l| {
                    l.exit_depth(&f.camera, &cam_to_out, f64::from(u), f64::from(v))
                        .is_some_and(|z| l.beyond_range(z, lp))
                })
            };
            valid += usize::from(f.depth.get(du, dv) > 0 || placeable());
        }
    }
    valid as f64 / seen as f64
}

#[cfg(test)]
mod tests {
    use super::evenly_sampled;

    #[test]
    fn samples_evenly_without_repeats() {
        let items: Vec<usize> = (0..10).collect();
        assert_eq!(evenly_sampled(&items, 5), vec![0, 2, 4, 6, 8]);
        assert_eq!(evenly_sampled(&items, 20), items);
        assert_eq!(evenly_sampled(&items[..3], 2), vec![0, 1]);
    }

    #[test]
    fn well_measured_frames_are_preferred_then_any_with_depth_then_all() {
        use super::split_by_depth;
        let hits = [3, 7, 9];
        assert_eq!(
            split_by_depth(&hits, &[0.3, 0.9, 0.1], 0.6, 0.2),
            (vec![7], vec![3, 9], Some(0.6))
        );
        assert_eq!(
            split_by_depth(&hits, &[0.3, 0.5, 0.1], 0.6, 0.2),
            (vec![3, 7], vec![9], Some(0.2))
        );
        assert_eq!(
            split_by_depth(&hits, &[0.0, 0.1, 0.1], 0.6, 0.2),
            (vec![3, 7, 9], vec![], None)
        );
    }

    #[test]
    fn depth_fraction_counts_readings_under_the_box() {
        use crate::geometry::{DepthMap, FrameCamera, Intrinsics};
        use nalgebra::Matrix4;
        use std::sync::Arc;
        // Colour 80x60, depth 40x30: the left half of the depth image has no reading.
        let depth = DepthMap::new(
            40,
            30,
            (0..40 * 30)
                .map(|i| if i % 40 < 20 { 0 } else { 1500 })
                .collect(),
        );
        let color = Intrinsics {
            fx: 60.0,
            fy: 60.0,
            cx: 39.5,
            cy: 29.5,
            width: 80,
            height: 60,
        };
        let camera = FrameCamera {
            color,
            depth: None,
            depth_size: (40, 30),
            pose: Matrix4::identity(),
            align: Matrix4::identity(),
        };
        let f = crate::scene::FrameData {
            idx: 0,
            name: "0".into(),
            usable: true,
            camera,
            depth: Arc::new(depth),
            color_path: "0.jpg".into(),
            instance_path: None,
        };
        assert_eq!(
            super::depth_fraction(&f, [0.0, 0.0, 38.0, 60.0], None, &Default::default()),
            0.0
        );
        assert_eq!(
            super::depth_fraction(&f, [40.0, 0.0, 80.0, 60.0], None, &Default::default()),
            1.0
        );
        assert!(
            (super::depth_fraction(&f, [20.0, 10.0, 60.0, 50.0], None, &Default::default()) - 0.5)
                .abs()
                < 0.05
        );
        assert_eq!(
            super::depth_fraction(&f, [90.0, 0.0, 100.0, 10.0], None, &Default::default()),
            0.0,
            "outside the image"
        );
    }
}
