//! Stage 5: segmentation and multi-view ensemble projection (paper Sec. 3.4). The chosen
//! box is segmented, the mask back-projected; other views that see those points are found
//! by reprojection (our replacement for image matching), a box is segmented in each (a
//! cached detection of the class, a candidate or the footprint's own box:
//! [`super::ensemble_boxes`]; the VLM's box in views left with the footprint when the
//! chosen view saw a part and no view has a detection: [`super::view_box`]; a view's
//! candidate is first checked against the chosen view: [`super::view_clouds`]), and the
//! views that agree (chamfer filter) are fused. Before the
//! union, each kept view's points are checked against the other views' masks, and the
//! union against the depth of the frames that see it (ours: `geometry::consensus`).

use image::RgbImage;
use nalgebra::Point3;
use serde_json::json;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

use super::ensemble_boxes::BoxFrom;
use super::grounding::Choice;
use super::preselect::Preselection;
use super::view_clouds::{
    check_candidates, complete_anchor_depth, segment_points, ViewCloud, ViewSegmenter,
};
use super::vlm_log::VlmLog;
use super::{exports, ms, step, VlmGrounder};
use crate::geometry::ensemble::{find_views_with_room, single_view_box, CandidateFrame};
use crate::geometry::floor_reach::stand_on_floor;
use crate::geometry::fusion::{fuse_segmented, SegmentedView, VotedFusion};
use crate::geometry::round_back::round_back;
use crate::geometry::support::{extend_to_support, median_point};
use crate::geometry::{
    face_depth_ratio, hidden_sides, partial_view, snap_planar_to_wall, view_bound, Aabb,
    LayoutParams, Mask, RoomLayout,
};
use crate::jobs::{JobContext, JobFailure};
use crate::vlm::CallBudget;

/// The 3D answer.
pub struct Projected {
    pub bbox: Aabb,
    pub views_used: usize,
}

/// Row-major run lengths, the first run being background (for traces).
pub fn mask_rle(m: &Mask) -> Vec<u32> {
    let mut runs = Vec::new();
    let mut cur = false;
    let mut n = 0u32;
    for &b in &m.data {
        if b != cur {
            runs.push(n);
            n = 0;
            cur = b;
        }
        n += 1;
    }
    runs.push(n);
    runs
}

/// The room's box (`geometry::estimate_room`) when the target is flat against a wall and
/// the layout prior is on: where no frame measured such an object, its pixels end on the
/// wall. Other objects stand somewhere in front of the wall, so for them it is not used.
/// Estimated once per loaded scene (at indexing or by the first job that needs it) and
/// shared: see [`crate::scene::RoomMemo`].
pub async fn room_layout(
    g: &VlmGrounder,
    ctx: &JobContext,
    target_class: &str,
) -> Result<Option<Arc<RoomLayout>>, JobFailure> {
    let params = &g.params.geometry;
    if !params.layout.enabled || !params.support.is_flat(target_class) {
        return Ok(None);
    }
    scene_room(ctx, params.layout.clone()).await
}

/// The scene's room box (estimated once per loaded scene, off the async threads).
async fn scene_room(
    ctx: &JobContext,
    layout: LayoutParams,
) -> Result<Option<Arc<RoomLayout>>, JobFailure> {
    let scene = ctx.scene.clone();
    tokio::task::spawn_blocking(move || scene.room_layout(&layout))
        .await
        .map_err(|e| JobFailure::new("internal", format!("layout task failed: {e}")))
}

/// The room's box for cutting an object's points off its walls
/// ([`crate::geometry::cut_room_walls`]), when walls are cut for this class and the cut and
/// the layout are on (estimated once per loaded scene, shared with [`room_layout`]).
async fn room_walls(
    g: &VlmGrounder,
    ctx: &JobContext,
    cut_walls: bool,
) -> Result<Option<Arc<RoomLayout>>, JobFailure> {
    let params = &g.params.geometry;
    if !cut_walls
        || !params.layout.enabled
        || !params.support.enabled
        || !params.support.room_wall_cut
    {
        return Ok(None);
    }
    scene_room(ctx, params.layout.clone()).await
}

