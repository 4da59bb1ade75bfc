//! Model-free box → mask for posed RGB-D frames.
//!
//! Inside the box: (1) a depth histogram, weighted towards the box centre, gives the surface
//! modes. (2) For each strong mode from near to far, seeds at that depth in the central part
//! of the box grow over 4-neighbours (also a little beyond the box) while the depth step
//! stays under a noise- and distance-dependent limit; when that surface runs past the box
//! (an object against a wall), it is grown again with the seeds' colour as a second limit,
//! and when it runs past the box at all, that coloured version is scored beside it in (4)
//! (two touching objects at one depth, told apart by colour).
//! (3) Where the growth leaked onto the supporting surface (floor, table top), the points
//! within a few cm of the lowest height (gravity = the output frame's +z) are cut and the
//! growth is redone, when that band lies flat (down the box's columns it recedes from the
//! camera more than it rises) and is not the object's own upright lower side. (4) Among the
//! surfaces that stay mostly inside the box, the one whose extent fills the box best while
//! running least past its edges is the object: a tight box ends where the object ends, an
//! occluder in front covers only part of it, and the background behind runs on past it.
//! When the best of them runs on past the box's whole margin (a background behind, or an
//! occluder before: a table top over a chair's seat), a surface that ends within the
//! margin is taken instead when it scores at least half as well (the factor for a surface
//! mostly outside the box): a strong mode's that lies behind the winner (which hides part
//! of it), or before it when it explains the box by itself (else it is an occluder of the
//! winner: a chair before a desk), or one of the weaker depth modes' (a thin object seen
//! along its length, a floor lamp's pole from above, spreads over many depth bins and
//! never makes a strong mode). Strong modes whose cells a nearer mode's surface already
//! holds (a slanted table top spans several) do not count towards the four modes grown.
//! When no surface explains the box so, or the first winner ran on past the margin (a
//! background explains no box, however well it fills one: the wall around a lamp whose box
//! reaches the frame's edge), each is grown again across the larger step between the parts
//! of one object (a lamp's shade in front of its pole), keeping only the pieces that adds
//! inside the box, and not when the whole runs past the margin itself. A background's own
//! growth so also offers what it reaches before it, without it: a lamp close-up whose box
//! runs from the frame's top (cutting the shade) to its foot, where the shade's growth
//! runs on over the floor into the walls.
//! (5) Inside the box, the surface's largest piece is kept with any other piece at least half
//! its size and of its colour (a window's panes either side of its mullion), and the pieces
//! of its colour that a nearer surface cuts off from it (a chair's legs below the table top
//! that hides its seat) are added (not with `hidden=off`). Small holes (missing depth) are
//! closed and depth-less pixels whose colour matches the region are added back.

use anyhow::{bail, Result};

use super::{SegmentInput, Segmenter};
use crate::geometry::camera::transform_point;
use crate::geometry::mask::Mask;

mod cells;
mod grid;
mod growth;
mod hidden;

pub(crate) use cells::same_hue;

use grid::Grid;
use growth::Reach;

