//! Point-cloud operations: voxel downsampling, Open3D-identical statistical outlier
//! removal and the chamfer distance of the ensemble filter. Nearest neighbours come from
//! the k-d tree searches of `knn`.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::num::NonZeroUsize;

use kiddo::SquaredEuclidean;
use nalgebra::Point3;
use rayon::prelude::*;

use super::knn::{build_tree, mean_distance, neighbour_lists, Neighbours, Tree, PAR_CHUNK};

/// Multiply-xorshift hasher for voxel keys (SipHash dominates the cost otherwise).
#[derive(Default)]
struct VoxelHasher(u64);

impl Hasher for VoxelHasher {
    fn finish(&self) -> u64 {
        let h = self.0.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        h ^ (h >> 29)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(0x100_0000_01B3);
        }
    }
    fn write_i64(&mut self, v: i64) {
        self.0 = (self.0.rotate_left(21) ^ v as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

/// `x.floor() as i64`, equal for every input (NaN and infinities included), without the
/// libm call `floor` compiles to on the default x86-64 target (no SSE4.1).
#[inline]
pub(crate) fn floor_i64(x: f64) -> i64 {
    // `as` truncates towards zero and saturates (NaN: 0).
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// Median of `v` (the upper one of an even count); `v` is reordered. Empty: 0.
pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// One point per occupied voxel of side `voxel` (the centroid of that voxel's points),
/// in order of first occurrence. `voxel <= 0` returns the input unchanged.
pub fn voxel_downsample(points: &[Point3<f64>], voxel: f64) -> Vec<Point3<f64>> {
    if voxel <= 0.0 || points.is_empty() {
        return points.to_vec();
    }
    let mut slot: HashMap<(i64, i64, i64), usize, BuildHasherDefault<VoxelHasher>> =
        HashMap::with_capacity_and_hasher(points.len() / 4, Default::default());
    let mut sums: Vec<([f64; 3], u32)> = Vec::new();
    // Clouds back-projected from depth come in pixel order, so runs of points share a
    // voxel: the previous point's voxel is checked before the map.
    let mut last: Option<((i64, i64, i64), usize)> = None;
    for p in points {
        let key = (
            floor_i64(p.x / voxel),
            floor_i64(p.y / voxel),
            floor_i64(p.z / voxel),
        );
        let i = match last {
            Some((k, i)) if k == key => i,
            _ => {
                let i = *slot.entry(key).or_insert_with(|| {
                    sums.push(([0.0; 3], 0));
                    sums.len() - 1
                });
                last = Some((key, i));
                i
            }
        };
        let s = &mut sums[i];
        s.0[0] += p.x;
        s.0[1] += p.y;
        s.0[2] += p.z;
        s.1 += 1;
    }
    sums.into_iter()
        .map(|(s, n)| {
            let n = n as f64;
            Point3::new(s[0] / n, s[1] / n, s[2] / n)
        })
        .collect()
}

/// Drop the points of small detached clusters: points are grouped into `voxel`-sized
/// cells, cells touching (26-neighbourhood) form clusters, and a cluster is kept when it
/// holds at least `min_fraction` of the points of the largest one. Returns keep-flags.
/// `voxel` <= 0 keeps everything.
pub fn cluster_keep(points: &[Point3<f64>], voxel: f64, min_fraction: f64) -> Vec<bool> {
    if voxel <= 0.0 || points.is_empty() {
        return vec![true; points.len()];
    }
    let (label, sizes) = cluster_labels(points, voxel);
    keep_by_fraction(&label, &sizes, min_fraction)
}

/// Per point (`label`: its cluster; `sizes`: each cluster's points), whether its cluster
/// holds at least `min_fraction` of the largest cluster's points.
pub fn keep_by_fraction(label: &[usize], sizes: &[usize], min_fraction: f64) -> Vec<bool> {
    let largest = sizes.iter().copied().max().unwrap_or(0) as f64;
    label
        .iter()
        .map(|&c| sizes[c] as f64 >= min_fraction * largest)
        .collect()
}

/// The clusters of [`cluster_keep`] (`voxel` > 0): each point's cluster and each
/// cluster's number of points.
pub fn cluster_labels(points: &[Point3<f64>], voxel: f64) -> (Vec<usize>, Vec<usize>) {
    let key = |p: &Point3<f64>| {
        (
            (p.x / voxel).floor() as i64,
            (p.y / voxel).floor() as i64,
            (p.z / voxel).floor() as i64,
        )
    };
    let mut cell: HashMap<(i64, i64, i64), usize, BuildHasherDefault<VoxelHasher>> =
        HashMap::with_capacity_and_hasher(points.len() / 4, Default::default());
    let mut counts: Vec<usize> = Vec::new();
    let point_cell: Vec<usize> = points
        .iter()
        .map(|p| {
            let i = *cell.entry(key(p)).or_insert_with(|| {
                counts.push(0);
                counts.len() - 1
            });
            counts[i] += 1;
            i
        })
        .collect();
    let keys: Vec<(i64, i64, i64)> = {
        let mut k = vec![(0, 0, 0); counts.len()];
        for (&c, &i) in &cell {
            k[i] = c;
        }
        k
    };
    // Flood fill over occupied cells.
    let mut label = vec![usize::MAX; counts.len()];
    let mut sizes: Vec<usize> = Vec::new();
    for start in 0..counts.len() {
        if label[start] != usize::MAX {
            continue;
        }
        let id = sizes.len();
        sizes.push(0);
        label[start] = id;
        let mut stack = vec![start];
        while let Some(i) = stack.pop() {
            sizes[id] += counts[i];
            let (x, y, z) = keys[i];
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        if let Some(&j) = cell.get(&(x + dx, y + dy, z + dz)) {
                            if label[j] == usize::MAX {
                                label[j] = id;
                                stack.push(j);
                            }
                        }
                    }
                }
            }
        }
    }
    let point_label = point_cell.iter().map(|&c| label[c]).collect();
    (point_label, sizes)
}

