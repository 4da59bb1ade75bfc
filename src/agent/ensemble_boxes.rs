//! The box segmented in each ensemble view (paper Sec. 3.4 with our additions): the cached
//! detection of the target class that holds the reprojected part of the object, else,
//! when candidates are on for the views, the view's class-agnostic candidate that holds
//! it, else the box of the reprojected points alone (the footprint). [`super::view_box`]
//! may then ask the VLM for one view's box.

use std::collections::BTreeMap;

use super::candidate_cache;
use super::preselect::{same_class, Preselection};
use super::VlmGrounder;
use crate::geometry::ensemble::ViewCandidate;
use crate::jobs::{JobContext, JobFailure};
use crate::vision::Detection;

/// The detection to segment in an ensemble view (the reference's rule): among `boxes`, the
/// one holding the most reprojected anchor pixels per unit box area, provided it holds at
/// least half of them. Containment, not overlap, so a partial anchor (an object cut by the
/// anchor frame's border) still selects the whole object's box in a view that sees all of it.
pub fn pick_detection(boxes: &[[f32; 4]], pixels: &[[u32; 2]]) -> Option<[f32; 4]> {
    if pixels.is_empty() {
        return None;
    }
    boxes
        .iter()
        .filter_map(|b| {
            let inside = pixels
                .iter()
                .filter(|&&[x, y]| {
                    (x as f32) >= b[0]
                        && (x as f32) < b[2]
                        && (y as f32) >= b[1]
                        && (y as f32) < b[3]
                })
                .count();
            let area = ((b[2] - b[0]) * (b[3] - b[1])).max(1.0);
            (2 * inside >= pixels.len()).then_some((inside as f32 / area, *b))
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, b)| b)
}

/// Where an ensemble view's box came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BoxFrom {
    /// A cached detection of the target class.
    Detection,
    /// One of the view's class-agnostic candidates (`vision::candidates`).
    Candidate,
    /// The box of the reprojected anchor points.
    Footprint,
    /// The VLM's box of the whole object in this view ([`super::view_box`]).
    VlmBox,
}

/// View `i`'s box when it is only the reprojection of the part the chosen view saw
/// (`partial`: the chosen view saw a part of the object; the view has no detection,
/// candidate or VLM box of its own). Such a view's mask is that part alone: it speaks only
/// inside this box, and around its mask lies the rest of the object (a window's glass
/// beyond the part), not what the object stands on or against.
pub fn part_only(
    view_boxes: &[(usize, [f32; 4], BoxFrom)],
    i: usize,
    partial: bool,
) -> Option<[f32; 4]> {
    let &(_, b, from) = view_boxes.iter().find(|v| v.0 == i)?;
    (partial && from == BoxFrom::Footprint).then_some(b)
}

/// View `i`'s box when it holds the whole object there, so that it may bound the object
/// as the chosen box does (`geometry::bound`): the VLM's box of the whole object, and the
/// view's matched detection when the view sees at least `detections` (`None`: never) of
/// the chosen view's points (`seen`, the view search's visible fraction): a detector
/// boxes what the view shows, less what hides there. A candidate may be a part or a merge
/// of objects, and a footprint is the chosen view's part.
pub fn whole_object_box(
    view_boxes: &[(usize, [f32; 4], BoxFrom)],
    i: usize,
    detections: Option<f64>,
    seen: f64,
) -> Option<[f32; 4]> {
    let &(_, b, from) = view_boxes.iter().find(|v| v.0 == i)?;
    let detection = from == BoxFrom::Detection && detections.is_some_and(|m| seen >= m);
    (from == BoxFrom::VlmBox || detection).then_some(b)
}

/// The context points support completion looks at: the chosen view's (`anchor`), then
/// those of each view in `views` (index, context) that `kept` (by the fusion) and whose
/// box is not the part only (`part_only`).
pub fn support_context<P: Copy>(
    anchor: Vec<P>,
    views: &[(usize, &[P])],
    kept: impl Fn(usize) -> bool,
    part_only: impl Fn(usize) -> bool,
) -> Vec<P> {
    let mut context = anchor;
    for &(i, ctx) in views {
        if kept(i) && !part_only(i) {
            context.extend_from_slice(ctx);
        }
    }
    context
}

/// The view's cached candidate holding the reprojected anchor `pixels` ([`pick_detection`]).
fn view_candidate(
    cands: &BTreeMap<usize, Vec<Detection>>,
    idx: usize,
    pixels: &[[u32; 2]],
) -> Option<[f32; 4]> {
    let boxes: Vec<[f32; 4]> = cands.get(&idx)?.iter().map(|c| c.bbox).collect();
    pick_detection(&boxes, pixels)
}

