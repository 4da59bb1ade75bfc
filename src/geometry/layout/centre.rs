//! Centring a wall found from outside the room on its densest readings.

use super::{spread, LayoutParams};

/// Width (m) of the run a wall is centred on: half the 3 cm between a wall and a picture on
/// it, so that the two stay apart, yet holding hundreds of the wall's readings.
pub(super) const MODE_WIDTH: f64 = 0.015;

/// Where a wall found about `start` is: the densest run of readings no wider than
/// [`MODE_WIDTH`] within the layer's thickness of it that spreads along the room as a wall
/// does (`min_spread`; a door's face by its wall is denser and narrower), its median.
pub(super) fn wall_centre(coord: &[f64], lateral: &[&[f64]], start: f64, p: &LayoutParams) -> f64 {
    let mut near: Vec<usize> = (0..coord.len())
        .filter(|&k| (coord[k] - start).abs() <= 3.0 * p.bin)
        .collect();
    near.sort_by(|&a, &b| coord[a].total_cmp(&coord[b]));
    let mut runs = Vec::with_capacity(near.len());
    let mut from = 0;
    for to in 0..near.len() {
        while coord[near[to]] - coord[near[from]] > MODE_WIDTH {
            from += 1;
        }
        runs.push((to + 1 - from, from, to + 1));
    }
    runs.sort_by_key(|r| std::cmp::Reverse(r.0));
    let mut tried: Vec<(usize, usize)> = Vec::new();
    for &(n, a, b) in &runs {
        if n < p.min_points || tried.len() >= 4 {
            break;
        }
        if tried.iter().any(|&(x, y)| a < y && x < b) {
            continue;
        }
        tried.push((a, b));
        let run = &near[a..b];
        if lateral
            .iter()
            .all(|l| spread(run.iter().map(|&k| l[k]).collect()) >= p.min_spread)
        {
            return coord[run[run.len() / 2]];
        }
    }
    start
}
