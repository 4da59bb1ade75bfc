//! Which frames measure what one frame's box shows where that frame has no depth reading
//! (ours, not the paper's).
//!
//! When the VLM picks an object that its frame did not measure (too far for the sensor, or
//! a surface that does not reflect it), the object still lies on the viewing rays through
//! the box. Each ray is walked from the camera outwards; a point on it that another frame's
//! depth reads at that point's depth (within the visibility tolerance) is a surface that
//! frame measured. The nearest such point along a ray is the first surface the chosen frame
//! looks at there: the object, or what is behind it where the ray misses it. A frame
//! *sights* a ray when it measures that first surface. The frames that sight most of the
//! box's rays are those to send the VLM to. Where no frame measured the object itself,
//! the first surface found is what lies behind it, and the frames that measured that are
//! named: the nearest place anything was measured.

use nalgebra::{Matrix4, Point3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::camera::transform_point;
use super::projection::project_one;
use super::{CandidateFrame, FrameCamera, GeometryParams, RoomLayout};

/// Rays across each side of the box (a grid of `RAYS` x `RAYS` over the box's inner part).
const RAYS: usize = 7;
/// Share of the box's width and height the rays cover, centred (its edges are mostly what
/// lies around the object).
const INNER: f64 = 0.8;
/// Nearest camera depth (m) walked along a ray.
const NEAR: f64 = 0.3;
/// Farthest camera depth (m) walked when the room's box does not end the ray.
const FAR: f64 = 10.0;
/// Step (m of camera depth) along a ray.
const STEP: f64 = 0.02;
/// How far (m) behind a ray's first surface a frame's measurement still counts as that
/// surface (the object's own depth as seen from elsewhere).
const SLACK: f64 = 0.1;

/// A frame that measures what the box shows.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Sighting {
    /// Caller's frame index.
    pub index: usize,
    /// Rays whose first surface this frame measured / rays whose first surface any frame
    /// measured.
    pub share: f64,
    /// Rays whose first surface this frame measured.
    pub rays: usize,
}

/// One viewing ray in the output frame: `o + t d` is the point at camera depth `t`.
struct Ray {
    o: Point3<f64>,
    d: Vector3<f64>,
    far: f64,
}

fn rays(camera: &FrameCamera, bbox: [f32; 4], room: Option<&RoomLayout>) -> Vec<Ray> {
    let m = camera.cam_to_out();
    let o = camera.centre();
    super::bound::box_lattice(bbox.map(f64::from), RAYS, INNER)
        .map(|(u, v)| {
            let p = transform_point(&m, &camera.color.unproject(u, v, 1.0));
            let d = p - o;
            let far = room.and_then(|r| r.exit(&o, &d)).unwrap_or(FAR).min(FAR);
            Ray { o, d, far }
        })
        .collect()
}

/// Camera depth of the first point along `ray` that `frame` measures, if any: where the
/// point lands and what depth is read there follow `projection::project_one`, with half a
/// step more tolerance (the point is one of a ray's samples, 2 cm apart).
fn first_measured(
    ray: &Ray,
    frame: &CandidateFrame<'_>,
    to_cam: &Matrix4<f64>,
    params: &GeometryParams,
) -> Option<f64> {
    let steps = ((ray.far - NEAR) / STEP).floor().max(0.0) as usize;
    (0..=steps).map(|k| NEAR + k as f64 * STEP).find(|&t| {
        project_one(
            &(ray.o + ray.d * t),
            to_cam,
            frame.camera,
            frame.depth,
            params,
        )
        .is_some_and(|p| {
            p.measured
                .is_some_and(|d| (d - p.z).abs() <= params.visibility_tolerance(p.z) + STEP / 2.0)
        })
    })
}