/// Each view's box and where it came from, in the order of `views`; `take_candidates`:
/// the views' class-agnostic candidates may be used. Also the views whose candidates the
/// index lacked and were computed now (`candidate_cache`).
pub async fn boxes(
    g: &VlmGrounder,
    ctx: &JobContext,
    pre: &Preselection,
    views: &[ViewCandidate],
    take_candidates: bool,
) -> Result<(Vec<(usize, [f32; 4], BoxFrom)>, Vec<usize>), JobFailure> {
    let scene = &ctx.scene;
    // A box in each view: the cached detection of the class that best overlaps the footprint.
    let dets = match &pre.detector_class {
        Some(_) => ctx
            .store
            .detections(&scene.id, &g.detector_key)
            .await
            .map_err(|e| JobFailure::new("storage_error", e.to_string()))?,
        None => Default::default(),
    };
    let best: Vec<Option<[f32; 4]>> = views
        .iter()
        .map(|v| {
            let c = pre.detector_class.as_ref()?;
            let boxes: Vec<[f32; 4]> = dets
                .get(&v.index)?
                .iter()
                .filter(|d| same_class(&d.label, c) && d.score > g.params.preselect_score)
                .map(|d| d.bbox)
                .collect();
            pick_detection(&boxes, &v.pixels)
        })
        .collect();
    // Else the view's class-agnostic candidates, by the same rule: the object the anchor's
    // points fall on, whole, where the anchor saw only a part of it (a chair's back over a
    // table's edge). Read for the views without a detection, in one query.
    let wanted: Vec<usize> = views
        .iter()
        .zip(&best)
        .filter(|(_, b)| b.is_none())
        .map(|(v, _)| v.index)
        .collect();
    let found = if take_candidates && !wanted.is_empty() {
        Some(candidate_cache::of_frames(g, ctx, &wanted, None).await?)
    } else {
        None
    };
    // Without either, the footprint's own box.
    let view_boxes = views
        .iter()
        .zip(best)
        .map(|(v, best)| {
            let cand = || view_candidate(&found.as_ref()?.by_frame, v.index, &v.pixels);
            match best {
                Some(b) => (v.index, b, BoxFrom::Detection),
                None => match cand() {
                    Some(b) => (v.index, b, BoxFrom::Candidate),
                    None => (v.index, v.bbox, BoxFrom::Footprint),
                },
            }
        })
        .collect();
    Ok((view_boxes, found.map(|f| f.computed).unwrap_or_default()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_view_that_segmented_only_the_part_gives_no_context_for_support() {
        let vb = [
            (3, [0.0, 0.0, 10.0, 10.0], BoxFrom::Footprint),
            (5, [0.0, 0.0, 20.0, 20.0], BoxFrom::VlmBox),
            (7, [0.0, 0.0, 30.0, 30.0], BoxFrom::Footprint),
        ];
        // Part-only: a footprint box, and only when the chosen view saw a part.
        assert_eq!(part_only(&vb, 3, true), Some([0.0, 0.0, 10.0, 10.0]));
        assert_eq!(part_only(&vb, 3, false), None);
        assert_eq!(part_only(&vb, 5, true), None);
        assert_eq!(part_only(&vb, 9, true), None);
        let (a, v3, v5, v7) = ([0], [3, 3], [5], [7]);
        let views: [(usize, &[i32]); 3] = [(3, &v3), (5, &v5), (7, &v7)];
        let kept = |i: usize| i != 7;
        for (partial, want) in [(true, vec![0, 5]), (false, vec![0, 3, 3, 5])] {
            let ctx = support_context(a.to_vec(), &views, kept, |i| {
                part_only(&vb, i, partial).is_some()
            });
            assert_eq!(ctx, want, "partial {partial}");
        }
    }

    #[test]
    fn the_vlms_box_and_a_matched_detection_bound_the_object_a_candidate_does_not() {
        let b = |k: f32| [k, k, k + 10.0, k + 10.0];
        let vb = [
            (1, b(1.0), BoxFrom::Detection),
            (2, b(2.0), BoxFrom::Candidate),
            (3, b(3.0), BoxFrom::Footprint),
            (4, b(4.0), BoxFrom::VlmBox),
        ];
        let of = |detections, seen| -> Vec<_> {
            (1..=5)
                .map(|i| whole_object_box(&vb, i, detections, seen))
                .collect()
        };
        let (some, vlm) = (Some(b(1.0)), Some(b(4.0)));
        assert_eq!(of(Some(0.9), 0.95), [some, None, None, vlm, None]);
        // A view that sees too little of the chosen view's points, or detections off.
        assert_eq!(of(Some(0.9), 0.8), [None, None, None, vlm, None]);
        assert_eq!(of(None, 1.0), [None, None, None, vlm, None]);
    }

    #[test]
    fn detection_pick_prefers_containment_per_area() {
        // Footprint: the top strip of an object cut by the anchor frame.
        let pixels: Vec<[u32; 2]> = (10..30)
            .flat_map(|x| (10..14).map(move |y| [x, y]))
            .collect();
        let whole = [8.0, 8.0, 32.0, 60.0]; // the whole object: holds all, IoU with the strip < 0.3
        let neighbour = [28.0, 8.0, 50.0, 30.0]; // holds a corner only
        let huge = [0.0, 0.0, 200.0, 200.0]; // holds all, but per area it loses
        assert_eq!(
            pick_detection(&[neighbour, huge, whole], &pixels),
            Some(whole)
        );
        assert_eq!(pick_detection(&[neighbour], &pixels), None);
        assert_eq!(pick_detection(&[whole], &[]), None);
    }
}
