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
//!    sensor's range is put on that wall. What an object has within the floor's band (a
//!    lamp's flat foot, a chair's feet) is cut with it, so the box of an object, group or
//!    part whose lowest cell lies within twice the margin of the floor is extended to its
//!    cells dropped onto the floor (`grid::floor_reach`): where it stands;
//! 3. **objects**: the remaining cells joined to their 4-neighbours across depth steps
//!    smaller than `step_fixed + step_per_m * z + step_footprints * footprint` (a cell's
//!    footprint at depth z is `cell_px * z / fx`, so a slanted face stays whole);
//! 4. **parts**: the same with each neighbour also of the same colour (hue and brightness,
//!    the depth segmenter's rule), so a lamp standing on its nightstand or a pillow lying on
//!    a bed of another colour is a candidate of its own;
//! 5. **groups**: object regions that touch in the image across a larger depth step
//!    (`group_step` + `group_per_m` per metre): a lamp's shade and the pole behind it, a
//!    chair's back and its seat seen over a table's edge. Offered beside their members,
//!    and in a group of three or more, each two members that touch across such a step;
//! 6. **on tops**: an object standing on a level top of its region (a box on a table of
//!    its colour, a lamp on a nightstand), split from it by height (`tops`), and each
//!    colour of it (two pillows side by side on a bed). In a colour part (4) or such a
//!    piece, objects side by side, each with a level top of its own, are offered each too
//!    (two pillows of one colour: `tops::side_by_side`);
//! 7. **on walls**: wall cells joined by colour, with the free cells of a colour other than
//!    the wall's that touch them, of objects that lie within twice the structure margin of
//!    that wall as a whole (a window standing out past the margin in part; not a chair's
//!    back against the wall, whose seat stands out). A wall's cells all face one way, so
//!    its light differs little: a cell more than `wall_brightness` times brighter or
//!    darker than the wall is not the wall, whatever its hue (a black window on a grey
//!    wall). The largest region of each wall is the wall; the others (pictures, windows,
//!    doors, boards) are candidates.
//!
//! Regions smaller than `min_cells` or larger than `max_extent` along any axis (what is left
//! of the room) are dropped; near-duplicates (box IoU above `dedupe_iou`) keep the larger.
//! The result is at most `max_per_frame` boxes in colour pixels, largest first.

