//! An object whose image boxes reach the floor while its measured points stop well above
//! it (ours, not the paper's): the thin part depth did not measure.
//!
//! A floor lamp is a shade on a pole a few centimetres wide. At a depth map's resolution
//! the pole is a pixel or less, so the depth segmenter's mask, and the points, are the
//! shade; nothing below it is measured, support completion finds no layer within reach
//! (the floor is a metre and more down), and the box is the shade. Tables on thin legs and
//! stools are the same case. The 2D boxes are not: a detector (or the VLM) boxes the
//! object's whole silhouette, pole included, so in each view the box's lower edge is
//! where the object ends in the image, and the object reaches down at least as far as the
//! line of sight through that edge, at the object's distance. When every view whose box
//! can be read says the object reaches down to the floor, and the measured bottom floats
//! above it, the bottom moves onto the floor.
//!
//! Where the line of sight through the middle of a box's lower edge meets the floor says
//! which: an object standing on the floor ends in the image where its foot meets the
//! floor, so that line meets the floor at the object's foot, under it; an object that
//! ends in the air (a cup on a table, a shade on a pole nobody boxed) ends where that line
//! passes under it and goes on to meet the floor well behind it. The foot is looked for
//! in the box's footprint on the floor grown by its larger horizontal half-size on every
//! side: one view sees only the object's front, and an object hidden behind its front is
//! about as deep as it is wide. A view whose box ends on the image's lower border (the
//! object is cut there), whose camera looks too far off upright, or whose line of sight
//! does not go down says nothing; a view whose line meets the floor elsewhere vetoes the
//! move, unless the box's lower edge lies on a surface nearer than the object and away
//! from its measured bottom (a desk before a lamp's pole): the box then ends where the
//! object is hidden, not where it ends, and the view says nothing. A nearer surface level
//! with the measured bottom is what the object stands on (a table top before a cup's
//! foot), and the view still vetoes.
//!
//! Where no view sets the bottom on the floor, the chosen view's box still says how far
//! down the object reaches at least ([`lower_to_box_edge`]): the line of sight through its
//! lower edge passes the object's hidden or unmeasured lower part no nearer than the
//! object's nearest measured point, so it is at least as low there as where it crosses
//! that distance.
//!
//! Some classes stand on the floor whatever the views say ([`stand_on_floor`]): a table,
//! a desk, a chair, a sofa, a bed. Their legs are as thin as a pole, and what lies just
//! below their measured bottom is often not what holds them up: the seats of chairs pushed
//! in under a table's edge form a level layer 30 cm under its top, all around it, and
//! support completion would set the table on them. For these classes (the query's target
//! class, from `support.standing`) the bottom goes to the room's floor before support
//! completion looks down, which then finds the measured floor there.

use nalgebra::{Matrix4, Point3, Vector3};
use serde::Serialize;

use super::camera::transform_point;
use super::cloud::median;
use super::fusion::SegmentedView;
use super::hidden_base::{object_depth, readable, upright_at};
use super::{Aabb, GeometryParams};

/// What a view's box says of where the object ends below.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReachVerdict {
    pub index: usize,
    /// Lowest row of the object's measured pixels (mask pixels whose point is in the box).
    pub mask_bottom: Option<u32>,
    /// The box's lower edge (row).
    pub box_bottom: f64,
    /// Where the line of sight through the middle of the box's lower edge meets the floor
    /// (x, y); `None` when the view was not read.
    pub floor_hit: Option<[f64; 2]>,
    /// That point lies in the box's grown footprint: the object reaches the floor there.
    pub reaches_floor: Option<bool>,
    /// What lies just below the box's lower edge (`None`: not read).
    pub below_edge: Option<BelowEdge>,
    /// Height (m) of the line of sight through the middle of the box's lower edge at the
    /// object's nearest measured distance in the view: the object reaches at least that
    /// far down (`None` when the view was not read).
    pub down_to: Option<f64>,
    /// Share of the box's height below the object's lowest measured pixel: what the box
    /// holds and depth did not measure.
    pub unmeasured: Option<f64>,
}

/// What lies just below a 2D box's lower edge, seen from the object.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BelowEdge {
    /// A nearer surface away from the object's measured bottom: it may hide the object's
    /// lower part (a desk before a lamp's pole), and a line of sight that passes under the
    /// object says nothing.
    Occluder,
    /// A nearer surface level with the object's measured bottom: what it stands on (a
    /// table top before a cup's foot); the object ends there.
    Support,
    /// Anything else: the object's continuation, or what lies behind it.
    Open,
}

/// The move of the box's bottom onto the floor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FloorReach {
    pub from: f64,
    pub to: f64,
    pub floor: f64,
    pub views: Vec<ReachVerdict>,
}

