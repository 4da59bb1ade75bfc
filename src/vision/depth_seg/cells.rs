//! Operations on a grid region: its extent in the box, its main components, and the
//! edge creases and holes closed after growth.

use super::{DepthSegmenter, Grid};
use crate::geometry::cloud::median;

impl DepthSegmenter {
    /// Share of the box that the bounding rectangle of the region's in-box cells covers
    /// (1 when the surface reaches all four box edges).
    pub(super) fn extent_fill(g: &Grid, region: &[bool]) -> f64 {
        let mut r = [usize::MAX, usize::MAX, 0, 0];
        for i in (0..region.len()).filter(|&i| region[i] && g.inb[i]) {
            let (x, y) = (i % g.w, i / g.w);
            r = [r[0].min(x), r[1].min(y), r[2].max(x + 1), r[3].max(y + 1)];
        }
        if r[0] >= r[2] {
            return 0.0;
        }
        let [bx0, by0, bx1, by1] = g.b;
        ((r[2] - r[0]) * (r[3] - r[1])) as f64 / ((bx1 - bx0) * (by1 - by0)).max(1) as f64
    }

    /// The region runs on past the box's margin: on some side where the grid reaches past
    /// the box (not cut by the image's edge), its cells on the grid's outermost line there
    /// cover at least a quarter of the box's length along that side. A tight box ends
    /// within a few pixels of its object, so a surface that continues a whole margin beyond
    /// it along much of an edge is what lies behind or beside the object (the wall behind a
    /// floor lamp's pole), or the object run together with it.
    pub(super) fn runs_past_margin(g: &Grid, region: &[bool]) -> bool {
        let [bx0, by0, bx1, by1] = g.b;
        let along = |len: usize| (len / 4).max(1);
        let column = |x: usize| (0..g.h).filter(|&y| region[y * g.w + x]).count();
        let row = |y: usize| (0..g.w).filter(|&x| region[y * g.w + x]).count();
        (bx0 > 0 && column(0) >= along(by1 - by0))
            || (bx1 < g.w && column(g.w - 1) >= along(by1 - by0))
            || (by0 > 0 && row(0) >= along(bx1 - bx0))
            || (by1 < g.h && row(g.h - 1) >= along(bx1 - bx0))
    }

    /// The winning surface `won` runs on past the box's margin (the caller checked): the
    /// best-scoring surface that ends within the margin and scores at least half as well
    /// (the factor given to a surface mostly outside the box), among:
    /// - the strong modes' surfaces already scored (`strong`) that lie behind `won` (median
    ///   depth in the box): `won` is an occluder before the object covering much of its box
    ///   (a table top before a chair's back), and it hides part of the object's extent;
    /// - those that lie before `won` only when they explain the box by themselves
    ///   ([`Self::group_below`]): nothing hides them, so the object in front of a
    ///   background fills its box, while a nearer surface that fills only part of the box
    ///   is an occluder of `won` (a chair pushed up to a desk that runs into the wall);
    /// - the surfaces of the `weak` modes, wherever they lie: a thin object seen along its
    ///   length (a floor lamp's pole from above) spreads over many depth bins and never
    ///   makes a strong mode, and `won` is then the background behind it;
    /// - what the box's central part holds besides `won` ([`Self::rest_surface`]), for a
    ///   pole whose depth spreads so far that it makes no weak mode either; before `won`,
    ///   on the strong modes' terms, and not when a strong mode's surface already holds
    ///   most of it (a chair under a desk: it was weighed above).
    pub(super) fn ended_surface(
        &self,
        g: &Grid,
        won: &(f64, Vec<bool>),
        strong: &[(f64, Vec<bool>)],
        weak: &[f64],
        cell_px: f64,
        score: &dyn Fn(&[bool], f64) -> f64,
    ) -> Option<(f64, Vec<bool>)> {
        let mut found: Option<(f64, Vec<bool>)> = None;
        let mut offer = |sc: f64, region: &[bool]| {
            let bar = found.as_ref().map_or(won.0 * 0.5, |(s, _)| *s);
            if sc > bar + 1e-9 && !Self::runs_past_margin(g, region) {
                found = Some((sc, region.to_vec()));
            }
        };
        let front = Self::median_depth(g, &won.1);
        for (sc, region) in strong {
            if Self::median_depth(g, region) > front || *sc >= self.group_below {
                offer(*sc, region);
            }
        }
        for &m in weak {
            let (region, outside) = self.surface(g, m, cell_px);
            offer(score(&region, outside), &region);
        }
        if self.prefer_within {
            // As a strong mode's: before `won`, it must explain the box by itself. What a
            // strong mode's surface already holds for the most part had its chance above.
            if let Some((region, outside)) = self.rest_surface(g, &won.1, cell_px) {
                let sc = score(&region, outside);
                let cells = region.iter().filter(|&&b| b).count();
                let grown = strong.iter().any(|(_, r)| {
                    2 * r.iter().zip(&region).filter(|(a, b)| **a && **b).count() >= cells
                });
                if !grown && (Self::median_depth(g, &region) > front || sc >= self.group_below) {
                    offer(sc, &region);
                }
            }
        }
        found
    }

