//! Parts of an object that the fused cloud holds apart because what joins them was never
//! seen: a chair pushed behind a table shows its back above the table top and its front
//! legs below it, and the seat between them is hidden from every view. The fusion drops a
//! cluster much smaller than the largest one as a stray ([`super::cloud::cluster_keep`]),
//! so the legs went and the box came out as deep as the back. Free space tells the two
//! apart: between a stray and the object, some frame has looked through the gap and seen
//! nothing there (two pillows side by side, a neighbour's leak past an edge); between the
//! legs and the back no frame has.

use nalgebra::Point3;

use super::cloud::{cluster_labels, keep_by_fraction};
use super::ensemble::Carve;
use super::knn::{
    build_tree, neighbour_mean_distances, neighbour_mean_distances_of_subset, Neighbours,
};
use super::GeometryParams;

/// Fewest points a dropped cluster must hold to be joined back: fewer is noise.
const MIN_POINTS: usize = 8;
/// Farthest (m) a dropped cluster may lie from the kept points: an object's own parts lie
/// within its size of each other, and the room's furniture is rarely larger.
pub(super) const MAX_GAP: f64 = 1.0;

/// A cloud, the indices of the points taken from it and its neighbour lists.
pub(super) type Known<'a> = (&'a [Point3<f64>], &'a [usize], &'a [Neighbours]);

/// [`super::cloud::cluster_keep`] with cells no finer than three times the cloud's median
/// neighbour spacing, so a sparse cloud (far away, low-resolution depth) is not cut into
/// pieces.
///
/// `known`: the cloud `points` was taken from, their indices in it, and its neighbour lists
/// for `sor_neighbors` (>= 2) nearest points, which spare most of the searches.
///
/// `carve` (the fusion's free-space test, with `consensus.bridge_unseen`) keeps a dropped
/// cluster that nothing seen empty parts from the rest ([`keep_bridged`]).
pub(super) fn drop_detached(
    points: Vec<Point3<f64>>,
    known: Option<Known<'_>>,
    carve: Option<Carve<'_>>,
    params: &GeometryParams,
) -> Vec<Point3<f64>> {
    if params.cluster_voxel <= 0.0 || points.len() < 10 {
        return points;
    }
    let k = params.sor_neighbors.max(2);
    let mean = match known {
        Some((cloud, kept, nn)) => neighbour_mean_distances_of_subset(cloud, kept, nn, k),
        None => neighbour_mean_distances(&points, k),
    };
    let mut d: Vec<f64> = mean.into_iter().filter(|d| *d >= 0.0).collect();
    d.sort_by(f64::total_cmp);
    let spacing = d.get(d.len() / 2).copied().unwrap_or(0.0);
    let voxel = params.cluster_voxel.max(3.0 * spacing);
    let (label, sizes) = cluster_labels(&points, voxel);
    let mut keep = keep_by_fraction(&label, &sizes, params.min_cluster_fraction);
    if let Some(carve) = carve.filter(|_| params.consensus.bridge_unseen) {
        if keep.iter().any(|k| !k) {
            keep_bridged(&points, &label, &sizes, &mut keep, voxel, carve);
        }
    }
    super::consensus::retain(&points, &keep)
}