/// The chosen view's box segmented, its empty depth pixels completed first (with `layout`
/// for an object flat against a wall), and what completion did.
async fn segment_anchor(
    g: &VlmGrounder,
    ctx: &JobContext,
    choice: &Choice,
    layout: Option<Arc<RoomLayout>>,
    cut_walls: bool,
    walls: Option<Arc<RoomLayout>>,
) -> Result<(ViewCloud, serde_json::Value), JobFailure> {
    let sc = ctx.scene.clone();
    let anchor = sc.frames[choice.frame_idx].clone();
    let (seg, params, image, bbox) = (
        g.segmenter.clone(),
        g.params.geometry.clone(),
        choice.image.clone(),
        choice.bbox,
    );
    tokio::task::spawn_blocking(move || {
        let (anchor, fill) = complete_anchor_depth(&sc, anchor, bbox, layout.as_deref(), &params);
        segment_points(
            seg.as_ref(),
            &anchor,
            &image,
            bbox,
            &params,
            cut_walls,
            walls.as_deref(),
        )
        .map(|c| (c, fill))
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("segmentation task failed: {e}")))?
    .map_err(|e| JobFailure::new("segmentation_failed", format!("{e:#}")))
}

/// The anchor's image comes with `choice`; the ensemble views are decoded here.
#[allow(clippy::too_many_arguments)]
pub async fn run(
    g: &VlmGrounder,
    ctx: &JobContext,
    budget: &CallBudget,
    log: &VlmLog,
    target_class: &str,
    pre: &Preselection,
    choice: &Choice,
    layout: Option<Arc<RoomLayout>>,
) -> Result<Projected, JobFailure> {
    let mut slot = Some(g.compute_slot(ctx).await?);
    let t = Instant::now();
    let scene = ctx.scene.clone();
    let cut_walls = !g.params.geometry.support.hangs(target_class)
        && !g.params.geometry.support.is_flat(target_class);
    let walls = room_walls(g, ctx, cut_walls).await?;
    let (mut cloud, mut fill) =
        segment_anchor(g, ctx, choice, layout.clone(), cut_walls, walls.clone()).await?;
    // No frame measured the object (its points were ended on the room's box): the other
    // views are found, and their depth completed, with the room too.
    let placed = |fill: &serde_json::Value| {
        fill.get("placed")
            .and_then(serde_json::Value::as_u64)
            .is_some_and(|n| n > 0)
    };
    let mut layout = layout;
    let mut sweep = serde_json::Value::Null;
    if let Some(room) = layout.clone().filter(|_| placed(&fill)) {
        // ...and a wall no reading reached is first placed by the object's colours.
        let refined = super::wall_sweep::refine(g, ctx, choice, &cloud.points, &room).await?;
        sweep = json!(refined.sweep);
        if let Some(moved) = refined.room {
            layout = Some(moved);
            (cloud, fill) =
                segment_anchor(g, ctx, choice, layout.clone(), cut_walls, walls.clone()).await?;
        }
    }
    let ViewCloud {
        mask: anchor_mask,
        points: anchor_pts,
        context: anchor_ctx,
        wall_cuts,
    } = cloud;
    // The views are found, and their empty pixels completed, with the room when the chosen
    // view's pixels were put on it, or when frames that saw the object beyond their range
    // may join (the room is only there for objects flat against a wall).
    let view_room = layout
        .clone()
        .filter(|_| g.params.geometry.layout.views_beyond_range || placed(&fill));
    step(
        ctx,
        "segmentation",
        json!({"image_id": format!("{:05}", choice.frame_idx), "box": choice.bbox, "segmenter": g.segmenter.name()}),
        json!({"image_id": format!("{:05}", choice.frame_idx), "frame": scene.frames[choice.frame_idx].name, "mask": {"width": anchor_mask.width, "height": anchor_mask.height, "rle": mask_rle(&anchor_mask)}, "pixels": anchor_mask.count(), "points": anchor_pts.len(), "wall_cuts": wall_cuts, "depth_fill": fill, "wall_sweep": sweep}),
        t,
    )
    .await;
    if anchor_pts.is_empty() {
        return Err(JobFailure::new(
            "empty_mask",
            "the mask has no pixel with a depth reading after clean-up",
        ));
    }

    let tp = Instant::now();
    // Views that see the anchor points.
    let others: Vec<usize> = scene
        .usable_frames()
        .map(|f| f.idx)
        .filter(|&i| i != choice.frame_idx)
        .collect();
    let params = g.params.geometry.clone();
    let (sc, ap, vr) = (scene.clone(), anchor_pts.clone(), view_room.clone());
    let views = tokio::task::spawn_blocking(move || {
        let cands: Vec<CandidateFrame> = others
            .iter()
            .map(|&i| CandidateFrame {
                index: i,
                camera: &sc.frames[i].camera,
                depth: &sc.frames[i].depth,
            })
            .collect();
        find_views_with_room(&ap, &cands, vr.as_deref(), &params)
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("view search failed: {e}")))?;
    let find_ms = ms(tp);

    // The views' candidates may widen the object only beyond what the anchor saw in part.
    let cp = &g.params.candidates;
    let anchor_partial = partial_view(
        &anchor_mask,
        &scene.frames[choice.frame_idx].camera,
        &scene.frames[choice.frame_idx].depth,
        &cp.partial,
    );
    // The chosen box, when drawn on the image (not a candidate's), and what it bounds.
    let anchor_box = (choice.source != super::proposal::BoxSource::Marks).then_some(choice.bbox);
    // The sides of that box a nearer surface crosses: the object may go on past them. A
    // mark's box bounds nothing, so its sides are not read (null in the trace).
    let anchor_hidden = anchor_box.map(|b| {
        hidden_sides(
            b,
            &anchor_mask,
            &scene.frames[choice.frame_idx].camera,
            &scene.frames[choice.frame_idx].depth,
            &cp.partial,
        )
    });
    let anchor_sides = anchor_hidden.unwrap_or_default();
    // A solid object (a chair, not a picture) measured as a thin slab: the view saw one
    // face of it, and the rest is behind that face.
    let anchor_depth_ratio = face_depth_ratio(&anchor_pts);
    let face_only =
        cut_walls && anchor_depth_ratio.is_some_and(|r| r < cp.partial.face_depth_ratio);
    let views_take_candidates = cp.enabled
        && cp.in_views
        && (!cp.in_views_partial_only || anchor_partial.partial || face_only);
    let (mut view_boxes, computed) =
        super::ensemble_boxes::boxes(g, ctx, pre, &views, views_take_candidates).await?;
    let candidates_computed: Vec<String> = computed.iter().map(|i| format!("{i:05}")).collect();
    let idxs: Vec<usize> = view_boxes.iter().map(|v| v.0).collect();
    let td = Instant::now();
    let decoded: HashMap<usize, Arc<RgbImage>> = if idxs.is_empty() {
        HashMap::new()
    } else {
        super::stitching::decode(&scene, &idxs).await?
    };
    let decode_ms = ms(td);
    let views_decoded = decoded.len();
    let vseg = ViewSegmenter {
        seg: g.segmenter.clone(),
        params: g.params.geometry.clone(),
        scene: scene.clone(),
        room: view_room.clone(),
        cut_walls,
        walls: walls.clone(),
    };
    // A view's candidate must agree with the chosen view before it is used.
    let tc = Instant::now();
    let has_candidate = view_boxes.iter().any(|v| v.2 == BoxFrom::Candidate);
    let (checked, candidate_check, decoded) = if has_candidate && cp.in_views_check {
        let footprints: Vec<(usize, [f32; 4])> = views.iter().map(|v| (v.index, v.bbox)).collect();
        let (vs, ap, rule) = (vseg.clone(), anchor_pts.clone(), cp.partial.clone());
        let mut vbs = view_boxes.clone();
        let anchor_idx = choice.frame_idx;
        let (checked, trace, vbs, decoded) = tokio::task::spawn_blocking(move || {
            let cam = &vs.scene.frames[anchor_idx].camera;
            let bound = anchor_box
                .and_then(|b| view_bound(cam, b, &anchor_partial, anchor_sides, &rule, &vs.params));
            let anchor = (&ap[..], bound.as_ref());
            let (checked, trace) = check_candidates(&vs, anchor, &footprints, &mut vbs, &decoded);
            (checked, trace, vbs, decoded)
        })
        .await
        .map_err(|e| JobFailure::new("internal", format!("candidate check failed: {e}")))?;
        view_boxes = vbs;
        (checked, json!(trace), decoded)
    } else {
        (HashMap::new(), serde_json::Value::Null, decoded)
    };
    let check_ms = ms(tc);
    let (anchor_idx, partial) = (choice.frame_idx, anchor_partial.partial);
    let asker = super::view_box::Asker {
        g,
        ctx,
        budget,
        log,
        target_class,
        anchor_idx,
    };
    let view_box = super::view_box::complete(
        &asker,
        partial,
        &views,
        &mut view_boxes,
        &decoded,
        &mut slot,
    )
    .await?;
    // Held to the end of the stage (taken again if the VLM was asked meanwhile).
    let _slot = match slot {
        Some(s) => s,
        None => g.compute_slot(ctx).await?,
    };
    let down = !g.params.geometry.support.hangs(target_class);
    let flat = g.params.geometry.support.is_flat(target_class);
    let pose = scene.frames[choice.frame_idx].camera.cam_to_out();
    let eye = [pose[(0, 3)], pose[(1, 3)], pose[(2, 3)]];
    let (sc, vb, room) = (scene.clone(), view_boxes.clone(), layout);
    let anchor_image = choice.image.clone();
    let trace = ctx.trace.clone();
    let flat_depth = g.params.geometry.layout.flat_depth_for(target_class);
    // The room's floor.
    let sp = &g.params.geometry.support;
    let standing = down && sp.stands(target_class);
    let floor = if down
        && sp.enabled
        && (sp.floor_reach || sp.box_edge || standing)
        && g.params.geometry.layout.enabled
    {
        match &walls {
            Some(room) => room.floor,
            None => scene_room(ctx, g.params.geometry.layout.clone())
                .await?
                .and_then(|r| r.floor),
        }
    } else {
        None
    };
    let rule = cp.partial.clone();
    // How much of the chosen view's points each view sees (a detection bounds by it).
    let seen: HashMap<usize, f64> = views
        .iter()
        .map(|v| (v.index, v.visible_fraction))
        .collect();
    let (fusion, single, support, votes, fills, exports, [segment_ms, fuse_ms, support_ms]) =
        tokio::task::spawn_blocking(move || {
            use rayon::prelude::*;
            let (params, rule) = (&vseg.params, &rule);
            let ts = Instant::now();
            // The views segmented while their candidates were checked are not redone.
            let done = |i: &usize, b: &[f32; 4]| checked.get(i).is_some_and(|(cb, _)| cb == b);
            let mut segmented: Vec<(usize, ViewCloud, serde_json::Value)> = vb
                .par_iter()
                .filter(|(i, b, _)| !done(i, b))
                .filter_map(|(i, b, _)| {
                    let (c, fill) = vseg.segment(*i, *b, decoded.get(i)?)?;
                    Some((*i, c, fill))
                })
                .collect();
            let mut checked = checked;
            segmented.extend(vb.iter().filter_map(|(i, b, _)| match checked.remove(i) {
                Some((cb, (c, fill))) if cb == *b => Some((*i, c, fill)),
                _ => None,
            }));
            let order = |i: usize| vb.iter().position(|v| v.0 == i);
            segmented.sort_by_key(|(i, _, _)| order(*i));
            // What depth completion did in each view (null when it was not asked to).
            let fills: HashMap<usize, serde_json::Value> =
                segmented.iter().map(|(i, _, f)| (*i, f.clone())).collect();
            let clouds: Vec<(usize, ViewCloud)> = segmented
                .into_iter()
                .map(|(i, c, _)| (i, c))
                .filter(|(_, c)| !c.points.is_empty())
                .collect();
            let segment_ms = ms(ts);
            let tf = Instant::now();
            let af = &sc.frames[anchor_idx];
            // The box drawn on the chosen image (not a candidate's, which may be a part)
            // bounds what the other views may add.
            let bound = anchor_box.and_then(|b| {
                view_bound(&af.camera, b, &anchor_partial, anchor_sides, rule, params)
            });
            let anchor_view = SegmentedView {
                index: anchor_idx,
                camera: &af.camera,
                depth: af.depth.as_ref(),
                mask: &anchor_mask,
                points: &anchor_pts,
                region: None,
                partial,
                border_frac: rule.border_frac,
                bound,
            };
            // A view that segmented only the reprojected part of a partly seen object
            // votes only inside that box.
            let part_only = |i: usize| super::ensemble_boxes::part_only(&vb, i, partial);
            let region =
                |i: usize| part_only(i).filter(|_| params.consensus.footprints_vote_inside);
            // The VLM's box of the whole object in a view, or the view's matched
            // detection (`consensus.detection_bound`), bounds it as the chosen box does,
            // when nothing hides part of the object there.
            let c = &params.consensus;
            let detections = c.detection_bound.then_some(c.detection_bound_seen);
            let whole_box = |i: usize| {
                super::ensemble_boxes::whole_object_box(&vb, i, detections, *seen.get(&i)?)
            };
            let views: Vec<SegmentedView> = clouds
                .iter()
                .map(|(i, c)| {
                    let (camera, depth) = (&sc.frames[*i].camera, sc.frames[*i].depth.as_ref());
                    let bound = whole_box(*i).and_then(|v| {
                        let seen = partial_view(&c.mask, camera, depth, rule);
                        let sides = hidden_sides(v, &c.mask, camera, depth, rule);
                        view_bound(camera, v, &seen, sides, rule, params)
                    });
                    SegmentedView {
                        index: *i,
                        camera,
                        depth,
                        mask: &c.mask,
                        points: &c.points,
                        region: region(*i),
                        partial: false,
                        border_frac: rule.border_frac,
                        bound,
                    }
                })
                .collect();
            let frames: Vec<_> = sc
                .usable_frames()
                .map(|f| (&f.camera, f.depth.as_ref()))
                .collect();
            let VotedFusion {
                fusion,
                votes,
                anchor_kept,
            } = fuse_segmented(anchor_view, &views, &frames, params);
            // The views whose box was a bound (`mask_votes.outside_view_boxes`).
            let bounding: Vec<String> = views
                .iter()
                .filter(|v| v.bound.is_some())
                .map(|v| format!("{:05}", v.index))
                .collect();
            let mut votes = json!(votes);
            votes["bounding_views"] = json!(bounding);
            let fuse_ms = ms(tf);
            let tsup = Instant::now();
            let kept = |i: usize| fusion.views.iter().any(|v| v.index == i && v.kept);
            // Support completion sees around the anchor and every view the fusion kept,
            // except those that segmented only the part (around it lies the object's rest).
            let view_ctx: Vec<(usize, &[Point3<f64>])> =
                clouds.iter().map(|(i, c)| (*i, &c.context[..])).collect();
            let context =
                super::ensemble_boxes::support_context(anchor_ctx, &view_ctx, kept, |i| {
                    part_only(i).is_some()
                });
            let anchor_kept: &[Point3<f64>] = &anchor_kept;
            let bulk = median_point(anchor_kept).unwrap_or_default();
            let support = fusion.aabb.map(|b| {
                // A table, a chair, a bed: on the floor, whatever lies just below.
                let (b, stood) = match floor.filter(|_| standing) {
                    Some(f) => stand_on_floor(&b, f, params.support.max_gap_column),
                    None => (b, None),
                };
                let (b, moved) = extend_to_support(&b, bulk, &context, &frames, down, params);
                let bottom_moved = moved.iter().any(|m| m.axis == "z" && m.side == "min");
                let stood_or_moved = bottom_moved || stood.is_some();
                let (b, bottom) = if down && params.support.enabled && !stood_or_moved {
                    let v = super::bottom::BottomViews {
                        anchor: &anchor_view,
                        anchor_box,
                        views: &views,
                        boxes: &vb,
                        kept: &kept,
                    };
                    super::bottom::complete(&b, &v, floor, params)
                } else {
                    (b, Default::default())
                };
                let (b, planar) = if flat {
                    snap_planar_to_wall(
                        &b,
                        anchor_kept,
                        &context,
                        room.as_deref(),
                        eye,
                        flat_depth,
                        params,
                    )
                } else {
                    (b, Vec::new())
                };
                let placed = moved.iter().any(|m| m.axis != "z");
                let (b, round) =
                    round_back(&b, &fusion.kept, eye.into(), placed, &params.round_back);
                (b, moved, planar, bottom, round, stood)
            });
            let support_ms = ms(tsup);
            // The masks of the views used and the object's points, written out as encoded.
            let mut mask_files = vec![(anchor_idx, &anchor_mask)];
            for (i, c) in &clouds {
                if kept(*i) {
                    mask_files.push((*i, &c.mask));
                }
            }
            // The single-view box only fills the trace: computed on the other core while
            // the exports are encoded and written.
            let (exports, single) = rayon::join(
                || exports::write(&trace, &mask_files, &fusion.kept, &af.camera, &anchor_image),
                || single_view_box(&anchor_pts, params),
            );
            (
                fusion,
                single,
                support,
                votes,
                fills,
                exports,
                [segment_ms, fuse_ms, support_ms],
            )
        })
        .await
        .map_err(|e| JobFailure::new("internal", format!("fusion task failed: {e}")))?;
    let (bbox, moved, planar, bottom, round_back, floor_standing) = support.ok_or_else(|| {
        JobFailure::new("projection_failed", "no points survived outlier removal")
    })?;
    let views_used = 1 + fusion.views.iter().filter(|v| v.kept).count();
    let exported = exports?;
    let view_json: Vec<_> = views
        .iter()
        .zip(&view_boxes)
        .map(|(v, (_, b, from))| {
            let d = fusion.views.iter().find(|d| d.index == v.index);
            json!({"image_id": format!("{:05}", v.index), "visible_fraction": v.visible_fraction, "footprint": v.bbox, "box": b, "box_from_detection": *from == BoxFrom::Detection, "box_from": from,
                   "chamfer": d.and_then(|d| d.chamfer), "cover": d.and_then(|d| d.cover), "kept": d.is_some_and(|d| d.kept), "complements": d.is_some_and(|d| d.complements), "agreement": d.and_then(|d| d.agreement), "beyond_cut": d.and_then(|d| d.beyond_cut), "points": d.map(|d| d.points), "depth_fill": fills.get(&v.index).cloned().unwrap_or_default()})
        })
        .collect();
    step(
        ctx,
        "projection",
        json!({"anchor_points": fusion.anchor_points, "candidate_views": views.len()}),
        json!({"box": bbox, "anchor_partial": anchor_partial, "anchor_hidden_sides": anchor_hidden, "anchor_depth_ratio": anchor_depth_ratio, "anchor_face_only": face_only, "views_take_candidates": views_take_candidates, "view_candidates_computed": candidates_computed, "candidate_check": candidate_check, "view_box": view_box, "fused_box": fusion.aabb, "flattened": fusion.flattened, "support": moved, "hidden_base": bottom.hidden, "floor_standing": floor_standing, "floor_reach": bottom.reach, "box_edge": bottom.edge, "planar": planar, "round_back": round_back, "mask_votes": votes, "carved_points": fusion.carved_points, "single_view_box": single, "views": view_json, "views_used": views_used, "fused_points": fusion.fused_points, "kept_points": fusion.kept_points, "views_decoded": views_decoded, "exports": exported,
               "timings_ms": {"find_views": find_ms, "decode": decode_ms, "candidate_check": check_ms, "segment": segment_ms, "fuse": fuse_ms, "support": support_ms}}),
        tp,
    )
    .await;
    Ok(Projected { bbox, views_used })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rle_starts_with_background() {
        let mut m = Mask::new(4, 1);
        m.set(0, 0, true);
        m.set(1, 0, true);
        assert_eq!(mask_rle(&m), vec![0, 2, 2]);
        let mut m = Mask::new(3, 1);
        m.set(2, 0, true);
        assert_eq!(mask_rle(&m), vec![2, 1]);
    }
}
