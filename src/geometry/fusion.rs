//! The multi-view fusion the agent runs on segmented views: the paper's chamfer filter
//! ([`chamfer_decisions`], on the points the chosen view's box allows: [`super::bound`]),
//! then our consensus checks ([`mask_votes`] among the anchor and the kept views,
//! [`free_space_votes`] on the union) and the box ([`fuse_clouds`]).
//! Pure: cameras, depth maps, masks and points in, points and a box out.

use nalgebra::Point3;
use serde::Serialize;

use super::bound::{within_bound, ViewBound};
use super::cloud::voxel_downsample;
use super::consensus::{free_space_votes, mask_votes, retain, MaskView};
use super::ensemble::{chamfer_decisions, fuse_clouds, FusionResult};
use super::{DepthMap, FrameCamera, GeometryParams, Mask};

/// One segmented view: its frame, the raw mask and the points back-projected from it.
#[derive(Debug, Clone, Copy)]
pub struct SegmentedView<'a> {
    /// Caller's frame index.
    pub index: usize,
    pub camera: &'a FrameCamera,
    pub depth: &'a DepthMap,
    pub mask: &'a Mask,
    pub points: &'a [Point3<f64>],
    /// Where the mask speaks for the frame in the votes (see [`MaskView::region`]).
    pub region: Option<[f32; 4]>,
    /// The mask holds only part of its object (see [`super::partial_view`]); meaningful for
    /// the anchor, where it lets the chamfer filter keep views that see more.
    pub partial: bool,
    /// How near the frame's edge a mask pixel meets it, as a share of the image's width:
    /// the partial-view rule's `border_frac`. The anchor's sets where its mask was cut.
    pub border_frac: f64,
    /// Where the object can be at all (see [`super::bound`]). The anchor's box bounds the
    /// points the other views give. Another view's bound (the VLM's box of the whole
    /// object there, asked when the anchor saw a part) bounds the anchor's points and the
    /// other views' too: a close-up whose mask ran on over the wall around a picture keeps
    /// only what projects into the picture's box seen from across the room.
    pub bound: Option<ViewBound<'a>>,
}

/// What the mask votes did (for traces).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct VoteStats {
    pub voters: usize,
    pub points_before: usize,
    pub points_after: usize,
    pub anchor_before: usize,
    pub anchor_after: usize,
    /// Points of the other views dropped, before the chamfer test, for projecting outside
    /// the chosen view's box ([`SegmentedView::bound`]).
    pub outside_anchor_box: usize,
    /// Points of the anchor and the other views dropped, before the chamfer test, for
    /// projecting outside another view's whole-object box ([`SegmentedView::bound`]).
    pub outside_view_boxes: usize,
}

/// The fusion and what led to it.
#[derive(Debug, Clone)]
pub struct VotedFusion {
    pub fusion: FusionResult,
    pub votes: VoteStats,
    /// The anchor's points after the votes (all of them when the votes left none).
    pub anchor_kept: Vec<Point3<f64>>,
}

