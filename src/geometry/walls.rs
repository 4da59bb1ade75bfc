//! Mask leaks onto a wall (ours). A segmenter that grows over depth lets an object standing
//! against a wall run onto the wall beside or above it: the object's cloud then holds a
//! patch of the wall plane, and its box stretches along the wall. The context around the
//! object (points outside its mask, see [`super::context_points`]) shows that plane as a
//! support layer at the box face; the object's points within one layer of it are the
//! leak. The back face they leave behind is restored by [`super::extend_to_support`].

use nalgebra::Point3;
use serde::Serialize;

use super::cloud::median;
use super::support_layer::find_layer;
use super::wall_colour::ColourSplit;
use super::{Aabb, RoomLayout, SupportParams};

/// One wall whose points were cut from an object's cloud.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WallCut {
    /// "x" or "y" (a wall found in the context, [`cut_wall_leaks`]); "u" or "v" (a wall of
    /// the room's box, on the room's own axes, [`cut_room_walls`]).
    pub axis: &'static str,
    /// "min" or "max" face of the cloud's box.
    pub side: &'static str,
    /// The wall's coordinate on `axis`.
    pub wall: f64,
    /// Points removed.
    pub removed: usize,
    /// Half-width (m) of the band cut about the wall.
    pub band: f64,
    /// Points within the band kept for a colour unlike the wall's ([`cut_room_walls`]).
    pub kept_by_colour: usize,
}

/// Remove from `points` those within one support layer of a wall that the `context` shows
/// at a vertical face of their box (or beyond it) and above their top. A cut that would remove more than half
/// of the points is not made: then the object is the plane (a picture, a door), not a leak.
pub fn cut_wall_leaks(
    points: &[Point3<f64>],
    context: &[Point3<f64>],
    p: &SupportParams,
) -> (Vec<Point3<f64>>, Vec<WallCut>) {
    const NAMES: [&str; 3] = ["x", "y", "z"];
    let mut pts = points.to_vec();
    let mut cuts = Vec::new();
    if !p.enabled || !p.wall_cut || context.is_empty() {
        return (pts, cuts);
    }
    for (axis, sign) in [(0usize, -1.0f64), (0, 1.0), (1, -1.0), (1, 1.0)] {
        let Some(b) = Aabb::from_points(&pts) else {
            break;
        };
        let face = if sign < 0.0 { b.min[axis] } else { b.max[axis] };
        let Some((wall, _)) = find_layer(&b, context, (axis, sign), p.layer, p.margin, p) else {
            continue;
        };
        if (wall - face).abs() > p.layer {
            continue;
        }
        // A wall rises above what stands against it; the front of the nightstand under a
        // lamp does not.
        let other = 1 - axis;
        let above = context
            .iter()
            .filter(|q| {
                (q[axis] - wall).abs() <= p.layer
                    && q[2] > b.max[2]
                    && q[2] <= b.max[2] + p.margin_far
                    && q[other] >= b.min[other] - p.margin
                    && q[other] <= b.max[other] + p.margin
            })
            .count();
        if above < p.min_points {
            continue;
        }
        let keep: Vec<Point3<f64>> = pts
            .iter()
            .filter(|q| sign * (q[axis] - wall) < -p.layer)
            .copied()
            .collect();
        let removed = pts.len() - keep.len();
        if removed == 0 || 2 * removed > pts.len() {
            continue;
        }
        cuts.push(WallCut {
            axis: NAMES[axis],
            side: if sign < 0.0 { "min" } else { "max" },
            wall,
            removed,
            band: p.layer,
            kept_by_colour: 0,
        });
        pts = keep;
    }
    (pts, cuts)
}