/// The box `b` with its bottom on the `floor` when the 2D boxes of `views` (each view with
/// the box it was segmented in) say so (see the module documentation), and the record
/// (`None` when no view was given or the box's bottom is within `support.layer` of the
/// floor already).
pub fn extend_to_floor_reach(
    b: &Aabb,
    views: &[(&SegmentedView<'_>, [f32; 4])],
    floor: f64,
    params: &GeometryParams,
) -> (Aabb, Option<FloorReach>) {
    if views.is_empty() || b.min[2] - floor <= params.support.layer {
        return (*b, None);
    }
    let verdicts: Vec<ReachVerdict> = views
        .iter()
        .map(|(v, bbox)| read_view(v, *bbox, b, Some(floor), params))
        .collect();
    let read: Vec<bool> = verdicts.iter().filter_map(|v| v.reaches_floor).collect();
    let mut out = *b;
    if !read.is_empty() && read.iter().all(|&r| r) {
        out.min[2] = floor;
    }
    let record = FloorReach {
        from: b.min[2],
        to: out.min[2],
        floor,
        views: verdicts,
    };
    (out, Some(record))
}

/// The move of the box's bottom down to where the chosen view's 2D box ends.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EdgeReach {
    pub from: f64,
    pub to: f64,
    pub view: ReachVerdict,
}

/// The box `b` with its bottom lowered to where the chosen view's 2D box says the object
/// reaches, from that view's reading `view` ([`read_view`] of the box on `b`): the line of
/// sight through the box's lower edge at the object's nearest measured distance
/// ([`ReachVerdict::down_to`]), when at least `support.box_edge_unmeasured` of the box's
/// height lies below the object's lowest measured pixel and that line passes below the
/// box's bottom by more than `support.layer`, and the edge does not lie on the object's
/// support ([`BelowEdge::Support`]); never below the `floor` when it is known. The record
/// is `None` when the view could not be read (a box on the image's lower border, a camera
/// rolled too far, a line of sight that does not go down).
///
/// Unlike [`extend_to_floor_reach`] this takes one view, and it moves the bottom only as
/// far as that view shows the object: an object whose lower part is hidden behind a nearer
/// surface (a lamp's pole behind a desk) still reaches at least where its image ends.
pub fn lower_to_box_edge(
    b: &Aabb,
    view: ReachVerdict,
    floor: Option<f64>,
    params: &GeometryParams,
) -> (Aabb, Option<EdgeReach>) {
    let Some(down_to) = view.down_to else {
        return (*b, None);
    };
    let to = floor.map_or(down_to, |f| down_to.max(f));
    let enough = view
        .unmeasured
        .is_some_and(|u| u >= params.support.box_edge_unmeasured);
    let on_support = view.below_edge == Some(BelowEdge::Support);
    let mut out = *b;
    if enough && !on_support && to < b.min[2] - params.support.layer {
        out.min[2] = to;
    }
    let record = EdgeReach {
        from: b.min[2],
        to: out.min[2],
        view,
    };
    (out, Some(record))
}

/// The move of a floor-standing object's bottom onto the floor ([`stand_on_floor`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FloorStand {
    pub from: f64,
    pub to: f64,
    pub floor: f64,
}

/// The box `b` of an object of a class that stands on the floor, with its bottom on the
/// `floor` when it floats above it by at most `max_gap` (farther, the box is not such an
/// object's, whatever the class says), and the record (`None` when the bottom is on or
/// below the floor, or too far above it).
pub fn stand_on_floor(b: &Aabb, floor: f64, max_gap: f64) -> (Aabb, Option<FloorStand>) {
    let gap = b.min[2] - floor;
    if gap <= 0.0 || gap > max_gap {
        return (*b, None);
    }
    let mut out = *b;
    out.min[2] = floor;
    let record = FloorStand {
        from: b.min[2],
        to: floor,
        floor,
    };
    (out, Some(record))
}