mod grid;
mod tops;

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::depth_seg::same_hue;
use crate::geometry::{DepthMap, FrameCamera, LayoutParams, PartialParams, RoomLayout};
use grid::{
    build_grid, colour_split, dominant_colour, floor_reach, opened_components, pairs, regions,
    to_candidate, Cell, Sets,
};

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
    /// On a wall, a cell this many times brighter or darker than the wall's colour is not
    /// the wall, whatever its hue (the hue rule allows a factor of 4 for faces turned from
    /// the light, and a wall's cells all face one way).
    pub wall_brightness: f64,
    /// A colour part must hold at least this share of its object's cells.
    pub min_part: f64,
    /// Depth step (m) across which touching object regions form a group...
    pub group_step: f64,
    /// ...plus this much per metre of depth.
    pub group_per_m: f64,
    /// Offer the objects that stand on a level top of their region as candidates of their
    /// own (`tops`: what rises above the top over its footprint, where the top reaches past
    /// it on both sides along an axis of the room), and each colour of such an object.
    pub tops: bool,
    /// A cell is level when its surface normal is within this angle (degrees) of vertical.
    pub top_level_deg: f64,
    /// Height (m) above a top from which a cell stands on it...
    pub top_lift: f64,
    /// ...plus this much per metre of depth.
    pub top_lift_per_m: f64,
    /// How far (m) the top must reach past an object on both sides along an axis: a part
    /// rising from the top's edge (a chair's back over its seat) is not an object on it.
    pub top_inset: f64,
    /// Offer each object of a colour part, or of a piece standing on a top, that holds
    /// several side by side: its level tops, grouped by overlapping footprints, and the
    /// cells nearest each group's footprint (two pillows of one colour on a bed).
    pub side_by_side: bool,
    /// Most candidates kept per frame (largest first).
    pub max_per_frame: usize,
    /// Box IoU above which the smaller of two candidates is dropped.
    pub dedupe_iou: f64,
    /// Offer the candidates beside the detector's boxes too (the VLM then always picks,
    /// even among one detection): a closed-vocabulary detector at the edge of its classes
    /// misses instances and boxes the wrong object. Candidates overlapping a detection by
    /// more than `dedupe_iou` are left out.
    pub beside_detections: bool,
    /// When the VLM answers that no marked region is the target, or the chosen image has no
    /// candidate at all, ask it for the target's box in that image (the `detector = "vlm"`
    /// request, in `[agent] box_format`) instead of sending it to another image.
    pub box_fallback: bool,
    /// In the multi-view ensemble, a view without a detection of the target class takes the
    /// candidate of that view that holds the reprojected object (the rule applied to
    /// detections), instead of the box of the reprojected points alone: a view that sees
    /// the whole of an object the chosen view saw in part then segments all of it.
    pub in_views: bool,
    /// ...only when the chosen view's mask shows it saw a part (`geometry::partial`: it
    /// reaches the frame's edge, a nearer surface hides part of its outline, or much of it
    /// has no depth). A view that saw the whole object needs no completing, and a
    /// class-agnostic region can hold the object together with what it stands on.
    pub in_views_partial_only: bool,
    /// A view's candidate is segmented and compared with the chosen view (the fusion's
    /// chamfer filter) before it is used; one that fails (a region that holds the object
    /// together with what touches it) gives way to the footprint's box, which
    /// `view_box` may then ask about. Off: the candidate is used, and the fusion drops the
    /// view.
    pub in_views_check: bool,
    /// When the chosen view saw a part of the object and no ensemble view has a detection
    /// of the class, ask the VLM for the whole object's box in the views whose box is
    /// still the part's footprint, most room around the part first (one call each; the
    /// part is outlined for it). An answer must hold at least half the reprojected part,
    /// as a detection must.
    pub view_box: bool,
    /// ...in at most this many views (0: none).
    pub view_box_views: usize,
    /// When the box from the marks or the VLM lies where under `unmeasured_fraction` of
    /// its depth pixels hold a reading (too far for the sensor; the room's box counts for
    /// objects flat against a wall), tell the VLM so, once per job, and let it choose
    /// another frame: the detector's boxes are checked at pre-selection, marks and VLM
    /// boxes were not.
    pub unmeasured_retry: bool,
    /// "Almost no reading" for `unmeasured_retry`. Lower than `[agent]
    /// min_depth_fraction`, which decides which frames are offered: here a choice is
    /// overruled, and a box with a fifth of its pixels read still gives a box through
    /// depth completion and the other views.
    pub unmeasured_fraction: f64,
    /// With `unmeasured_retry`, name in that feedback the offered frames that measured what
    /// the box shows (`geometry::sightings`: the first surface along its viewing rays),
    /// best first, and ask the VLM to choose among them.
    pub nearer_frames: bool,
    /// A frame is named when it measured at least this share of the rays' first surfaces...
    pub nearer_share: f64,
    /// ...and at most this many are named.
    pub nearer_max: usize,
    /// What counts as a part (see `in_views_partial_only`).
    pub partial: PartialParams,
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
            wall_brightness: 2.0,
            min_part: 0.02,
            group_step: 0.25,
            group_per_m: 0.05,
            tops: true,
            top_level_deg: 20.0,
            top_lift: 0.02,
            top_lift_per_m: 0.01,
            top_inset: 0.05,
            side_by_side: true,
            max_per_frame: 24,
            dedupe_iou: 0.85,
            beside_detections: true,
            box_fallback: true,
            in_views: true,
            in_views_partial_only: true,
            in_views_check: true,
            view_box: true,
            view_box_views: 3,
            unmeasured_retry: true,
            unmeasured_fraction: 0.05,
            nearer_frames: true,
            nearer_share: 0.5,
            nearer_max: 6,
            partial: PartialParams::default(),
        }
    }
}

/// Version of what [`frame_candidates`] computes from the same frame and settings. Raise it
/// with every change to its output, a change to the room's box they are cut against
/// ([`crate::geometry::estimate_room`]) included: cached candidates of another version are
/// not read (they are computed again where a job needs them, and replaced at the next
/// indexing).
pub const ALGORITHM_VERSION: u32 = 7;

