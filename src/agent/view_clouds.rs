//! One view's segmentation in the projection stage: depth completion, the segmenter, the
//! points and their context, and wall cuts ([`segment_points`]); the same for every
//! ensemble view ([`ViewSegmenter`]); and the check that a view's class-agnostic candidate
//! agrees with the chosen view before it is used ([`check_candidates`]).

use std::collections::HashMap;
use std::sync::Arc;

use image::RgbImage;
use nalgebra::Point3;
use serde_json::json;

use super::ensemble_boxes::BoxFrom;
use crate::geometry::bound::{within_bound, ViewBound};
use crate::geometry::ensemble::{chamfer_decisions, mask_points};
use crate::geometry::export::point_colours;
use crate::geometry::support::context_points;
use crate::geometry::{
    cut_room_walls, cut_wall_leaks, fill_depth, GeometryParams, Mask, RoomLayout, WallCut,
};
use crate::scene::{FrameData, SceneData};
use crate::vision::{SegmentInput, Segmenter};

/// A view's segmentation: raw mask, the object's points, and the context points around it
/// (for support completion; empty when that is off).
pub(super) struct ViewCloud {
    pub mask: Mask,
    pub points: Vec<Point3<f64>>,
    pub context: Vec<Point3<f64>>,
    /// Wall patches cut from the points (see [`cut_wall_leaks`]).
    pub wall_cuts: Vec<WallCut>,
}

/// `cut_walls`: remove wall patches the mask leaked onto, found in the context around
/// the mask and, given `walls` (the room's box), on the room's faced walls (not for
/// objects that are flat against a wall: there the wall is the object's own plane).
pub(super) fn segment_points(
    seg: &dyn Segmenter,
    frame: &FrameData,
    image: &RgbImage,
    bbox: [f32; 4],
    params: &GeometryParams,
    cut_walls: bool,
    walls: Option<&RoomLayout>,
) -> anyhow::Result<ViewCloud> {
    let mask = seg.segment(
        &SegmentInput {
            color: image,
            depth: &frame.depth,
            camera: &frame.camera,
        },
        bbox,
    )?;
    let points = mask_points(&mask, &frame.camera, &frame.depth, params)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let context = if params.support.enabled && !points.is_empty() {
        context_points(&mask, bbox, &frame.camera, &frame.depth, &params.support)
            .map_err(|e| anyhow::anyhow!("{e}"))?
    } else {
        Vec::new()
    };
    let (points, wall_cuts) = if cut_walls {
        let (points, mut cuts) = match walls {
            Some(room) => {
                // What the frame shows at given points, for telling by colour what stands
                // within a wall's band (looked up only when some point is in one).
                let look = |pts: &[Point3<f64>]| point_colours(pts, &frame.camera, image, [0; 3]);
                cut_room_walls(&points, &context, room, Some(&look), &params.support)
            }
            None => (points, Vec::new()),
        };
        let (points, more) = cut_wall_leaks(&points, &context, &params.support);
        cuts.extend(more);
        (points, cuts)
    } else {
        (points, Vec::new())
    };
    Ok(ViewCloud {
        mask,
        points,
        context,
        wall_cuts,
    })
}

/// The anchor frame with the empty depth pixels inside `bbox` filled from the other usable
/// frames (`geometry::fill_depth`) and the room's `layout`, when that is on, and what it did
/// for the trace (null when off; the reason when the frame could not be completed, which
/// leaves it as it was).
pub(super) fn complete_anchor_depth(
    scene: &crate::scene::SceneData,
    anchor: FrameData,
    bbox: [f32; 4],
    layout: Option<&RoomLayout>,
    params: &GeometryParams,
) -> (FrameData, serde_json::Value) {
    if !params.depth_fill.enabled {
        return (anchor, serde_json::Value::Null);
    }
    let others: Vec<_> = scene
        .usable_frames()
        .filter(|f| f.idx != anchor.idx)
        .map(|f| (&f.camera, f.depth.as_ref()))
        .collect();
    complete_depth(anchor, bbox, &others, layout, params)
}

/// `frame` with the empty depth pixels inside `bbox` completed from `others` and `layout`
/// (see [`complete_anchor_depth`]).
fn complete_depth(
    mut frame: FrameData,
    bbox: [f32; 4],
    others: &[(&crate::geometry::FrameCamera, &crate::geometry::DepthMap)],
    layout: Option<&RoomLayout>,
    params: &GeometryParams,
) -> (FrameData, serde_json::Value) {
    match fill_depth(&frame.camera, &frame.depth, bbox, others, layout, params) {
        Ok((depth, stats)) => {
            if stats.filled > 0 {
                frame.depth = Arc::new(depth);
            }
            (frame, json!(stats))
        }
        Err(e) => (frame, json!({"error": e.to_string()})),
    }
}