/// Evenly spaced subset of at most `max` points (every k-th point); `max == 0` keeps all.
pub fn subsample_even(points: &[Point3<f64>], max: usize) -> Vec<Point3<f64>> {
    if max == 0 || points.len() <= max {
        return points.to_vec();
    }
    let step = points.len() as f64 / max as f64;
    (0..max)
        .map(|i| points[(i as f64 * step) as usize])
        .collect()
}

/// Indices of the points kept by statistical outlier removal, exactly as Open3D's
/// `remove_statistical_outlier(nb_neighbors, std_ratio)` defines it:
///
/// * for every point, `d_i` = mean Euclidean distance to its `nb_neighbors` nearest points
///   of the cloud, the point itself included (so one of them is 0);
/// * `n` = points that have neighbours; `mean` = (sum of the `d_i > 0`) / n;
///   `std` = sqrt(sum over `d_i > 0` of (d_i − mean)² / (n − 1)) — Open3D's formulas, which
///   count points with `d_i = 0` (exact duplicates) in n but not in the sums;
/// * keep point i when `0 < d_i < mean + std_ratio * std` (strict, as Open3D).
///
/// Returns all indices when there are fewer than 2 usable points or `nb_neighbors == 0`
/// (Open3D reports an error there; we prefer a no-op).
pub fn statistical_outlier_indices(
    points: &[Point3<f64>],
    nb_neighbors: usize,
    std_ratio: f64,
) -> Vec<usize> {
    outliers_and_neighbours(points, nb_neighbors, std_ratio).0
}

/// [`statistical_outlier_indices`] and, when it computed them, every point's
/// `nb_neighbors` nearest points (for [`super::knn::neighbour_mean_distances_of_subset`]).
pub(crate) fn outliers_and_neighbours(
    points: &[Point3<f64>],
    nb_neighbors: usize,
    std_ratio: f64,
) -> (Vec<usize>, Option<Vec<Neighbours>>) {
    let all = || (0..points.len()).collect();
    let Some(k) = NonZeroUsize::new(nb_neighbors) else {
        return (all(), None);
    };
    if points.len() < 2 {
        return (all(), None);
    }
    let nn = neighbour_lists(points, &build_tree(points), k);
    let avg: Vec<f64> = nn.iter().map(mean_distance).collect();
    let valid = avg.iter().filter(|&&d| d >= 0.0).count();
    if valid < 2 {
        return (all(), Some(nn));
    }
    let mean = avg.iter().filter(|&&d| d > 0.0).sum::<f64>() / valid as f64;
    let sq: f64 = avg
        .iter()
        .filter(|&&d| d > 0.0)
        .map(|d| (d - mean) * (d - mean))
        .sum();
    let std = (sq / (valid - 1) as f64).sqrt();
    let threshold = mean + std_ratio * std;
    let kept = (0..points.len())
        .filter(|&i| avg[i] > 0.0 && avg[i] < threshold)
        .collect();
    (kept, Some(nn))
}

/// The points kept by [`statistical_outlier_indices`].
pub fn remove_statistical_outliers(
    points: &[Point3<f64>],
    nb_neighbors: usize,
    std_ratio: f64,
) -> Vec<Point3<f64>> {
    statistical_outlier_indices(points, nb_neighbors, std_ratio)
        .into_iter()
        .map(|i| points[i])
        .collect()
}