/// Remove from `points` those within a band (either side) of a wall of the room's box that
/// a camera faced (`RoomLayout::faced`): an object that is not flat against
/// a wall has no surface on the wall's plane, so points there are the wall seen around or
/// behind it (a floor lamp's thin pole in front of a wall fills little of its box; the
/// segmenter grows over the wall that fills the rest). Not for classes flat against a
/// wall, whose plane it is (the caller decides).
///
/// The room's box is fitted to every frame, and one frame's pose error moves its points a
/// few centimetres off it; far from the camera, depth noise spreads a wall over a layer
/// several centimetres thick. So each wall is taken from this frame's `context` (its
/// points around the mask): at the densest layer within `room_wall_search` of the box's
/// wall, with a band of [`WALL_SPREADS`] times the spread of the context's points about it
/// (a robust standard deviation), at least `layer` and at most `room_wall_search`. Too
/// few context points there: the box's wall, `layer` either side. Nothing is cut when
/// fewer than `min_points` points would remain: then the mask holds nothing but wall, and
/// no cut makes it the object. Given a colour lookup `colour_of` (and `room_wall_colour`
/// on), a point in a band whose colour is unlike the wall's there and like the object's is kept
/// ([`super::wall_colour`]): what stands within the wall's noise is told from it by colour.
pub fn cut_room_walls(
    points: &[Point3<f64>],
    context: &[Point3<f64>],
    room: &RoomLayout,
    colour_of: Option<ColourLookup<'_>>,
    p: &SupportParams,
) -> (Vec<Point3<f64>>, Vec<WallCut>) {
    if !p.enabled || !p.room_wall_cut {
        return (points.to_vec(), Vec::new());
    }
    // Coordinate on the room's u or v axis: walls 0, 1 are u low / high, 2, 3 v low / high.
    let along = |i: usize, q: &Point3<f64>| {
        let (u, v) = room.turn(q.x, q.y);
        if i < 2 {
            u
        } else {
            v
        }
    };
    // The points' extent on u and v: a wall farther from them than the search cannot
    // hold any of them (no band is wider), and its context is not looked at.
    let mut reach = [[f64::INFINITY, f64::NEG_INFINITY]; 2];
    for q in points {
        let (u, v) = room.turn(q.x, q.y);
        for (r, c) in reach.iter_mut().zip([u, v]) {
            r[0] = r[0].min(c);
            r[1] = r[1].max(c);
        }
    }
    // (wall index, where this frame has it, half-width of the band cut).
    let walls: Vec<(usize, f64, f64)> = [room.u[0], room.u[1], room.v[0], room.v[1]]
        .into_iter()
        .enumerate()
        .filter_map(|(i, w)| w.filter(|_| room.faced[i]).map(|w| (i, w)))
        .filter(|&(i, w)| {
            let [lo, hi] = reach[i / 2];
            w >= lo - 2.0 * p.room_wall_search && w <= hi + 2.0 * p.room_wall_search
        })
        .map(|(i, w)| {
            let mut near: Vec<f64> = context
                .iter()
                .map(|q| along(i, q))
                .filter(|c| (c - w).abs() <= p.room_wall_search)
                .collect();
            near.sort_by(f64::total_cmp);
            match densest_layer(&near, p.layer, p.min_points) {
                Some(at) => {
                    let sigma = 1.4826
                        * median(&mut near.iter().map(|c| (c - at).abs()).collect::<Vec<f64>>());
                    let band = (WALL_SPREADS * sigma).clamp(p.layer, p.room_wall_search);
                    (i, at, band)
                }
                None => (i, w, p.layer),
            }
        })
        .collect();
    if walls.is_empty() {
        return (points.to_vec(), Vec::new());
    }
    // The wall whose band each point lies in, if any.
    let in_band = |q: &Point3<f64>| {
        walls
            .iter()
            .find(|&&(i, w, band)| (along(i, q) - w).abs() <= band)
            .map(|&(i, _, _)| i)
    };
    let bands: Vec<Option<usize>> = points.iter().map(in_band).collect();
    // Which band points colour keeps (empty when it cannot tell, or is not asked).
    let by_colour_keep = match colour_of {
        Some(look) if p.room_wall_colour && bands.iter().any(Option::is_some) => {
            colour_keeps(look, points, context, &bands, &walls, &along, p)
        }
        _ => Vec::new(),
    };
    let mut removed = [0usize; 4];
    let mut by_colour = [0usize; 4];
    let mut keep = Vec::with_capacity(points.len());
    for (k, (q, band)) in points.iter().zip(&bands).enumerate() {
        match band {
            Some(i) if by_colour_keep.get(k) == Some(&true) => {
                by_colour[*i] += 1;
                keep.push(*q);
            }
            Some(i) => removed[*i] += 1,
            None => keep.push(*q),
        }
    }
    if removed.iter().sum::<usize>() == 0 || keep.len() < p.min_points {
        return (points.to_vec(), Vec::new());
    }
    let cuts = walls
        .iter()
        .filter(|&&(i, _, _)| removed[i] > 0 || by_colour[i] > 0)
        .map(|&(i, wall, band)| WallCut {
            axis: if i < 2 { "u" } else { "v" },
            side: if i % 2 == 0 { "min" } else { "max" },
            wall,
            removed: removed[i],
            band,
            kept_by_colour: by_colour[i],
        })
        .collect();
    (keep, cuts)
}

