//! A detection seen again from other frames (ours, not the paper's).
//!
//! Pre-selection offers the frames in which the detector found the target's class. A
//! detector misses an object in some of the frames that show it well: seen from another
//! side, cut by the frame's edge, small, or just below the score threshold. When the
//! object was found in one frame, the depth under its box says where it stands in the room,
//! and another frame that looks at that place, and whose own depth reads the same surface
//! there (nothing nearer hides it), sees the object too.

use nalgebra::Point3;

use super::camera::transform_point;
use super::projection::project_one;
use super::{DepthMap, FrameCamera, GeometryParams};

/// Probe points across each side of the box's central part.
const GRID: usize = 7;
/// Share of the box's width and height the probe covers, centred: the object fills the
/// middle of its box more surely than the edges.
const INNER: f64 = 0.5;
/// How far (m) behind or before the probe's median depth a sample still counts as the
/// object: what shows through its gaps (a wall behind a chair's back) lies farther.
const LAYER: f64 = 0.3;
/// Fewest samples a probe needs; a box with less depth under it says too little.
const MIN_POINTS: usize = 6;
/// Share of the probe another frame must see for it to see the object.
const MIN_SEEN: f64 = 0.5;

/// What a box shows, placed in the room.
#[derive(Debug, Clone, PartialEq)]
pub struct Probe {
    /// Points (output frame) on the object's surface that the box's frame measured.
    pub points: Vec<Point3<f64>>,
    /// Half the box's larger side (m) at the points' median depth, at most `MAX_REACH`:
    /// how much nearer than a probe point another frame may read the object's own surface
    /// (its side or front, seen from there).
    pub reach: f64,
}

/// Largest [`Probe::reach`] (m).
const MAX_REACH: f64 = 1.0;

/// The probe of a box (colour pixels): the depth readings on a lattice over the box's
/// central half that lie within `LAYER` of their median depth. `None` when too few
/// readings lie there.
pub fn box_probe(camera: &FrameCamera, depth: &DepthMap, bbox: [f32; 4]) -> Option<Probe> {
    camera.check_depth(depth).ok()?;
    let b = super::bound::proper_box(bbox)?;
    let (w, h) = (b[2] - b[0], b[3] - b[1]);
    let (iw, ih) = (
        f64::from(camera.color.width),
        f64::from(camera.color.height),
    );
    let samples: Vec<(f64, f64, f64)> = super::bound::box_lattice(b, GRID, INNER)
        .filter(|(u, v)| (0.0..iw).contains(u) && (0.0..ih).contains(v))
        .filter_map(|(u, v)| Some((u, v, camera.depth_at_color(depth, u, v)?)))
        .collect();
    if samples.len() < MIN_POINTS {
        return None;
    }
    let mut zs: Vec<f64> = samples.iter().map(|s| s.2).collect();
    zs.sort_by(f64::total_cmp);
    let median = zs[zs.len() / 2];
    let to_out = camera.cam_to_out();
    let points: Vec<Point3<f64>> = samples
        .into_iter()
        .filter(|s| (s.2 - median).abs() <= LAYER)
        .map(|(u, v, z)| transform_point(&to_out, &camera.color.unproject(u, v, z)))
        .collect();
    let side = (w / camera.color.fx).max(h / camera.color.fy) * median;
    (points.len() >= MIN_POINTS).then_some(Probe {
        points,
        reach: (side / 2.0).min(MAX_REACH),
    })
}