/// What `view`'s 2D box `bbox` says of where the object whose box is `b` ends below (see
/// the module documentation); the floor's verdict only when the `floor` is known.
pub fn read_view(
    view: &SegmentedView<'_>,
    bbox: [f32; 4],
    b: &Aabb,
    floor: Option<f64>,
    params: &GeometryParams,
) -> ReachVerdict {
    let cam = view.camera;
    let mut verdict = ReachVerdict {
        index: view.index,
        mask_bottom: None,
        box_bottom: f64::from(bbox[3]),
        floor_hit: None,
        reaches_floor: None,
        below_edge: None,
        down_to: None,
        unmeasured: None,
    };
    let Some((_, to_out)) = readable(view).filter(|(to_cam, _)| upright_at(cam, to_cam, b)) else {
        return verdict;
    };
    // The object's measured pixels: mask pixels whose point lies in the box.
    let (w, h) = (view.mask.width, view.mask.height);
    let measured: Vec<(u32, f64)> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .filter_map(|(x, y)| Some((y, object_depth(view, &to_out, b, params, x, y)?)))
        .collect();
    let Some(bottom) = measured.iter().map(|&(y, _)| y).max() else {
        return verdict;
    };
    verdict.mask_bottom = Some(bottom);
    // A box on the image's lower border: the object may go on below the image.
    if f64::from(bbox[3]) >= f64::from(h) - 1.5 {
        return verdict;
    }
    let tall = f64::from(bbox[3] - bbox[1]);
    if tall > 0.0 {
        verdict.unmeasured = Some((f64::from(bbox[3]) - f64::from(bottom)).max(0.0) / tall);
    }
    // The object's nearest measured distance: what the box holds below the measured
    // pixels (a pole under its shade, legs under a seat) is at least that far.
    let mut depths: Vec<f64> = measured.into_iter().map(|(_, d)| d).collect();
    let near = low_quantile(&mut depths, NEAR_QUANTILE);
    verdict.below_edge = below_edge(view, &to_out, bbox, b, near, params);
    // The line of sight through the middle of the box's lower edge. Going down, it
    // passes the object's lower end no nearer than the object's nearest point: it is at
    // least as low there as where it crosses that distance.
    let c = cam.centre();
    let u = f64::from(bbox[0] + bbox[2]) / 2.0;
    let at = |d: f64| transform_point(&to_out, &cam.color.unproject(u, f64::from(bbox[3]), d));
    let dir: Vector3<f64> = at(1.0) - c;
    if dir.z >= -1e-9 {
        return verdict;
    }
    verdict.down_to = Some(at(near).z);
    // Down to the floor.
    let Some(floor) = floor.filter(|&f| c.z > f) else {
        return verdict;
    };
    let hit: Point3<f64> = c + dir * ((floor - c.z) / dir.z);
    verdict.floor_hit = Some([hit.x, hit.y]);
    let grow = (b.max[0] - b.min[0]).max(b.max[1] - b.min[1]) / 2.0;
    let reaches = (0..2).all(|k| hit[k] >= b.min[k] - grow && hit[k] <= b.max[k] + grow);
    // A line that passes under the object says it ends in the air, unless the edge lies
    // on something nearer that may hide where the object ends.
    let hidden = verdict.below_edge == Some(BelowEdge::Occluder);
    verdict.reaches_floor = (reaches || !hidden).then_some(reaches);
    verdict
}

/// The object's nearest distance in a view: this quantile of its measured depths (a few
/// flying pixels at its silhouette are nearer still).
const NEAR_QUANTILE: f64 = 0.05;

/// Rows below the box's lower edge read for what lies there, at 640 pixels of frame
/// width (scaled with the frame).
const EDGE_ROWS_640: f64 = 4.0;

/// The `q` quantile of `v` (reordered); `v` must not be empty.
fn low_quantile(v: &mut [f64], q: f64) -> f64 {
    let k = ((v.len() - 1) as f64 * q).round() as usize;
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

/// What lies just below the box's lower edge, read on the few rows under it over the
/// box's middle half (`None`: no reading). Most readings nearer than the object (`near`,
/// its nearest distance) by more than the visibility tolerance make a nearer surface; at a
/// median height within `support.layer` of the object's measured bottom (`b.min[2]`) it is
/// the object's support, else an occluder.
fn below_edge(
    view: &SegmentedView<'_>,
    to_out: &Matrix4<f64>,
    bbox: [f32; 4],
    b: &Aabb,
    near: f64,
    params: &GeometryParams,
) -> Option<BelowEdge> {
    let cam = view.camera;
    let (w, h) = (view.mask.width, view.mask.height);
    let rows = (EDGE_ROWS_640 * f64::from(w) / 640.0).round().max(2.0) as u32;
    let quarter = f64::from(bbox[2] - bbox[0]) / 4.0;
    let x0 = (f64::from(bbox[0]) + quarter).floor().max(0.0) as u32;
    let x1 = ((f64::from(bbox[2]) - quarter).ceil().max(0.0) as u32).min(w - 1);
    let y0 = (f64::from(bbox[3]).ceil().max(0.0) as u32 + 1).min(h);
    let y1 = (y0 + rows).min(h);
    let tol = params.visibility_tolerance(near);
    let mut read = 0usize;
    let mut nearer: Vec<f64> = Vec::new();
    for y in y0..y1 {
        for x in x0..=x1 {
            let (u, v) = (f64::from(x), f64::from(y));
            let Some(d) = cam.depth_at_color(view.depth, u, v) else {
                continue;
            };
            read += 1;
            if d < near - tol {
                nearer.push(transform_point(to_out, &cam.color.unproject(u, v, d)).z);
            }
        }
    }
    if read == 0 {
        return None;
    }
    Some(if 2 * nearer.len() <= read {
        BelowEdge::Open
    } else if (median(&mut nearer) - b.min[2]).abs() <= params.support.layer {
        BelowEdge::Support
    } else {
        BelowEdge::Occluder
    })
}

#[cfg(test)]
#[path = "floor_reach_tests.rs"]
mod tests;
