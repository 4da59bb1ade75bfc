//! Mask leaks onto a wall (ours). A segmenter that grows over depth lets an object standing
//! against a wall run onto the wall beside or above it: the object's cloud then holds a
//! patch of the wall plane, and its box stretches along the wall. The context around the
//! object (points outside its mask, see [`super::context_points`]) shows that plane as a
//! support layer at the box face; the object's points within one layer of it are the
//! leak. The back face they leave behind is restored by [`super::extend_to_support`].

use nalgebra::Point3;
use serde::Serialize;

use super::support::find_layer;
use super::{Aabb, SupportParams};

/// One wall whose points were cut from an object's cloud.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WallCut {
    /// "x" or "y".
    pub axis: &'static str,
    /// "min" or "max" face of the cloud's box.
    pub side: &'static str,
    /// The wall's coordinate on `axis`.
    pub wall: f64,
    /// Points removed.
    pub removed: usize,
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
        });
        pts = keep;
    }
    (pts, cuts)
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
}
