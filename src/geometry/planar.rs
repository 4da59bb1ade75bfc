//! Flat objects against a wall (windows, pictures, doors): their depth, measured in one
//! view.
//!
//! A few centimetres of depth noise and pose error per view are nothing for a chair, but
//! a window is 6 cm deep: the union of several views, each offset by its own pose error,
//! comes out 15–30 cm deep, and even one view's min–max spans its noise. Two things are
//! still measured well: the median of the object's points along the wall normal (its front
//! face), and the wall around it, found in the same views; their difference is the
//! object's depth.
//!
//! The agent applies it only to classes known to be flat against a wall
//! (`SupportParams::is_flat`): a chair pushed against the wall, seen from the front, shows
//! its back as one plane with the wall just behind, and is no window.
//!
//! So, on a horizontal axis where the anchor view's points form one plane facing it
//! (interquartile range at most `planar_iqr` and at most a quarter of that on both other
//! axes) and a wall layer lies behind that plane (seen from the camera) within
//! `planar_max_depth`, the box spans from the plane to the wall on that axis.

use nalgebra::Point3;
use serde::Serialize;

use super::cloud::{remove_statistical_outliers, voxel_downsample};
use super::support::SupportParams;
use super::{Aabb, GeometryParams, RoomLayout};

/// What was found on one horizontal axis.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlanarSnap {
    /// "x" or "y".
    pub axis: &'static str,
    /// Interquartile range of the anchor's points on the axis.
    pub iqr: f64,
    /// The front plane (the anchor's front layer on the axis, see `planar_front_share`).
    pub front: f64,
    /// The wall behind it, when one was found within reach.
    pub wall: Option<f64>,
    /// The wall is the room's box (see [`super::layout`]), not a layer of the context.
    pub room_wall: bool,
    /// The box's extent on the axis before.
    pub was: [f64; 2],
}

impl PlanarSnap {
    /// Did this axis change the box?
    pub fn applied(&self) -> bool {
        self.wall.is_some()
    }
}

/// The object's front face on `axis`: the `median` of its points, unless a separate layer
/// lies before it (on the camera's side `toward`, +1 or -1): a local maximum of the
/// points' 1 cm histogram (smoothed 1-2-1, within `reach` of the median) whose three bins
/// hold at least `share` of the points, with a valley between it and the main layer. The nearest such
/// layer wins. A picture or a door is one layer, and its front is its median; a window's
/// frame stands a few centimetres before its glass, and the glass, the larger part, would
/// put the front behind the frame. `share` 0 gives the median.
fn front_layer(
    points: &[Point3<f64>],
    axis: usize,
    toward: f64,
    median: f64,
    share: f64,
    reach: f64,
) -> f64 {
    const BIN: f64 = 0.01;
    if share <= 0.0 || points.is_empty() {
        return median;
    }
    let n = (2.0 * reach / BIN).ceil() as usize + 1;
    let lo = median - reach;
    let mut counts = vec![0usize; n];
    for p in points {
        let k = ((p[axis] - lo) / BIN).round();
        if (0.0..n as f64).contains(&k) {
            counts[k as usize] += 1;
        }
    }
    let at = |k: isize| {
        if k < 0 || k as usize >= n {
            0
        } else {
            counts[k as usize]
        }
    };
    let smooth: Vec<usize> = (0..n as isize)
        .map(|k| at(k - 1) + 2 * at(k) + at(k + 1))
        .collect();
    let need = share * points.len() as f64;
    let Some(main) = (0..n).max_by_key(|&k| smooth[k]) else {
        return median;
    };
    // A layer before the main one, apart from it: a local maximum with its share, and a
    // valley between the two below half its height (noise spreads one surface over
    // several bins, with no valley).
    let pos = |k: usize| lo + k as f64 * BIN;
    (0..n)
        .filter(|&k| {
            let s = smooth[k];
            let (a, b) = (k.min(main), k.max(main));
            toward * (pos(k) - pos(main)) > 0.0
                && ((at(k as isize - 1) + at(k as isize) + at(k as isize + 1)) as f64) >= need
                && (k == 0 || smooth[k - 1] < s)
                && (k + 1 == n || smooth[k + 1] <= s)
                && smooth[a..=b].iter().any(|&v| 2 * v < s)
        })
        .map(pos)
        .max_by(|x, y| (toward * x).total_cmp(&(toward * y)))
        .unwrap_or(median)
}

fn quartiles(points: &[Point3<f64>], a: usize) -> (f64, f64, f64) {
    let mut v: Vec<f64> = points.iter().map(|p| p[a]).collect();
    v.sort_by(f64::total_cmp);
    let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
    (q(0.25), q(0.5), q(0.75))
}