/// Mean over `a` of the squared distance to the nearest point of `b` (`tree` is built on `b`).
fn directional_mean_sq(a: &[Point3<f64>], tree: &Tree) -> f64 {
    let d: Vec<f64> = a
        .par_iter()
        .with_min_len(PAR_CHUNK)
        .map(|p| {
            tree.nearest_one::<SquaredEuclidean>(&[p.x, p.y, p.z])
                .distance
        })
        .collect();
    // Summed in order, so the result does not depend on how the queries were split.
    d.iter().sum::<f64>() / a.len() as f64
}

/// Chamfer distance (m^2) as the ensemble filter uses it:
/// `mean_{a∈A} min_{b∈B} |a−b|² + mean_{b∈B} min_{a∈A} |a−b|²`.
/// `None` when either cloud is empty.
pub fn chamfer_distance(a: &[Point3<f64>], b: &[Point3<f64>]) -> Option<f64> {
    chamfer_distances(a, &[b]).pop().flatten()
}

/// [`chamfer_distance`] of `a` to each of `bs`, with `a`'s k-d tree built once for all of
/// them (a view's value does not depend on the others: the same to the bit as alone).
pub fn chamfer_distances<B: AsRef<[Point3<f64>]>>(a: &[Point3<f64>], bs: &[B]) -> Vec<Option<f64>> {
    directional_chamfers(a, bs)
        .into_iter()
        .map(|d| d.map(|[ab, ba]| ab + ba))
        .collect()
}

