//! Model-free box → mask for posed RGB-D frames.
//!
//! Inside the box: (1) a depth histogram, weighted towards the box centre, gives the surface
//! modes; the nearest strong mode is the object (things in front of the target are rarely the
//! box's main content, the background is farther). (2) Seeds near that depth in the central
//! part of the box grow over 4-neighbours while the depth step stays under a noise- and
//! distance-dependent limit. (3) Where the growth leaked onto the supporting surface (floor,
//! table top), the points within a few cm of the lowest height (gravity = the output frame's
//! +z) are cut and the component holding the seeds is kept. (4) Small holes (missing depth)
//! are closed and depth-less pixels whose colour matches the region are added back.

use std::collections::VecDeque;

use anyhow::{bail, Result};

use super::{SegmentInput, Segmenter};
use crate::geometry::camera::transform_point;
use crate::geometry::mask::Mask;

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
    /// Upper bound on grid cells (larger boxes are subsampled).
    pub max_cells: usize,
}

impl Default for DepthSegmenter {
    fn default() -> Self {
        Self {
            bin: 0.03,
            strong_mode: 0.35,
            step_abs: 0.02,
            step_rel: 0.025,
            support_band: 0.03,
            max_cells: 200_000,
        }
    }
}

/// A grid of sample cells over the box (stride `s` colour pixels).
struct Grid {
    x0: u32,
    y0: u32,
    s: u32,
    w: usize,
    h: usize,
    /// depth in metres (0 = none)
    z: Vec<f64>,
    /// height along the output frame's z axis
    height: Vec<f64>,
    rgb: Vec<[u8; 3]>,
}

impl DepthSegmenter {
    fn grid(&self, input: &SegmentInput<'_>, bbox: [f32; 4]) -> Option<Grid> {
        let (cw, ch) = input.color.dimensions();
        let x0 = bbox[0].max(0.0).floor() as u32;
        let y0 = bbox[1].max(0.0).floor() as u32;
        let x1 = (bbox[2].ceil().max(0.0) as u32).min(cw);
        let y1 = (bbox[3].ceil().max(0.0) as u32).min(ch);
        if x1 <= x0 || y1 <= y0 {
            return None;
        }
        let area = ((x1 - x0) * (y1 - y0)) as f64;
        let s = ((area / self.max_cells as f64).sqrt().ceil() as u32).max(1);
        let w = ((x1 - x0) as usize).div_ceil(s as usize);
        let h = ((y1 - y0) as usize).div_ceil(s as usize);
        let cam = input.camera;
        let to_out = cam.cam_to_out();
        let (mut z, mut height, mut rgb) =
            (vec![0.0; w * h], vec![0.0; w * h], vec![[0u8; 3]; w * h]);
        for gy in 0..h {
            for gx in 0..w {
                let u = (x0 + gx as u32 * s + s / 2).min(x1 - 1);
                let v = (y0 + gy as u32 * s + s / 2).min(y1 - 1);
                let i = gy * w + gx;
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
                height[i] = transform_point(&to_out, &p).z;
            }
        }
        Some(Grid {
            x0,
            y0,
            s,
            w,
            h,
            z,
            height,
            rgb,
        })
    }