/// Does the frame (`camera`, `depth`) see what `probe` stands for? At least `MIN_SEEN` of
/// its points must fall inside the image, in front of the camera, where the frame reads a
/// surface no farther than the point (within the visibility tolerance: nothing is seen
/// through it) and no nearer than the probe's reach (the object's own side may face this
/// frame; anything nearer hides it).
pub fn sees_probe(
    probe: &Probe,
    camera: &FrameCamera,
    depth: &DepthMap,
    params: &GeometryParams,
) -> bool {
    if probe.points.is_empty() || camera.check_depth(depth).is_err() {
        return false;
    }
    let Ok(to_cam) = camera.out_to_cam() else {
        return false;
    };
    let seen = probe
        .points
        .iter()
        .filter_map(|p| project_one(p, &to_cam, camera, depth, params))
        .filter(|q| {
            let tol = params.visibility_tolerance(q.z);
            q.inside
                && q.measured
                    .is_some_and(|m| (-tol..=probe.reach + tol).contains(&(q.z - m)))
        })
        .count();
    seen as f64 >= MIN_SEEN * probe.points.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::camera::look_at_pose;
    use crate::geometry::test_scene::render_coloured;
    use crate::geometry::Intrinsics;
    use nalgebra::{Matrix4, Vector3};

    fn camera(eye: [f64; 3], at: [f64; 3]) -> FrameCamera {
        FrameCamera {
            color: Intrinsics {
                fx: 100.0,
                fy: 100.0,
                cx: 79.5,
                cy: 59.5,
                width: 160,
                height: 120,
            },
            depth: None,
            depth_size: (160, 120),
            pose: look_at_pose(eye.into(), at.into(), Vector3::z()),
            align: Matrix4::identity(),
        }
    }

    type Part = ([f64; 3], [f64; 3], [u8; 3]);

    /// A chair-sized box in a room, and a screen that hides it from one side.
    fn room() -> Vec<Part> {
        vec![
            ([-3.0, -3.0, -0.1], [4.0, 4.0, 0.0], [150, 110, 70]),
            ([1.0, -0.25, 0.0], [1.5, 0.25, 0.9], [40, 70, 160]),
            ([3.0, -3.0, 0.0], [3.1, 3.0, 3.0], [200, 200, 190]),
            ([1.0, -2.0, 0.0], [1.6, -1.9, 1.8], [90, 90, 90]),
        ]
    }

    fn view(eye: [f64; 3], at: [f64; 3]) -> (FrameCamera, DepthMap, [f32; 4]) {
        let cam = camera(eye, at);
        let (_, depth, _) = render_coloured(&cam, &room(), 0);
        let (_, _, mask) = render_coloured(&cam, &room(), 1);
        let b = crate::geometry::morph::bounds(&mask, 0).map(|b| b.map(|v| v as f32));
        (cam, depth, b.unwrap_or([0.0; 4]))
    }

    #[test]
    fn a_frame_that_looks_at_the_detected_object_sees_it_and_one_that_is_blocked_does_not() {
        let (cam, depth, b) = view([-1.0, 0.0, 1.2], [1.25, 0.0, 0.45]);
        let probe = box_probe(&cam, &depth, b).expect("depth under the box");
        assert!(
            probe.points.iter().all(|p| (0.95..=1.55).contains(&p.x)),
            "{probe:?}"
        );
        assert!((0.2..0.6).contains(&probe.reach), "{probe:?}");
        let params = GeometryParams::default();
        // From the side, nothing between: seen.
        let (side, side_depth, _) = view([1.25, 2.0, 1.2], [1.25, 0.0, 0.45]);
        assert!(sees_probe(&probe, &side, &side_depth, &params));
        // From behind the screen: the screen is read nearer, so not seen.
        let (hidden, hidden_depth, _) = view([1.25, -2.8, 1.0], [1.25, 0.0, 0.45]);
        assert!(!sees_probe(&probe, &hidden, &hidden_depth, &params));
        // Looking away: not seen.
        let (away, away_depth, _) = view([1.25, 2.0, 1.2], [1.25, 4.0, 1.2]);
        assert!(!sees_probe(&probe, &away, &away_depth, &params));
    }

    #[test]
    fn a_box_with_no_depth_under_it_gives_no_probe() {
        let cam = camera([-1.0, 0.0, 1.2], [1.25, 0.0, 0.45]);
        let empty = DepthMap::new(160, 120, vec![0; 160 * 120]);
        assert!(box_probe(&cam, &empty, [40.0, 30.0, 120.0, 90.0]).is_none());
        assert!(box_probe(&cam, &empty, [f32::NAN, 0.0, 1.0, 1.0]).is_none());
    }
}
