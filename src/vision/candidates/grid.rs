//! The cell grid behind [`super::frame_candidates`]: each cell's depth, point, colour and
//! kind (structure or free), and the region operations on it (union-find regions,
//! connected and opened components, colour splits).

use image::RgbImage;
use nalgebra::Point3;

use super::{Candidate, CandidateKind, CandidateParams};
use crate::geometry::camera::transform_point;
use crate::geometry::percentile;
use crate::geometry::{DepthMap, FrameCamera, LayoutParams, RoomLayout};
use crate::vision::depth_seg::same_hue;

/// What a cell is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Cell {
    /// No depth and no wall behind it.
    Empty,
    /// Off the room's structure: may belong to an object.
    Free,
    /// On wall 0–3 of the layout.
    Wall(u8),
    /// Floor or ceiling.
    Flat,
}

pub(super) struct Grid {
    pub(super) s: u32,
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) kind: Vec<Cell>,
    pub(super) z: Vec<f64>,
    pub(super) pts: Vec<Point3<f64>>,
    pub(super) rgb: Vec<[u8; 3]>,
}

/// Union-find over cell indices.
pub(super) struct Sets(Vec<usize>);

impl Sets {
    pub(super) fn new(n: usize) -> Self {
        Sets((0..n).collect())
    }
    pub(super) fn find(&mut self, mut i: usize) -> usize {
        while self.0[i] != i {
            self.0[i] = self.0[self.0[i]];
            i = self.0[i];
        }
        i
    }
    pub(super) fn join(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.0[ra.max(rb)] = ra.min(rb);
        }
    }
}

/// Median of the valid depth readings (m) in the 3x3 window around (x, y); 0 when fewer
/// than five are valid.
pub(super) fn robust_depth(depth: &DepthMap, x: u32, y: u32) -> f64 {
    let mut v: Vec<u16> = Vec::with_capacity(9);
    for dy in -1i64..=1 {
        for dx in -1i64..=1 {
            let (px, py) = (i64::from(x) + dx, i64::from(y) + dy);
            if px < 0 || py < 0 {
                continue;
            }
            let d = depth.get(px as u32, py as u32);
            if d > 0 {
                v.push(d);
            }
        }
    }
    if v.len() < 5 {
        return 0.0;
    }
    v.sort_unstable();
    f64::from(v[v.len() / 2]) / 1000.0
}

/// Mean colour of the cell at (x0, y0) of side `s`, from at most 4 x 4 of its pixels
/// (sensor noise averages out; the cell's edge pixels are left out).
pub(super) fn cell_colour(img: &RgbImage, x0: u32, y0: u32, s: u32) -> [u8; 3] {
    let (w, h) = img.dimensions();
    let k = s.clamp(1, 4);
    let (mut sum, mut n) = ([0u32; 3], 0u32);
    for a in 0..k {
        for b in 0..k {
            let x = (x0 + (2 * a + 1) * s / (2 * k)).min(w - 1);
            let y = (y0 + (2 * b + 1) * s / (2 * k)).min(h - 1);
            let p = img.get_pixel(x, y).0;
            for c in 0..3 {
                sum[c] += u32::from(p[c]);
            }
            n += 1;
        }
    }
    sum.map(|v| (v / n.max(1)) as u8)
}

pub(super) fn build_grid(
    cam: &FrameCamera,
    depth: &DepthMap,
    color: &RgbImage,
    layout: Option<&RoomLayout>,
    lp: &LayoutParams,
    p: &CandidateParams,
) -> Grid {
    let (cw, ch) = color.dimensions();
    let s = (cw / p.cells_across.max(1)).max(1);
    let (w, h) = (cw.div_ceil(s) as usize, ch.div_ceil(s) as usize);
    let to_out = cam.cam_to_out();
    let n = w * h;
    let mut g = Grid {
        s,
        w,
        h,
        kind: vec![Cell::Empty; n],
        z: vec![0.0; n],
        pts: vec![Point3::origin(); n],
        rgb: vec![[0; 3]; n],
    };
    for gy in 0..h {
        for gx in 0..w {
            let i = gy * w + gx;
            let u = (gx as u32 * s + s / 2).min(cw - 1);
            let v = (gy as u32 * s + s / 2).min(ch - 1);
            g.rgb[i] = cell_colour(color, gx as u32 * s, gy as u32 * s, s);
            let (dx, dy) = cam.depth_pixel_for_color(f64::from(u), f64::from(v));
            let mut z = robust_depth(depth, dx, dy);
            let mut measured = true;
            if z <= 0.0 {
                // A ray no frame measured ends on the room's wall when that lies beyond
                // the sensor's range (a wall seen from afar, a window in it).
                match layout.and_then(|l| {
                    l.exit_depth(cam, &to_out, f64::from(u), f64::from(v))
                        .filter(|&e| l.beyond_range(e, lp))
                }) {
                    Some(e) => {
                        z = e;
                        measured = false;
                    }
                    None => continue,
                }
            }
            let pc = match (&cam.depth, measured) {
                (Some(k), true) => k.unproject(f64::from(dx), f64::from(dy), z),
                _ => cam.color.unproject(f64::from(u), f64::from(v), z),
            };
            let q = transform_point(&to_out, &pc);
            if !(q.x.is_finite() && q.y.is_finite() && q.z.is_finite()) {
                continue;
            }
            g.z[i] = z;
            g.pts[i] = q;
            let margin = p.structure_margin + p.structure_per_m * z;
            g.kind[i] = match layout.and_then(|l| l.nearest_side(&q)) {
                Some((side, d)) if d < margin || !measured => {
                    if side < 4 {
                        Cell::Wall(side as u8)
                    } else {
                        Cell::Flat
                    }
                }
                _ => Cell::Free,
            };
        }
    }
    g
}

