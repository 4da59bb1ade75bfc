//! The base of an object hidden behind the top edge of what it stands on, when that edge
//! is above every camera that saw the object (ours, not the paper's).
//!
//! A cup on a bookshelf taller than the camera is seen from below: the shelf's front edge
//! hides the cup's lower part, and the shelf's top, which the cup stands on, is never in
//! view. Support completion ([`super::support`]) looks for that top as a layer of points
//! around the box and finds none, so the box stops where the line of sight over the edge
//! meets the cup (its top few centimetres).
//!
//! What the views do show is the edge: in a view where the object's mask ends on a
//! surface nearer to the camera than the object, the mask's lower border is that
//! surface's top edge, and the points just below it give the edge's height. When the
//! edge is above the camera, whatever lies behind it and below the line of sight is
//! hidden in that view, down to the plane of the edge's top; an object standing there
//! stands on that plane (nothing else holds it up at that height). So when every view
//! whose mask's lower border can be read finds it on such an edge above the camera, and
//! the box's bottom lies above the edge, the bottom moves down onto the highest of the
//! edges found. A view in which the object's bottom ends on a farther surface or on
//! nothing (it is seen in the open) vetoes the move; views whose mask reaches the image's
//! lower border, or that look too far off upright for "down" to be "down the image", say
//! nothing.

use nalgebra::{Matrix4, Point3, Vector3};
use serde::Serialize;

use super::camera::transform_point;
use super::cloud::median;
use super::fusion::SegmentedView;
use super::{Aabb, DepthMap, FrameCamera, GeometryParams};

/// Fewest pixels below a mask column's lowest pixel walked to find the surface under it,
/// at 640 pixels of frame width (scaled with the frame); the walk goes as far as the
/// box's height in the view when that is more. A column closer than this to the image's
/// lower border has no verdict.
const REACH_640: f64 = 12.0;
/// Least number of columns with a verdict for a view to count.
const MIN_COLUMNS: usize = 3;

/// What a view shows under the object's mask, in a word.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum BaseReading {
    /// Most of the border lies on a nearer surface whose top is above the camera.
    #[serde(rename = "edge above the eye")]
    EdgeAboveEye,
    /// Most of the border lies on a nearer surface whose top is below the camera.
    #[serde(rename = "edge below the eye")]
    EdgeBelowEye,
    /// Most of the border ends on a farther surface or on the object's own continuation.
    #[serde(rename = "open")]
    Open,
    /// Too few columns, a mask on the image's lower border, or a camera too far off
    /// upright.
    #[serde(rename = "unread")]
    Unread,
}

/// What a view shows under the object's mask.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BaseVerdict {
    pub index: usize,
    /// Columns of the mask whose walk down from the object's lowest pixel decided:
    /// it met a depth jump, or ran its full reach on readings without one.
    pub columns: usize,
    /// Of those, columns where the surface below is nearer than the object.
    pub occluded: usize,
    /// Median height (m) of the nearer surface's points right below the border.
    pub edge_z: Option<f64>,
    /// Height (m) of the camera.
    pub eye_z: f64,
    pub reads: BaseReading,
}

/// The move of the box's bottom onto a hidden base.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HiddenBase {
    pub from: f64,
    pub to: f64,
    pub views: Vec<BaseVerdict>,
}

