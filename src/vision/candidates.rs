//! Class-agnostic object candidates from one posed RGB-D frame (ours, not the paper's).
//!
//! A detector only proposes boxes for the classes it was trained on; most indoor nouns
//! (cabinet, door, window, shelf, lamp, pillow, curtain...) are outside COCO. These
//! candidates come from the scan itself, so they exist for any object:
//! 1. the frame is sampled on a grid of cells (`cells_across` over the colour width); each
//!    cell gets a robust depth (median of the 3x3 depth pixels it reads), its point in the
//!    output frame (+z up) and its colour;
//! 2. with the room's layout (`geometry::layout`), a cell within `structure_margin` (+
//!    `structure_per_m` per metre of depth) of the floor, the ceiling or a wall is room
//!    structure, not an object. A cell without depth whose ray leaves the room beyond the
//!    sensor's range is put on that wall;
//! 3. **objects**: the remaining cells joined to their 4-neighbours across depth steps
//!    smaller than `step_fixed + step_per_m * z + step_footprints * footprint` (a cell's
//!    footprint at depth z is `cell_px * z / fx`, so a slanted face stays whole);
//! 4. **parts**: the same with each neighbour also of the same colour (hue and brightness,
//!    the depth segmenter's rule), so a lamp standing on its nightstand or a pillow lying on
//!    a bed of another colour is a candidate of its own;
//! 5. **groups**: object regions that touch in the image across a larger depth step
//!    (`group_step` + `group_per_m` per metre): a lamp's shade and the pole behind it, a
//!    chair's back and its seat seen over a table's edge. Offered beside their members;
//! 6. **on walls**: wall cells joined by colour. The largest region of each wall is the
//!    wall; the others (pictures, windows, doors, boards) are candidates.
//!
//! Regions smaller than `min_cells` or larger than `max_extent` along any axis (what is left
//! of the room) are dropped; near-duplicates (box IoU above `dedupe_iou`) keep the larger.
//! The result is at most `max_per_frame` boxes in colour pixels, largest first.

use image::RgbImage;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::depth_seg::same_hue;
use crate::geometry::camera::transform_point;
use crate::geometry::{DepthMap, FrameCamera, LayoutParams, RoomLayout};

/// Settings of [`frame_candidates`] (file section `[agent.candidates]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CandidateParams {
    /// Compute candidates at indexing and offer them when the detector cannot help.
    pub enabled: bool,
    /// Grid cells across the colour image's width.
    pub cells_across: u32,
    /// Distance (m) from a side of the room within which a point is structure...
    pub structure_margin: f64,
    /// ...plus this much per metre of depth (sensor noise grows with distance).
    pub structure_per_m: f64,
    /// Depth step (m) that separates two neighbouring cells: fixed part...
    pub step_fixed: f64,
    /// ...plus this much per metre of depth...
    pub step_per_m: f64,
    /// ...plus this many cell footprints (a face seen at a slant).
    pub step_footprints: f64,
    /// Fewest cells a candidate may have.
    pub min_cells: usize,
    /// Largest extent (m) of a candidate along any axis.
    pub max_extent: f64,
    /// Colour tolerance of parts and wall regions (the depth segmenter's hue rule, tighter
    /// than the segmenter's 60: brown against a grey wall is within 60).
    pub colour_tol: f64,
    /// A colour part must hold at least this share of its object's cells.
    pub min_part: f64,
    /// Depth step (m) across which touching object regions form a group...
    pub group_step: f64,
    /// ...plus this much per metre of depth.
    pub group_per_m: f64,
    /// Most candidates kept per frame (largest first).
    pub max_per_frame: usize,
    /// Box IoU above which the smaller of two candidates is dropped.
    pub dedupe_iou: f64,
    /// Offer the candidates beside the detector's boxes too (the VLM then always picks,
    /// even among one detection): a closed-vocabulary detector at the edge of its classes
    /// misses instances and boxes the wrong object. Candidates overlapping a detection by
    /// more than `dedupe_iou` are left out.
    pub beside_detections: bool,
}

impl Default for CandidateParams {
    fn default() -> Self {
        Self {
            enabled: true,
            cells_across: 160,
            structure_margin: 0.04,
            structure_per_m: 0.01,
            step_fixed: 0.03,
            step_per_m: 0.02,
            step_footprints: 2.5,
            min_cells: 20,
            max_extent: 3.0,
            colour_tol: 30.0,
            min_part: 0.02,
            group_step: 0.25,
            group_per_m: 0.05,
            max_per_frame: 24,
            dedupe_iou: 0.85,
            beside_detections: true,
        }
    }
}