/// Neighbour pairs (right and below) of every cell.
pub(super) fn pairs(w: usize, h: usize) -> impl Iterator<Item = (usize, usize)> {
    pairs_from(w, h, 0..w * h)
}

/// The pairs of [`pairs`] whose first cell is one of `cells`.
pub(super) fn pairs_from(
    w: usize,
    h: usize,
    cells: impl Iterator<Item = usize>,
) -> impl Iterator<Item = (usize, usize)> {
    cells.flat_map(move |i| {
        let (x, y) = (i % w, i / w);
        let right = (x + 1 < w).then_some((i, i + 1));
        let below = (y + 1 < h).then_some((i, i + w));
        right.into_iter().chain(below)
    })
}

/// The regions of `sets` among the cells `member` selects, as lists of cell indices,
/// largest first (equal sizes in the order of their roots, so the same every run).
pub(super) fn regions(
    sets: &mut Sets,
    member: impl Fn(usize) -> bool,
    n: usize,
) -> Vec<Vec<usize>> {
    let mut by_root: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for i in (0..n).filter(|&i| member(i)) {
        by_root.entry(sets.find(i)).or_default().push(i);
    }
    let mut out: Vec<Vec<usize>> = by_root.into_values().collect();
    out.sort_by_key(|r| std::cmp::Reverse(r.len()));
    out
}

/// The colour most of `cells` have: the mean of the most populated bin of chromaticity
/// (8 x 8 bins of red and green shares; near-black cells in a bin of their own). A
/// per-channel median would blend two colours of equal share into a third.
pub(super) fn dominant_colour(g: &Grid, cells: &[usize]) -> [f64; 3] {
    let bin = |c: &[u8; 3]| {
        let sum: u32 = c.iter().map(|&v| u32::from(v)).sum();
        if sum < 45 {
            return 64;
        }
        let r = (u32::from(c[0]) * 8 / (sum + 1)).min(7);
        let gr = (u32::from(c[1]) * 8 / (sum + 1)).min(7);
        (r * 8 + gr) as usize
    };
    let mut counts = [0usize; 65];
    for &i in cells {
        counts[bin(&g.rgb[i])] += 1;
    }
    let best = (0..65).max_by_key(|&b| counts[b]).unwrap_or(0);
    let (mut sum, mut n) = ([0.0; 3], 0.0);
    for &i in cells.iter().filter(|&&i| bin(&g.rgb[i]) == best) {
        for (s, &v) in sum.iter_mut().zip(&g.rgb[i]) {
            *s += f64::from(v);
        }
        n += 1.0;
    }
    sum.map(|v| v / f64::max(n, 1.0))
}

impl Grid {
    /// The 4-neighbours of cell `i` (left, right, above, below; `None` past the grid's edge).
    pub(super) fn neighbours(&self, i: usize) -> [Option<usize>; 4] {
        crate::vision::common::grid_neighbours(i, self.w, self.h)
    }
}

/// The 4-connected components of the cells `set`.
pub(super) fn components(g: &Grid, set: &[usize]) -> Vec<Vec<usize>> {
    let mut member = vec![false; g.w * g.h];
    for &i in set {
        member[i] = true;
    }
    let mut out = Vec::new();
    for &start in set {
        if !member[start] {
            continue;
        }
        member[start] = false;
        let (mut comp, mut stack) = (Vec::new(), vec![start]);
        while let Some(i) = stack.pop() {
            comp.push(i);
            for j in g.neighbours(i).into_iter().flatten() {
                if member[j] {
                    member[j] = false;
                    stack.push(j);
                }
            }
        }
        out.push(comp);
    }
    out
}