/// Parameters of the depth segmenter.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthSegmenter {
    /// Histogram bin width (m).
    pub bin: f64,
    /// A mode is strong when its centre-weighted mass is at least this fraction of the largest.
    pub strong_mode: f64,
    /// Allowed depth step between neighbouring depth pixels: `step_abs + step_rel * z` (m).
    pub step_abs: f64,
    pub step_rel: f64,
    /// Points lower than this above the region's lowest point are treated as support (m).
    pub support_band: f64,
    /// Margin around the box (fraction of its size) used to see whether a surface ends there.
    pub margin: f64,
    /// A surface with more than this fraction of its cells outside the box is not the object.
    pub max_outside: f64,
    /// Upper bound on grid cells (larger boxes are subsampled).
    pub max_cells: usize,
    /// When a surface grown on depth alone runs past the box (an object standing against a
    /// wall, the depth step between them too small), it is grown again admitting only cells
    /// whose colour is within this sum of absolute RGB differences of the seeds' median.
    pub colour_tol: f64,
    /// Do not grow into depth-edge cells (flying pixels between an object and the surface
    /// behind it; spec `depth:edges=on`). Off by default. Measured with the oracle VLM:
    /// realistic 1296x968 scenes 81.3/61.3 -> 82.0/68.0 Acc@0.25/0.5, small noise-free
    /// 320x240 scenes 0.99/0.88 -> 0.93/0.82 (one chair loses its seat in one view).
    pub block_edges: bool,
    /// Score each depth-grown surface that runs past the box beside its colour-limited
    /// version and keep the better (spec `depth:colour=off` turns it off).
    pub colour_alternative: bool,
    /// Score each surface beside the same growth across the larger step between the parts
    /// of one object (`group_step + group_per_m * z`, the candidates' group step): a floor
    /// lamp's shade stands in front of its pole by the shade's radius, so the shade alone
    /// is one surface and the pole with its foot another, neither filling the lamp's box,
    /// and a plant behind fills more of it than either (spec `depth:groups=off`).
    pub group_alternative: bool,
    /// ...only when no one surface scores this much (extent filling the box, less what
    /// runs past it): a surface that explains most of its box is the object, and joining
    /// across the larger step would add what stands beside it (a table's end by a chair).
    /// A winner that runs on past the box's margin is a background and explains no box
    /// whatever its score.
    pub group_below: f64,
    pub group_step: f64,
    pub group_per_m: f64,
    /// When the best surface runs on past the box's margin, also try the modes of at least
    /// this fraction of the largest (0 turns it off; spec `depth:weak=off`).
    pub weak_mode: f64,
    /// When the best surface runs on past the box's margin, the strong modes' surfaces that
    /// end within it compete again: at half its score behind it, at `group_below` before it
    /// (spec `depth:within=off` turns it off, and the segmenter is then the one before it).
    pub prefer_within: bool,
    /// Add the pieces of the object's colour that a nearer surface cuts off from the chosen
    /// one in the image (a chair's legs below the table top that hides its seat; spec
    /// `hidden=off` turns it off). See [`Self::with_hidden_parts`].
    pub hidden_parts: bool,
    /// When a background won, also score on its own each piece that the background's
    /// growth across the larger step reaches before it (spec `front=off` turns it off).
    /// See [`Self::before_background`].
    pub front_parts: bool,
}

impl Default for DepthSegmenter {
    fn default() -> Self {
        Self {
            bin: 0.03,
            strong_mode: 0.35,
            step_abs: 0.02,
            step_rel: 0.025,
            support_band: 0.03,
            margin: 0.12,
            max_outside: 0.35,
            max_cells: 200_000,
            colour_tol: 60.0,
            block_edges: false,
            colour_alternative: true,
            group_alternative: true,
            group_below: 0.5,
            group_step: 0.25,
            group_per_m: 0.05,
            weak_mode: 0.1,
            prefer_within: true,
            hidden_parts: true,
            front_parts: true,
        }
    }
}

impl DepthSegmenter {
    /// Options after `depth:`, comma-separated: `edges=on|off` ([`Self::block_edges`]),
    /// `colour=on|off` ([`Self::colour_alternative`]), `groups=on|off`
    /// ([`Self::group_alternative`]), `weak=on|off` ([`Self::weak_mode`]), `within=on|off`
    /// ([`Self::prefer_within`]), `hidden=on|off` ([`Self::hidden_parts`]), `front=on|off`
    /// ([`Self::front_parts`]).
    pub fn from_spec(spec: &str) -> Result<Self> {
        let mut d = Self::default();
        for part in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            match part.split_once('=').map(|(k, v)| (k.trim(), v.trim())) {
                Some(("edges", "on")) => d.block_edges = true,
                Some(("edges", "off")) => d.block_edges = false,
                Some(("colour", "on")) => d.colour_alternative = true,
                Some(("colour", "off")) => d.colour_alternative = false,
                Some(("groups", "on")) => d.group_alternative = true,
                Some(("groups", "off")) => d.group_alternative = false,
                Some(("weak", "on")) => d.weak_mode = Self::default().weak_mode,
                Some(("weak", "off")) => d.weak_mode = 0.0,
                Some(("within", "on")) => d.prefer_within = true,
                Some(("within", "off")) => d.prefer_within = false,
                Some(("hidden", "on")) => d.hidden_parts = true,
                Some(("hidden", "off")) => d.hidden_parts = false,
                Some(("front", "on")) => d.front_parts = true,
                Some(("front", "off")) => d.front_parts = false,
                _ => bail!(
                    "unknown depth segmenter option `{part}` (expected edges=on|off, \
                     colour=on|off, groups=on|off, weak=on|off, within=on|off, hidden=on|off or \
                     front=on|off)"
                ),
            }
        }
        Ok(d)
    }
}

