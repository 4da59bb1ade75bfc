//! Finding the support layer beyond one face of a box: the nearest dense planar slice of
//! the context points in the ring around the box's footprint ([`super::support`] explains
//! the four tests a layer must pass).

use nalgebra::Point3;
use std::collections::HashSet;

use super::cloud::median;
use super::support::SupportParams;
use super::Aabb;

/// Fraction `q` (0–1) percentile of `sorted` (ascending, not empty), nearest rank.
pub(crate) fn percentile(sorted: &[f64], q: f64) -> f64 {
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// The nearest support layer beyond face (`axis`, `sign`) of `b`: its coordinate on `axis`
/// and its voxel count.
pub(crate) fn find_layer(
    b: &Aabb,
    ctx: &[Point3<f64>],
    (axis, sign): (usize, f64),
    max_gap: f64,
    margin: f64,
    p: &SupportParams,
) -> Option<(f64, usize)> {
    let others = [(axis + 1) % 3, (axis + 2) % 3];
    let face = if sign < 0.0 { b.min[axis] } else { b.max[axis] };
    // (gap beyond the face, point) for points in range.
    // Only the ring around the footprint: inside it the object hides its support, and any
    // point there may be the object itself (legs, an unsegmented part).
    let in_ring = |q: &Point3<f64>| {
        others
            .iter()
            .all(|&o| q[o] >= b.min[o] - margin && q[o] <= b.max[o] + margin)
            && others.iter().any(|&o| q[o] < b.min[o] || q[o] > b.max[o])
    };
    let min_gap = -p.max_inside.max(0.5 * p.layer);
    // A layer's thickness before the search range and two beyond it too: the slabs beside
    // each window ([`SupportParams::layer_peak`]); only the range itself is searched.
    let mut cands: Vec<(f64, &Point3<f64>)> = ctx
        .iter()
        .filter(|q| in_ring(q))
        .map(|q| (sign * (q[axis] - face), q))
        .filter(|(gap, _)| *gap >= min_gap - p.layer && *gap <= max_gap + 2.0 * p.layer)
        .collect();
    cands.sort_by(|a, c| a.0.total_cmp(&c.0));
    let in_range = |c: &(f64, &Point3<f64>)| c.0 >= min_gap && c.0 <= max_gap;
    if cands.iter().filter(|c| in_range(c)).count() < p.min_points {
        return None;
    }
    let step = 0.25 * p.layer;
    let mut start = min_gap;
    let mut lo = 0usize;
    while start <= max_gap {
        while lo < cands.len() && cands[lo].0 < start {
            lo += 1;
        }
        let hi = lo + cands[lo..].partition_point(|c| c.0 < start + p.layer.min(max_gap - start));
        let before = lo - cands[..lo].partition_point(|c| c.0 < start - p.layer);
        let after = cands[hi..].partition_point(|c| c.0 < start + 2.0 * p.layer);
        let peak =
            p.layer_peak <= 0.0 || (hi - lo) as f64 >= p.layer_peak * before.min(after) as f64;
        if hi - lo >= p.min_points && peak {
            let layer = &cands[lo..hi];
            if let Some((coord, n)) = accept_layer(b, layer, (axis, others), margin, p) {
                // The first window to qualify holds the near fringe of a noisy surface:
                // re-centre on the median of the points within one layer of it, twice.
                let mut c = coord;
                for _ in 0..2 {
                    let mut v: Vec<f64> = cands
                        .iter()
                        .filter(|c| in_range(c))
                        .map(|(_, q)| q[axis])
                        .filter(|x| (x - c).abs() <= p.layer)
                        .collect();
                    if v.is_empty() {
                        break;
                    }
                    c = median(&mut v);
                }
                return Some((c, n));
            }
        }
        start += step;
    }
    None
}

/// Spread and coverage tests of one candidate layer; its coordinate and size when it passes.
fn accept_layer(
    b: &Aabb,
    layer: &[(f64, &Point3<f64>)],
    (axis, others): (usize, [usize; 2]),
    margin: f64,
    p: &SupportParams,
) -> Option<(f64, usize)> {
    for &o in &others {
        let mut v: Vec<f64> = layer.iter().map(|(_, q)| q[o]).collect();
        v.sort_by(f64::total_cmp);
        let spread = percentile(&v, 0.9) - percentile(&v, 0.1);
        // Never below 1.5 layers: a slab of zero thickness must not accept a line.
        let need = p
            .min_spread
            .min(0.5 * (b.max[o] - b.min[o]))
            .max(1.5 * p.layer);
        if spread < need {
            return None;
        }
    }
    // Coverage of the ring around the box's footprint (the object hides its own footprint
    // on a wall behind it or a floor below it; a slice through legs lies inside it), less
    // the band of width `rim` that the object's own silhouette lies in.
    let rim = p.rim.clamp(0.0, margin);
    let outside = |q: &Point3<f64>| {
        others
            .iter()
            .map(|&o| (b.min[o] - q[o]).max(q[o] - b.max[o]))
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let cell = |v: f64| (v / p.voxel).floor() as i64;
    let cells: HashSet<(i64, i64)> = layer
        .iter()
        .filter(|(_, q)| outside(q) > rim)
        .map(|(_, q)| (cell(q[others[0]]), cell(q[others[1]])))
        .collect();
    let n = |o: usize, m: f64| ((b.max[o] - b.min[o] + 2.0 * m) / p.voxel).max(0.0);
    let ring = n(others[0], margin) * n(others[1], margin) - n(others[0], rim) * n(others[1], rim);
    if cells.len() < p.min_points || (cells.len() as f64) < p.min_coverage * ring {
        return None;
    }
    let mut c: Vec<f64> = layer.iter().map(|(_, q)| q[axis]).collect();
    Some((median(&mut c), cells.len()))
}