/// Settings of [`CandidateParams`] that decide how the candidates are used, not which are
/// found: changing them keeps the cache.
const USE_ONLY: [&str; 14] = [
    "enabled",
    "beside_detections",
    "box_fallback",
    "in_views",
    "in_views_partial_only",
    "in_views_check",
    "view_box",
    "view_box_views",
    "unmeasured_retry",
    "unmeasured_fraction",
    "nearer_frames",
    "nearer_share",
    "nearer_max",
    "partial",
];

impl CandidateParams {
    /// The key the candidates found with these settings (and the room found with `layout`)
    /// are cached under: `candidates/v{ALGORITHM_VERSION}/` and a digest of every setting
    /// that changes what is found. A cache written by another version or other settings
    /// has another key, so it is never read as this one.
    pub fn cache_key(&self, layout: &LayoutParams) -> String {
        use sha2::{Digest, Sha256};
        let mut own = serde_json::to_value(self).unwrap_or_default();
        if let Some(m) = own.as_object_mut() {
            for k in USE_ONLY {
                m.remove(k);
            }
        }
        let both = serde_json::json!({ "candidates": own, "layout": layout });
        // Fields serialise in a fixed order, so the same settings give the same text.
        let digest = Sha256::digest(both.to_string().as_bytes());
        let hex: String = digest.iter().take(6).map(|b| format!("{b:02x}")).collect();
        format!("{CACHE_PREFIX}/v{ALGORITHM_VERSION}/{hex}")
    }
}

/// Prefix of every candidates cache key (before versions: the key itself).
pub const CACHE_PREFIX: &str = "candidates";

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
    /// What stands on a level top of a region.
    OnTop,
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
            CandidateKind::OnTop => "object on a top",
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

