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
    /// Colour tolerance of parts and wall regions (the depth segmenter's hue rule).
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
            colour_tol: 60.0,
            min_part: 0.02,
            group_step: 0.25,
            group_per_m: 0.05,
            max_per_frame: 24,
            dedupe_iou: 0.85,
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
            g.rgb[i] = color.get_pixel(u, v).0;
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

fn box_iou(a: &[f32; 4], b: &[f32; 4]) -> f64 {
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
    let colour = |a: usize| g.rgb[a].map(f64::from);
    let alike = |a: usize, b: usize| same_hue(&colour(a), &g.rgb[b], p.colour_tol);

    let grouped = |a: usize, b: usize| {
        let z = g.z[a].min(g.z[b]);
        (g.z[a] - g.z[b]).abs() < p.group_step + p.group_per_m * z
    };
    let (mut objects, mut parts, mut walls) = (Sets::new(n), Sets::new(n), Sets::new(n));
    let mut groups = Sets::new(n);
    for (a, b) in pairs(g.w, g.h) {
        match (g.kind[a], g.kind[b]) {
            (Cell::Free, Cell::Free) if near(a, b) => {
                objects.join(a, b);
                groups.join(a, b);
                if alike(a, b) {
                    parts.join(a, b);
                }
            }
            (Cell::Free, Cell::Free) if grouped(a, b) => groups.join(a, b),
            (Cell::Wall(x), Cell::Wall(y)) if x == y && alike(a, b) => walls.join(a, b),
            _ => {}
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
    for r in regions(&mut parts, free, n) {
        let whole = object_regions[object_of[r[0]]].len();
        let share = r.len() as f64 / whole as f64;
        if share >= p.min_part && share < 0.9 {
            let c = to_candidate(&g, &r, CandidateKind::Part, dims);
            if fits(&c) {
                out.push(c);
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
        let on = |i: usize| g.kind[i] == Cell::Wall(side);
        let total = (0..n).filter(|&i| on(i)).count();
        // The largest colour region of a wall is the wall itself.
        for r in regions(&mut walls, on, n).into_iter().skip(1) {
            if (r.len() as f64) < 0.6 * total as f64 {
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