/// How colour limits the growth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Colour {
    /// Depth alone.
    Off,
    /// Within `colour_tol` (sum of absolute RGB differences) of the seeds' median.
    Rgb,
    /// Of the seeds' hue whatever the shading ([`same_hue`]).
    Hue,
}

impl DepthSegmenter {
    fn grid(&self, input: &SegmentInput<'_>, bbox: [f32; 4]) -> Option<Grid> {
        let (cw, ch) = input.color.dimensions();
        let bx0 = bbox[0].max(0.0).floor() as u32;
        let by0 = bbox[1].max(0.0).floor() as u32;
        let bx1 = (bbox[2].ceil().max(0.0) as u32).min(cw);
        let by1 = (bbox[3].ceil().max(0.0) as u32).min(ch);
        if bx1 <= bx0 || by1 <= by0 {
            return None;
        }
        let mx = ((bx1 - bx0) as f64 * self.margin).ceil() as u32;
        let my = ((by1 - by0) as f64 * self.margin).ceil() as u32;
        let (x0, y0) = (bx0.saturating_sub(mx), by0.saturating_sub(my));
        let (x1, y1) = ((bx1 + mx).min(cw), (by1 + my).min(ch));
        let area = ((x1 - x0) * (y1 - y0)) as f64;
        // No finer than the depth image: a colour image larger than its depth map (ScanNet:
        // 1296 against 640 wide) has no more depth detail per pixel to grow over.
        let depth_stride = (cw / input.depth.width.max(1)).max(1);
        let s = ((area / self.max_cells as f64).sqrt().ceil() as u32).max(depth_stride);
        let w = ((x1 - x0) as usize).div_ceil(s as usize);
        let h = ((y1 - y0) as usize).div_ceil(s as usize);
        let cam = input.camera;
        let to_out = cam.cam_to_out();
        let eye = cam.centre();
        let n = w * h;
        let (mut z, mut height, mut reach, mut rgb, mut inb) = (
            vec![0.0; n],
            vec![0.0; n],
            vec![0.0; n],
            vec![[0u8; 3]; n],
            vec![false; n],
        );
        let mut b = [usize::MAX, usize::MAX, 0, 0];
        for gy in 0..h {
            for gx in 0..w {
                let u = (x0 + gx as u32 * s + s / 2).min(x1 - 1);
                let v = (y0 + gy as u32 * s + s / 2).min(y1 - 1);
                let i = gy * w + gx;
                inb[i] = (bx0..bx1).contains(&u) && (by0..by1).contains(&v);
                if inb[i] {
                    b = [
                        b[0].min(gx),
                        b[1].min(gy),
                        b[2].max(gx + 1),
                        b[3].max(gy + 1),
                    ];
                }
                rgb[i] = input.color.get_pixel(u, v).0;
                let (dx, dy) = cam.depth_pixel_for_color(u as f64, v as f64);
                let d = input.depth.get(dx, dy);
                if d == 0 {
                    continue;
                }
                let zm = d as f64 / 1000.0;
                z[i] = zm;
                let p = match &cam.depth {
                    Some(k) => k.unproject(dx as f64, dy as f64, zm),
                    None => cam.color.unproject(u as f64, v as f64, zm),
                };
                let q = transform_point(&to_out, &p);
                height[i] = q.z;
                reach[i] = (q.x - eye.x).hypot(q.y - eye.y);
            }
        }
        (b[0] < b[2]).then_some(Grid {
            x0,
            y0,
            s,
            w,
            h,
            z,
            height,
            reach,
            rgb,
            inb,
            b,
            edge: vec![false; n],
        })
    }