/// The frames among `frames` that measure what `bbox` (colour pixels of `camera`'s frame)
/// shows, best first (ties: lower index), with at least `min_share` of the rays whose first
/// surface some frame measured. The rays end where they leave `room`, when there is one.
/// Frames with an unusable pose or depth map are skipped. Empty when no frame measures
/// anything on the rays.
pub fn sightings(
    camera: &FrameCamera,
    bbox: [f32; 4],
    room: Option<&RoomLayout>,
    frames: &[CandidateFrame<'_>],
    min_share: f64,
    params: &GeometryParams,
) -> Vec<Sighting> {
    if bbox[2] <= bbox[0] || bbox[3] <= bbox[1] {
        return Vec::new();
    }
    let rays = rays(camera, bbox, room);
    // first[f][r]: where frame f first measured ray r.
    let first: Vec<Vec<Option<f64>>> = frames
        .par_iter()
        .map(|f| {
            let usable = f.camera.check_depth(f.depth).is_ok();
            match f.camera.out_to_cam() {
                Ok(to_cam) if usable => rays
                    .iter()
                    .map(|r| first_measured(r, f, &to_cam, params))
                    .collect(),
                _ => vec![None; rays.len()],
            }
        })
        .collect();
    let surface: Vec<Option<f64>> = (0..rays.len())
        .map(|r| {
            first
                .iter()
                .filter_map(|f| f[r])
                .min_by(|a, b| a.total_cmp(b))
        })
        .collect();
    let measured = surface.iter().flatten().count();
    if measured == 0 {
        return Vec::new();
    }
    let mut out: Vec<Sighting> = frames
        .iter()
        .zip(&first)
        .filter_map(|(f, hits)| {
            let n = hits
                .iter()
                .zip(&surface)
                .filter(|(h, s)| matches!((h, s), (Some(h), Some(s)) if *h <= s + SLACK))
                .count();
            let share = n as f64 / measured as f64;
            (n > 0 && share >= min_share).then_some(Sighting {
                index: f.index,
                share,
                rays: n,
            })
        })
        .collect();
    out.sort_by(|a, b| b.share.total_cmp(&a.share).then(a.index.cmp(&b.index)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::test_scene::{camera, render, room_box, room_slabs};
    use crate::geometry::DepthMap;

    /// A lamp-sized block standing in an 8 x 4 x 3 m room, 6 m from the chosen camera.
    const LAMP: ([f64; 3], [f64; 3]) = ([6.5, 1.8, 0.0], [6.9, 2.2, 1.6]);
    const RANGE: f64 = 4.0;

    fn scene() -> Vec<([f64; 3], [f64; 3])> {
        let mut s = room_slabs(8.0, 4.0, 3.0);
        s.push(LAMP);
        s
    }

    /// The block's box in `cam`'s colour pixels.
    fn box_of(cam: &FrameCamera) -> [f32; 4] {
        let to_cam = cam.out_to_cam().expect("pose");
        let (mut x1, mut y1, mut x2, mut y2) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for i in 0..8 {
            let c = |k: usize| {
                if i >> k & 1 == 0 {
                    LAMP.0[k]
                } else {
                    LAMP.1[k]
                }
            };
            let p = transform_point(&to_cam, &Point3::new(c(0), c(1), c(2)));
            let (u, v, _) = cam.color.project(&p).expect("in front");
            (x1, y1, x2, y2) = (x1.min(u), y1.min(v), x2.max(u), y2.max(v));
        }
        [x1 as f32, y1 as f32, x2 as f32, y2 as f32]
    }

    #[test]
    fn the_frames_that_measured_a_far_object_are_found_and_those_that_did_not_are_not() {
        let world = scene();
        let anchor = camera([0.5, 2.0, 1.2], [6.7, 2.0, 0.8]);
        let bbox = box_of(&anchor);
        // The chosen frame itself has no reading under the box: too far.
        let own = render(&anchor, &world, RANGE);
        let [x1, y1, x2, y2] = bbox.map(|v| v as f64);
        let (cu, cv) = ((x1 + x2) / 2.0, (y1 + y2) / 2.0);
        assert_eq!(anchor.depth_at_color(&own, cu, cv), None);

        let cams = [
            // 0: in front of the block, 2 m from it: measures what the box shows.
            camera([4.5, 2.1, 1.3], [6.7, 2.0, 0.8]),
            // 1: looks at the far wall away from the block.
            camera([4.5, 3.6, 1.3], [7.9, 3.7, 1.2]),
            // 2: sees the block, but from beyond the sensor's range.
            camera([1.0, 1.0, 1.3], [6.7, 2.0, 0.8]),
            // 3: behind the block: measures its back, not the face the box shows.
            camera([7.7, 2.0, 1.3], [6.7, 2.0, 0.8]),
        ];
        let depths: Vec<DepthMap> = cams.iter().map(|c| render(c, &world, RANGE)).collect();
        let frames: Vec<CandidateFrame> = cams
            .iter()
            .zip(&depths)
            .enumerate()
            .map(|(i, (c, d))| CandidateFrame {
                index: 10 + i,
                camera: c,
                depth: d,
            })
            .collect();
        let room = room_box(0.0, 8.0, 4.0, 3.0);
        let params = GeometryParams::default();
        for room in [Some(&room), None] {
            let found = sightings(&anchor, bbox, room, &frames, 0.5, &params);
            let ids: Vec<usize> = found.iter().map(|s| s.index).collect();
            assert_eq!(ids, vec![10], "{found:?}");
            assert!(found[0].share > 0.9, "{found:?}");
        }
        // Without a frame that measured anything on the rays, there is nothing to name.
        assert!(sightings(&anchor, bbox, Some(&room), &frames[2..3], 0.5, &params).is_empty());
        // With only the frame behind it, that frame measured the block (its back) first.
        let behind = sightings(&anchor, bbox, Some(&room), &frames[3..], 0.5, &params);
        assert_eq!(behind.iter().map(|s| s.index).collect::<Vec<_>>(), vec![13]);
        // A degenerate box names nothing.
        let flat = [bbox[0], bbox[1], bbox[0], bbox[3]];
        assert!(sightings(&anchor, flat, Some(&room), &frames, 0.5, &params).is_empty());
    }
}