    /// Depth of the nearest strong, centre-weighted histogram mode.
    fn target_depth(&self, g: &Grid) -> Option<f64> {
        let valid: Vec<f64> = g.z.iter().copied().filter(|&z| z > 0.0).collect();
        let zmin = valid.iter().copied().fold(f64::INFINITY, f64::min);
        let zmax = valid.iter().copied().fold(0.0, f64::max);
        if valid.is_empty() {
            return None;
        }
        let nb = (((zmax - zmin) / self.bin).floor() as usize + 1).min(2000);
        let mut hist = vec![0.0; nb];
        let (cx, cy) = (g.w as f64 / 2.0, g.h as f64 / 2.0);
        let (sx, sy) = ((g.w as f64 * 0.35).max(1.0), (g.h as f64 * 0.35).max(1.0));
        for gy in 0..g.h {
            for gx in 0..g.w {
                let z = g.z[gy * g.w + gx];
                if z <= 0.0 {
                    continue;
                }
                let (dx, dy) = ((gx as f64 + 0.5 - cx) / sx, (gy as f64 + 0.5 - cy) / sy);
                let wgt = (-0.5 * (dx * dx + dy * dy)).exp();
                hist[(((z - zmin) / self.bin) as usize).min(nb - 1)] += wgt;
            }
        }
        // smooth with [1, 2, 3, 2, 1]
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
        let first = (0..nb).find(|&i| is_mode(i) && sm[i] >= self.strong_mode * peak)?;
        Some(zmin + (first as f64 + 0.5) * self.bin)
    }

    fn step_limit(&self, z: f64, cell_px: f64) -> f64 {
        (self.step_abs + self.step_rel * z) * cell_px.max(1.0)
    }

