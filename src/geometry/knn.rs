//! k-nearest-neighbour searches on a kiddo k-d tree: every point's neighbour list (a heap
//! search sorted once), Open3D's mean neighbour distance, and the same statistic for a
//! subset that reuses the lists of the whole cloud.

use std::num::NonZeroUsize;

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use nalgebra::Point3;
use rayon::prelude::*;

pub(super) type Tree = ImmutableKdTree<f64, u32, 3, 32>;

/// Nearest-neighbour queries per parallel task: small clouds stay on one thread.
pub(super) const PAR_CHUNK: usize = 2048;

/// A k-d tree over `points` (items are their indices).
pub(super) fn build_tree(points: &[Point3<f64>]) -> Tree {
    let coords: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
    Tree::new_from_slice(&coords)
}

/// A point's nearest points of a cloud: (squared distance, index), nearest first.
pub(crate) type Neighbours = Vec<(f64, u32)>;

/// The `k` nearest points of `tree` to each of `points`, nearest first. kiddo keeps
/// them in a binary heap here (its sorted vector, used when asked for sorted results, cost
/// more than the search itself), sorted once at the end.
pub(super) fn neighbour_lists(
    points: &[Point3<f64>],
    tree: &Tree,
    k: NonZeroUsize,
) -> Vec<Neighbours> {
    points
        .par_iter()
        .with_min_len(PAR_CHUNK)
        .map(|p| {
            let mut nn: Neighbours = tree
                .nearest_n_within::<SquaredEuclidean>(&[p.x, p.y, p.z], f64::INFINITY, k, false)
                .into_iter()
                .map(|n| (n.distance, n.item))
                .collect();
            nn.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            nn
        })
        .collect()
}

/// Mean Euclidean distance of a neighbour list, summed nearest first (as the sorted
/// search gave them, so the value is the same to the bit); -1 when empty.
pub(super) fn mean_distance(nn: &Neighbours) -> f64 {
    if nn.is_empty() {
        return -1.0;
    }
    nn.iter().map(|n| n.0.sqrt()).sum::<f64>() / nn.len() as f64
}

/// [`neighbour_mean_distances`] of the subset `kept` (indices into the cloud `nn` was
/// computed on, with the same `nb_neighbors`): a point whose nearest points all stay keeps
/// its value, since they are then its nearest points of the subset too; the others are
/// searched again among the subset. Equal to `neighbour_mean_distances(subset)`.
pub(crate) fn neighbour_mean_distances_of_subset(
    points: &[Point3<f64>],
    kept: &[usize],
    nn: &[Neighbours],
    nb_neighbors: usize,
) -> Vec<f64> {
    let Some(k) = NonZeroUsize::new(nb_neighbors) else {
        return vec![-1.0; kept.len()];
    };
    let mut stays = vec![false; points.len()];
    for &i in kept {
        stays[i] = true;
    }
    let reusable = |i: usize| nn[i].len() == k.get() && nn[i].iter().all(|n| stays[n.1 as usize]);
    let mut out: Vec<f64> = kept
        .iter()
        .map(|&i| {
            if reusable(i) {
                mean_distance(&nn[i])
            } else {
                f64::NAN
            }
        })
        .collect();
    let redo: Vec<usize> = (0..kept.len()).filter(|&j| out[j].is_nan()).collect();
    if !redo.is_empty() {
        let subset: Vec<Point3<f64>> = kept.iter().map(|&i| points[i]).collect();
        let queries: Vec<Point3<f64>> = redo.iter().map(|&j| subset[j]).collect();
        let again = neighbour_lists(&queries, &build_tree(&subset), k);
        for (j, n) in redo.into_iter().zip(&again) {
            out[j] = mean_distance(n);
        }
    }
    out
}

/// For each point, the mean Euclidean distance to its `nb_neighbors` nearest points of
/// the cloud, the point itself included (Open3D's statistic); -1 when there are none.
pub fn neighbour_mean_distances(points: &[Point3<f64>], nb_neighbors: usize) -> Vec<f64> {
    let Some(k) = NonZeroUsize::new(nb_neighbors) else {
        return vec![-1.0; points.len()];
    };
    if points.is_empty() {
        return Vec::new();
    }
    // Queries are independent: split them over the cores (order and values unchanged).
    neighbour_lists(points, &build_tree(points), k)
        .iter()
        .map(mean_distance)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::cloud::{outliers_and_neighbours, statistical_outlier_indices};
    use super::super::test_grid::noisy_planes as cloud;
    use super::*;

    /// The distances as kiddo's sorted search gives them (the code before the heap).
    fn sorted_search_means(points: &[Point3<f64>], k: usize) -> Vec<f64> {
        let tree = build_tree(points);
        let k = NonZeroUsize::new(k).unwrap();
        points
            .iter()
            .map(|p| {
                let nn = tree.nearest_n::<SquaredEuclidean>(&[p.x, p.y, p.z], k);
                nn.iter().map(|n| n.distance.sqrt()).sum::<f64>() / nn.len() as f64
            })
            .collect()
    }

    #[test]
    fn neighbour_means_equal_the_sorted_search_to_the_bit() {
        for (n, k) in [(3000, 20), (500, 2), (7, 20)] {
            let pts = cloud(n, n as u64);
            let want = sorted_search_means(&pts, k);
            let got = neighbour_mean_distances(&pts, k);
            assert_eq!(
                got.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
                want.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
                "n = {n}, k = {k}"
            );
        }
    }

    #[test]
    fn subset_means_reuse_the_neighbours_and_equal_a_fresh_search() {
        let pts = cloud(3000, 7);
        let (kept, nn) = outliers_and_neighbours(&pts, 20, 1.0);
        let nn = nn.expect("neighbours computed");
        assert!(
            kept.len() < pts.len() && kept.len() > pts.len() / 2,
            "some points are outliers: {} of {}",
            kept.len(),
            pts.len()
        );
        let subset: Vec<Point3<f64>> = kept.iter().map(|&i| pts[i]).collect();
        let want = sorted_search_means(&subset, 20);
        let got = neighbour_mean_distances_of_subset(&pts, &kept, &nn, 20);
        assert_eq!(
            got.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            want.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
        );
        // The same indices as before the neighbour lists were kept.
        let plain = statistical_outlier_indices(&pts, 20, 1.0);
        assert_eq!(plain, kept);
    }
}