    /// Mark the cells on depth edges: their two opposite neighbours (left/right or
    /// above/below) differ by more than one growth step. Growth never enters them, so a
    /// sensor's "flying pixels" (the two sides of an edge mixed into a depth halfway
    /// between) cannot bridge an object and the wall behind it in two small steps. The
    /// object loses its one-cell outline, which on a real sensor is mostly mixed pixels.
    ///
    /// A surface seen at a grazing angle also changes depth fast from cell to cell, and by
    /// more the coarser the image. So the gap must also exceed what a surface at
    /// `EDGE_TAN` (about 84 degrees from facing the camera) spans over two cells. At 640x480
    /// that is at most one growth step up to 5 m; at 160x120 it is two steps or more, where
    /// marking can no longer stop a bridge, and so it rarely marks anything there.
    fn mark_edges(&self, g: &mut Grid, cell_px: f64, fx_depth: f64) {
        /// Tangent of the viewing angle past which a surface's depth change counts as a step.
        const EDGE_TAN: f64 = 9.0;
        if !self.block_edges {
            return;
        }
        let (w, h) = (g.w, g.h);
        let z = &g.z;
        let mut edge = vec![false; z.len()];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let zi = z[i];
                if zi <= 0.0 {
                    continue;
                }
                let step = (self.step_abs + self.step_rel * zi) * cell_px.max(1.0);
                let footprint = zi * cell_px.max(1.0) / fx_depth.max(1.0);
                let lim = step.max(2.0 * EDGE_TAN * footprint);
                let differs =
                    |a: usize, b: usize| z[a] > 0.0 && z[b] > 0.0 && (z[a] - z[b]).abs() > lim;
                edge[i] = (x > 0 && x + 1 < w && differs(i - 1, i + 1))
                    || (y > 0 && y + 1 < h && differs(i - w, i + w));
            }
        }
        g.edge = edge;
    }

    /// Every mode of the centre-weighted depth histogram, near to far: its depth and its
    /// mass as a share of the largest.
    fn modes(&self, g: &Grid) -> Vec<(f64, f64)> {
        let valid: Vec<f64> = (0..g.z.len())
            .filter(|&i| g.inb[i] && g.z[i] > 0.0)
            .map(|i| g.z[i])
            .collect();
        if valid.is_empty() {
            return Vec::new();
        }
        let zmin = valid.iter().copied().fold(f64::INFINITY, f64::min);
        let zmax = valid.iter().copied().fold(0.0, f64::max);
        let nb = (((zmax - zmin) / self.bin).floor() as usize + 1).min(2000);
        let mut hist = vec![0.0; nb];
        let [bx0, by0, bx1, by1] = g.b;
        let (cx, cy) = ((bx0 + bx1) as f64 / 2.0, (by0 + by1) as f64 / 2.0);
        let (sx, sy) = (
            ((bx1 - bx0) as f64 * 0.35).max(1.0),
            ((by1 - by0) as f64 * 0.35).max(1.0),
        );
        for i in (0..g.z.len()).filter(|&i| g.inb[i] && g.z[i] > 0.0) {
            let (gx, gy) = ((i % g.w) as f64 + 0.5, (i / g.w) as f64 + 0.5);
            let (dx, dy) = ((gx - cx) / sx, (gy - cy) / sy);
            hist[(((g.z[i] - zmin) / self.bin) as usize).min(nb - 1)] +=
                (-0.5 * (dx * dx + dy * dy)).exp();
        }
        let k = [1.0, 2.0, 3.0, 2.0, 1.0];
        let sm: Vec<f64> = (0..nb)
            .map(|i| {
                (0..5)
                    .filter_map(|j| {
                        (i + j)
                            .checked_sub(2)
                            .filter(|&t| t < nb)
                            .map(|t| hist[t] * k[j])
                    })
                    .sum()
            })
            .collect();
        let peak = sm.iter().copied().fold(0.0, f64::max);
        let is_mode =
            |i: usize| (i == 0 || sm[i] >= sm[i - 1]) && (i + 1 == nb || sm[i] > sm[i + 1]);
        (0..nb)
            .filter(|&i| is_mode(i) && peak > 0.0)
            .map(|i| (zmin + (i as f64 + 0.5) * self.bin, sm[i] / peak))
            .collect()
    }
}