/// A view's segmentation and what depth completion did for it.
pub(super) type Segmented = (ViewCloud, serde_json::Value);

/// The views whose candidate passed [`check_candidates`]: the box checked and its
/// segmentation, by view index.
pub(super) type Checked = HashMap<usize, ([f32; 4], Segmented)>;

/// What segments the ensemble views of one job, the same way for every view: depth
/// completion with `room` (when given), then [`segment_points`].
#[derive(Clone)]
pub(super) struct ViewSegmenter {
    pub seg: Arc<dyn Segmenter>,
    pub params: GeometryParams,
    pub scene: Arc<SceneData>,
    pub room: Option<Arc<RoomLayout>>,
    pub cut_walls: bool,
    pub walls: Option<Arc<RoomLayout>>,
}

impl ViewSegmenter {
    /// View `i`'s box `b` segmented in `image`, and what depth completion did (null when it
    /// was not asked to); None when the segmenter failed.
    pub fn segment(&self, i: usize, b: [f32; 4], image: &RgbImage) -> Option<Segmented> {
        let (frame, fill) = match &self.room {
            Some(room) => complete_depth(
                self.scene.frames[i].clone(),
                b,
                &[],
                Some(room.as_ref()),
                &self.params,
            ),
            None => (self.scene.frames[i].clone(), serde_json::Value::Null),
        };
        segment_points(
            self.seg.as_ref(),
            &frame,
            image,
            b,
            &self.params,
            self.cut_walls,
            self.walls.as_deref(),
        )
        .ok()
        .map(|c| (c, fill))
    }
}

/// The views whose box is a class-agnostic candidate, segmented and compared with the
/// chosen view's points (`anchor`) by the fusion's chamfer filter before the box is used,
/// within the chosen box's `bound` as the fusion compares them.
/// A candidate can be a region that holds the object together with what touches it (a
/// chair behind a bed of a like colour): its points then lie far from the anchor's, the
/// fusion would drop the view, and the view is lost. Such a view takes its footprint's box
/// instead (as without candidates; [`super::view_box`] may then ask the VLM for it). The
/// views that pass keep their segmentation, returned by index for the fusion to reuse, with
/// what was checked for the trace.
pub(super) fn check_candidates(
    vs: &ViewSegmenter,
    (anchor, bound): (&[Point3<f64>], Option<&ViewBound<'_>>),
    footprints: &[(usize, [f32; 4])],
    view_boxes: &mut [(usize, [f32; 4], BoxFrom)],
    decoded: &HashMap<usize, Arc<RgbImage>>,
) -> (Checked, Vec<serde_json::Value>) {
    use rayon::prelude::*;
    let segmented: Vec<(usize, [f32; 4], Option<Segmented>)> = view_boxes
        .par_iter()
        .filter(|(_, _, from)| *from == BoxFrom::Candidate)
        .filter_map(|&(i, b, _)| {
            let img = decoded.get(&i)?;
            Some((i, b, vs.segment(i, b, img)))
        })
        .collect();
    // Judged on what the fusion would take from it: the points the chosen box allows.
    let clouds: Vec<(usize, Vec<Point3<f64>>)> = segmented
        .iter()
        .map(|(i, _, c)| {
            let pts = c.as_ref().map_or(&[][..], |(c, _)| &c.points[..]);
            (
                *i,
                bound.map_or_else(|| pts.to_vec(), |b| within_bound(pts, b)),
            )
        })
        .collect();
    // Symmetric, though the anchor is a part here: the one-sided test would pass the
    // region that holds the object with its neighbour, which is what this check is for.
    let decisions = chamfer_decisions(anchor, &clouds, false, &vs.params);
    let mut kept = HashMap::new();
    let mut trace = Vec::new();
    for ((i, b, cloud), d) in segmented.into_iter().zip(decisions) {
        let (image_id, chamfer) = (format!("{i:05}"), d.chamfer);
        trace.push(json!({"image_id": image_id, "box": b, "chamfer": chamfer, "kept": d.kept}));
        match cloud {
            Some(c) if d.kept => {
                kept.insert(i, (b, c));
            }
            _ => {
                let footprint = footprints.iter().find(|v| v.0 == i).map(|v| v.1);
                let entry = view_boxes.iter_mut().find(|v| v.0 == i);
                if let (Some(f), Some(vb)) = (footprint, entry) {
                    *vb = (i, f, BoxFrom::Footprint);
                }
            }
        }
    }
    (kept, trace)
}
