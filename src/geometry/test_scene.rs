//! Test helper: small posed cameras and depth rendered from axis-aligned boxes (shared by
//! the geometry modules' tests).

use image::{Rgb, RgbImage};
use nalgebra::{Matrix4, Point3, Vector3};

use super::camera::{look_at_pose, transform_point};
use super::depth_fill::color_pixel;
use super::{DepthMap, FrameCamera, Intrinsics, RoomLayout};

/// Colour 80x60, depth 40x30 (ratio rule, no depth K).
pub(crate) fn camera(eye: [f64; 3], target: [f64; 3]) -> FrameCamera {
    let color = Intrinsics {
        fx: 60.0,
        fy: 60.0,
        cx: 39.5,
        cy: 29.5,
        width: 80,
        height: 60,
    };
    let pose = look_at_pose(Point3::from(eye), Point3::from(target), Vector3::z());
    FrameCamera {
        color,
        depth: None,
        depth_size: (40, 30),
        pose,
        align: Matrix4::identity(),
    }
}

/// The first of `boxes` (`[min, max]`) that the ray `o + t d`, t > 0, enters: its index
/// and `t`.
pub(crate) fn first_hit<'a>(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    boxes: impl Iterator<Item = (&'a [f64; 3], &'a [f64; 3])>,
) -> Option<(usize, f64)> {
    let mut best: Option<(usize, f64)> = None;
    for (n, (lo, hi)) in boxes.enumerate() {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            if d[k].abs() < 1e-12 {
                if o[k] < lo[k] || o[k] > hi[k] {
                    t1 = -1.0;
                }
                continue;
            }
            let (a, b) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        if t0 <= t1 && t0 > 0.0 && best.is_none_or(|(_, t)| t0 < t) {
            best = Some((n, t0));
        }
    }
    best
}

/// The ray from `cam`'s centre through colour pixel `(u, v)`, in the output frame, scaled
/// so that its parameter is the camera depth.
pub(crate) fn pixel_ray(cam: &FrameCamera, u: f64, v: f64) -> (Point3<f64>, Vector3<f64>) {
    let m = cam.cam_to_out();
    let o = transform_point(&m, &Point3::origin());
    (o, transform_point(&m, &cam.color.unproject(u, v, 1.0)) - o)
}

/// Depth of a scene of axis-aligned boxes `[min, max]` seen by `cam`, with readings beyond
/// `range` metres dropped.
pub(crate) fn render(cam: &FrameCamera, boxes: &[([f64; 3], [f64; 3])], range: f64) -> DepthMap {
    let (w, h) = cam.depth_size;
    let mut data = vec![0u16; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = color_pixel(cam, x as f64, y as f64);
            let (o, d) = pixel_ray(cam, u, v);
            if let Some((_, t)) = first_hit(&o, &d, boxes.iter().map(|(lo, hi)| (lo, hi))) {
                if t <= range {
                    data[(y * w + x) as usize] = (t * 1000.0).round() as u16;
                }
            }
        }
    }
    DepthMap::new(w, h, data)
}

/// Colour, depth and the mask of box `target` of a scene of coloured axis-aligned boxes
/// `(min, max, rgb)` seen by `cam`, whose depth is aligned with its colour at one size.
pub(crate) fn render_coloured(
    cam: &FrameCamera,
    boxes: &[([f64; 3], [f64; 3], [u8; 3])],
    target: usize,
) -> (RgbImage, DepthMap, super::Mask) {
    let (w, h) = (cam.color.width, cam.color.height);
    assert_eq!(cam.depth_size, (w, h), "depth aligned with colour");
    let mut color = RgbImage::new(w, h);
    let mut depth = vec![0u16; (w * h) as usize];
    let mut mask = super::Mask::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let (o, d) = pixel_ray(cam, f64::from(x), f64::from(y));
            if let Some((n, t)) = first_hit(&o, &d, boxes.iter().map(|(lo, hi, _)| (lo, hi))) {
                depth[(y * w + x) as usize] = (t * 1000.0).round() as u16;
                color.put_pixel(x, y, Rgb(boxes[n].2));
                mask.set(x, y, n == target);
            }
        }
    }
    (color, DepthMap::new(w, h, depth), mask)
}

/// A room [0, w] x [0, d] x [0, h] as six 10 cm slabs (floor, ceiling, four walls).
pub(crate) fn room_slabs(w: f64, d: f64, h: f64) -> Vec<([f64; 3], [f64; 3])> {
    vec![
        ([-0.1, -0.1, -0.1], [w + 0.1, d + 0.1, 0.0]),
        ([-0.1, -0.1, h], [w + 0.1, d + 0.1, h + 0.1]),
        ([-0.1, -0.1, 0.0], [0.0, d + 0.1, h]),
        ([w, -0.1, 0.0], [w + 0.1, d + 0.1, h]),
        ([-0.1, -0.1, 0.0], [w + 0.1, 0.0, h]),
        ([-0.1, d, 0.0], [w + 0.1, d + 0.1, h]),
    ]
}

/// The room [0, w] x [0, d] x [0, h] as `estimate_room` would give it, turned by `angle`
/// degrees, every wall faced.
pub(crate) fn room_box(angle: f64, w: f64, d: f64, h: f64) -> RoomLayout {
    RoomLayout {
        angle_deg: angle,
        u: [Some(0.0), Some(w)],
        v: [Some(0.0), Some(d)],
        faced: [true; 4],
        floor: Some(0.0),
        ceiling: Some(h),
        range: 5.0,
        reach: [[0.0, w], [0.0, d], [0.0, h]],
        points: 1000,
    }
}

/// The colour pixels where `object` is the first surface `cam` sees in `world` (a
/// segmenter's perfect mask of what depth measured of it), and the depth of `world`.
pub(crate) fn first_surface_mask(
    cam: &FrameCamera,
    world: &[([f64; 3], [f64; 3])],
    object: ([f64; 3], [f64; 3]),
    range: f64,
) -> (DepthMap, super::Mask) {
    let all = render(cam, world, range);
    let alone = render(cam, &[object], range);
    let mut m = super::Mask::new(cam.color.width, cam.color.height);
    for y in 0..m.height {
        for x in 0..m.width {
            let (u, v) = (f64::from(x), f64::from(y));
            let hit = matches!(
                (cam.depth_at_color(&all, u, v), cam.depth_at_color(&alone, u, v)),
                (Some(a), Some(b)) if (a - b).abs() < 0.005
            );
            m.set(x, y, hit);
        }
    }
    (all, m)
}

/// The box of what `cam` measured under `mask`.
pub(crate) fn seen_box(cam: &FrameCamera, depth: &DepthMap, mask: &super::Mask) -> super::Aabb {
    use super::projection::{backproject_mask, BackprojectOptions};
    let pts = backproject_mask(mask, cam, depth, BackprojectOptions::default()).expect("pose");
    super::Aabb::from_points(&pts).expect("the object is in view")
}

/// A segmented view of `mask` (no points, no region).
pub(crate) fn segmented_view<'a>(
    index: usize,
    camera: &'a FrameCamera,
    depth: &'a DepthMap,
    mask: &'a super::Mask,
) -> super::fusion::SegmentedView<'a> {
    super::fusion::SegmentedView {
        index,
        camera,
        depth,
        mask,
        points: &[],
        region: None,
        partial: false,
        border_frac: super::PartialParams::default().border_frac,
        bound: None,
    }
}