impl Segmenter for DepthSegmenter {
    fn name(&self) -> String {
        "depth".into()
    }

    fn segment(&self, input: &SegmentInput<'_>, bbox: [f32; 4]) -> Result<Mask> {
        let (cw, ch) = input.color.dimensions();
        if input.camera.color.width != cw || input.camera.color.height != ch {
            bail!(
                "colour image is {cw}x{ch} but the camera says {}x{}",
                input.camera.color.width,
                input.camera.color.height
            );
        }
        if input.depth.data.len() != input.depth.width as usize * input.depth.height as usize {
            bail!(
                "depth buffer does not match its {}x{} size",
                input.depth.width,
                input.depth.height
            );
        }
        let Some(mut g) = self.grid(input, bbox) else {
            return Ok(Mask::new(cw, ch));
        };
        let all_modes = self.modes(&g);
        let modes: Vec<f64> = all_modes
            .iter()
            .filter(|(_, share)| *share >= self.strong_mode)
            .map(|&(z, _)| z)
            .collect();
        if modes.is_empty() {
            // no depth at all in the box: the box is the best guess
            return Ok(Mask::from_box(cw, ch, bbox));
        }
        let cell_px = g.s as f64 * input.depth.width as f64 / cw as f64;
        let fx_depth = match &input.camera.depth {
            Some(k) => k.fx,
            None => input.camera.color.fx * input.depth.width as f64 / cw as f64,
        };
        self.mark_edges(&mut g, cell_px, fx_depth);
        // Each strong mode's surface is scored by how well it explains a tight box: its
        // extent inside the box should fill the box (an occluder covering part of it does
        // not) and it should stop at the box edges (a wall behind runs on past them).
        // With `colour_alternative`, each surface grown on depth alone that runs past the box
        // at all is scored beside the same surface grown with the seeds' colour too, when
        // what colour removes is mostly a neighbour running in from outside the box: two
        // touching objects at one depth (pillows side by side) are one surface to depth, and
        // the coloured one then stops at the box as tightly while running past it less.
        // With `group_alternative`, when no surface scores `group_below`, each is also
        // scored grown across the step between the parts of one object (a lamp's shade
        // with the pole and foot behind it): the pieces it adds that lie in the box
        // ([`Self::with_parts`]).
        let mut best: Option<(f64, Vec<bool>)> = None;
        let score = |region: &[bool], outside: f64| {
            Self::extent_fill(&g, region)
                * (1.0 - outside)
                * if outside <= self.max_outside {
                    1.0
                } else {
                    0.5
                }
        };
        let mut plain = Vec::with_capacity(4);
        let mut scored = Vec::with_capacity(8);
        // Four surfaces near to far; a mode whose cells a nearer mode's surface already
        // holds (a slanted table top spans several) is grown too but not counted, up to 8.
        let mut distinct = 0;
        for &m in &modes {
            if distinct == 4 || plain.len() == 8 {
                break;
            }
            if !(self.prefer_within && Self::mode_grown(&g, m, &plain)) {
                distinct += 1;
            }
            let (region, outside) = self.surface(&g, m, cell_px);
            let mut cands = Vec::with_capacity(2);
            if self.colour_alternative && outside > 0.0 {
                let (coloured, out_c) =
                    self.surface_with(&g, m, cell_px, Colour::Hue, Reach::Surface);
                if Self::colour_drops_a_leak(&g, &region, &coloured) {
                    cands.push((score(&coloured, out_c), coloured));
                }
            }
            cands.insert(0, (score(&region, outside), region.clone()));
            for (sc, region) in cands {
                if best.as_ref().is_none_or(|(s, _)| sc > *s + 1e-9) {
                    best = Some((sc, region.clone()));
                }
                scored.push((sc, region));
            }
            plain.push((m, region));
        }
        // A background or an occluder won: a surface that ends within the margin may be
        // the object (a chair's back above the table before it; a thin object's weak mode).
        let past = best
            .as_ref()
            .is_some_and(|(_, r)| Self::runs_past_margin(&g, r));
        let background = self.prefer_within && past;
        if let Some(won) = best.as_ref().filter(|_| past) {
            let weak: Vec<f64> = all_modes
                .iter()
                .filter(|(_, share)| (self.weak_mode..self.strong_mode).contains(share))
                .take(if self.weak_mode > 0.0 { 4 } else { 0 })
                .map(|&(m, _)| m)
                .collect();
            let strong = if self.prefer_within { &scored[..] } else { &[] };
            if let Some(found) = self.ended_surface(&g, won, strong, &weak, cell_px, &score) {
                best = Some(found);
            }
        }
        // Parts are joined only when no one surface explains the box; a surface that ran
        // past the margin is a background and explains none, even when it fills the box
        // well enough to score above the bar (the box reaching the frame's edge leaves it
        // little margin to run into).
        let unexplained = background || best.as_ref().is_none_or(|(s, _)| *s < self.group_below);
        if self.group_alternative && unexplained {
            for (m, region) in plain {
                let (grouped, _) = self.surface_with(&g, m, cell_px, Colour::Off, Reach::Group);
                // A background's own growth across the step reaches what stands before it.
                if self.front_parts && background && Self::runs_past_margin(&g, &region) {
                    for front in Self::before_background(&g, &region, &grouped, bbox, (cw, ch)) {
                        let sc = score(&front, g.outside_share(&front));
                        if best.as_ref().is_none_or(|(s, _)| sc > *s + 1e-9) {
                            best = Some((sc, front));
                        }
                    }
                }
                if let Some(whole) = Self::with_parts(&g, &region, &grouped, (cw, ch)) {
                    // What was set aside for running past the margin does not come back
                    // joined to another surface.
                    if background && Self::runs_past_margin(&g, &whole) {
                        continue;
                    }
                    let sc = score(&whole, g.outside_share(&whole));
                    if best.as_ref().is_none_or(|(s, _)| sc > *s + 1e-9) {
                        best = Some((sc, whole));
                    }
                }
            }
        }
        let Some((_, region)) = best else {
            return Ok(Mask::from_box(cw, ch, bbox));
        };
        let mut region = Self::main_components(&g, &region, self.colour_tol);
        if self.hidden_parts {
            region = self.with_hidden_parts(&g, &region, cell_px, fx_depth, (cw, ch));
        }
        Self::close_edges(&g, &mut region);
        Self::fill_holes(&g, &mut region);
        let mut mask = Mask::new(cw, ch);
        let (bx0, by0, bx1, by1) = (
            bbox[0].floor(),
            bbox[1].floor(),
            bbox[2].ceil(),
            bbox[3].ceil(),
        );
        for i in (0..region.len()).filter(|&i| region[i]) {
            let (gx, gy) = ((i % g.w) as u32, (i / g.w) as u32);
            for dy in 0..g.s {
                for dx in 0..g.s {
                    let (x, y) = (g.x0 + gx * g.s + dx, g.y0 + gy * g.s + dy);
                    if (x as f32) >= bx0
                        && (y as f32) >= by0
                        && (x as f32) < bx1
                        && (y as f32) < by1
                    {
                        mask.set(x, y, true);
                    }
                }
            }
        }
        Ok(mask)
    }
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_views;