/// The box `b` with its bottom on the hidden base that `views` show (see the module
/// documentation), and the record of what each view showed (`None` when no view could be
/// looked at: a bad pose, depth map or mask size; the box is then as given).
pub fn extend_to_hidden_base(
    b: &Aabb,
    views: &[&SegmentedView<'_>],
    params: &GeometryParams,
) -> (Aabb, Option<HiddenBase>) {
    let verdicts: Vec<BaseVerdict> = views
        .iter()
        .filter_map(|v| read_view(v, b, params))
        .collect();
    if verdicts.is_empty() {
        return (*b, None);
    }
    let read: Vec<&BaseVerdict> = verdicts
        .iter()
        .filter(|v| v.reads != BaseReading::Unread)
        .collect();
    let all_above = !read.is_empty() && read.iter().all(|v| v.reads == BaseReading::EdgeAboveEye);
    let to = read
        .iter()
        .filter_map(|v| v.edge_z)
        .fold(f64::NEG_INFINITY, f64::max);
    let gap = b.min[2] - to;
    let mut out = *b;
    let moved = all_above && gap > 0.0 && gap <= params.support.max_gap_down;
    if moved {
        out.min[2] = to;
    }
    let record = HiddenBase {
        from: b.min[2],
        to: if moved { to } else { b.min[2] },
        views: verdicts,
    };
    (out, Some(record))
}

/// What `view` shows under its mask, for an object whose box is `b`. `None` when the
/// view's pose is unusable or its mask is empty.
fn read_view(view: &SegmentedView<'_>, b: &Aabb, params: &GeometryParams) -> Option<BaseVerdict> {
    let cam = view.camera;
    let (to_cam, to_out) = readable(view)?;
    let m = view.mask;
    let (w, h) = (m.width, m.height);
    let eye_z = cam.centre().z;
    let unread = |columns, occluded| BaseVerdict {
        index: view.index,
        columns,
        occluded,
        edge_z: None,
        eye_z,
        reads: BaseReading::Unread,
    };
    if !upright_at(cam, &to_cam, b) {
        return Some(unread(0, 0));
    }
    let min_reach = (REACH_640 * f64::from(w) / 640.0).round().max(2.0) as u32;
    // As far down as the box reaches in this view (the mask may stop short of the
    // object's silhouette by more than a few pixels in a close-up).
    let reach = min_reach.max(box_height(cam, &to_cam, b).min(f64::from(h)) as u32);
    let mut columns = 0;
    let mut edge: Vec<f64> = Vec::new();
    let object_depth = |x: u32, y: u32| object_depth(view, &to_out, b, params, x, y);
    for x in 0..w {
        // The object's lowest pixel in the column and its depth.
        let Some((bottom, inside)) = (0..h).rev().find_map(|y| Some((y, object_depth(x, y)?)))
        else {
            continue;
        };
        if bottom + min_reach >= h {
            continue;
        }
        // Walk down the column from the border along the surface under it: a jump
        // between successive readings of more than the visibility tolerance is where one
        // surface ends and another begins, and decides (nearer: something hides the
        // object's lower part). A walk that runs its length without a jump stays on the
        // object or on what it meets in view (its mask stopped short, or it stands on a
        // surface seen from above): its bottom is not hidden there.
        let end = bottom + reach;
        let mut prev = inside;
        let mut read = false;
        let mut jump = None;
        for y in bottom + 1..=end.min(h - 1) {
            let Some(d) = reading(cam, view.depth, x, y) else {
                continue;
            };
            read = true;
            if (d - prev).abs() > params.visibility_tolerance(prev) {
                jump = Some((y, d, d < prev));
                break;
            }
            prev = d;
        }
        match jump {
            Some((y, d, true)) => {
                columns += 1;
                let p = cam.color.unproject(f64::from(x), f64::from(y), d);
                edge.push(transform_point(&to_out, &p).z);
            }
            Some((_, _, false)) => columns += 1,
            // Cut by the image's border: no verdict.
            None if read && end < h => columns += 1,
            None => {}
        }
    }
    let occluded = edge.len();
    if columns < MIN_COLUMNS {
        return Some(unread(columns, occluded));
    }
    // A majority of the border's columns decides.
    if 2 * occluded <= columns {
        return Some(BaseVerdict {
            reads: BaseReading::Open,
            ..unread(columns, occluded)
        });
    }
    let edge_z = median(&mut edge);
    Some(BaseVerdict {
        index: view.index,
        columns,
        occluded,
        edge_z: Some(edge_z),
        eye_z,
        reads: if edge_z > eye_z {
            BaseReading::EdgeAboveEye
        } else {
            BaseReading::EdgeBelowEye
        },
    })
}

/// The transforms (world to camera, camera to world) of a view whose pose inverts, whose
/// depth map fits its camera and whose mask is the colour image's size; `None` otherwise.
pub(crate) fn readable(view: &SegmentedView<'_>) -> Option<(Matrix4<f64>, Matrix4<f64>)> {
    let cam = view.camera;
    let to_cam = cam.out_to_cam().ok()?;
    let fits = cam.check_depth(view.depth).is_ok()
        && view.mask.width == cam.color.width
        && view.mask.height == cam.color.height;
    fits.then(|| (to_cam, cam.cam_to_out()))
}

/// The depth (m) of mask pixel (x, y) of `view` when the point it measured lies in `b`
/// (within `support.layer`): the object's pixels, so a loose mask (a box-shaped one, or one
/// that spilled onto the wall behind) does not set where the object ends. `to_out` is the
/// view's camera-to-world transform.
pub(crate) fn object_depth(
    view: &SegmentedView<'_>,
    to_out: &Matrix4<f64>,
    b: &Aabb,
    params: &GeometryParams,
    x: u32,
    y: u32,
) -> Option<f64> {
    if !view.mask.get(x, y) {
        return None;
    }
    let cam = view.camera;
    let d = reading(cam, view.depth, x, y)?;
    let p = transform_point(to_out, &cam.color.unproject(f64::from(x), f64::from(y), d));
    b.contains(&p, params.support.layer).then_some(d)
}

/// Height in pixels of `b`'s corners' projections into `cam` (0 when one is behind it).
fn box_height(cam: &FrameCamera, to_cam: &Matrix4<f64>, b: &Aabb) -> f64 {
    let mut vs = Vec::with_capacity(8);
    for i in 0..8 {
        let c = |k: usize| if i >> k & 1 == 0 { b.min[k] } else { b.max[k] };
        match cam
            .color
            .project(&transform_point(to_cam, &Point3::new(c(0), c(1), c(2))))
        {
            Some((_, v, _)) => vs.push(v),
            None => return 0.0,
        }
    }
    let (lo, hi) = vs
        .iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    (hi - lo).max(0.0)
}

/// Depth (m) read at colour pixel (x, y).
fn reading(cam: &FrameCamera, depth: &DepthMap, x: u32, y: u32) -> Option<f64> {
    cam.depth_at_color(depth, f64::from(x), f64::from(y))
}

/// Does "down" at the box's centre point mostly down the image (within 30 degrees)?
pub(crate) fn upright_at(cam: &FrameCamera, to_cam: &Matrix4<f64>, b: &Aabb) -> bool {
    let c = Point3::from(b.center());
    let below = c - Vector3::new(0.0, 0.0, 0.1);
    let (Some((u0, v0, _)), Some((u1, v1, _))) = (
        cam.color.project(&transform_point(to_cam, &c)),
        cam.color.project(&transform_point(to_cam, &below)),
    ) else {
        return false;
    };
    let (du, dv) = (u1 - u0, v1 - v0);
    dv > 0.0 && du.abs() <= dv * 30f64.to_radians().tan()
}

#[cfg(test)]
#[path = "hidden_base_tests.rs"]
mod tests;