/// The wall behind the plane `slab` (zero extent on `axis`): among the context points in the
/// ring of width `margin` around its footprint and between 1 cm and `planar_max_depth`
/// behind it (on the `sign` side), the `layer`-thick slice holding the most points, if it
/// holds at least `min_points` and reaches past the footprint sideways at the footprint's
/// height; its median coordinate. The densest slice, not the nearest: the plane's own noisy
/// fringe shows up just behind it, but a wall around an object is much larger than that.
fn densest_layer(
    slab: &Aabb,
    context: &[Point3<f64>],
    (axis, sign): (usize, f64),
    p: &SupportParams,
) -> Option<f64> {
    let others = [(axis + 1) % 3, (axis + 2) % 3];
    let front = slab.min[axis];
    let in_ring = |q: &Point3<f64>| {
        others
            .iter()
            .all(|&o| q[o] >= slab.min[o] - p.margin && q[o] <= slab.max[o] + p.margin)
            && others
                .iter()
                .any(|&o| q[o] < slab.min[o] || q[o] > slab.max[o])
    };
    let mut gaps: Vec<f64> = context
        .iter()
        .filter(|q| in_ring(q))
        .map(|q| sign * (q[axis] - front))
        .filter(|g| *g >= MIN_DEPTH && *g <= p.planar_max_depth)
        .collect();
    gaps.sort_by(f64::total_cmp);
    let (mut best, mut best_n) = (None, 0usize);
    for (lo, &g) in gaps.iter().enumerate() {
        let n = gaps[lo..].partition_point(|x| *x < g + p.layer);
        if n > best_n {
            (best, best_n) = (Some(lo), n);
        }
    }
    let lo = best.filter(|_| best_n >= p.min_points)?;
    let (g0, g1) = (gaps[lo], gaps[lo + best_n - 1]);
    // A wall runs on past the object at its height: `min_points` of the slice beside the
    // footprint (one side may be hidden: a corner, a cupboard). What lies behind a chair's
    // back (its seat) or past a cabinet's front (its top) is below or above it.
    let lateral = 1 - axis;
    let beside = |q: &&Point3<f64>| q[2] >= slab.min[2] && q[2] <= slab.max[2];
    let slice = context
        .iter()
        .filter(|q| in_ring(q))
        .filter(beside)
        .filter(|q| (g0..=g1).contains(&(sign * (q[axis] - front))));
    if slice
        .filter(|q| q[lateral] < slab.min[lateral] || q[lateral] > slab.max[lateral])
        .count()
        < p.min_points
    {
        return None;
    }
    Some(front + sign * gaps[lo + best_n / 2])
}

/// Nearest a wall may be behind a plane (m): nearer, it is the plane's own noise.
const MIN_DEPTH: f64 = 0.01;

/// Distance (m) within which a point counts as lying on one of the room's walls: points
/// put there by depth completion sit on it up to rounding; measured ones scatter by
/// centimetres.
pub const ON_ROOM_WALL: f64 = 0.002;