    /// Median depth of the region's cells in the box (0 without any).
    fn median_depth(g: &Grid, region: &[bool]) -> f64 {
        let mut z: Vec<f64> = (0..region.len())
            .filter(|&i| region[i] && g.inb[i] && g.z[i] > 0.0)
            .map(|i| g.z[i])
            .collect();
        median(&mut z)
    }

    /// `region` with the parts of the object that the growth across the larger step
    /// (`grouped`) reached: each connected piece it adds is kept when nine in ten of its
    /// cells lie inside the box and none on the frame's edge (`size`: the image's). A tight
    /// box holds all of its object, while what stands beside, behind or under it across
    /// such a step (the wall around a window, the floor under a chair) runs on past the
    /// box, or past the frame where the box reaches it. None when no piece is kept.
    pub(super) fn with_parts(
        g: &Grid,
        region: &[bool],
        grouped: &[bool],
        size: (u32, u32),
    ) -> Option<Vec<bool>> {
        let mut out = region.to_vec();
        let mut any = false;
        for piece in g.components(|i| grouped[i] && !region[i]) {
            let outside = piece.iter().filter(|&&i| !g.inb[i]).count();
            if outside * 10 <= piece.len()
                && !piece.iter().any(|&i| g.frame_edges(i, size) != [false; 4])
            {
                piece.iter().for_each(|&i| out[i] = true);
                any = true;
            }
        }
        any.then_some(out)
    }

    /// What the growth across the larger step (`grouped`) reaches before a background
    /// (`region`, a surface that ran on past the box's margin), without the background:
    /// each piece it adds that lies nine in ten inside the box, nearer than the background
    /// (median depth in the box), and meets the frame's edge only on sides where the box
    /// `bbox` meets it too (`size`: the image's), as a region of its own. One object is one
    /// piece; scored together, the bits of a window's frame before its glass would span
    /// the box that none of them fills. A close-up of a floor lamp whose box runs
    /// from the frame's top, which cuts its shade, to its foot at the bottom is one such
    /// piece before the wall: its parts lie too far apart in depth for one surface, and
    /// grown from the shade across the larger step they run on over the floor into the
    /// walls. Where the box meets the frame, the object is cut there as well, so meeting
    /// that edge says nothing against a piece.
    pub(super) fn before_background(
        g: &Grid,
        region: &[bool],
        grouped: &[bool],
        bbox: [f32; 4],
        size: (u32, u32),
    ) -> Vec<Vec<bool>> {
        let tol = g.s as f32;
        let (w, h) = (size.0 as f32, size.1 as f32);
        let box_meets = [
            bbox[0] <= tol,
            bbox[1] <= tol,
            bbox[2] >= w - tol,
            bbox[3] >= h - tol,
        ];
        let behind = Self::median_depth(g, region);
        let mut out = Vec::new();
        for piece in g.components(|i| grouped[i] && !region[i]) {
            let outside = piece.iter().filter(|&&i| !g.inb[i]).count();
            let meets_only_with_box = piece.iter().all(|&i| {
                let e = g.frame_edges(i, size);
                (0..4).all(|k| !e[k] || box_meets[k])
            });
            let mut z: Vec<f64> = piece
                .iter()
                .filter(|&&i| g.inb[i] && g.z[i] > 0.0)
                .map(|&i| g.z[i])
                .collect();
            let nearer = !z.is_empty() && median(&mut z) < behind;
            if outside * 10 <= piece.len() && meets_only_with_box && nearer {
                let mut alone = vec![false; region.len()];
                piece.iter().for_each(|&i| alone[i] = true);
                out.push(alone);
            }
        }
        out
    }

