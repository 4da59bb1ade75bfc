//! Pieces of the object that a nearer surface cuts off from its chosen surface in the image.

use super::{same_hue, DepthSegmenter, Grid};

/// Fewest cells a cut-off piece must hold (and at least this share of the region's).
const MIN_CELLS: usize = 4;
const MIN_SHARE: f64 = 0.02;
/// Most a piece's brightness may differ from the region's (as a factor): neutral colours
/// (grey, black, white) share one hue, and a grey chair's dark table is not the chair.
const MAX_SHADE: f64 = 1.5;
/// How far (depth pixels) an occluder may lie from what it hides: a sensor reads no depth
/// along much of an edge between surfaces at different depths.
const GAP_PX: f64 = 3.0;

impl DepthSegmenter {
    /// `region` (the object's surface, after [`Self::main_components`]) with the pieces of
    /// the object that something nearer splits off from it in the image: a chair pushed
    /// behind a table shows its back above the table top and its legs below it, and no
    /// growth crosses the table between them, so every view of it keeps only the back and
    /// the box comes out a few centimetres deep. A piece is a surface (4-connected cells
    /// whose depths differ by at most a growth step)
    /// - within the region's own extent (its height span or its width, the larger) nearer
    ///   than the region's depths, and no farther than them by more than a growth step:
    ///   another object of that colour stands farther away, and so does the room behind
    ///   the object (a wall of its colour), while what an occluder hides of it lies no
    ///   deeper than what shows;
    /// - at least nine in ten of them in the box and none on the frame's edge (`size`), as
    ///   for [`Self::with_parts`], not lying flat ([`Self::lies_flat`]: a floor of the
    ///   object's colour), and of at least `MIN_CELLS` cells and `MIN_SHARE` of the region;
    /// - of the region's colour more strictly than growth takes it (its hue at half
    ///   `colour_tol`, its brightness within a factor `MAX_SHADE`), as nothing but colour
    ///   vouches for a piece across an occluder;
    /// - not touching the region: there growth refused it across a depth step;
    /// - bordering (within `GAP_PX`, where depth is often missing) a surface of another
    ///   colour nearer than itself by a growth step, a surface that also borders the region
    ///   nearer than it by a step: one occluder hides what lies between them. A surface of
    ///   the object's own colour is never taken for that occluder, so a grey table before a
    ///   grey chair joins nothing.
    pub(super) fn with_hidden_parts(
        &self,
        g: &Grid,
        region: &[bool],
        cell_px: f64,
        fx_depth: f64,
        size: (u32, u32),
    ) -> Vec<bool> {
        let cells: Vec<usize> = (0..region.len())
            .filter(|&i| region[i] && g.inb[i] && g.z[i] > 0.0)
            .collect();
        let mut out = region.to_vec();
        if cells.len() < MIN_CELLS {
            return out;
        }
        let step = |z: f64| (self.step_abs + self.step_rel * z) * cell_px.max(1.0);
        let (mut zlo, mut zhi) = (f64::INFINITY, 0.0f64);
        let (mut hlo, mut hhi) = (f64::INFINITY, f64::NEG_INFINITY);
        let (mut xlo, mut xhi) = (usize::MAX, 0);
        let mut zs = Vec::with_capacity(cells.len());
        for &i in &cells {
            zlo = zlo.min(g.z[i]);
            zhi = zhi.max(g.z[i]);
            hlo = hlo.min(g.height[i]);
            hhi = hhi.max(g.height[i]);
            xlo = xlo.min(i % g.w);
            xhi = xhi.max(i % g.w + 1);
            zs.push(g.z[i]);
        }
        let zmid = crate::geometry::cloud::median(&mut zs);
        let width = (xhi - xlo) as f64 * cell_px * zmid / fx_depth.max(1.0);
        let ext = (hhi - hlo).max(width);
        let mut mid = [0.0f64; 3];
        for (c, m) in mid.iter_mut().enumerate() {
            let mut v: Vec<f64> = cells.iter().map(|&i| f64::from(g.rgb[i][c])).collect();
            *m = crate::geometry::cloud::median(&mut v);
        }
        let bright = |i: usize| g.rgb[i].iter().map(|&v| f64::from(v)).sum::<f64>();
        let lum: f64 = mid.iter().sum();
        let like: Vec<bool> = (0..region.len())
            .map(|i| {
                !region[i]
                    && g.z[i] > 0.0
                    && (zlo - ext..=zhi + step(zhi)).contains(&g.z[i])
                    && same_hue(&mid, &g.rgb[i], self.colour_tol / 2.0)
                    && bright(i) <= MAX_SHADE * lum
                    && lum <= MAX_SHADE * bright(i)
            })
            .collect();
        // The cells within the gap of cell `i`.
        let r = (GAP_PX / cell_px.max(1e-6)).ceil().max(1.0) as usize;
        let around = |i: usize| {
            let (x, y) = (i % g.w, i / g.w);
            let xs = x.saturating_sub(r)..(x + r + 1).min(g.w);
            (y.saturating_sub(r)..(y + r + 1).min(g.h))
                .flat_map(move |y| xs.clone().map(move |x| y * g.w + x))
        };
        // The cells within the gap of the region's outline.
        let mut by_region = vec![false; region.len()];
        let outline = (0..region.len())
            .filter(|&i| region[i] && g.neighbours(i).into_iter().flatten().any(|j| !region[j]));
        for i in outline {
            around(i).for_each(|j| by_region[j] = true);
        }
        // The occluders: the surfaces of another colour that are nearer than a region cell
        // within the gap by a step somewhere, grown from those cells.
        let other = |i: usize| !region[i] && g.z[i] > 0.0 && !like[i];
        let before = |o: usize| {
            let near = |r: usize| region[r] && g.z[o] < g.z[r] - step(g.z[r]);
            by_region[o] && other(o) && around(o).any(near)
        };
        let mut hiding = vec![false; region.len()];
        let mut queue: Vec<usize> = (0..region.len()).filter(|&o| before(o)).collect();
        if queue.is_empty() {
            return out;
        }
        queue.iter().for_each(|&o| hiding[o] = true);
        while let Some(i) = queue.pop() {
            for j in g.neighbours(i).into_iter().flatten() {
                if !hiding[j] && other(j) && (g.z[i] - g.z[j]).abs() <= step(g.z[i].min(g.z[j])) {
                    hiding[j] = true;
                    queue.push(j);
                }
            }
        }
        let s = g.s as usize;
        let on_edge = |i: usize| {
            let (x, y) = (g.x0 as usize + (i % g.w) * s, g.y0 as usize + (i / g.w) * s);
            x == 0 || y == 0 || x + s >= size.0 as usize || y + s >= size.1 as usize
        };
        let least = MIN_CELLS.max((MIN_SHARE * cells.len() as f64).ceil() as usize);
        for piece in surfaces(g, |i| like[i], &step) {
            let outside = piece.iter().filter(|&&i| !g.inb[i]).count();
            // A piece the region touches is a surface growth refused across a depth
            // step (a chair's back before a cabinet of its colour), not one an occluder
            // cut off.
            let touches = |i: usize| g.neighbours(i).into_iter().flatten().any(|j| region[j]);
            if piece.len() < least
                || outside * 10 > piece.len()
                || piece.iter().any(|&i| on_edge(i) || touches(i))
            {
                continue;
            }
            let hidden = piece
                .iter()
                .any(|&p| around(p).any(|o| hiding[o] && g.z[o] < g.z[p] - step(g.z[p])));
            if !hidden {
                continue;
            }
            let mut cut = vec![false; region.len()];
            piece.iter().for_each(|&i| cut[i] = true);
            if !Self::lies_flat(g, &cut) {
                piece.iter().for_each(|&i| out[i] = true);
            }
        }
        out
    }
}

/// The 4-connected surfaces of the cells for which `member` holds: neighbours join when
/// their depths differ by at most `step` of the nearer's.
fn surfaces(
    g: &Grid,
    member: impl Fn(usize) -> bool,
    step: &dyn Fn(f64) -> f64,
) -> Vec<Vec<usize>> {
    g.joined(member, |i, j| {
        let (a, b) = (g.z[i], g.z[j]);
        (a - b).abs() <= step(a.min(b))
    })
}