/// What a frame's colour image shows at each of the given points, in their order
/// (`geometry::export::point_colours` with the frame's camera and image).
pub type ColourLookup<'a> = &'a dyn Fn(&[Point3<f64>]) -> Vec<[u8; 3]>;

/// For each point, whether it lies in a wall's band and colour says it is the object's:
/// each wall with points in its band has its colours (the context within its band) set
/// against the object's (the points in no band). Colours are looked up only for the
/// points and the context in a band.
fn colour_keeps(
    look: ColourLookup<'_>,
    points: &[Point3<f64>],
    context: &[Point3<f64>],
    bands: &[Option<usize>],
    walls: &[(usize, f64, f64)],
    along: &dyn Fn(usize, &Point3<f64>) -> f64,
    p: &SupportParams,
) -> Vec<bool> {
    let colours = look(points);
    if colours.len() != points.len() {
        return Vec::new();
    }
    let object: Vec<[u8; 3]> = bands
        .iter()
        .zip(&colours)
        .filter(|(b, _)| b.is_none())
        .map(|(_, &c)| c)
        .collect();
    let mut splits: [Option<ColourSplit>; 4] = [None, None, None, None];
    for &(i, w, band) in walls {
        if !bands.contains(&Some(i)) {
            continue;
        }
        let near: Vec<Point3<f64>> = context
            .iter()
            .filter(|q| (along(i, q) - w).abs() <= band)
            .copied()
            .collect();
        let wall = look(&near);
        if wall.len() == near.len() {
            splits[i] = ColourSplit::new(&wall, &object, p.min_points);
        }
    }
    bands
        .iter()
        .zip(&colours)
        .map(|(b, &c)| b.is_some_and(|i| splits[i].as_ref().is_some_and(|s| s.is_object(c))))
        .collect()
}

/// The band [`cut_room_walls`] cuts about a wall, in robust standard deviations of the
/// frame's wall points: nearly all of a normally spread layer.
pub const WALL_SPREADS: f64 = 2.5;