    /// Is what colour took away from the depth-grown `region` (cells of `region` not in
    /// `coloured`) mostly a neighbour running in from outside the box? At least half of
    /// the removed in-box cells must connect, through removed cells, to removed cells
    /// outside the box. A face of the object itself shaded differently lies inside the box
    /// and is not a leak.
    pub(super) fn colour_drops_a_leak(g: &Grid, region: &[bool], coloured: &[bool]) -> bool {
        let removed = |i: usize| region[i] && !coloured[i];
        let mut seen = vec![false; region.len()];
        let mut queue: std::collections::VecDeque<usize> = (0..region.len())
            .filter(|&i| removed(i) && !g.inb[i])
            .collect();
        queue.iter().for_each(|&i| seen[i] = true);
        while let Some(i) = queue.pop_front() {
            for j in g.neighbours(i).into_iter().flatten() {
                if !seen[j] && removed(j) {
                    seen[j] = true;
                    queue.push_back(j);
                }
            }
        }
        let inside: Vec<usize> = (0..region.len())
            .filter(|&i| removed(i) && g.inb[i])
            .collect();
        let reached = inside.iter().filter(|&&i| seen[i]).count();
        2 * reached >= inside.len()
    }

    /// Does the band of `cut` cells lie flat like a floor or a table top, rather than stand
    /// upright like the object's own lower side? Down each column of the box, a surface
    /// lying flat recedes from the camera while its height stays; an upright side rises
    /// while its distance stays. A small object seen from the side (a cup on a shelf at eye
    /// level) fills most of its box's rows with its lowest few centimetres, and no support
    /// is seen at all when the camera is below it.
    pub(super) fn lies_flat(g: &Grid, cut: &[bool]) -> bool {
        let [bx0, by0, bx1, by1] = g.b;
        let (mut rise, mut recede) = (0.0, 0.0);
        for x in bx0..bx1 {
            let mut h = (f64::INFINITY, f64::NEG_INFINITY);
            let mut r = h;
            for i in (by0..by1).map(|y| y * g.w + x).filter(|&i| cut[i]) {
                h = (h.0.min(g.height[i]), h.1.max(g.height[i]));
                r = (r.0.min(g.reach[i]), r.1.max(g.reach[i]));
            }
            if h.0 < h.1 {
                rise += h.1 - h.0;
                recede += r.1 - r.0;
            }
        }
        recede > rise
    }