/// Components of `set` after an opening: the cells whose four neighbours are all in the
/// set form the cores, and every other cell joins a core it touches. A line one or two
/// cells wide (the blended outline of a neighbouring object) no longer bridges two
/// regions.
pub(super) fn opened_components(g: &Grid, set: &[usize]) -> Vec<Vec<usize>> {
    let n = g.w * g.h;
    let mut member = vec![false; n];
    for &i in set {
        member[i] = true;
    }
    let core: Vec<usize> = set
        .iter()
        .copied()
        .filter(|&i| g.neighbours(i).iter().all(|j| j.is_some_and(|j| member[j])))
        .collect();
    let mut comps = components(g, &core);
    let mut label = vec![usize::MAX; n];
    for (k, c) in comps.iter().enumerate() {
        for &i in c {
            label[i] = k;
        }
    }
    for &i in set.iter().filter(|&&i| label[i] == usize::MAX) {
        if let Some(k) = g
            .neighbours(i)
            .iter()
            .flatten()
            .map(|&j| label[j])
            .find(|&k| k != usize::MAX && k < comps.len())
        {
            comps[k].push(i);
        }
    }
    comps
}

/// Split `cells` by colour: the cells of their dominant (median) colour and the others,
/// each as connected pieces of at least `least` cells; the others are split again, down to
/// `depth` levels. Comparing every cell with one reference colour, not with its neighbour,
/// keeps a blend of colours along an edge from chaining two objects into one.
pub(super) fn colour_split(
    g: &Grid,
    cells: &[usize],
    tol: f64,
    least: usize,
    depth: usize,
) -> Vec<Vec<usize>> {
    let main = dominant_colour(g, cells);
    let (same, other): (Vec<usize>, Vec<usize>) = cells
        .iter()
        .partition(|&&i| same_hue(&main, &g.rgb[i], tol));
    if other.len() < least {
        return Vec::new();
    }
    let mut out: Vec<Vec<usize>> = components(g, &same)
        .into_iter()
        .filter(|c| c.len() >= least)
        .collect();
    for c in opened_components(g, &other)
        .into_iter()
        .filter(|c| c.len() >= least)
    {
        if depth > 1 {
            out.extend(colour_split(g, &c, tol, least, depth - 1));
        }
        out.push(c);
    }
    out
}

pub(super) fn to_candidate(
    g: &Grid,
    cells: &[usize],
    kind: CandidateKind,
    dims: (u32, u32),
) -> Candidate {
    let (mut b, mut lo, mut hi) = (
        [usize::MAX, usize::MAX, 0, 0],
        [f64::INFINITY; 3],
        [f64::NEG_INFINITY; 3],
    );
    for &i in cells {
        let (x, y) = (i % g.w, i / g.w);
        b = [b[0].min(x), b[1].min(y), b[2].max(x + 1), b[3].max(y + 1)];
        for k in 0..3 {
            lo[k] = lo[k].min(g.pts[i][k]);
            hi[k] = hi[k].max(g.pts[i][k]);
        }
    }
    let px = |c: usize, lim: u32| ((c as u32 * g.s).min(lim)) as f32;
    Candidate {
        bbox: [
            px(b[0], dims.0),
            px(b[1], dims.1),
            px(b[2], dims.0),
            px(b[3], dims.1),
        ],
        kind,
        cells: cells.len(),
        min: lo,
        max: hi,
    }
}

/// Where the object of `cells` meets the floor, in the image: for a region standing on the
/// floor at height `floor` (its lowest cell within twice the structure margin of it, at
/// that cell's depth: what lies below was cut as the floor's band, a lamp's flat foot or a
/// chair's feet), the box of its cells' points dropped straight onto the floor and
/// projected with `cam`, clamped to the image `dims`, each side at the 2nd or 98th
/// percentile of the dropped points (a few noisy readings before a face would otherwise
/// set them; the caller joins it to the region's own box). `None` for a region above that (on a top,
/// hung, or with its lower part hidden), or when no dropped point is in front of the
/// camera.
pub(super) fn floor_reach(
    g: &Grid,
    cells: &[usize],
    cam: &FrameCamera,
    floor: f64,
    p: &CandidateParams,
    dims: (u32, u32),
) -> Option<[f32; 4]> {
    let lowest = cells
        .iter()
        .copied()
        .min_by(|&a, &b| g.pts[a].z.total_cmp(&g.pts[b].z))?;
    let margin = p.structure_margin + p.structure_per_m * g.z[lowest];
    if g.pts[lowest].z - floor > 2.0 * margin {
        return None;
    }
    let to_cam = cam.cam_to_out().try_inverse()?;
    let (mut us, mut vs): (Vec<f64>, Vec<f64>) = cells
        .iter()
        .filter_map(|&i| {
            let dropped = Point3::new(g.pts[i].x, g.pts[i].y, floor);
            cam.color
                .project(&transform_point(&to_cam, &dropped))
                .map(|(u, v, _)| (u, v))
        })
        .unzip();
    if us.is_empty() {
        return None;
    }
    us.sort_by(f64::total_cmp);
    vs.sort_by(f64::total_cmp);
    let (w, h) = (f64::from(dims.0), f64::from(dims.1));
    Some([
        percentile(&us, 0.02).clamp(0.0, w) as f32,
        percentile(&vs, 0.02).clamp(0.0, h) as f32,
        percentile(&us, 0.98).clamp(0.0, w) as f32,
        percentile(&vs, 0.98).clamp(0.0, h) as f32,
    ])
}