/// The median of the most populous run of the sorted `values` no wider than `width`, when
/// it holds at least `min` of them.
fn densest_layer(values: &[f64], width: f64, min: usize) -> Option<f64> {
    let (mut best, mut start) = ((0, 0), 0);
    for end in 0..values.len() {
        while values[end] - values[start] > width {
            start += 1;
        }
        if end + 1 - start > best.1 - best.0 {
            best = (start, end + 1);
        }
    }
    let run = &values[best.0..best.1];
    (run.len() >= min.max(1)).then(|| run[run.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::geometry::test_grid::grid;

    #[test]
    fn a_box_against_a_wall_loses_the_wall_patch_its_mask_took() {
        // Wall x = 0. A box x 0..0.4, y 1.4..1.7, z 0..0.5: its front face (x = 0.4) and top.
        let mut obj = grid((1.4, 1.7), (0.0, 0.5), 0.02, |y, z| Point3::new(0.4, y, z));
        obj.extend(grid((0.0, 0.4), (1.4, 1.7), 0.02, |x, y| {
            Point3::new(x, y, 0.5)
        }));
        let real = Aabb::from_points(&obj).unwrap();
        // The leak: the wall beside the box, y 1.0..1.4, z 0.2..0.5.
        let mut leaky = obj.clone();
        leaky.extend(grid((1.0, 1.38), (0.2, 0.5), 0.02, |y, z| {
            Point3::new(0.0, y, z)
        }));
        // Context: the wall around, outside the mask.
        let ctx: Vec<Point3<f64>> =
            grid((0.6, 2.2), (0.0, 1.0), 0.02, |y, z| Point3::new(0.0, y, z))
                .into_iter()
                .filter(|q| !(q.y > 0.98 && q.y < 1.72 && q.z < 0.52))
                .collect();
        let (kept, cuts) = cut_wall_leaks(&leaky, &ctx, &SupportParams::default());
        assert_eq!(cuts.len(), 1, "{cuts:?}");
        assert_eq!((cuts[0].axis, cuts[0].side), ("x", "min"));
        let b = Aabb::from_points(&kept).unwrap();
        assert!((b.min[1] - real.min[1]).abs() < 1e-9, "{b:?}");
        // Only the top's strip within a layer of the wall went with it.
        assert!(b.min[0] > 0.0 && b.min[0] <= 0.06, "{b:?}");
        // A vertical surface that ends below the box's top (the front of a nightstand under a
        // lamp) is no wall.
        let low: Vec<Point3<f64>> = ctx.iter().filter(|q| q.z < 0.45).copied().collect();
        assert!(cut_wall_leaks(&leaky, &low, &SupportParams::default())
            .1
            .is_empty());
        // Switched off, or without context, nothing is cut.
        let off = SupportParams {
            wall_cut: false,
            ..SupportParams::default()
        };
        assert!(cut_wall_leaks(&leaky, &ctx, &off).1.is_empty());
        assert_eq!(
            cut_wall_leaks(&leaky, &[], &SupportParams::default())
                .0
                .len(),
            leaky.len()
        );
    }

    #[test]
    fn a_picture_on_its_wall_is_not_cut_away() {
        // A picture 2 cm in front of the wall y = 3: all of it within a layer of the wall.
        let pic = grid((1.0, 1.6), (1.2, 1.7), 0.02, |x, z| Point3::new(x, 2.98, z));
        let ctx: Vec<Point3<f64>> =
            grid((0.6, 2.0), (0.8, 2.1), 0.02, |x, z| Point3::new(x, 3.0, z))
                .into_iter()
                .filter(|q| !(q.x > 0.98 && q.x < 1.62 && q.z > 1.18 && q.z < 1.72))
                .collect();
        let (kept, cuts) = cut_wall_leaks(&pic, &ctx, &SupportParams::default());
        assert!(cuts.is_empty(), "{cuts:?}");
        assert_eq!(kept.len(), pic.len());
    }

    /// A 4 x 3 m room turned by `angle` degrees, its walls u = 0, 4 and v = 0, 3, all
    /// faced but the first when `first_faced` is false.
    fn room(angle: f64, first_faced: bool) -> RoomLayout {
        let mut r = crate::geometry::test_scene::room_box(angle, 4.0, 3.0, 2.5);
        r.faced[0] = first_faced;
        r
    }

    #[test]
    fn a_floor_lamp_keeps_its_pole_and_loses_the_wall_behind_it() {
        // In room coordinates (u, v, z): a pole 25 cm in front of the wall u = 0 and the
        // wall behind and beside it, a little noisy (within 1.5 cm of the plane), which
        // fills most of the mask. Turned by the room's angle into x, y.
        for angle in [0.0, 30.0] {
            let r = room(angle, true);
            let (s, c) = f64::to_radians(angle).sin_cos();
            // (u, v) -> (x, y): the inverse of `RoomLayout::turn`.
            let at = |u: f64, v: f64, z: f64| Point3::new(c * u - s * v, s * u + c * v, z);
            let pole = grid((1.0, 1.03), (0.0, 1.5), 0.01, |v, z| at(0.25, v, z));
            let mut mask = pole.clone();
            mask.extend(grid((0.8, 1.25), (0.0, 1.5), 0.01, |v, z| {
                at(0.015 * ((v * 100.0).round() % 3.0 - 1.0), v, z)
            }));
            let (kept, cuts) = cut_room_walls(&mask, &[], &r, None, &SupportParams::default());
            assert_eq!(kept.len(), pole.len(), "angle {angle}: {cuts:?}");
            for (a, b) in kept.iter().zip(&pole) {
                assert!((a - b).norm() < 1e-12);
            }
            assert_eq!(cuts.len(), 1, "{cuts:?}");
            assert_eq!((cuts[0].axis, cuts[0].side), ("u", "min"));
            assert_eq!(cuts[0].removed, mask.len() - pole.len());
            // A wall no camera faced is where the points end, not a measured plane: kept.
            let (kept, cuts) = cut_room_walls(
                &mask,
                &[],
                &room(angle, false),
                None,
                &SupportParams::default(),
            );
            assert!(cuts.is_empty() && kept.len() == mask.len());
        }
    }

    #[test]
    fn the_wall_is_cut_where_this_frame_measures_it() {
        // The frame's pose error puts its wall 6 cm in front of the room's (u = 0): the
        // band around the room's wall misses most of the patch; the frame's context, the
        // wall around the mask, says where it lies in this frame.
        let r = room(0.0, true);
        let off = 0.06;
        let pole = grid((1.0, 1.03), (0.0, 1.5), 0.01, |y, z| Point3::new(0.3, y, z));
        let mut mask = pole.clone();
        mask.extend(grid((0.8, 1.25), (0.0, 1.5), 0.01, |y, z| {
            Point3::new(off + 0.015 * ((y * 100.0).round() % 3.0 - 1.0), y, z)
        }));
        let ctx: Vec<Point3<f64>> =
            grid((0.5, 1.6), (0.0, 2.0), 0.02, |y, z| Point3::new(off, y, z))
                .into_iter()
                .filter(|q| !(q.y > 0.78 && q.y < 1.27 && q.z < 1.52))
                .collect();
        let p = SupportParams::default();
        let (kept, cuts) = cut_room_walls(&mask, &ctx, &r, None, &p);
        assert_eq!(kept.len(), pole.len(), "{cuts:?}");
        assert!((cuts[0].wall - off).abs() < 0.011, "{cuts:?}");
        // Without the context, the room's wall: most of the patch is left.
        let (kept, _) = cut_room_walls(&mask, &[], &r, None, &p);
        assert!(kept.len() > pole.len() + (mask.len() - pole.len()) / 2);
        // A surface farther from the room's wall than `room_wall_search` is not taken for
        // it: the box's wall is used.
        let far: Vec<Point3<f64>> = ctx.iter().map(|q| Point3::new(0.3, q.y, q.z)).collect();
        let (_, cuts) = cut_room_walls(&mask, &far, &r, None, &p);
        assert!(cuts.iter().all(|c| c.wall == 0.0), "{cuts:?}");
    }

    #[test]
    fn a_wall_far_from_the_camera_is_cut_over_the_thickness_its_noise_gives_it() {
        // Depth noise about 3 cm (a wall 4–5 m away): the wall points spread over ±7 cm.
        let r = room(0.0, true);
        let mut seed = 7u64;
        let mut noise = move || {
            // The sum of four uniforms, scaled to a standard deviation of 3 cm.
            let mut sum = 0.0;
            for _ in 0..4 {
                seed = seed
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                sum += (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            }
            sum * 0.03 / (4.0f64 / 12.0).sqrt()
        };
        let pole = grid((1.0, 1.03), (0.0, 1.5), 0.01, |y, z| Point3::new(0.3, y, z));
        let wall: Vec<Point3<f64>> =
            grid((0.8, 1.25), (0.0, 1.5), 0.01, |y, z| Point3::new(0.0, y, z))
                .into_iter()
                .map(|q| Point3::new(noise(), q.y, q.z))
                .collect();
        let ctx: Vec<Point3<f64>> =
            grid((0.5, 1.6), (0.0, 2.0), 0.02, |y, z| Point3::new(0.0, y, z))
                .into_iter()
                .filter(|q| !(q.y > 0.78 && q.y < 1.27 && q.z < 1.52))
                .map(|q| Point3::new(noise(), q.y, q.z))
                .collect();
        let mut mask = pole.clone();
        mask.extend(&wall);
        let p = SupportParams::default();
        let (kept, cuts) = cut_room_walls(&mask, &ctx, &r, None, &p);
        let left = kept.len() - pole.len();
        assert!(kept.iter().filter(|q| q.x > 0.29).count() == pole.len());
        assert!(
            left * 50 < wall.len(),
            "{left} of {} wall points left",
            wall.len()
        );
        assert_eq!(cuts[0].removed, mask.len() - kept.len());
        // The fixed band of one layer (±4 cm) leaves the sixth of them beyond it.
        let (kept, _) = cut_room_walls(&mask, &[], &r, None, &p);
        assert!((kept.len() - pole.len()) * 10 > wall.len());
    }

    #[test]
    fn a_mask_of_nothing_but_wall_is_not_cut_to_nothing_and_the_cut_can_be_switched_off() {
        let r = room(0.0, true);
        let wall = grid((0.8, 1.25), (0.0, 1.5), 0.01, |y, z| {
            Point3::new(0.01, y, z)
        });
        // Fewer than `min_points` would remain: the mask is left as it is.
        let mut few = wall.clone();
        few.extend(grid((1.0, 1.02), (0.5, 0.52), 0.01, |y, z| {
            Point3::new(0.3, y, z)
        }));
        let p = SupportParams::default();
        assert!(few.len() - wall.len() < p.min_points);
        let (kept, cuts) = cut_room_walls(&few, &[], &r, None, &p);
        assert!(cuts.is_empty() && kept.len() == few.len());
        // Enough remain: cut. Off, or with support completion off: not.
        let mut lamp = wall.clone();
        lamp.extend(grid((1.0, 1.03), (0.0, 1.5), 0.01, |y, z| {
            Point3::new(0.3, y, z)
        }));
        assert_eq!(cut_room_walls(&lamp, &[], &r, None, &p).1.len(), 1);
        for off in [
            SupportParams {
                room_wall_cut: false,
                ..SupportParams::default()
            },
            SupportParams {
                enabled: false,
                ..SupportParams::default()
            },
        ] {
            let (kept, cuts) = cut_room_walls(&lamp, &[], &r, None, &off);
            assert!(cuts.is_empty() && kept.len() == lamp.len());
        }
    }
}
