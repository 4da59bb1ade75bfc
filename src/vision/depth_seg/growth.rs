//! Growing one surface from seeds at a depth mode: the growth itself, the cut of the
//! supporting surface it leaked onto, and the colour-limited retry.

use std::collections::VecDeque;

use super::{same_hue, Colour, DepthSegmenter, Grid};

/// The depth step a growth crosses between neighbouring cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Reach {
    /// One surface: the noise- and distance-dependent step of a continuous face.
    Surface,
    /// Also the step between the parts of one object seen across its own depth (a lamp's
    /// shade in front of the pole that holds it): `group_step + group_per_m * z`.
    Group,
}

impl DepthSegmenter {
    /// Grow from seeds at the target depth (central part of the box first).
    /// With `colour`, only cells within `colour_tol` of the seeds' median colour join.
    pub(super) fn grow(
        &self,
        g: &Grid,
        target: f64,
        cell_px: f64,
        blocked: &[bool],
        (rule, reach): (Colour, Reach),
    ) -> Vec<bool> {
        let colour = rule != Colour::Off;
        let tol = Self::seed_tol(target);
        let near = |i: usize| {
            g.inb[i] && g.z[i] > 0.0 && (g.z[i] - target).abs() <= tol && !blocked[i] && !g.edge[i]
        };
        let [bx0, by0, bx1, by1] = g.b;
        let (qx, qy) = ((bx1 - bx0) / 4, (by1 - by0) / 4);
        let mut seeds: Vec<usize> = Vec::new();
        for gy in by0 + qy..(by1 - qy).max(by0 + qy + 1).min(g.h) {
            for gx in bx0 + qx..(bx1 - qx).max(bx0 + qx + 1).min(g.w) {
                let i = gy * g.w + gx;
                if near(i) {
                    seeds.push(i);
                }
            }
        }
        if seeds.is_empty() {
            seeds = (0..g.z.len()).filter(|&i| near(i)).collect();
        }
        // Per-channel median colour of the seeds (robust when some seeds lie on a wall at
        // the object's depth); only computed when colour limits the growth.
        let mut mid = [0.0f64; 3];
        if colour {
            for (c, m) in mid.iter_mut().enumerate() {
                let mut v: Vec<u8> = seeds.iter().map(|&i| g.rgb[i][c]).collect();
                if !v.is_empty() {
                    let k = v.len() / 2;
                    *m = f64::from(*v.select_nth_unstable(k).1);
                }
            }
        }
        let like = |i: usize| match rule {
            Colour::Off => true,
            Colour::Rgb => {
                mid.iter()
                    .zip(&g.rgb[i])
                    .map(|(m, &c)| (m - f64::from(c)).abs())
                    .sum::<f64>()
                    <= self.colour_tol
            }
            Colour::Hue => same_hue(&mid, &g.rgb[i], self.colour_tol),
        };
        if colour {
            seeds.retain(|&i| like(i));
        }
        let mut region = vec![false; g.z.len()];
        let mut queue: VecDeque<usize> = VecDeque::new();
        for &s in &seeds {
            region[s] = true;
            queue.push_back(s);
        }
        while let Some(i) = queue.pop_front() {
            let mut lim = (self.step_abs + self.step_rel * g.z[i]) * cell_px.max(1.0);
            if reach == Reach::Group {
                lim = lim.max(self.group_step + self.group_per_m * g.z[i]);
            }
            for j in g.neighbours(i).into_iter().flatten() {
                if !region[j]
                    && !blocked[j]
                    && !g.edge[j]
                    && g.z[j] > 0.0
                    && (g.z[j] - g.z[i]).abs() <= lim
                    && like(j)
                {
                    region[j] = true;
                    queue.push_back(j);
                }
            }
        }
        region
    }

    /// How far from mode `target` (m) a cell's depth may lie to seed a growth from it.
    fn seed_tol(target: f64) -> f64 {
        0.05 + 0.03 * target
    }

    /// Whether the box's cells at mode `target` (those a growth from it would seed on) lie
    /// mostly on surfaces already grown: a slanted table top spreads over several strong
    /// modes that all grow into the one surface, and counting each would crowd a surface
    /// farther back out of the modes grown.
    pub(super) fn mode_grown(g: &Grid, target: f64, grown: &[(f64, Vec<bool>)]) -> bool {
        let tol = Self::seed_tol(target);
        let (mut at, mut held) = (0usize, 0usize);
        for i in (0..g.z.len()).filter(|&i| g.inb[i] && g.z[i] > 0.0) {
            if (g.z[i] - target).abs() <= tol {
                at += 1;
                held += usize::from(grown.iter().any(|(_, r)| r[i]));
            }
        }
        at > 0 && held as f64 >= 0.8 * at as f64
    }