/// Set the extent of `b` to [front plane, wall] on each horizontal axis where the anchor's
/// points `anchor` are a plane facing `camera` (the anchor camera's centre) and the context
/// points `context` (see [`super::support::context_points`]) hold a wall behind it, or else
/// the `room`'s box has one there (see [`super::layout`]).
/// A plane lying on its wall (no frame resolved the object's front from the wall: its
/// points were ended on the room's box, or it meets the wall found behind it) gets
/// `flat_depth` in front of that wall. When most of the anchor's points lie on one of the
/// room's walls (within [`ON_ROOM_WALL`]: depth completion ends the rays no frame measured
/// exactly there, while measured points scatter by the sensor's noise), that wall is the
/// object's, whatever layer the context shows nearby.
/// Every plane found is reported, with its wall or none. Off when `planar_iqr` is 0 or
/// support completion is disabled.
pub fn snap_planar_to_wall(
    b: &Aabb,
    anchor: &[Point3<f64>],
    context: &[Point3<f64>],
    room: Option<&RoomLayout>,
    camera: [f64; 3],
    flat_depth: f64,
    params: &GeometryParams,
) -> (Aabb, Vec<PlanarSnap>) {
    const NAMES: [&str; 2] = ["x", "y"];
    let p = &params.support;
    let mut out = *b;
    let mut snaps = Vec::new();
    if !p.enabled || p.planar_iqr <= 0.0 || (context.is_empty() && room.is_none()) {
        return (out, snaps);
    }
    // The cloud single-view boxes use: one point per fusion voxel (even density, whatever
    // the distance), statistical outliers removed.
    let anchor = &remove_statistical_outliers(
        &voxel_downsample(anchor, params.fusion_voxel),
        params.sor_neighbors,
        params.sor_std_ratio,
    );
    let Some(extent) = Aabb::from_points(anchor).filter(|_| anchor.len() >= 20) else {
        return (out, snaps);
    };
    let qs = [
        quartiles(anchor, 0),
        quartiles(anchor, 1),
        quartiles(anchor, 2),
    ];
    let iqr = |a: usize| qs[a].2 - qs[a].0;
    for a in 0..2 {
        let others = [(a + 1) % 3, (a + 2) % 3];
        if iqr(a) > p.planar_iqr || others.iter().any(|&o| iqr(o) < 4.0 * iqr(a).max(0.005)) {
            continue;
        }
        // The wall is on the far side of the plane from the camera.
        let sign = if qs[a].1 >= camera[a] { 1.0 } else { -1.0 };
        let front = front_layer(
            anchor,
            a,
            -sign,
            qs[a].1,
            p.planar_front_share,
            p.planar_max_depth,
        );
        // The wall is looked for around the plane's own footprint in the anchor view, not
        // the fused box's, which other views may have widened.
        let mut slab = extent;
        slab.min[a] = front;
        slab.max[a] = front;
        let centre = Point3::new(
            (extent.min[0] + extent.max[0]) / 2.0,
            (extent.min[1] + extent.max[1]) / 2.0,
            (extent.min[2] + extent.max[2]) / 2.0,
        );
        let from_room = || {
            let walls = room?.walls_on_axis(a, &centre);
            walls
                .into_iter()
                .filter(|w| (-p.layer..=p.planar_max_depth).contains(&(sign * (w - front))))
                .min_by(|x, y| (sign * (x - front)).total_cmp(&(sign * (y - front))))
        };
        // The room's wall the anchor's points were ended on, if most of them were.
        // (Each point against the wall where it stands: a wall turned a little off the axis
        // moves by millimetres along the object.)
        let placed_on = || {
            let room = room?;
            let at_centre = room.walls_on_axis(a, &centre);
            let mut on = vec![0usize; at_centre.len()];
            for q in anchor {
                for (k, w) in room.walls_on_axis(a, q).iter().enumerate() {
                    if (q[a] - w).abs() <= ON_ROOM_WALL {
                        on[k] += 1;
                    }
                }
            }
            on.iter()
                .position(|&n| 2 * n >= anchor.len())
                .map(|k| at_centre[k])
        };
        let (wall, room_wall, on_wall) = match placed_on() {
            Some(w) => (Some(w), true, true),
            None => match densest_layer(&slab, context, (a, sign), p) {
                Some(w) => (Some(w), false, false),
                None => (from_room(), true, false),
            },
        };
        snaps.push(PlanarSnap {
            axis: NAMES[a],
            iqr: iqr(a),
            front,
            wall,
            room_wall: room_wall && wall.is_some(),
            was: [b.min[a], b.max[a]],
        });
        if let Some(wall) = wall {
            // On its wall: the object's front was never seen apart from it.
            let front = if on_wall || sign * (wall - front) < MIN_DEPTH {
                wall - sign * flat_depth
            } else {
                front
            };
            out.min[a] = front.min(wall);
            out.max[a] = front.max(wall);
        }
    }
    (out, snaps)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic noise in [-1, 1].
    fn jitter(i: usize, k: u64) -> f64 {
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

    #[test]
    fn a_noisy_window_spans_from_its_plane_to_the_wall() {
        // Window 6 cm deep flush with the wall at y = 6.11; its face at 6.05 seen with
        // ±3 cm of noise, the camera in the room (y < 6).
        let window = plane_y(6.05, (0.7, 1.9), (1.0, 2.1), 0.03, None);
        let wall = plane_y(
            6.11,
            (0.4, 2.2),
            (0.7, 2.4),
            0.01,
            Some([0.7, 1.9, 1.0, 2.1]),
        );
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
        // With the median (one layer), the front is the glass.
        let mut median = gp.clone();
        median.support.planar_front_share = 0.0;
        let b = run(&median);
        assert!((b.min[1] - 6.10).abs() < 0.01, "{b:?}");
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
        // A cabinet: its front and its top are seen, so the cloud is no plane.
        let mut cabinet = plane_y(5.6, (0.7, 1.9), (0.0, 0.9), 0.005, None);
        for k in 0..25 {
            cabinet.extend(plane_y(
                5.6 + 0.02 * k as f64,
                (0.7, 1.9),
                (0.9, 0.9),
                0.0,
                None,
            ));
        }
        let b = Aabb::new([0.7, 5.6, 0.0], [1.9, 6.1, 0.9]);
        assert_eq!(
            snap_planar_to_wall(&b, &cabinet, &wall, None, [1.3, 3.0, 1.5], 0.05, &gp),
            (b, vec![]),
            "not a plane"
        );
        // A screen standing 40 cm in front of the wall: the wall is too far to be its back.
        let screen = plane_y(5.7, (0.7, 1.9), (0.2, 0.9), 0.02, None);
        let b = Aabb::new([0.7, 5.66, 0.2], [1.9, 5.74, 0.9]);
        let (same, snaps) =
            snap_planar_to_wall(&b, &screen, &wall, None, [1.3, 3.0, 1.5], 0.05, &gp);
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
            snap_planar_to_wall(&b, &window, &wall, None, [1.3, 3.0, 1.5], 0.05, &gp).1[0]
                .applied()
        );
    }
}
