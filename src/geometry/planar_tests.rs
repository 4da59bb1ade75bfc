//! Tests of [`super`].

use super::*;

/// Deterministic noise in [-1, 1].
pub(super) fn jitter(i: usize, k: u64) -> f64 {
    let h = (i as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(k.wrapping_mul(0xBF58_476D_1CE4_E5B9));
    ((h >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

/// Points on the plane y = `y` over x in [x0, x1], z in [z0, z1], with noise `n` on y.
fn plane_y(
    y: f64,
    (x0, x1): (f64, f64),
    (z0, z1): (f64, f64),
    n: f64,
    hole: Option<[f64; 4]>,
) -> Vec<Point3<f64>> {
    let mut out = Vec::new();
    let mut i = 0;
    let mut x = x0;
    while x <= x1 {
        let mut z = z0;
        while z <= z1 {
            i += 1;
            if !hole.is_some_and(|h| x > h[0] && x < h[1] && z > h[2] && z < h[3]) {
                out.push(Point3::new(x, y + n * jitter(i, 1), z));
            }
            z += 0.02;
        }
        x += 0.02;
    }
    out
}

/// A flat object's face at y = `face` over `xs` and `zs` (noise `noise`), and the wall at
/// y = 6.11 around it, 30 cm beyond it on every side (noise 1 cm).
fn on_wall(
    face: f64,
    xs: (f64, f64),
    zs: (f64, f64),
    noise: f64,
) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
    let object = plane_y(face, xs, zs, noise, None);
    let hole = [xs.0, xs.1, zs.0, zs.1];
    let wall = plane_y(
        6.11,
        (xs.0 - 0.3, xs.1 + 0.3),
        (zs.0 - 0.3, zs.1 + 0.3),
        0.01,
        Some(hole),
    );
    (object, wall)
}

#[test]
fn a_noisy_window_spans_from_its_plane_to_the_wall() {
    // Window 6 cm deep flush with the wall at y = 6.11; its face at 6.05 seen with
    // ±3 cm of noise, the camera in the room (y < 6).
    let (window, wall) = on_wall(6.05, (0.7, 1.9), (1.0, 2.1), 0.03);
    let fused = Aabb::new([0.68, 5.9, 0.98], [1.92, 6.2, 2.12]);
    let (b, snaps) = snap_planar_to_wall(
        &fused,
        &window,
        &wall,
        None,
        [1.3, 3.0, 1.5],
        0.05,
        &GeometryParams::default(),
    );
    assert_eq!(snaps.len(), 1, "{snaps:?}");
    assert_eq!(snaps[0].axis, "y");
    assert!(snaps[0].applied());
    assert!(
        (b.min[1] - 6.05).abs() < 0.01 && (b.max[1] - 6.11).abs() < 0.01,
        "{b:?}"
    );
    assert_eq!(
        (b.min[0], b.max[0], b.min[2], b.max[2]),
        (0.68, 1.92, 0.98, 2.12)
    );
}

#[test]
fn a_window_frame_before_its_glass_is_the_front() {
    // Glass at y = 6.10 (the wall at 6.11), the frame's face 6 cm before it at 6.04:
    // a 10 cm border of a 1.2 x 1.1 m window, a third of its points.
    let all = plane_y(6.10, (0.7, 1.9), (1.0, 2.1), 0.005, None);
    let frame = |p: &Point3<f64>| p.x < 0.8 || p.x > 1.8 || p.z < 1.1 || p.z > 2.0;
    let window: Vec<Point3<f64>> = all
        .iter()
        .map(|p| {
            if frame(p) {
                Point3::new(p.x, p.y - 0.06, p.z)
            } else {
                *p
            }
        })
        .collect();
    let wall = plane_y(
        6.11,
        (0.4, 2.2),
        (0.7, 2.4),
        0.005,
        Some([0.7, 1.9, 1.0, 2.1]),
    );
    let fused = Aabb::new([0.68, 5.95, 0.98], [1.92, 6.15, 2.12]);
    let gp = GeometryParams::default();
    let run = |gp: &GeometryParams| {
        snap_planar_to_wall(&fused, &window, &wall, None, [1.3, 3.0, 1.5], 0.05, gp).0
    };
    let b = run(&gp);
    assert!(
        (b.min[1] - 6.04).abs() < 0.01 && (b.max[1] - 6.11).abs() < 0.01,
        "{b:?}"
    );
    // With the median (one layer), the plane found is the glass, 1 cm before the wall:
    // thinner than any window, so the box gets the class's depth.
    let mut median = gp.clone();
    median.support.planar_front_share = 0.0;
    let (b, snaps) =
        snap_planar_to_wall(&fused, &window, &wall, None, [1.3, 3.0, 1.5], 0.05, &median);
    assert!((snaps[0].front - 6.10).abs() < 0.01, "{snaps:?}");
    assert!(
        (b.min[1] - 6.06).abs() < 0.01 && (b.max[1] - 6.11).abs() < 0.01,
        "{b:?}"
    );
    // A class known to be thinner keeps the plane it measured.
    let b = snap_planar_to_wall(
        &fused,
        &window,
        &wall,
        None,
        [1.3, 3.0, 1.5],
        0.005,
        &median,
    )
    .0;
    assert!((b.min[1] - 6.10).abs() < 0.01, "{b:?}");
}

#[test]
fn a_close_up_showing_little_of_the_frame_still_finds_it_before_the_glass() {
    // A close-up of the glass at y = 6.10 (the wall at 6.11): of the frame, only the
    // mullion shows, 6 cm before the glass, about 4 % of the points (the outlier removal
    // leaves 2.5 %).
    let hole = Some([1.24, 1.34, 0.9, 2.2]);
    let mut window = plane_y(6.10, (0.1, 2.5), (1.0, 2.1), 0.005, hole);
    window.extend(plane_y(6.04, (1.25, 1.33), (1.0, 2.1), 0.005, None));
    let mullion = window.iter().filter(|p| p.y < 6.07).count() as f64;
    assert!((0.03..0.05).contains(&(mullion / window.len() as f64)));
    let wall = plane_y(
        6.11,
        (-0.2, 2.8),
        (0.7, 2.4),
        0.005,
        Some([0.1, 2.5, 1.0, 2.1]),
    );
    let fused = Aabb::new([0.08, 5.95, 0.98], [2.52, 6.15, 2.12]);
    let gp = GeometryParams::default();
    let (b, snaps) = snap_planar_to_wall(&fused, &window, &wall, None, [1.3, 3.0, 1.5], 0.05, &gp);
    assert!((snaps[0].front - 6.04).abs() < 0.01, "{snaps:?}");
    assert!(
        (b.min[1] - 6.04).abs() < 0.01 && (b.max[1] - 6.11).abs() < 0.01,
        "{b:?}"
    );
    // Asked for a third of the points (a far view's share of a frame), the front is the
    // glass, and the box only the class's depth.
    let mut third = gp.clone();
    third.support.planar_front_share = 0.3;
    let (_, snaps) =
        snap_planar_to_wall(&fused, &window, &wall, None, [1.3, 3.0, 1.5], 0.05, &third);
    assert!((snaps[0].front - 6.10).abs() < 0.01, "{snaps:?}");
}

#[test]
fn a_window_no_frame_measured_gets_its_depth_in_front_of_the_rooms_wall() {
    use crate::geometry::RoomLayout;
    // The window's points were ended on the room's wall y = 6.11 (no reading anywhere);
    // nothing measured around it.
    let window = plane_y(6.11, (0.7, 1.9), (1.0, 2.1), 0.0, None);
    let b = Aabb::new([0.7, 6.11, 1.0], [1.9, 6.11, 2.1]);
    let room = RoomLayout {
        angle_deg: 0.0,
        u: [Some(0.0), Some(5.0)],
        v: [Some(0.0), Some(6.11)],
        faced: [true; 4],
        floor: Some(0.0),
        ceiling: None,
        reach: [[0.0, 5.0], [0.0, 6.11], [0.0, 2.5]],
        range: 5.0,
        points: 1000,
    };
    let gp = GeometryParams::default();
    let (got, snaps) = snap_planar_to_wall(
        &b,
        &window,
        &[],
        Some(&room),
        [1.3, 1.0, 1.5],
        gp.layout.flat_depth,
        &gp,
    );
    assert!(
        snaps.len() == 1 && snaps[0].applied() && snaps[0].room_wall,
        "{snaps:?}"
    );
    assert!(
        (got.min[1] - (6.11 - gp.layout.flat_depth)).abs() < 1e-6
            && (got.max[1] - 6.11).abs() < 1e-6,
        "{got:?}"
    );
    // A window measured 6 cm in front of that wall spans to it (the room's wall stands
    // in for a wall the context missed).
    let measured = plane_y(6.05, (0.7, 1.9), (1.0, 2.1), 0.005, None);
    let (got, _) = snap_planar_to_wall(
        &Aabb::new([0.7, 6.04, 1.0], [1.9, 6.06, 2.1]),
        &measured,
        &[],
        Some(&room),
        [1.3, 1.0, 1.5],
        0.05,
        &gp,
    );
    assert!(
        (got.min[1] - 6.05).abs() < 0.01 && (got.max[1] - 6.11).abs() < 1e-6,
        "{got:?}"
    );
    // Without a room and a context, nothing to snap to.
    assert_eq!(
        snap_planar_to_wall(
            &b,
            &window,
            &[],
            None,
            [1.3, 1.0, 1.5],
            gp.layout.flat_depth,
            &gp
        ),
        (b, vec![])
    );
    // A room's wall 1 m behind the plane is out of reach.
    let far = RoomLayout {
        v: [Some(0.0), Some(7.11)],
        ..room
    };
    let (same, snaps) = snap_planar_to_wall(
        &b,
        &window,
        &[],
        Some(&far),
        [1.3, 1.0, 1.5],
        gp.layout.flat_depth,
        &gp,
    );
    assert!(same == b && !snaps[0].applied(), "{snaps:?}");
}

#[test]
fn a_window_frame_measured_before_glass_ended_on_the_rooms_wall_is_the_front() {
    // The sensor read no depth on the glass: depth completion put those points on the
    // room's wall y = 6.11, two thirds of the window. The frame, a 10 cm border, was
    // measured 5 cm in front of it (with 5 mm of noise).
    let room = crate::geometry::test_scene::room_box(0.0, 5.0, 6.11, 2.5);
    let frame = |p: &Point3<f64>| p.x < 0.8 || p.x > 1.8 || p.z < 1.1 || p.z > 2.0;
    let window: Vec<Point3<f64>> = plane_y(6.11, (0.7, 1.9), (1.0, 2.1), 0.0, None)
        .into_iter()
        .enumerate()
        .map(|(i, p)| {
            if frame(&p) {
                Point3::new(p.x, 6.06 + 0.005 * jitter(i, 7), p.z)
            } else {
                p
            }
        })
        .collect();
    let on_wall = window.iter().filter(|p| p.y == 6.11).count();
    assert!(2 * on_wall >= window.len(), "most points on the wall");
    let b = Aabb::new([0.7, 6.05, 1.0], [1.9, 6.11, 2.1]);
    let gp = GeometryParams::default();
    let run = |w: &[Point3<f64>]| {
        snap_planar_to_wall(
            &b,
            w,
            &[],
            Some(&room),
            [1.3, 1.0, 1.5],
            gp.layout.flat_depth,
            &gp,
        )
    };
    let (got, snaps) = run(&window);
    assert!(snaps.len() == 1 && snaps[0].room_wall, "{snaps:?}");
    let seen = snaps[0].seen_front.expect("the frame was measured");
    assert!((seen - 6.06).abs() < 0.01, "{snaps:?}");
    assert!(
        (got.min[1] - seen).abs() < 1e-9 && (got.max[1] - 6.11).abs() < 1e-6,
        "{got:?}"
    );
    // The frame measured within the wall's noise (4 mm before it) does not stand apart:
    // the class's flat depth, as for a window measured nowhere.
    let close: Vec<Point3<f64>> = window
        .iter()
        .map(|p| {
            if p.y < 6.11 {
                Point3::new(p.x, 6.106, p.z)
            } else {
                *p
            }
        })
        .collect();
    let (got, snaps) = run(&close);
    assert_eq!(snaps[0].seen_front, None, "{snaps:?}");
    assert!(
        (got.min[1] - (6.11 - gp.layout.flat_depth)).abs() < 1e-6,
        "{got:?}"
    );
}

#[test]
fn a_picture_ended_on_the_rooms_wall_keeps_that_wall_over_a_layer_behind_it() {
    use crate::geometry::RoomLayout;
    // Depth completion put the picture's points on the room's wall x = 6.99; the
    // context, measured at the range's end, holds a noisy layer 2.5 cm behind it.
    // The room is turned by 1 degree: its wall's x changes by 12 mm along the picture.
    let room = RoomLayout {
        angle_deg: 1.0,
        u: [Some(0.0), Some(6.99)],
        v: [Some(0.0), Some(5.0)],
        faced: [true; 4],
        floor: Some(0.0),
        ceiling: None,
        reach: [[0.0, 6.99], [0.0, 5.0], [0.0, 2.5]],
        range: 5.0,
        points: 1000,
    };
    let (s1, c1) = 1f64.to_radians().sin_cos();
    let wall_x = |y: f64| (6.99 - s1 * y) / c1;
    let picture: Vec<Point3<f64>> = plane_y(0.0, (2.5, 3.2), (1.4, 1.9), 0.0, None)
        .into_iter()
        .map(|p| Point3::new(wall_x(p.x), p.x, p.z))
        .collect();
    let layer: Vec<Point3<f64>> =
        plane_y(0.0, (2.2, 3.5), (1.1, 2.2), 0.0, Some([2.5, 3.2, 1.4, 1.9]))
            .into_iter()
            .enumerate()
            .map(|(i, p)| Point3::new(wall_x(p.x) + 0.025 + 0.005 * jitter(i, 3), p.x, p.z))
            .collect();
    let b = Aabb::new([6.9, 2.5, 1.4], [7.0, 3.2, 1.9]);
    let gp = GeometryParams::default();
    let depth = gp.layout.flat_depth_for("purple picture");
    assert_eq!(depth, 0.03);
    let (got, snaps) = snap_planar_to_wall(
        &b,
        &picture,
        &layer,
        Some(&room),
        [3.0, 2.0, 1.5],
        depth,
        &gp,
    );
    assert!(snaps.len() == 1 && snaps[0].room_wall, "{snaps:?}");
    let w = wall_x(2.85);
    assert!(
        (got.min[0] - (w - 0.03)).abs() < 1e-3 && (got.max[0] - w).abs() < 1e-3,
        "{got:?}"
    );
    // The same points measured (scattered by noise) are a front plane: the layer behind
    // is their wall.
    let measured: Vec<Point3<f64>> = picture
        .iter()
        .enumerate()
        .map(|(i, p)| Point3::new(p.x + 0.01 * jitter(i, 5), p.y, p.z))
        .collect();
    let (got, snaps) = snap_planar_to_wall(
        &b,
        &measured,
        &layer,
        Some(&room),
        [3.0, 2.0, 1.5],
        depth,
        &gp,
    );
    assert!(
        !snaps[0].room_wall && (got.max[0] - (w + 0.025)).abs() < 0.008,
        "{got:?} {snaps:?}"
    );
    // Classes without an entry get the default depth.
    assert_eq!(gp.layout.flat_depth_for("door"), gp.layout.flat_depth);
    assert_eq!(gp.layout.flat_depth_for("pictures"), 0.03);
}

/// A cabinet 1.2 m wide and 0.9 m tall whose front (y = 5.6, noise `front`) and top (25 rows
/// back to y = 6.08, noise `top`) are seen.
fn cabinet(front: f64, top: f64) -> Vec<Point3<f64>> {
    let mut out = plane_y(5.6, (0.7, 1.9), (0.0, 0.9), front, None);
    for k in 0..25 {
        out.extend(plane_y(
            5.6 + 0.02 * k as f64,
            (0.7, 1.9),
            (0.9, 0.9),
            top,
            None,
        ));
    }
    out
}

#[test]
fn deep_objects_free_standing_planes_and_disabled_settings_are_left_alone() {
    let gp = GeometryParams::default();
    let wall = plane_y(
        6.11,
        (0.4, 2.2),
        (0.0, 2.4),
        0.005,
        Some([0.7, 1.9, 0.0, 1.0]),
    );
    // A cabinet: its front and its top are seen, so the cloud is no plane; seen from afar
    // too, its readings scattered by centimetres: its spread on the axis is its depth.
    for (front, top) in [(0.005, 0.0), (0.03, 0.03)] {
        let cabinet = cabinet(front, top);
        let b = Aabb::new([0.7, 5.6, 0.0], [1.9, 6.1, 0.9]);
        assert_eq!(
            snap_planar_to_wall(&b, &cabinet, &wall, None, [1.3, 3.0, 1.5], 0.05, &gp),
            (b, vec![]),
            "not a plane ({front}, {top})"
        );
    }
    // A screen standing 40 cm in front of the wall: the wall is too far to be its back.
    let screen = plane_y(5.7, (0.7, 1.9), (0.2, 0.9), 0.02, None);
    let b = Aabb::new([0.7, 5.66, 0.2], [1.9, 5.74, 0.9]);
    let (same, snaps) = snap_planar_to_wall(&b, &screen, &wall, None, [1.3, 3.0, 1.5], 0.05, &gp);
    assert_eq!(same, b);
    assert!(
        snaps.len() == 1 && !snaps[0].applied(),
        "a plane, but no wall within reach: {snaps:?}"
    );
    // A chair seen from behind: its back is a plane, its seat lies behind it, but only
    // below the back, not on both sides as a wall does.
    let back = plane_y(2.0, (1.0, 1.45), (0.5, 0.95), 0.005, None);
    let mut seat = Vec::new();
    for k in 0..8 {
        seat.extend(plane_y(
            2.02 + 0.01 * k as f64,
            (0.95, 1.5),
            (0.45, 0.45),
            0.0,
            None,
        ));
        seat.extend(plane_y(
            2.02 + 0.01 * k as f64,
            (0.95, 1.5),
            (0.43, 0.43),
            0.0,
            None,
        ));
    }
    let b = Aabb::new([1.0, 1.98, 0.0], [1.45, 2.45, 0.95]);
    let (same, snaps) = snap_planar_to_wall(&b, &back, &seat, None, [1.2, 0.5, 1.2], 0.05, &gp);
    assert_eq!(same, b, "{snaps:?}");
    // Seen from behind the wall (camera at y > 6.11), the wall is on the camera's side.
    let window = plane_y(6.05, (0.7, 1.9), (0.0, 1.0), 0.02, None);
    let b = Aabb::new([0.7, 6.0, 0.0], [1.9, 6.1, 1.0]);
    assert_eq!(
        snap_planar_to_wall(&b, &window, &wall, None, [1.3, 8.0, 1.5], 0.05, &gp).0,
        b
    );
    // Off switches.
    let mut off = gp.clone();
    off.support.planar_iqr = 0.0;
    assert_eq!(
        snap_planar_to_wall(&b, &window, &wall, None, [1.3, 3.0, 1.5], 0.05, &off).1,
        vec![]
    );
    assert!(
        snap_planar_to_wall(&b, &window, &wall, None, [1.3, 3.0, 1.5], 0.05, &gp).1[0].applied()
    );
}

#[test]
fn a_far_picture_whose_readings_scatter_wider_than_a_plane_is_still_one() {
    // A picture 3 cm thick on the wall at y = 6.11, its face at 6.08, seen from 5 m: its
    // readings scatter ±8 cm about the face: their interquartile range is more than a
    // quarter of that of its 36 cm height (about 18 cm), which a plane's was held to.
    let (picture, wall) = on_wall(6.08, (0.7, 1.2), (1.3, 1.66), 0.08);
    let fused = Aabb::new([0.7, 6.0, 1.3], [1.2, 6.16, 1.66]);
    let gp = GeometryParams::default();
    let (b, snaps) = snap_planar_to_wall(&fused, &picture, &wall, None, [1.0, 1.1, 1.5], 0.03, &gp);
    assert_eq!(snaps.len(), 1, "{snaps:?}");
    let s = &snaps[0];
    assert!(s.iqr > gp.support.planar_iqr || 4.0 * s.iqr > 0.18, "{s:?}");
    assert!(s.noise > 0.015 && s.noise < 0.08, "{s:?}");
    assert!(s.applied(), "{s:?}");
    assert!(
        (b.min[1] - 6.08).abs() < 0.015 && (b.max[1] - 6.11).abs() < 0.01,
        "{b:?}"
    );
}

#[test]
fn the_wall_behind_glass_a_centimetre_before_it_is_not_put_behind_its_readings() {
    // Far view: the glass at y = 6.10, 1 cm before the wall at 6.11, both read with noise
    // of 2 cm standard deviation (bell-shaped, up to ±6 cm); the frame is not told apart.
    // Only the wall's readings a centimetre behind the glass's median would be its far
    // half, and put the wall about 1.5 cm too far.
    let bell = |points: Vec<Point3<f64>>, k: u64| -> Vec<Point3<f64>> {
        points
            .into_iter()
            .enumerate()
            .map(|(i, p)| {
                let n: f64 = (0..3).map(|j| jitter(i, k + j)).sum();
                Point3::new(p.x, p.y + 0.02 * n, p.z)
            })
            .collect()
    };
    let window = bell(plane_y(6.10, (0.7, 1.9), (1.0, 2.1), 0.0, None), 11);
    let wall = bell(
        plane_y(
            6.11,
            (0.4, 2.2),
            (0.7, 2.4),
            0.0,
            Some([0.7, 1.9, 1.0, 2.1]),
        ),
        21,
    );
    let fused = Aabb::new([0.68, 5.95, 0.98], [1.92, 6.2, 2.12]);
    let gp = GeometryParams::default();
    let (b, snaps) = snap_planar_to_wall(&fused, &window, &wall, None, [1.3, 3.0, 1.5], 0.05, &gp);
    let wall_found = snaps[0].wall.expect("a wall");
    assert!((wall_found - 6.11).abs() < 0.006, "{snaps:?}");
    // The glass is nearer the wall than any window is deep: the class's depth before it.
    assert!(
        (b.max[1] - wall_found).abs() < 1e-9 && (b.min[1] - (wall_found - 0.05)).abs() < 1e-9,
        "{b:?}"
    );
}
