//! The chosen view's box as a bound on where the object can be (ours, not the paper's).
//!
//! A box drawn on the chosen image (a detector's, or the VLM's) holds all of the object
//! that image shows. When nothing hides part of the object in that image (no nearer
//! surface along its outline: `geometry::partial`), it holds all of the object: every
//! point of it projects into the box. A box that touches the frame's edge bounds what the
//! image shows, not what lies beyond the frame (the object may go on there). Another
//! view's points that project outside the bound are not the object, whatever that view's
//! mask says: a region that holds a pillow with the bed it lies on, where the chosen view
//! saw the pillow alone, gives the pillow and none of the bed.
//!
//! The bound speaks where the chosen view's mask cannot: for points that view does not
//! measure (hidden behind the object or by something else, out of its depth range) and
//! for those beside its region; [`super::mask_votes`] already drops the ones it measures
//! outside its mask.

use nalgebra::Point3;

use super::camera::transform_point;
use super::{FrameCamera, GeometryParams, PartialParams, PartialView};

/// The chosen view's bound: its camera, the box (colour pixels, widened) and whether a
/// side of it lies on the frame's edge.
#[derive(Debug, Clone, Copy)]
pub struct ViewBound<'a> {
    pub camera: &'a FrameCamera,
    pub bbox: [f64; 4],
    /// The object may go on beyond the frame: what projects outside the image is not
    /// bounded (in the image, the box still is: the object enters the frame through the
    /// box's side on the edge).
    pub open: bool,
    /// Sides (left, top, right, bottom) past which the object may go on in the image,
    /// hidden by a nearer surface (`sides`, see [`super::partial::hidden_sides`], at or
    /// above `rule.min_side_occluded`): what projects beyond such a side is not bounded.
    pub open_sides: [bool; 4],
}

/// The bound `bbox` (colour pixels of `camera`, as chosen) puts on its object, widened by
/// `consensus.anchor_box_margin` of its size and the mask votes' pose tolerance; `None`
/// when it puts none: switched off, a degenerate box, or `partial` finds a nearer surface
/// along the mask's outline (`partial.occluded` at or above `rule.min_occluded`). A side
/// within `rule.border_frac` of the image's width from the frame's edge makes it `open`; a
/// side that a nearer surface crosses (`sides`) is open by itself.
pub fn view_bound<'a>(
    camera: &'a FrameCamera,
    bbox: [f32; 4],
    partial: &PartialView,
    sides: [f64; 4],
    rule: &PartialParams,
    params: &GeometryParams,
) -> Option<ViewBound<'a>> {
    let c = &params.consensus;
    if !c.anchor_box_bound || partial.occluded >= rule.min_occluded {
        return None;
    }
    let b = proper_box(bbox)?;
    let (bw, bh) = (b[2] - b[0], b[3] - b[1]);
    let (w, h) = (
        f64::from(camera.color.width),
        f64::from(camera.color.height),
    );
    let edge = rule.border_frac * w;
    // Pose error moves a point by about as much as the mask votes allow for.
    let tol = f64::from(super::consensus::pose_tolerance_px(
        params,
        camera.color.width,
    ));
    let (mx, my) = (
        c.anchor_box_margin * bw + tol,
        c.anchor_box_margin * bh + tol,
    );
    Some(ViewBound {
        camera,
        bbox: [b[0] - mx, b[1] - my, b[2] + mx, b[3] + my],
        open: b[0] <= edge || b[1] <= edge || b[2] >= w - edge || b[3] >= h - edge,
        open_sides: sides.map(|s| s >= rule.min_side_occluded),
    })
}

/// A box (pixels) in f64, if its numbers are finite and it has an area.
pub fn proper_box(bbox: [f32; 4]) -> Option<[f64; 4]> {
    let b = bbox.map(f64::from);
    (b.iter().all(|v| v.is_finite()) && b[2] > b[0] && b[3] > b[1]).then_some(b)
}

/// Pixel points of an `n` x `n` lattice over the centred `inner` share of box `b`'s width
/// and height (cell centres), row by row.
pub fn box_lattice(b: [f64; 4], n: usize, inner: f64) -> impl Iterator<Item = (f64, f64)> {
    let (w, h) = (b[2] - b[0], b[3] - b[1]);
    let at = move |k: usize| (1.0 - inner) / 2.0 + inner * (k as f64 + 0.5) / n as f64;
    (0..n).flat_map(move |j| (0..n).map(move |i| (b[0] + at(i) * w, b[1] + at(j) * h)))
}