impl From<Candidate> for crate::vision::Detection {
    /// The row a candidate is cached and offered as: its kind's label, score 1.
    fn from(c: Candidate) -> Self {
        Self {
            label: c.kind.label().to_string(),
            score: 1.0,
            bbox: c.bbox,
        }
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
    // A region standing on the floor reaches down to it, past the floor's band.
    let floor = layout.and_then(|l| l.floor);
    let standing = |r: &[usize], kind: CandidateKind| {
        let mut c = to_candidate(&g, r, kind, dims);
        // (Too small to be offered: not worth the projections.)
        let reach = floor.filter(|_| r.len() >= p.min_cells);
        if let Some(b) = reach.and_then(|f| floor_reach(&g, r, cam, f, p, dims)) {
            c.bbox = [
                c.bbox[0].min(b[0]),
                c.bbox[1].min(b[1]),
                c.bbox[2].max(b[2]),
                c.bbox[3].max(b[3]),
            ];
        }
        c
    };
    let mut out: Vec<Candidate> = Vec::new();
    let free = |i: usize| g.kind[i] == Cell::Free;
    let object_regions = regions(&mut objects, free, n);
    for r in &object_regions {
        let c = standing(r, CandidateKind::Object);
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
    let angle = layout.map_or(0.0, |l| l.angle_deg);
    // A colour part or a piece on a top, and the objects side by side in it.
    let with_side_by_side = |r: Vec<usize>| {
        let mut all = if p.side_by_side {
            tops::side_by_side(&g, &r, angle, &near, p)
        } else {
            Vec::new()
        };
        all.insert(0, r);
        all
    };
    for whole in object_regions.iter().filter(|r| r.len() >= 2 * p.min_cells) {
        let least = p.min_cells.max((p.min_part * whole.len() as f64) as usize);
        for r in colour_split(&g, whole, p.colour_tol, least, 2) {
            if r.len() < whole.len() * 9 / 10 {
                for r in with_side_by_side(r) {
                    let c = standing(&r, CandidateKind::Part);
                    if fits(&c) {
                        out.push(c);
                    }
                }
            }
        }
    }
    if p.tops {
        let eye_z = cam.centre().z;
        for r in tops::on_tops(&g, &object_regions, &object_of, eye_z, angle, p) {
            // What stands on one top can be several things side by side (two pillows on a
            // bed): each of its colours is offered too, as the object regions' are.
            let mut found = Vec::new();
            if r.len() >= 2 * p.min_cells {
                let least = p.min_cells.max((p.min_part * r.len() as f64) as usize);
                found.extend(
                    colour_split(&g, &r, p.colour_tol, least, 2)
                        .into_iter()
                        .filter(|part| part.len() < r.len() * 9 / 10),
                );
            }
            found.insert(0, r);
            let found: Vec<Vec<usize>> = found.into_iter().flat_map(with_side_by_side).collect();
            for r in &found {
                let c = to_candidate(&g, r, CandidateKind::OnTop, dims);
                if fits(&c) {
                    out.push(c);
                }
            }
        }
    }
    // Members of a group of three or more: each pair that touches across a group step is
    // offered too (a plant's leaves over its pot, beside a cabinet the leaves touch).
    let mut touching: std::collections::BTreeSet<(usize, usize)> = Default::default();
    for (a, b) in pairs(g.w, g.h) {
        let (ka, kb) = (object_of[a], object_of[b]);
        if ka != kb && ka != usize::MAX && kb != usize::MAX && grouped(a, b) {
            touching.insert((ka.min(kb), ka.max(kb)));
        }
    }
    let big = |k: usize| object_regions[k].len() >= p.min_cells;
    for r in regions(&mut groups, free, n) {
        let mut members: Vec<usize> = r.iter().map(|&i| object_of[i]).collect();
        members.sort_unstable();
        members.dedup();
        if members.len() > 1 {
            let c = standing(&r, CandidateKind::Group);
            if fits(&c) {
                out.push(c);
            }
        }
        if members.len() > 2 {
            for &(ka, kb) in touching.iter().filter(|(ka, kb)| {
                members.binary_search(ka).is_ok() && members.binary_search(kb).is_ok()
            }) {
                if big(ka) && big(kb) {
                    let both = [&object_regions[ka][..], &object_regions[kb][..]].concat();
                    let c = standing(&both, CandidateKind::Group);
                    if fits(&c) {
                        out.push(c);
                    }
                }
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
        let sw = wall.iter().sum::<f64>();
        let off_colour = |i: usize| {
            let c = &g.rgb[i];
            let sc = c.iter().map(|&v| f64::from(v)).sum::<f64>();
            !same_hue(&wall, c, p.colour_tol)
                || sc > p.wall_brightness * sw
                || sw > p.wall_brightness * sc
        };
        let mut off: Vec<usize> = on.iter().copied().filter(|&i| off_colour(i)).collect();
        if let Some(l) = layout {
            let margin = |i: usize| p.structure_margin + p.structure_per_m * g.z[i];
            let by_wall = |i: usize| {
                l.nearest_side(&g.pts[i])
                    .is_some_and(|(s, d)| s == usize::from(side) && d < 2.0 * margin(i))
            };
            // Only an object that is flat on the wall as a whole: the back of a chair
            // standing against it is as near, and its seat is not.
            let flat: Vec<bool> = object_regions
                .iter()
                .map(|r| r.iter().all(|&i| by_wall(i)))
                .collect();
            let flat_on = |i: usize| object_of[i] != usize::MAX && flat[object_of[i]];
            off = straddling(&g, off, |a, b| near(a, b) && off_colour(b) && flat_on(b));
        }
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

/// `seed` (off-colour cells of one wall) grown over the free cells that `joins(from, to)`
/// admits: a flat object on a wall that stands out past the structure margin (a window's
/// frame, a door's leaf, a board) has cells on both sides of it, and sensor noise decides
/// which; the cells past the margin belong to it as much as those within.
fn straddling(
    g: &grid::Grid,
    seed: Vec<usize>,
    joins: impl Fn(usize, usize) -> bool,
) -> Vec<usize> {
    let mut member = vec![false; g.w * g.h];
    for &i in &seed {
        member[i] = true;
    }
    let mut out = seed.clone();
    let mut queue: std::collections::VecDeque<usize> = seed.into();
    while let Some(i) = queue.pop_front() {
        for j in g.neighbours(i).into_iter().flatten() {
            if !member[j] && g.kind[j] == Cell::Free && joins(i, j) {
                member[j] = true;
                out.push(j);
                queue.push_back(j);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests;
