use super::*;
use crate::geometry::camera::look_at_pose;
use crate::geometry::Intrinsics;
use nalgebra::Vector3;

/// Colour 80x60, depth 40x30 (ratio rule, no depth K).
fn camera(eye: [f64; 3], target: [f64; 3]) -> FrameCamera {
    let color = Intrinsics { fx: 60.0, fy: 60.0, cx: 39.5, cy: 29.5, width: 80, height: 60 };
    let pose = look_at_pose(Point3::from(eye), Point3::from(target), Vector3::z());
    FrameCamera { color, depth: None, depth_size: (40, 30), pose, align: Matrix4::identity() }
}

/// Depth of a scene of axis-aligned boxes `[min, max]` seen by `cam`, with readings beyond
/// `range` metres dropped.
fn render(cam: &FrameCamera, boxes: &[([f64; 3], [f64; 3])], range: f64) -> DepthMap {
    let (w, h) = cam.depth_size;
    let m = cam.cam_to_out();
    let mut data = vec![0u16; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = color_pixel(cam, x as f64, y as f64);
            let o = transform_point(&m, &Point3::origin());
            let d = transform_point(&m, &cam.color.unproject(u, v, 1.0)) - o; // one metre of depth
            let mut best = f64::INFINITY;
            for (lo, hi) in boxes {
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
                if t0 <= t1 && t0 > 0.0 {
                    best = best.min(t0);
                }
            }
            if best <= range {
                data[(y * w + x) as usize] = (best * 1000.0).round() as u16;
            }
        }
    }
    DepthMap::new(w, h, data)
}

/// A wall: the plane y = 0 (its front face), 10 m wide and 3 m high.
const WALL: ([f64; 3], [f64; 3]) = ([-5.0, 0.0, 0.0], [5.0, 0.1, 3.0]);

#[test]
fn a_wall_beyond_range_gets_the_depth_nearer_views_measured() {
    let far = camera([0.0, -6.0, 1.5], [0.0, 0.0, 1.5]);
    let depth = render(&far, &[WALL], 5.0);
    assert!(depth.data.iter().all(|&d| d == 0), "the wall is beyond range");
    let near: Vec<FrameCamera> = [[-1.0, -2.0, 1.4], [1.0, -2.5, 1.6], [0.0, -2.6, 1.2]].iter().map(|&e| camera(e, [e[0] * 0.5, 0.0, 1.5])).collect();
    let maps: Vec<DepthMap> = near.iter().map(|c| render(c, &[WALL], 5.0)).collect();
    let others: Vec<(&FrameCamera, &DepthMap)> = near.iter().zip(&maps).collect();
    let p = GeometryParams::default();
    let (filled, stats) = fill_depth(&far, &depth, [30.0, 20.0, 50.0, 40.0], &others, &p).unwrap();
    // The box reads depth pixels [15, 26) x [10, 21): all missing, all reached.
    let holes: Vec<(u32, u32)> = (10..21).flat_map(|y| (15..26).map(move |x| (x, y))).filter(|&(x, y)| filled.get(x, y) == 0).collect();
    assert_eq!((stats.missing, stats.rays, stats.filled), (121, 121, 121), "{stats:?} {holes:?}");
    let truth = render(&far, &[WALL], 100.0);
    for y in 10..21 {
        for x in 15..26 {
            let (got, want) = (filled.get(x, y) as f64, truth.get(x, y) as f64);
            assert!((got - want).abs() < 40.0, "({x}, {y}): {got} mm, wall at {want} mm");
        }
    }
    // Outside the box nothing is filled.
    assert_eq!((filled.get(0, 0), filled.get(39, 29)), (0, 0));
}

#[test]
fn readings_stay_and_the_nearest_surface_wins() {
    // A cabinet 1 m in front of the wall; the far camera measures the wall's left part
    // itself (a 5.9 m reading is kept as is) but not the cabinet (a blob of no readings).
    let cabinet = ([-0.4, -1.0, 0.0], [0.4, -0.6, 2.0]);
    let far = camera([0.0, -6.0, 1.5], [0.0, 0.0, 1.5]);
    let mut depth = render(&far, &[WALL, cabinet], 100.0);
    let kept = depth.get(2, 15);
    for y in 0..30 {
        for x in 12..40 {
            depth.data[(y * 40 + x) as usize] = 0;
        }
    }
    let near: Vec<FrameCamera> = [[-1.5, -3.0, 1.5], [1.5, -3.0, 1.5], [0.0, -3.5, 1.8]].iter().map(|&e| camera(e, [0.0, -0.8, 1.0])).collect();
    let maps: Vec<DepthMap> = near.iter().map(|c| render(c, &[WALL, cabinet], 5.0)).collect();
    let others: Vec<(&FrameCamera, &DepthMap)> = near.iter().zip(&maps).collect();
    let (filled, stats) = fill_depth(&far, &depth, [0.0, 0.0, 80.0, 60.0], &others, &GeometryParams::default()).unwrap();
    assert!(stats.resolved > 0, "{stats:?}");
    assert_eq!(filled.get(2, 15), kept, "a reading is never replaced");
    // The cabinet's face is 5.0 m away (y = -1): the ray stops there, not at the wall.
    let truth = render(&far, &[WALL, cabinet], 100.0);
    let centre = filled.get(20, 15);
    assert_eq!(truth.get(20, 15), 5000);
    assert!((centre as f64 - 5000.0).abs() < 60.0, "cabinet centre filled with {centre} mm");
}

#[test]
fn rays_no_other_view_measures_stay_empty() {
    let far = camera([0.0, -6.0, 1.5], [0.0, 0.0, 1.5]);
    let depth = render(&far, &[WALL], 5.0);
    // One view only: below `min_votes`.
    let near = camera([0.0, -2.0, 1.5], [0.0, 0.0, 1.5]);
    let map = render(&near, &[WALL], 5.0);
    let (filled, stats) = fill_depth(&far, &depth, [0.0, 0.0, 80.0, 60.0], &[(&near, &map)], &GeometryParams::default()).unwrap();
    assert_eq!((stats.resolved, stats.filled), (0, 0), "{stats:?}");
    assert!(filled.data.iter().all(|&d| d == 0));
    // A view whose depth does not match its camera is an error, not a panic.
    let bad = DepthMap::new(10, 10, vec![0; 100]);
    assert!(fill_depth(&far, &bad, [0.0, 0.0, 80.0, 60.0], &[], &GeometryParams::default()).is_err());
}