/// `points` less those that project outside `bound`: into the image outside the box (past
/// a side that is not open), or outside the image when the bound is not `open`. A point
/// behind the camera is kept (the bound does not speak for it), and so is every point when
/// the pose is unusable.
pub fn within_bound(points: &[Point3<f64>], bound: &ViewBound<'_>) -> Vec<Point3<f64>> {
    let Ok(to_cam) = bound.camera.out_to_cam() else {
        return points.to_vec();
    };
    let (b, k) = (bound.bbox, &bound.camera.color);
    let (w, h) = (f64::from(k.width), f64::from(k.height));
    points
        .iter()
        .filter(|p| match k.project(&transform_point(&to_cam, p)) {
            Some((u, v, _)) => {
                let o = bound.open_sides;
                let in_box = (u >= b[0] || o[0])
                    && (v >= b[1] || o[1])
                    && (u <= b[2] || o[2])
                    && (v <= b[3] || o[3]);
                let in_image = u >= 0.0 && u < w && v >= 0.0 && v < h;
                in_box || (bound.open && !in_image)
            }
            None => true,
        })
        .copied()
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Intrinsics;
    use nalgebra::Matrix4;

    /// A 100x80 camera at the origin looking down +z (output frame = camera frame).
    fn camera() -> FrameCamera {
        FrameCamera {
            color: Intrinsics {
                fx: 100.0,
                fy: 100.0,
                cx: 50.0,
                cy: 40.0,
                width: 100,
                height: 80,
            },
            depth: None,
            depth_size: (100, 80),
            pose: Matrix4::identity(),
            align: Matrix4::identity(),
        }
    }

    fn whole() -> PartialView {
        PartialView {
            border: false,
            occluded: 0.0,
            missing: 0.3,
            partial: true,
        }
    }

    /// A 10 % margin and a pose tolerance of one pixel.
    fn params() -> GeometryParams {
        let mut p = GeometryParams::default();
        p.consensus.anchor_box_margin = 0.1;
        p.erode_reference_width = 0;
        p.consensus.mask_dilate = 3;
        p
    }

    /// A point at depth 2 m that projects to colour pixel (u, v).
    fn at(u: f64, v: f64) -> Point3<f64> {
        Point3::new((u - 50.0) / 100.0 * 2.0, (v - 40.0) / 100.0 * 2.0, 2.0)
    }

    #[test]
    fn points_beside_the_box_go_and_those_in_it_or_behind_the_camera_stay() {
        let cam = camera();
        let b = view_bound(
            &cam,
            [40.0, 30.0, 60.0, 50.0],
            &whole(),
            [0.0; 4],
            &PartialParams::default(),
            &params(),
        );
        let b = b.expect("a whole object's box bounds it");
        let behind = Point3::new(0.0, 0.0, -1.0);
        let pts = [
            at(50.0, 40.0),
            at(61.0, 40.0),
            at(70.0, 40.0),
            at(50.0, 75.0),
            at(150.0, 40.0),
            behind,
        ];
        // 61 is within the margin (2 pixels, 10 % of the 20-pixel side, and one for the
        // tolerance); 70, the row 75 and what lies beyond the frame are not.
        assert_eq!(within_bound(&pts, &b), vec![pts[0], pts[1], behind]);
    }

    #[test]
    fn a_side_on_the_frames_edge_is_no_bound() {
        let cam = camera();
        let b = view_bound(
            &cam,
            [40.0, 30.0, 100.0, 50.0],
            &whole(),
            [0.0; 4],
            &PartialParams::default(),
            &params(),
        );
        let b = b.expect("bounded on three sides");
        // Far right of the frame, and anywhere beyond the frame: the object may go on
        // there; in the frame, the box still bounds it.
        let pts = [
            at(99.0, 40.0),
            at(180.0, 45.0),
            at(50.0, -30.0),
            at(20.0, 40.0),
        ];
        assert_eq!(within_bound(&pts, &b), vec![pts[0], pts[1], pts[2]]);
        assert!(within_bound(&[at(70.0, 75.0)], &b).is_empty());
    }

    #[test]
    fn an_occluded_object_or_a_switched_off_bound_bounds_nothing() {
        let cam = camera();
        let bx = [40.0, 30.0, 60.0, 50.0];
        let hidden = PartialView {
            occluded: 0.3,
            ..whole()
        };
        let rule = PartialParams::default();
        assert!(view_bound(&cam, bx, &hidden, [0.0; 4], &rule, &params()).is_none());
        let mut off = params();
        off.consensus.anchor_box_bound = false;
        assert!(view_bound(&cam, bx, &whole(), [0.0; 4], &rule, &off).is_none());
        let flat = [40.0, 30.0, 40.0, 50.0];
        assert!(view_bound(&cam, flat, &whole(), [0.0; 4], &rule, &params()).is_none());
    }

    #[test]
    fn a_hidden_side_lets_the_object_go_on_past_it_and_only_that_side() {
        let cam = camera();
        let bx = [40.0, 30.0, 60.0, 50.0];
        let rule = PartialParams::default();
        // A table's top crosses the bottom of the box, a few pixels of its left side are
        // nearer too (depth noise).
        let below = [0.1, 0.0, 0.0, 0.9];
        let b = view_bound(&cam, bx, &whole(), below, &rule, &params()).expect("a bound");
        assert_eq!(b.open_sides, [false, false, false, true]);
        let pts = [
            at(50.0, 70.0),
            at(50.0, 10.0),
            at(30.0, 40.0),
            at(30.0, 70.0),
        ];
        // Below the box, the seat goes on; above, beside, and below-beside it does not.
        assert_eq!(within_bound(&pts, &b), vec![pts[0]]);
        let mut never = rule.clone();
        never.min_side_occluded = 1.1;
        let closed = view_bound(&cam, bx, &whole(), below, &never, &params()).expect("a bound");
        assert!(within_bound(&pts, &closed).is_empty());
    }
}