/// Fuse `anchor` with the views of `others` that pass the chamfer filter. Each cloud is
/// taken at the fusion voxel first (the union is downsampled to it anyway, and the votes
/// cost one projection per point and view); when `consensus.mask_votes` is on and a view
/// was kept, every point is checked against the other kept views' masks; the union is
/// carved with `frames` when `consensus.free_space` is on.
pub fn fuse_segmented(
    anchor: SegmentedView<'_>,
    others: &[SegmentedView<'_>],
    frames: &[(&FrameCamera, &DepthMap)],
    params: &GeometryParams,
) -> VotedFusion {
    // The other views' points that the chosen view's box rules out are not the object.
    let bounded: Vec<Option<Vec<Point3<f64>>>> = others
        .iter()
        .map(|v| anchor.bound.as_ref().map(|b| within_bound(v.points, b)))
        .collect();
    let in_anchor_box = |k: usize| bounded[k].as_deref().unwrap_or(others[k].points);
    let outside_anchor_box = (0..others.len())
        .map(|k| others[k].points.len() - in_anchor_box(k).len())
        .sum();
    // Nor are the points, the anchor's included, that another view's whole-object box
    // rules out (a bound that would leave a cloud empty is not applied to it).
    let view_bounds: Vec<(usize, &ViewBound<'_>)> = others
        .iter()
        .filter_map(|v| v.bound.as_ref().map(|b| (v.index, b)))
        .collect();
    let by_views = |own: usize, pts: &[Point3<f64>]| -> Option<Vec<Point3<f64>>> {
        let mut kept: Option<Vec<Point3<f64>>> = None;
        for (_, b) in view_bounds.iter().filter(|(i, _)| *i != own) {
            let next = within_bound(kept.as_deref().unwrap_or(pts), b);
            if !next.is_empty() {
                kept = Some(next);
            }
        }
        kept
    };
    let anchor_bounded = by_views(anchor.index, anchor.points);
    let anchor_pts = anchor_bounded.as_deref().unwrap_or(anchor.points);
    let view_bounded: Vec<Option<Vec<Point3<f64>>>> = (0..others.len())
        .map(|k| by_views(others[k].index, in_anchor_box(k)))
        .collect();
    let points_of = |k: usize| view_bounded[k].as_deref().unwrap_or(in_anchor_box(k));
    let outside_view_boxes = anchor.points.len() - anchor_pts.len()
        + (0..others.len())
            .map(|k| in_anchor_box(k).len() - points_of(k).len())
            .sum::<usize>();
    let other_pts: Vec<(usize, &[Point3<f64>])> = (0..others.len())
        .map(|k| (others[k].index, points_of(k)))
        .collect();
    let mut decisions = chamfer_decisions(anchor_pts, &other_pts, anchor.partial, params);
    let anchor_view = MaskView {
        camera: anchor.camera,
        depth: anchor.depth,
        mask: anchor.mask,
        region: anchor.region,
    };
    let anchor_ds = voxel_downsample(anchor_pts, params.fusion_voxel);
    // Views downsampled already (by the complement test), by view.
    let mut sampled: Vec<Option<Vec<Point3<f64>>>> = vec![None; others.len()];
    if anchor.partial {
        super::complement::complements(
            &mut decisions,
            &other_pts,
            &anchor_view,
            anchor.border_frac,
            &anchor_ds,
            &mut sampled,
            params,
        );
    }
    let mut voters = vec![anchor_view];
    let mut owned = vec![anchor_ds];
    for (k, (v, d)) in others.iter().zip(&decisions).enumerate() {
        if d.kept {
            voters.push(MaskView {
                camera: v.camera,
                depth: v.depth,
                mask: v.mask,
                region: v.region,
            });
            owned.push(
                sampled[k]
                    .take()
                    .unwrap_or_else(|| voxel_downsample(points_of(k), params.fusion_voxel)),
            );
        }
    }
    let clouds: Vec<&[Point3<f64>]> = owned.iter().map(Vec::as_slice).collect();
    let voted: Vec<Vec<Point3<f64>>> = if params.consensus.mask_votes && voters.len() > 1 {
        mask_votes(&clouds, &voters, params)
            .iter()
            .zip(&clouds)
            .map(|(k, c)| retain(c, k))
            .collect()
    } else {
        clouds.iter().map(|c| c.to_vec()).collect()
    };
    let votes = VoteStats {
        voters: voters.len(),
        points_before: clouds.iter().map(|c| c.len()).sum(),
        points_after: voted.iter().map(Vec::len).sum(),
        anchor_before: clouds[0].len(),
        anchor_after: voted[0].len(),
        outside_anchor_box,
        outside_view_boxes,
    };
    let carve = |pts: &[Point3<f64>]| free_space_votes(pts, frames, params);
    let refs: Vec<&[Point3<f64>]> = voted.iter().map(Vec::as_slice).collect();
    let fusion = fuse_clouds(
        anchor_pts.len(),
        &refs,
        decisions,
        params.consensus.free_space.then_some(&carve as _),
        params,
    );
    let anchor_kept = if voted[0].is_empty() {
        anchor_pts.to_vec()
    } else {
        voted[0].clone()
    };
    VotedFusion {
        fusion,
        votes,
        anchor_kept,
    }
}

#[cfg(test)]
#[path = "fusion_tests.rs"]
mod tests;
