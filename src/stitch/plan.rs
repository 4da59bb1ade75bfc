//! The dynamic-stitching layout plan (paper Sec. 3.2, supplementary Algorithm 1).
//!
//! Given `n` images and a soft limit `L` on the number of stitched images, choose how many
//! grids of each candidate layout to use. Layouts are (rows, cols): (4, 1), (2, 4), (8, 2)
//! and (9, 3). Counts follow the published branches exactly; the images are then cut into
//! consecutive slices, one slice per layout in ascending size, the last slice taking the
//! rest, and each slice is cut into grids of that layout's capacity.

use serde::{Deserialize, Serialize};

/// One stitched image of the plan: a `rows` x `cols` grid holding `frames` images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct GridSpec {
    /// Rows of tiles.
    pub rows: u32,
    /// Columns of tiles.
    pub cols: u32,
    /// Number of images placed in this grid (1 ..= rows * cols), row-major order.
    pub frames: u32,
}

impl GridSpec {
    /// Number of tiles the layout can hold.
    pub fn capacity(&self) -> u32 {
        self.rows * self.cols
    }
}

/// Layout (4, 1): four rows, one column.
pub const L4: (u32, u32) = (4, 1);
/// Layout (2, 4): two rows, four columns.
pub const L8: (u32, u32) = (2, 4);
/// Layout (8, 2): eight rows, two columns.
pub const L16: (u32, u32) = (8, 2);
/// Layout (9, 3): nine rows, three columns.
pub const L27: (u32, u32) = (9, 3);

/// Default soft limit on stitched images per request (paper: L = 6).
pub const DEFAULT_LIMIT: usize = 6;

/// Ceiling of `a / b` for a possibly negative `a` and positive `b` (as Python's `math.ceil`).
fn ceil_div(a: i64, b: i64) -> i64 {
    a.div_euclid(b) + i64::from(a.rem_euclid(b) != 0)
}

/// Cut `n` images into grids of `layout`, appending to `out`.
fn stitch_slice(n: i64, layout: (u32, u32), out: &mut Vec<GridSpec>) {
    let cap = i64::from(layout.0 * layout.1);
    let mut left = n.max(0);
    while left > 0 {
        let k = left.min(cap);
        out.push(GridSpec {
            rows: layout.0,
            cols: layout.1,
            frames: k as u32,
        });
        left -= k;
    }
}

/// Cut `n` images into consecutive slices of the given layouts. Every slice but the last
/// holds `4 * count` / `8 * count` / ... images (clamped to what is left); the last slice
/// takes all remaining images.
fn stitch_slices(n: i64, parts: &[((u32, u32), i64)], out: &mut Vec<GridSpec>) {
    let mut left = n;
    for (i, &(layout, count)) in parts.iter().enumerate() {
        let take = if i + 1 == parts.len() {
            left
        } else {
            (count.max(0) * i64::from(layout.0 * layout.1)).min(left)
        };
        stitch_slice(take, layout, out);
        left -= take;
    }
}

/// The layout plan for `n` images under soft limit `limit` (a limit of 0 is treated as 1).
///
/// Returns one [`GridSpec`] per stitched image, in the order the images fill them:
/// grid `i` holds the `frames` images following those of grids `0..i`.
pub fn plan(n: usize, limit: usize) -> Vec<GridSpec> {
    let mut out = Vec::new();
    plan_into(n as i64, limit.max(1) as i64, &mut out);
    out
}

fn plan_into(n: i64, l: i64, out: &mut Vec<GridSpec>) {
    if n <= 0 {
        return;
    }
    if n <= 4 * l {
        // (4, 1) alone is enough.
        stitch_slice(n, L4, out);
    } else if n <= 8 * l {
        // At least one (2, 4).
        let n8 = ceil_div(n - 4 * l, 4);
        let n4 = l - n8;
        stitch_slices(n, &[(L4, n4), (L8, n8)], out);
    } else if n <= 16 * l {
        // At least one (8, 2).
        let n16 = ceil_div(n - 8 * l, 8);
        let rest = (n - 16 * n16).max(0);
        let n48 = l - n16;
        let n8 = ceil_div(rest - 4 * n48, 4);
        let n4 = n48 - n8;
        stitch_slices(n, &[(L4, n4), (L8, n8), (L16, n16)], out);
    } else if n <= 27 * l {
        // At least one (9, 3).
        let n27 = ceil_div(n - 16 * l, 11);
        let n4816 = l - n27;
        let rest = (n - 27 * n27).max(0);
        let n16 = ceil_div(rest - 8 * n4816, 8);
        let n48 = n4816 - n16;
        let rest = (rest - 16 * n16).max(0);
        let n8 = ceil_div(rest - 4 * n48, 4);
        let n4 = n48 - n8;
        stitch_slices(n, &[(L4, n4), (L8, n8), (L16, n16), (L27, n27)], out);
    } else {
        // Beyond the soft limit: full (9, 3) grids first, then the rest with L = 1.
        let n27 = n / 27;
        stitch_slice(27 * n27, L27, out);
        plan_into(n - 27 * n27, 1, out);
    }
}

/// Start index (into the image sequence) of each grid of a plan.
pub fn grid_starts(specs: &[GridSpec]) -> Vec<usize> {
    let mut acc = 0usize;
    specs
        .iter()
        .map(|s| {
            let start = acc;
            acc += s.frames as usize;
            start
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ceil_div_matches_python() {
        assert_eq!(ceil_div(7, 4), 2);
        assert_eq!(ceil_div(8, 4), 2);
        assert_eq!(ceil_div(0, 4), 0);
        assert_eq!(ceil_div(-3, 4), 0);
        assert_eq!(ceil_div(-4, 4), -1);
        assert_eq!(ceil_div(-5, 4), -1);
    }
}