/// How a candidate was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CandidateKind {
    /// A depth-connected region off the room's structure.
    Object,
    /// One colour of such a region.
    Part,
    /// Touching regions across a larger depth step.
    Group,
    /// A colour region on a wall.
    OnWall,
}

impl CandidateKind {
    /// The label candidates are cached under.
    pub fn label(self) -> &'static str {
        match self {
            CandidateKind::Object => "object",
            CandidateKind::Part => "object part",
            CandidateKind::Group => "object group",
            CandidateKind::OnWall => "on wall",
        }
    }
}

/// One class-agnostic candidate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Candidate {
    /// [x1, y1, x2, y2] in colour pixels.
    pub bbox: [f32; 4],
    pub kind: CandidateKind,
    /// Grid cells it covers.
    pub cells: usize,
    /// Its points' box in the output frame (m).
    pub min: [f64; 3],
    pub max: [f64; 3],
}

/// What a cell is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cell {
    /// No depth and no wall behind it.
    Empty,
    /// Off the room's structure: may belong to an object.
    Free,
    /// On wall 0–3 of the layout.
    Wall(u8),
    /// Floor or ceiling.
    Flat,
}

struct Grid {
    s: u32,
    w: usize,
    h: usize,
    kind: Vec<Cell>,
    z: Vec<f64>,
    pts: Vec<Point3<f64>>,
    rgb: Vec<[u8; 3]>,
}

/// Union-find over cell indices.
struct Sets(Vec<usize>);

impl Sets {
    fn new(n: usize) -> Self {
        Sets((0..n).collect())
    }
    fn find(&mut self, mut i: usize) -> usize {
        while self.0[i] != i {
            self.0[i] = self.0[self.0[i]];
            i = self.0[i];
        }
        i
    }
    fn join(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.0[ra.max(rb)] = ra.min(rb);
        }
    }
}