/// The two terms of [`chamfer_distance`] of `a` to each of `bs`, apart: `[a→b, b→a]`, the
/// mean squared distance from `a`'s points to `b`'s nearest, and back. The first is small
/// when `b` holds all of `a` (whatever else `b` holds). `None` when either cloud is empty.
pub fn directional_chamfers<B: AsRef<[Point3<f64>]>>(
    a: &[Point3<f64>],
    bs: &[B],
) -> Vec<Option<[f64; 2]>> {
    let ta = (!a.is_empty() && bs.iter().any(|b| !b.as_ref().is_empty())).then(|| build_tree(a));
    bs.iter()
        .map(|b| {
            let b = b.as_ref();
            let ta = ta.as_ref().filter(|_| !b.is_empty())?;
            Some([
                directional_mean_sq(a, &build_tree(b)),
                directional_mean_sq(b, ta),
            ])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::test_grid::noisy_planes;
    use super::*;

    #[test]
    fn a_detached_cluster_is_dropped_a_large_one_stays() {
        let block = |x0: f64, n: usize| -> Vec<Point3<f64>> {
            (0..n * n * n)
                .map(|i| {
                    Point3::new(
                        x0 + 0.02 * (i % n) as f64,
                        0.02 * (i / n % n) as f64,
                        0.02 * (i / (n * n)) as f64,
                    )
                })
                .collect()
        };
        // 1000 points, 125 points 30 cm away (12.5 %), 8 points 1 m away (0.8 %).
        let mut pts = block(0.0, 10);
        pts.extend(block(0.5, 5));
        pts.extend(block(1.4, 2));
        let keep = cluster_keep(&pts, 0.05, 0.1);
        assert_eq!(keep.iter().filter(|k| **k).count(), 1125);
        assert!(keep[..1125].iter().all(|k| *k) && keep[1125..].iter().all(|k| !*k));
        // Cells wider than the gaps join everything; 0 turns the filter off.
        assert!(cluster_keep(&pts, 0.8, 0.1).iter().all(|k| *k));
        assert!(cluster_keep(&pts, 0.0, 0.1).iter().all(|k| *k));
        assert!(cluster_keep(&[], 0.05, 0.1).is_empty());
    }

    fn p(x: f64, y: f64, z: f64) -> Point3<f64> {
        Point3::new(x, y, z)
    }

    #[test]
    fn chamfer_hand_computed() {
        let a = [p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0)];
        let b = [p(0.0, 0.5, 0.0)];
        // A->B: (0.25 + 1.25) / 2 = 0.75 ; B->A: 0.25 ; total 1.0
        let c = chamfer_distance(&a, &b).unwrap_or(f64::NAN);
        assert!((c - 1.0).abs() < 1e-12, "{c}");
        assert_eq!(chamfer_distance(&a, &a), Some(0.0));
        assert_eq!(chamfer_distance(&a, &[]), None);
    }

    #[test]
    fn chamfer_distances_with_one_tree_equal_the_pairwise_ones_to_the_bit() {
        let a = noisy_planes(1500, 3);
        let bs: Vec<Vec<Point3<f64>>> = vec![
            noisy_planes(900, 4),
            Vec::new(),
            noisy_planes(40, 5),
            a.iter()
                .map(|q| q + nalgebra::Vector3::new(0.01, -0.02, 0.005))
                .collect(),
        ];
        let bits = |v: Vec<Option<f64>>| -> Vec<Option<u64>> {
            v.into_iter().map(|d| d.map(f64::to_bits)).collect()
        };
        let want: Vec<Option<f64>> = bs.iter().map(|b| chamfer_distance(&a, b)).collect();
        assert!(want[0].is_some_and(|d| d > 0.0) && want[1].is_none());
        assert_eq!(bits(chamfer_distances(&a, &bs)), bits(want));
        assert_eq!(chamfer_distances(&[], &bs), vec![None; 4]);
        assert!(chamfer_distances::<Vec<Point3<f64>>>(&a, &[]).is_empty());
    }

    #[test]
    fn voxel_centroids() {
        let pts = [p(0.01, 0.01, 0.01), p(0.03, 0.03, 0.03), p(0.15, 0.0, 0.0)];
        let d = voxel_downsample(&pts, 0.1);
        assert_eq!(d.len(), 2);
        assert!((d[0] - p(0.02, 0.02, 0.02)).norm() < 1e-12);
        assert!((d[1] - p(0.15, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(voxel_downsample(&pts, 0.0).len(), 3);
    }

    #[test]
    fn sor_hand_computed_line() {
        // Points on a line at 0,1,2,3 and an outlier at 20; nb = 2 (self + nearest).
        let pts = [
            p(0.0, 0.0, 0.0),
            p(1.0, 0.0, 0.0),
            p(2.0, 0.0, 0.0),
            p(3.0, 0.0, 0.0),
            p(20.0, 0.0, 0.0),
        ];
        // d = [0.5, 0.5, 0.5, 0.5, 8.5]; mean = 2.1; std = sqrt(4*1.6^2+6.4^2)/2 = 3.577..
        // threshold (ratio 1) = 5.677 -> outlier dropped.
        assert_eq!(statistical_outlier_indices(&pts, 2, 1.0), vec![0, 1, 2, 3]);
        // ratio 2 -> threshold 9.25 keeps all.
        assert_eq!(statistical_outlier_indices(&pts, 2, 2.0).len(), 5);
    }

    #[test]
    fn sor_drops_exact_duplicates_like_open3d() {
        // With nb = 2 a point whose nearest other point coincides has d = 0 and is dropped.
        let pts = [
            p(0.0, 0.0, 0.0),
            p(0.0, 0.0, 0.0),
            p(1.0, 0.0, 0.0),
            p(2.5, 0.0, 0.0),
        ];
        let kept = statistical_outlier_indices(&pts, 2, 3.0);
        assert_eq!(kept, vec![2, 3]);
    }

    #[test]
    fn even_subsample() {
        let pts: Vec<_> = (0..10).map(|i| p(i as f64, 0.0, 0.0)).collect();
        let s = subsample_even(&pts, 5);
        assert_eq!(
            s.iter().map(|q| q.x as i32).collect::<Vec<_>>(),
            vec![0, 2, 4, 6, 8]
        );
    }

    #[test]
    fn floor_without_libm_equals_floor() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            -1.0 - f64::EPSILON,
            2.0f64.powi(53) + 2.0,
            -(2.0f64.powi(53)) - 2.0,
            2.0f64.powi(63),
            -(2.0f64.powi(63)),
            1e30,
            -1e30,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
        ];
        xs.extend((0..2000).map(|i| (i as f64 - 1000.0) * 0.0137 / 0.02));
        for x in xs {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
    }

    #[test]
    fn voxel_downsample_of_runs_equals_the_plain_map() {
        // Raster-ordered points (runs share voxels) and shuffled ones give the centroids
        // a plain per-point map gives, in order of first occurrence.
        let raster: Vec<Point3<f64>> = (0..4000)
            .map(|i| {
                Point3::new(
                    (i % 80) as f64 * 0.003,
                    (i / 80) as f64 * 0.003,
                    1.0 - 0.0001 * i as f64,
                )
            })
            .collect();
        for pts in [raster, noisy_planes(2000, 3)] {
            let mut order: Vec<(i64, i64, i64)> = Vec::new();
            let mut acc: HashMap<(i64, i64, i64), ([f64; 3], u32)> = HashMap::new();
            for p in &pts {
                let k = (
                    (p.x / 0.02).floor() as i64,
                    (p.y / 0.02).floor() as i64,
                    (p.z / 0.02).floor() as i64,
                );
                let e = acc.entry(k).or_insert_with(|| {
                    order.push(k);
                    ([0.0; 3], 0)
                });
                e.0[0] += p.x;
                e.0[1] += p.y;
                e.0[2] += p.z;
                e.1 += 1;
            }
            let want: Vec<Point3<f64>> = order
                .iter()
                .map(|k| {
                    let (s, n) = acc[k];
                    Point3::new(s[0] / n as f64, s[1] / n as f64, s[2] / n as f64)
                })
                .collect();
            assert_eq!(voxel_downsample(&pts, 0.02), want);
        }
    }
}
