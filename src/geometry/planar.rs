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

use std::collections::HashMap;

use nalgebra::Point3;
use serde::Serialize;

use super::cloud::{median, remove_statistical_outliers, voxel_downsample};
use super::support::SupportParams;
use super::{Aabb, GeometryParams, RoomLayout};

/// What was found on one horizontal axis.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlanarSnap {
    /// "x" or "y".
    pub axis: &'static str,
    /// Interquartile range of the anchor's points on the axis.
    pub iqr: f64,
    /// How far the readings of one spot scatter on the axis (standard deviation, see
    /// [`reading_noise`]; 0 on an axis the points spread wider on than on another); the
    /// plane's own thickness is `iqr` less that share.
    pub noise: f64,
    /// The front plane (the anchor's front layer on the axis, see `planar_front_share`).
    pub front: f64,
    /// When the anchor's points were ended on the room's wall: the front layer of those
    /// the sensor measured in front of it, if at least `min_points` stand at least 1 cm
    /// before the wall (the object's front then; else it gets the class's flat depth).
    pub seen_front: Option<f64>,
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

/// How many standard deviations of a Poisson count a front layer must stand above the
/// valley before it (see [`front_layer`]): the usual three.
const LAYER_SIGNIFICANCE: f64 = 3.0;

/// The object's front face on `axis`: the `median` of its points, unless a separate layer
/// lies before it (on the camera's side `toward`, +1 or -1): a local maximum of the
/// points' 1 cm histogram (smoothed 1-2-1, within `reach` of the median) whose three bins
/// hold at least `share` of the points and that stands out of the readings between it and
/// the main layer by more than counting noise: its three bins exceed the emptiest three
/// between the two by [`LAYER_SIGNIFICANCE`] times the square root of the latter (a
/// surface, not the tail of noisy readings: a far picture's few measured points scatter
/// over the centimetres before it, and any bump of them would pass the share; one noisy
/// plane's readings thin out away from it, so no bump of them clears its floor). The
/// readings between need not fall to a valley: a view from the side sees the inner faces
/// of a window's frame, which fill the centimetres between the frame's face and the glass.
/// The nearest such layer wins. A picture or a door is one layer, and its front is its
/// median; a window's frame stands a few centimetres before its glass, and the glass, the
/// larger part, would put the front behind the frame. `share` 0 gives the median.
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
    // A layer before the main one: a local maximum with its share, standing out of the
    // readings between the two.
    let pos = |k: usize| lo + k as f64 * BIN;
    let three = |k: usize| (at(k as isize - 1) + at(k as isize) + at(k as isize + 1)) as f64;
    (0..n)
        .filter(|&k| {
            let s = smooth[k];
            let (a, b) = (k.min(main), k.max(main));
            // The emptiest three bins strictly between the layer and the main one.
            let floor = (a + 1..b)
                .map(three)
                .fold(f64::INFINITY, f64::min)
                .min(three(k));
            toward * (pos(k) - pos(main)) > 0.0
                && three(k) >= need
                && (k == 0 || smooth[k - 1] < s)
                && (k + 1 == n || smooth[k + 1] <= s)
                && three(k) - floor > LAYER_SIGNIFICANCE * floor.sqrt()
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
/// ring of width `margin` around its footprint and from `nearest` to `planar_max_depth`
/// behind it (on the `sign` side), the `layer`-thick slice holding the most points, if it
/// holds at least `min_points` and reaches past the footprint sideways at the footprint's
/// height; its median coordinate. The densest slice, not the nearest: the plane's own noisy
/// fringe shows up just behind it, but a wall around an object is much larger than that.
fn densest_layer(
    slab: &Aabb,
    context: &[Point3<f64>],
    (axis, sign): (usize, f64),
    nearest: f64,
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
        .filter(|g| *g >= nearest && *g <= p.planar_max_depth)
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

/// Interquartile range of a normal distribution in standard deviations.
const IQR_PER_SIGMA: f64 = 1.349;

/// How far the readings of one spot of the surface `points` sample scatter along `axis`
/// (a normal's standard deviation): the points are binned on the two other axes in square
/// cells of side `cell`; in each cell of at least three points the median absolute
/// deviation along `axis` is read (/ 0.6745), and the median over the cells is returned
/// (0 without such a cell). A depth sensor's noise grows with distance, so a far
/// picture's readings scatter over centimetres about its one plane; the surface's own
/// relief (a window's frame before its glass, a curtain's folds) lies in other cells than
/// one another, so it stays out of this and in the interquartile range.
fn reading_noise(points: &[Point3<f64>], axis: usize, cell: f64) -> f64 {
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut cells: HashMap<(i64, i64), Vec<f64>> = HashMap::new();
    for p in points {
        let key = ((p[u] / cell).floor() as i64, (p[v] / cell).floor() as i64);
        cells.entry(key).or_default().push(p[axis]);
    }
    let mut mads: Vec<f64> = cells
        .into_values()
        .filter(|c| c.len() >= 3)
        .map(|mut c| {
            let m = median(&mut c);
            let mut dev: Vec<f64> = c.iter().map(|x| (x - m).abs()).collect();
            median(&mut dev) / 0.6745
        })
        .collect();
    median(&mut mads)
}

/// How far apart a plane and the wall behind it must be to be told apart (m): nearer, the
/// difference is the readings' noise.
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
/// `flat_depth` (the class's depth) in front of that wall, and so does a plane found nearer
/// the wall than that: it is the object's back layer (a window's glass, when its frame
/// was not told apart from it), as no object of the class is thinner. But when some of the
/// points ended on the room's box were measured well in front of it (a window's frame
/// before glass the sensor does not see), those give the front. When most of the anchor's points lie on one of the
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
    // Noise is measured in cells a few fusion voxels across: enough points per cell at the
    // voxel density, small beside the objects this is for.
    let cell = (4.0 * params.fusion_voxel).max(0.02);
    // The sensor's noise lies along the line of sight, across a plane that faces the
    // camera: on the axis where the points spread least. Along the plane, the cells of the
    // two other axes are strips across the whole plane, and what they hold is its extent.
    let across = if iqr(0) <= iqr(1) { 0 } else { 1 };
    for a in 0..2 {
        let others = [(a + 1) % 3, (a + 2) % 3];
        // The plane's own thickness: its points' spread on the axis less what the sensor's
        // noise alone spreads one plane over (variances add).
        let noise = if a == across && iqr(a) <= iqr(2) {
            reading_noise(anchor, a, cell)
        } else {
            0.0
        };
        let thick = (iqr(a).powi(2) - (IQR_PER_SIGMA * noise).powi(2))
            .max(0.0)
            .sqrt();
        if thick > p.planar_iqr || others.iter().any(|&o| iqr(o) < 4.0 * thick.max(0.005)) {
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
        // The room's wall the anchor's points were ended on, if most of them were (its
        // index among the walls on the axis).
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
                .map(|k| (k, at_centre[k]))
        };
        // The wall's readings are looked for from a centimetre behind the plane, past the
        // object's own fringe. But a wall found that near the object's main layer (its
        // median: a window's glass, not its frame before it) that its readings reach the
        // cut (within a centimetre plus the readings' noise, at least a centimetre) may
        // lie nearer still: a window's glass sits a centimetre before its wall, and the
        // cut kept only the far part of the wall's readings. The wall is then looked for
        // again from a centimetre before that layer, whose readings are the wall's own.
        let main = sign * (qs[a].1 - front);
        let behind = |w: f64| {
            if sign * (w - qs[a].1) < MIN_DEPTH + noise.max(MIN_DEPTH) {
                densest_layer(&slab, context, (a, sign), main - MIN_DEPTH, p).unwrap_or(w)
            } else {
                w
            }
        };
        let (wall, room_wall, on_wall) = match placed_on() {
            Some((k, w)) => (Some(w), true, Some(k)),
            None => match densest_layer(&slab, context, (a, sign), MIN_DEPTH, p) {
                Some(w) => (Some(behind(w)), false, None),
                None => (from_room(), true, None),
            },
        };
        // On its wall: the points the sensor measured in front of it (depth completion put
        // the others there) are the object's front, when they stand apart from the wall;
        // a window's frame before its unmeasured glass.
        let seen_front = on_wall.zip(room).zip(wall).and_then(|((k, room), wall)| {
            let seen: Vec<Point3<f64>> = anchor
                .iter()
                .filter(|q| {
                    room.walls_on_axis(a, q).get(k).is_some_and(|w| {
                        let gap = sign * (w - q[a]);
                        gap > ON_ROOM_WALL && gap <= p.planar_max_depth
                    })
                })
                .copied()
                .collect();
            if seen.len() < p.min_points {
                return None;
            }
            let mid = quartiles(&seen, a).1;
            let f = front_layer(
                &seen,
                a,
                -sign,
                mid,
                p.planar_front_share,
                p.planar_max_depth,
            );
            (sign * (wall - f) >= MIN_DEPTH).then_some(f)
        });
        snaps.push(PlanarSnap {
            axis: NAMES[a],
            iqr: iqr(a),
            noise,
            front,
            seen_front,
            wall,
            room_wall: room_wall && wall.is_some(),
            was: [b.min[a], b.max[a]],
        });
        if let Some(wall) = wall {
            // On its wall: the object's front was never seen apart from it.
            // A plane found nearer its wall than the class's depth is the object's back
            // layer (a window's glass, its frame not told apart from it) or the object
            // lying on the wall: it gets that depth.
            let front = match (on_wall, seen_front) {
                (Some(_), Some(f)) => f,
                (Some(_), None) => wall - sign * flat_depth,
                (None, _) if sign * (wall - front) < flat_depth.max(MIN_DEPTH) => {
                    wall - sign * flat_depth
                }
                (None, _) => front,
            };
            out.min[a] = front.min(wall);
            out.max[a] = front.max(wall);
        }
    }
    (out, snaps)
}

#[cfg(test)]
#[path = "planar_tests.rs"]
mod tests;

#[cfg(test)]
#[path = "planar_front_tests.rs"]
mod front_tests;