/// Median of the valid depth readings (m) in the 3x3 window around (x, y); 0 when fewer
/// than five are valid.
fn robust_depth(depth: &DepthMap, x: u32, y: u32) -> f64 {
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
fn cell_colour(img: &RgbImage, x0: u32, y0: u32, s: u32) -> [u8; 3] {
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

fn build_grid(
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
fn pairs(w: usize, h: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..h).flat_map(move |y| {
        (0..w).flat_map(move |x| {
            let i = y * w + x;
            let right = (x + 1 < w).then_some((i, i + 1));
            let below = (y + 1 < h).then_some((i, i + w));
            right.into_iter().chain(below)
        })
    })
}

/// The regions of `sets` among the cells `member` selects, as lists of cell indices.
fn regions(sets: &mut Sets, member: impl Fn(usize) -> bool, n: usize) -> Vec<Vec<usize>> {
    let mut by_root: std::collections::HashMap<usize, Vec<usize>> = Default::default();
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
fn dominant_colour(g: &Grid, cells: &[usize]) -> [f64; 3] {
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

/// The 4-connected components of the cells `set`.
fn components(g: &Grid, set: &[usize]) -> Vec<Vec<usize>> {
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
            let (x, y) = (i % g.w, i / g.w);
            let mut visit = |j: usize| {
                if member[j] {
                    member[j] = false;
                    stack.push(j);
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
        out.push(comp);
    }
    out
}

/// Components of `set` after an opening: the cells whose four neighbours are all in the
/// set form the cores, and every other cell joins a core it touches. A line one or two
/// cells wide (the blended outline of a neighbouring object) no longer bridges two
/// regions.
fn opened_components(g: &Grid, set: &[usize]) -> Vec<Vec<usize>> {
    let n = g.w * g.h;
    let mut member = vec![false; n];
    for &i in set {
        member[i] = true;
    }
    let neighbours = |i: usize| {
        let (x, y) = (i % g.w, i / g.w);
        [
            (x > 0).then(|| i - 1),
            (x + 1 < g.w).then(|| i + 1),
            (y > 0).then(|| i - g.w),
            (y + 1 < g.h).then(|| i + g.w),
        ]
    };
    let core: Vec<usize> = set
        .iter()
        .copied()
        .filter(|&i| neighbours(i).iter().all(|j| j.is_some_and(|j| member[j])))
        .collect();
    let mut comps = components(g, &core);
    let mut label = vec![usize::MAX; n];
    for (k, c) in comps.iter().enumerate() {
        for &i in c {
            label[i] = k;
        }
    }
    for &i in set.iter().filter(|&&i| label[i] == usize::MAX) {
        if let Some(k) = neighbours(i)
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
fn colour_split(
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

fn to_candidate(g: &Grid, cells: &[usize], kind: CandidateKind, dims: (u32, u32)) -> Candidate {
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

/// Intersection over union of two boxes [x1, y1, x2, y2].
pub fn box_iou(a: &[f32; 4], b: &[f32; 4]) -> f64 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = f64::from(iw * ih);
    let area = |r: &[f32; 4]| f64::from((r[2] - r[0]) * (r[3] - r[1]));
    let union = area(a) + area(b) - inter;
    if union <= 0.0 {
        0.0
    } else {
        inter / union
    }
}

/// The class-agnostic candidates of one frame, largest first (see the module docs).
/// `layout` is the room's box (None: nothing counts as structure and only `max_extent`
/// removes the room).
pub fn frame_candidates(
    cam: &FrameCamera,
    depth: &DepthMap,
    color: &RgbImage,
    layout: Option<&RoomLayout>,
    lp: &LayoutParams,
    p: &CandidateParams,
) -> Vec<Candidate> {
    if color.width() == 0 || color.height() == 0 || depth.width == 0 || depth.height == 0 {
        return Vec::new();
    }
    let g = build_grid(cam, depth, color, layout, lp, p);
    let n = g.w * g.h;
    let fx = cam.color.fx.abs().max(1e-6);
    let step =
        |z: f64| p.step_fixed + p.step_per_m * z + p.step_footprints * f64::from(g.s) * z / fx;
    let near = |a: usize, b: usize| (g.z[a] - g.z[b]).abs() < step(g.z[a].min(g.z[b]));

    let grouped = |a: usize, b: usize| {
        let z = g.z[a].min(g.z[b]);
        (g.z[a] - g.z[b]).abs() < p.group_step + p.group_per_m * z
    };
    let (mut objects, mut groups) = (Sets::new(n), Sets::new(n));
    for (a, b) in pairs(g.w, g.h) {
        if (g.kind[a], g.kind[b]) != (Cell::Free, Cell::Free) {
            continue;
        }
        if near(a, b) {
            objects.join(a, b);
            groups.join(a, b);
        } else if grouped(a, b) {
            groups.join(a, b);
        }
    }
    let dims = color.dimensions();
    let fits = |c: &Candidate| {
        c.cells >= p.min_cells && (0..3).all(|k| c.max[k] - c.min[k] <= p.max_extent)
    };
    let mut out: Vec<Candidate> = Vec::new();
    let free = |i: usize| g.kind[i] == Cell::Free;
    let object_regions = regions(&mut objects, free, n);
    for r in &object_regions {
        let c = to_candidate(&g, r, CandidateKind::Object, dims);
        if fits(&c) {
            out.push(c);
        }
    }
    let mut object_of = vec![usize::MAX; n];
    for (k, r) in object_regions.iter().enumerate() {
        for &i in r {
            object_of[i] = k;
        }
    }
    for whole in object_regions.iter().filter(|r| r.len() >= 2 * p.min_cells) {
        let least = p.min_cells.max((p.min_part * whole.len() as f64) as usize);
        for r in colour_split(&g, whole, p.colour_tol, least, 2) {
            if r.len() < whole.len() * 9 / 10 {
                let c = to_candidate(&g, &r, CandidateKind::Part, dims);
                if fits(&c) {
                    out.push(c);
                }
            }
        }
    }
    for r in regions(&mut groups, free, n) {
        let mut members: Vec<usize> = r.iter().map(|&i| object_of[i]).collect();
        members.sort_unstable();
        members.dedup();
        if members.len() > 1 {
            let c = to_candidate(&g, &r, CandidateKind::Group, dims);
            if fits(&c) {
                out.push(c);
            }
        }
    }
    for side in 0..4u8 {
        let on: Vec<usize> = (0..n).filter(|&i| g.kind[i] == Cell::Wall(side)).collect();
        if on.len() < 2 * p.min_cells {
            continue;
        }
        // The wall's own colour is the one most of its cells have; what differs from it
        // and hangs together is on the wall.
        let wall = dominant_colour(&g, &on);
        let off: Vec<usize> = on
            .iter()
            .copied()
            .filter(|&i| !same_hue(&wall, &g.rgb[i], p.colour_tol))
            .collect();
        for r in opened_components(&g, &off) {
            if r.len() >= p.min_cells && r.len() * 10 < on.len() * 6 {
                let c = to_candidate(&g, &r, CandidateKind::OnWall, dims);
                if fits(&c) {
                    out.push(c);
                }
            }
        }
    }
    out.sort_by_key(|c| std::cmp::Reverse(c.cells));
    let mut kept: Vec<Candidate> = Vec::new();
    for c in out {
        if kept.len() >= p.max_per_frame {
            break;
        }
        if kept
            .iter()
            .all(|k| box_iou(&k.bbox, &c.bbox) <= p.dedupe_iou)
        {
            kept.push(c);
        }
    }
    kept
}

#[cfg(test)]
#[path = "candidates_tests.rs"]
mod tests;