/// `keep` (flags over `points` from [`super::cloud::cluster_labels`]' clusters, `label`
/// and `sizes`) with each dropped cluster of at least [`MIN_POINTS`] points kept again
/// when the segment from its point nearest the kept points to that kept point is at most
/// [`MAX_GAP`] long and no sample on it, `step` apart, is seen empty by `carve` (the
/// fusion's free-space test). Returns how many clusters were kept again.
pub fn keep_bridged(
    points: &[Point3<f64>],
    label: &[usize],
    sizes: &[usize],
    keep: &mut [bool],
    step: f64,
    carve: Carve<'_>,
) -> usize {
    if step <= 0.0 || points.len() != label.len() || points.len() != keep.len() {
        return 0;
    }
    let kept: Vec<Point3<f64>> = points
        .iter()
        .zip(keep.iter())
        .filter(|(_, k)| **k)
        .map(|(p, _)| *p)
        .collect();
    if kept.is_empty() {
        return 0;
    }
    let tree = build_tree(&kept);
    // Each dropped cluster's point nearest the kept points: (squared distance, point,
    // nearest kept point).
    let mut nearest: Vec<Option<(f64, usize, usize)>> = vec![None; sizes.len()];
    for (i, p) in points.iter().enumerate() {
        let c = label[i];
        if keep[i] || sizes[c] < MIN_POINTS {
            continue;
        }
        let n = tree.nearest_one::<kiddo::SquaredEuclidean>(&[p.x, p.y, p.z]);
        if nearest[c].is_none_or(|(d, _, _)| n.distance < d) {
            nearest[c] = Some((n.distance, i, n.item as usize));
        }
    }
    let mut joined = vec![false; sizes.len()];
    for (c, near) in nearest.iter().enumerate() {
        let Some((d2, i, j)) = *near else { continue };
        let gap = d2.sqrt();
        if gap > MAX_GAP {
            continue;
        }
        let (a, b) = (points[i], kept[j]);
        let n = (gap / step).floor() as usize;
        let samples: Vec<Point3<f64>> = (1..n)
            .map(|k| a + (b - a) * (k as f64 / n as f64))
            .collect();
        if samples.is_empty() || carve(&samples).iter().all(|&k| k) {
            joined[c] = true;
        }
    }
    for (i, k) in keep.iter_mut().enumerate() {
        if joined[label[i]] {
            *k = true;
        }
    }
    joined.iter().filter(|&&j| j).count()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blob(at: [f64; 3], n: usize) -> Vec<Point3<f64>> {
        (0..n)
            .map(|k| {
                let f = k as f64 * 0.01;
                Point3::new(at[0] + f % 0.05, at[1] + (f * 7.0) % 0.05, at[2])
            })
            .collect()
    }

    /// A back (large cluster) and legs (small cluster) 40 cm apart: kept again when no
    /// sample between them is seen empty, dropped when one is, and never when too far.
    #[test]
    fn a_dropped_cluster_joins_when_nothing_was_seen_between() {
        let mut points = blob([0.0, 0.0, 0.5], 200);
        points.extend(blob([0.0, 0.4, 0.1], 20));
        points.extend(blob([3.0, 0.0, 0.5], 20));
        let (label, sizes) = super::super::cloud::cluster_labels(&points, 0.05);
        let largest = sizes.iter().copied().max().unwrap_or(0);
        let base: Vec<bool> = label.iter().map(|&c| sizes[c] == largest).collect();
        assert_eq!(base.iter().filter(|k| **k).count(), 200);

        let unseen = |s: &[Point3<f64>]| vec![true; s.len()];
        let mut keep = base.clone();
        assert_eq!(
            keep_bridged(&points, &label, &sizes, &mut keep, 0.05, &unseen),
            1
        );
        assert!(keep[..220].iter().all(|k| *k), "the legs join");
        assert!(keep[220..].iter().all(|k| !*k), "3 m away stays dropped");

        // A frame saw through the gap's middle.
        let seen = |s: &[Point3<f64>]| s.iter().map(|p| p.y < 0.15 || p.y > 0.25).collect();
        let mut keep = base.clone();
        assert_eq!(
            keep_bridged(&points, &label, &sizes, &mut keep, 0.05, &seen),
            0
        );
        assert_eq!(keep, base);
    }

    fn grid(x0: f64, y0: f64, z: f64, n: usize) -> Vec<Point3<f64>> {
        (0..n * n)
            .map(|k| Point3::new(x0 + (k % n) as f64 * 0.02, y0 + (k / n) as f64 * 0.02, z))
            .collect()
    }

    /// Through the fusion: a back of 400 points and legs of 25 (under a tenth of it) 30 cm
    /// below. With the free-space test seeing nothing between them the legs stay; with
    /// `bridge_unseen` off, or without the free-space test, they go as before.
    #[test]
    fn the_fusion_keeps_legs_no_frame_saw_apart_from_the_back() {
        use crate::geometry::ensemble::fuse_clouds;
        use crate::geometry::GeometryParams;
        let mut cloud = grid(0.0, 0.0, 0.8, 20);
        cloud.extend(grid(0.1, 0.1, 0.5, 5));
        let unseen = |s: &[Point3<f64>]| vec![true; s.len()];
        let on = GeometryParams::default();
        let off = GeometryParams {
            consensus: crate::geometry::consensus::ConsensusParams {
                bridge_unseen: false,
                ..on.consensus.clone()
            },
            ..on.clone()
        };
        let kept = |p: &GeometryParams, carve: bool| {
            let c = carve.then_some(&unseen as _);
            let r = fuse_clouds(cloud.len(), &[&cloud], Vec::new(), c, p);
            r.aabb.map(|b| b.min[2]).unwrap_or(f64::NAN)
        };
        assert!((kept(&on, true) - 0.5).abs() < 0.02, "{}", kept(&on, true));
        assert!(
            (kept(&off, true) - 0.8).abs() < 0.02,
            "{}",
            kept(&off, true)
        );
        assert!(
            (kept(&on, false) - 0.8).abs() < 0.02,
            "{}",
            kept(&on, false)
        );
    }
}
