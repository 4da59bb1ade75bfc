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
//! move.
//!
//! Some classes stand on the floor whatever the views say ([`stand_on_floor`]): a table,
//! a desk, a chair, a sofa, a bed. Their legs are as thin as a pole, and what lies just
//! below their measured bottom is often not what holds them up: the seats of chairs pushed
//! in under a table's edge form a level layer 30 cm under its top, all around it, and
//! support completion would set the table on them. For these classes (the query's target
//! class, from `support.standing`) the bottom goes to the room's floor before support
//! completion looks down, which then finds the measured floor there.

use nalgebra::{Point3, Vector3};
use serde::Serialize;

use super::camera::transform_point;
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
        .map(|(v, bbox)| read_view(v, *bbox, b, floor, params))
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

fn read_view(
    view: &SegmentedView<'_>,
    bbox: [f32; 4],
    b: &Aabb,
    floor: f64,
    params: &GeometryParams,
) -> ReachVerdict {
    let cam = view.camera;
    let mut verdict = ReachVerdict {
        index: view.index,
        mask_bottom: None,
        box_bottom: f64::from(bbox[3]),
        floor_hit: None,
        reaches_floor: None,
    };
    let Some((_, to_out)) = readable(view).filter(|(to_cam, _)| upright_at(cam, to_cam, b)) else {
        return verdict;
    };
    // The object's lowest measured pixel: a mask pixel whose point lies in the box.
    let (w, h) = (view.mask.width, view.mask.height);
    let measured = |x: u32, y: u32| object_depth(view, &to_out, b, params, x, y).is_some();
    let Some(bottom) = (0..h).rev().find(|&y| (0..w).any(|x| measured(x, y))) else {
        return verdict;
    };
    verdict.mask_bottom = Some(bottom);
    // A box on the image's lower border: the object may go on below the image.
    if f64::from(bbox[3]) >= f64::from(h) - 1.5 {
        return verdict;
    }
    // The line of sight through the middle of the box's lower edge, down to the floor.
    let c = cam.centre();
    let u = f64::from(bbox[0] + bbox[2]) / 2.0;
    let far = transform_point(&to_out, &cam.color.unproject(u, f64::from(bbox[3]), 1.0));
    let dir: Vector3<f64> = far - c;
    if dir.z >= -1e-9 || c.z <= floor {
        return verdict;
    }
    let hit: Point3<f64> = c + dir * ((floor - c.z) / dir.z);
    verdict.floor_hit = Some([hit.x, hit.y]);
    let grow = (b.max[0] - b.min[0]).max(b.max[1] - b.min[1]) / 2.0;
    verdict.reaches_floor =
        Some((0..2).all(|k| hit[k] >= b.min[k] - grow && hit[k] <= b.max[k] + grow));
    verdict
}

#[cfg(test)]
#[path = "floor_reach_tests.rs"]
mod tests;