    /// Grow from seeds at the target depth; returns the region (grid-sized).
    fn grow(&self, g: &Grid, target: f64, cell_px: f64, blocked: &[bool]) -> Vec<bool> {
        let tol = 0.05 + 0.03 * target;
        let near = |i: usize| g.z[i] > 0.0 && (g.z[i] - target).abs() <= tol && !blocked[i];
        let mut seeds: Vec<usize> = Vec::new();
        let (qx, qy) = (g.w / 4, g.h / 4);
        for gy in qy..(g.h - qy).max(qy + 1) {
            for gx in qx..(g.w - qx).max(qx + 1) {
                let i = gy * g.w + gx;
                if i < g.z.len() && near(i) {
                    seeds.push(i);
                }
            }
        }
        if seeds.is_empty() {
            seeds = (0..g.z.len()).filter(|&i| near(i)).collect();
        }
        let mut region = vec![false; g.z.len()];
        let mut queue: VecDeque<usize> = VecDeque::new();
        for &s in &seeds {
            region[s] = true;
            queue.push_back(s);
        }
        while let Some(i) = queue.pop_front() {
            let (x, y) = (i % g.w, i / g.w);
            let lim = self.step_limit(g.z[i], cell_px);
            let mut visit = |j: usize| {
                if !region[j] && !blocked[j] && g.z[j] > 0.0 && (g.z[j] - g.z[i]).abs() <= lim {
                    region[j] = true;
                    queue.push_back(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < g.w {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - g.w);
            }
            if y + 1 < g.h {
                visit(i + g.w);
            }
        }
        region
    }

    /// Cut the supporting surface if the region leaked onto it.
    fn support_cut(&self, g: &Grid, region: &[bool]) -> Option<Vec<bool>> {
        let mut hs: Vec<f64> = (0..region.len())
            .filter(|&i| region[i])
            .map(|i| g.height[i])
            .collect();
        if hs.len() < 20 {
            return None;
        }
        hs.sort_by(f64::total_cmp);
        let low = hs[hs.len() / 50];
        let cut: Vec<bool> = (0..region.len())
            .map(|i| region[i] && g.height[i] < low + self.support_band)
            .collect();
        let n_cut = cut.iter().filter(|&&b| b).count();
        // only a real leak: a sizeable low part whose removal leaves most of the object
        let frac = n_cut as f64 / hs.len() as f64;
        // a support surface spans many rows of the box; the object's own bottom strip does not
        let rows: Vec<usize> = (0..g.h)
            .filter(|&y| cut[y * g.w..(y + 1) * g.w].iter().any(|&b| b))
            .collect();
        let span = match (rows.first(), rows.last()) {
            (Some(a), Some(b)) => b - a + 1,
            _ => 0,
        };
        let low_side = span as f64 >= 0.15 * g.h as f64;
        (frac > 0.03 && frac < 0.7 && low_side).then_some(cut)
    }

    /// Keep the largest 4-connected component of `region` (grid cells).
    fn largest_component(g: &Grid, region: &[bool]) -> Vec<bool> {
        let mut label = vec![0u32; region.len()];
        let (mut best, mut best_n, mut next) = (0u32, 0usize, 0u32);
        for start in 0..region.len() {
            if !region[start] || label[start] != 0 {
                continue;
            }
            next += 1;
            let mut n = 0;
            let mut stack = vec![start];
            label[start] = next;
            while let Some(i) = stack.pop() {
                n += 1;
                let (x, y) = (i % g.w, i / g.w);
                let nbrs = [
                    (x > 0).then(|| i - 1),
                    (x + 1 < g.w).then(|| i + 1),
                    (y > 0).then(|| i - g.w),
                    (y + 1 < g.h).then(|| i + g.w),
                ];
                for j in nbrs.into_iter().flatten() {
                    if region[j] && label[j] == 0 {
                        label[j] = next;
                        stack.push(j);
                    }
                }
            }
            if n > best_n {
                best_n = n;
                best = next;
            }
        }
        label.iter().map(|&l| l != 0 && l == best).collect()
    }

    /// Close small holes: depth-less cells with at least 3 region neighbours, or whose colour is
    /// close to the region's mean colour and touch it.
    fn fill_holes(g: &Grid, region: &mut [bool]) {
        let n = region.iter().filter(|&&b| b).count().max(1) as f64;
        let mut mean = [0.0f64; 3];
        for (i, _) in region.iter().enumerate().filter(|(_, &b)| b) {
            for c in 0..3 {
                mean[c] += g.rgb[i][c] as f64 / n;
            }
        }
        for _ in 0..3 {
            let snapshot = region.to_vec();
            for i in 0..region.len() {
                if snapshot[i] || g.z[i] > 0.0 {
                    continue;
                }
                let (x, y) = (i % g.w, i / g.w);
                let nbrs = [
                    (x > 0).then(|| i - 1),
                    (x + 1 < g.w).then(|| i + 1),
                    (y > 0).then(|| i - g.w),
                    (y + 1 < g.h).then(|| i + g.w),
                ];
                let k = nbrs.into_iter().flatten().filter(|&j| snapshot[j]).count();
                let dc: f64 = (0..3).map(|c| (g.rgb[i][c] as f64 - mean[c]).abs()).sum();
                if k >= 3 || (k >= 1 && dc < 45.0) {
                    region[i] = true;
                }
            }
        }
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
        let Some(g) = self.grid(input, bbox) else {
            return Ok(Mask::new(cw, ch));
        };
        let Some(target) = self.target_depth(&g) else {
            // no depth at all in the box: the box is the best guess
            return Ok(Mask::from_box(cw, ch, bbox));
        };
        let cell_px = g.s as f64 * input.depth.width as f64 / cw as f64;
        let none = vec![false; g.z.len()];
        let mut region = self.grow(&g, target, cell_px, &none);
        if let Some(cut) = self.support_cut(&g, &region) {
            let regrown = self.grow(&g, target, cell_px, &cut);
            if regrown.iter().any(|&b| b) {
                region = regrown;
            }
        }
        let mut region = Self::largest_component(&g, &region);
        Self::fill_holes(&g, &mut region);
        let mut mask = Mask::new(cw, ch);
        for gy in 0..g.h {
            for gx in 0..g.w {
                if !region[gy * g.w + gx] {
                    continue;
                }
                for dy in 0..g.s {
                    for dx in 0..g.s {
                        let (x, y) = (g.x0 + gx as u32 * g.s + dx, g.y0 + gy as u32 * g.s + dy);
                        if (x as f32) < bbox[2].ceil() && (y as f32) < bbox[3].ceil() {
                            mask.set(x, y, true);
                        }
                    }
                }
            }
        }
        Ok(mask)
    }
}