    /// Cells of the supporting surface if the region leaked onto it.
    pub(super) fn support_cut(&self, g: &Grid, region: &[bool]) -> Option<Vec<bool>> {
        let mut hs: Vec<f64> = (0..region.len())
            .filter(|&i| region[i] && g.inb[i])
            .map(|i| g.height[i])
            .collect();
        if hs.len() < 20 {
            return None;
        }
        // The 2nd percentile: the same value a full sort puts there, without the sort.
        let k = hs.len() / 50;
        let low = *hs.select_nth_unstable_by(k, f64::total_cmp).1;
        let cut: Vec<bool> = (0..region.len())
            .map(|i| region[i] && g.height[i] < low + self.support_band)
            .collect();
        let n_cut = (0..cut.len()).filter(|&i| cut[i] && g.inb[i]).count();
        let frac = n_cut as f64 / hs.len() as f64;
        // a support surface spans many rows of the box; the object's own bottom strip does not
        let [bx0, by0, bx1, by1] = g.b;
        let rows: Vec<usize> = (by0..by1)
            .filter(|&y| (bx0..bx1).any(|x| cut[y * g.w + x]))
            .collect();
        let span = match (rows.first(), rows.last()) {
            (Some(a), Some(b)) => b - a + 1,
            _ => 0,
        };
        (frac > 0.03
            && frac < 0.7
            && span as f64 >= 0.15 * (by1 - by0) as f64
            && Self::lies_flat(g, &cut))
        .then_some(cut)
    }

    /// Region for one mode, with the support removed; and its fraction outside the box.
    pub(super) fn surface(&self, g: &Grid, target: f64, cell_px: f64) -> (Vec<bool>, f64) {
        let (region, outside) = self.surface_with(g, target, cell_px, Colour::Off, Reach::Surface);
        if outside <= self.max_outside {
            return (region, outside);
        }
        // Leaked past the box on depth alone: try again with colour as a second limit.
        let (coloured, out_c) = self.surface_with(g, target, cell_px, Colour::Rgb, Reach::Surface);
        if out_c <= self.max_outside {
            (coloured, out_c)
        } else {
            (region, outside)
        }
    }

    /// What lies in the box's central part besides `won` (a background that ran past the
    /// box), grown as a surface with `won` kept out: the object before it when its depth
    /// spreads over too many bins to make a mode of its own (a floor lamp's pole seen along
    /// its length in front of the wall). Seeded at the median depth of the central cells
    /// that `won` does not hold; None when fewer than four such cells have depth.
    pub(super) fn rest_surface(
        &self,
        g: &Grid,
        won: &[bool],
        cell_px: f64,
    ) -> Option<(Vec<bool>, f64)> {
        let [bx0, by0, bx1, by1] = g.b;
        let (qx, qy) = ((bx1 - bx0) / 4, (by1 - by0) / 4);
        let mut z: Vec<f64> = (by0 + qy..(by1 - qy).min(g.h))
            .flat_map(|gy| (bx0 + qx..(bx1 - qx).min(g.w)).map(move |gx| gy * g.w + gx))
            .filter(|&i| !won[i] && g.z[i] > 0.0 && !g.edge[i])
            .map(|i| g.z[i])
            .collect();
        if z.len() < 4 {
            return None;
        }
        let target = crate::geometry::cloud::median(&mut z);
        let (region, outside) =
            self.surface_blocked(g, target, cell_px, won, (Colour::Off, Reach::Surface));
        region.iter().any(|&b| b).then_some((region, outside))
    }

    pub(super) fn surface_with(
        &self,
        g: &Grid,
        target: f64,
        cell_px: f64,
        colour: Colour,
        reach: Reach,
    ) -> (Vec<bool>, f64) {
        let none = vec![false; g.z.len()];
        self.surface_blocked(g, target, cell_px, &none, (colour, reach))
    }

    /// The surface grown from `target` by `rule` without entering `blocked`, grown again
    /// with its support kept out too when it leaked onto one; with its outside share.
    fn surface_blocked(
        &self,
        g: &Grid,
        target: f64,
        cell_px: f64,
        blocked: &[bool],
        rule: (Colour, Reach),
    ) -> (Vec<bool>, f64) {
        let mut region = self.grow(g, target, cell_px, blocked, rule);
        if let Some(cut) = self.support_cut(g, &region) {
            let blocked: Vec<bool> = blocked.iter().zip(&cut).map(|(a, b)| *a || *b).collect();
            let regrown = self.grow(g, target, cell_px, &blocked, rule);
            if regrown.iter().any(|&b| b) {
                region = regrown;
            }
        }
        let outside = g.outside_share(&region);
        (region, outside)
    }
}