    /// Keep the largest 4-connected component of the in-box cells of `region`, and any
    /// other that holds at least half as many cells and either is of its colour (mean RGB
    /// within `colour_tol`, summed over the channels) or lies wholly within the box (the
    /// grown surface it belongs to does not leave the box). Stray bits go; one surface
    /// split by something before it (the panes of a window either side of its mullion)
    /// stays whole; and a part of another colour at the object's depth that nothing joins
    /// to the room outside the box (a plant's pot below its foliage, the stem too thin to
    /// resolve) is the object's, as the box around both says, not a neighbour's.
    pub(super) fn main_components(g: &Grid, region: &[bool], colour_tol: f64) -> Vec<bool> {
        // Cells whose grown piece reaches outside the box.
        let mut leaves = vec![false; region.len()];
        for piece in g.components(|i| region[i]) {
            if piece.iter().any(|&i| !g.inb[i]) {
                piece.iter().for_each(|&i| leaves[i] = true);
            }
        }
        let comps: Vec<(Vec<usize>, [f64; 3])> = g
            .components(|i| region[i] && g.inb[i])
            .into_iter()
            .map(|cells| {
                let mut rgb = [0.0; 3];
                for &i in &cells {
                    for (c, v) in rgb.iter_mut().zip(g.rgb[i]) {
                        *c += f64::from(v);
                    }
                }
                let n = cells.len() as f64;
                (cells, rgb.map(|c| c / n))
            })
            .collect();
        let largest = (0..comps.len()).max_by_key(|&k| (comps[k].0.len(), std::cmp::Reverse(k)));
        let mut out = vec![false; region.len()];
        let Some(top) = largest else {
            return out;
        };
        let (top_n, top_mean) = (comps[top].0.len(), comps[top].1);
        for (k, (cells, mean)) in comps.iter().enumerate() {
            let near: f64 = mean.iter().zip(top_mean).map(|(a, b)| (a - b).abs()).sum();
            let enclosed = !cells.iter().any(|&i| leaves[i]);
            if k == top || (2 * cells.len() >= top_n && (near <= colour_tol || enclosed)) {
                cells.iter().for_each(|&i| out[i] = true);
            }
        }
        out
    }

    /// Edge cells with the region on two opposite sides are a crease inside the object (a
    /// seat's front over its legs), not its outline: they join.
    pub(super) fn close_edges(g: &Grid, region: &mut [bool]) {
        let snapshot = region.to_vec();
        let (w, h) = (g.w, g.h);
        for i in (0..region.len()).filter(|&i| g.edge[i] && !snapshot[i] && g.inb[i]) {
            let (x, y) = (i % w, i / w);
            if (x > 0 && x + 1 < w && snapshot[i - 1] && snapshot[i + 1])
                || (y > 0 && y + 1 < h && snapshot[i - w] && snapshot[i + w])
            {
                region[i] = true;
            }
        }
    }

    /// Close small holes: depth-less cells with at least 3 region neighbours, or whose colour
    /// is close to the region's mean colour and touch it.
    pub(super) fn fill_holes(g: &Grid, region: &mut [bool]) {
        let n = region.iter().filter(|&&b| b).count().max(1) as f64;
        let mut mean = [0.0f64; 3];
        for i in (0..region.len()).filter(|&i| region[i]) {
            for (m, &v) in mean.iter_mut().zip(&g.rgb[i]) {
                *m += f64::from(v) / n;
            }
        }
        for _ in 0..3 {
            let snapshot = region.to_vec();
            for i in 0..region.len() {
                if snapshot[i] || g.z[i] > 0.0 || !g.inb[i] {
                    continue;
                }
                let k = g
                    .neighbours(i)
                    .into_iter()
                    .flatten()
                    .filter(|&j| snapshot[j])
                    .count();
                let dc: f64 = (0..3).map(|c| (g.rgb[i][c] as f64 - mean[c]).abs()).sum();
                if k >= 3 || (k >= 1 && dc < 45.0) {
                    region[i] = true;
                }
            }
        }
    }
}

/// Same surface colour under different light: the chromaticities (each channel's share
/// of the sum) differ by at most `tol / 765` in sum, and the brightness by at most a
/// factor of 4 (a face turned from the light). Near-black colours (sum under 45) carry no
/// reliable hue: they match each other.
pub(crate) fn same_hue(mid: &[f64; 3], c: &[u8; 3], tol: f64) -> bool {
    let (sm, sc) = (
        mid.iter().sum::<f64>(),
        c.iter().map(|&v| f64::from(v)).sum::<f64>(),
    );
    const DARK: f64 = 45.0;
    if sm < DARK || sc < DARK {
        return sm < DARK && sc < DARK;
    }
    if sc > 4.0 * sm || sm > 4.0 * sc {
        return false;
    }
    let d: f64 = mid
        .iter()
        .zip(c)
        .map(|(m, &v)| (m / sm - f64::from(v) / sc).abs())
        .sum();
    d <= tol / 765.0 * 3.0
}
