//! Support completion: extend an object's box through space no camera saw, down to the
//! planar surface it rests on or back to the wall it hangs on.
//!
//! Back-projected masks only hold surfaces a camera saw, and the paper's erosion removes
//! thin parts (legs) on top. So the box of a chair stops at its seat, and the box of a
//! picture is a zero-thickness slab at its front face, though the annotated box of either
//! reaches the floor or the wall. Objects are held up by something: when, right beyond a
//! face of the box, the depth *around* the object shows a dense planar layer perpendicular
//! to that axis (floor or table top below, a wall behind), the space between the face and
//! that layer is hidden by the object itself and belongs to it, so the face moves onto it.
//!
//! Searched directions: down (−z of the output frame, gravity; the ScanNet axis alignment
//! has +z up) and the four horizontal ones. Up is never searched: nothing is held from
//! above in our scenes, and ceilings would be wrongly joined.
//!
//! A candidate layer must (1) lie within `max_gap` beyond the face (or `max_inside` within
//! it: depth noise spreads a picture's points behind its wall, and the face is then pulled
//! back onto the wall), (2) fall in the ring of width `margin` around the box's footprint
//! along the other two axes (inside the footprint the object hides its support, and points
//! there may be the object itself), (3) spread over at least
//! `min_spread` along both of them (so a wall seen below a picture, which is a line in a
//! horizontal slice, is not a floor), and (4) cover at least `min_coverage` of the ring of
//! width `margin` around the box's footprint, less its inner band of width `rim` (the
//! object's own silhouette), with occupied voxels (the object hides its own
//! footprint on the support; a slice through four chair legs lies inside the footprint and
//! covers none of the ring). The nearest such layer wins; the face moves to its median coordinate.
//! When both side faces of one axis fall back onto one surface (medians within a layer)
//! with the object's median between them, the surface runs through the object and is its
//! own: neither face moves.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::cloud::{median, voxel_downsample};
use super::mask::pixel_box;
use super::morph::dilate_square_within;
use super::projection::{
    backproject_mask_within, project_points, BackprojectOptions, ProjectionError,
};
use super::support_layer::find_layer;
use super::{Aabb, DepthMap, FrameCamera, GeometryParams, Mask};

/// Settings of [`extend_to_support`] and [`context_points`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SupportParams {
    /// Off: the box is the fused points' box, as in the paper.
    pub enabled: bool,
    /// Largest gap (m) between the box bottom and a support below it (a chair seat whose
    /// legs were eroded away sits ~0.45 m above the floor; a table top ~0.75 m).
    pub max_gap_down: f64,
    /// Largest gap (m) down to a floor joined through a column: past `max_gap_down`, the
    /// bottom moves onto a support only when measured points under the box's footprint
    /// join the two without a break longer than `column_break` (a floor lamp's shade on its
    /// pole, a round table's top on its pedestal). 0 disables.
    pub max_gap_column: f64,
    /// Longest stretch (m) of a column without a measured point (the mask's clearance
    /// leaves the top of a pole out of the context).
    pub column_break: f64,
    /// Largest gap (m) between a vertical face and a wall behind it that is taken as is
    /// (a picture's or a door's thickness).
    pub max_gap_side: f64,
    /// Largest gap (m) to a wall behind a vertical face when no frame saw that gap empty
    /// (a cabinet's depth, only its front ever seen). 0 disables.
    pub max_gap_far: f64,
    /// A far gap is refused when more than this share of its sample points is seen empty
    /// by some frame (the measured surface there lies behind the point).
    pub max_free: f64,
    /// Spacing (m) of the sample points in a far gap (at most 12 per axis).
    pub free_step: f64,
    /// In-plane margin (m) for the far search: a wall is large, look wider around the box.
    pub margin_far: f64,
    /// Thickness (m) of a support layer (depth noise included).
    pub layer: f64,
    /// How far (m) inside the box a support may lie: depth noise puts part of an object's
    /// cloud behind the wall it hangs on or below the floor it stands on, and an object
    /// does not go through its support, so the face is pulled back onto it.
    pub max_inside: f64,
    /// Margin (m) around the box's extent along the other two axes where support points count.
    pub margin: f64,
    /// Spread (m, 10th–90th percentile) a layer needs along each of the other two axes;
    /// the smaller of this and half the box's own extent on that axis is used, but never
    /// less than 1.5 `layer`.
    pub min_spread: f64,
    /// Share of the ring (width `margin`) around the box's footprint that the layer's
    /// occupied voxels must cover.
    pub min_coverage: f64,
    /// Width (m) of the band right around the footprint whose points do not count toward
    /// that coverage (the band is left out of the ring too): the object's own silhouette
    /// lies there, outside its mask by the clearance and the erosion. Seen from above or
    /// in front, that rim is a ring or a frame of points at one height or depth (a vase's
    /// belly, a monitor's screen), a layer hugging the footprint; a floor, table top or
    /// wall reaches out across the ring.
    pub rim: f64,
    /// Voxel (m) for the context cloud; also the unit of `min_points`.
    pub voxel: f64,
    /// Occupied voxels a layer needs.
    pub min_points: usize,
    /// A layer must hold at least this many times the points of one of the two slabs of
    /// its thickness beside it (just before it, toward the object, or just beyond it). A
    /// surface perpendicular to the search axis packs its points at one coordinate, with
    /// open space on at least one side; surfaces running along the axis (a sofa's seat and
    /// back beside a pillow) spread theirs evenly over every slab, and are no layer.
    /// 0 disables.
    pub layer_peak: f64,
    /// The 2D context region is the detection box grown by this share of its size per side.
    pub context_grow: f64,
    /// Pixels (at 1296 px frame width, scaled with the frame) around the raw mask that are
    /// left out of the context: the object's own silhouette edge and its flying pixels.
    pub mask_clearance: u32,
    /// Classes that hang on a wall rather than rest on something below (compared with the
    /// query's target class, whole or by its last word): their bottom face never moves
    /// down, since the layer below a window is a cabinet or table in front of the wall.
    pub hanging: Vec<String>,
    /// Classes that stand on the floor (compared like `hanging`): with the room's floor
    /// known, their bottom goes onto it before the search for a support below
    /// ([`super::floor_reach::stand_on_floor`]; the seats of chairs pushed in under a table
    /// are not what holds it up). Empty: every class looks for its support.
    pub standing: Vec<String>,
    /// Classes besides `hanging` that are flat against a wall (a door stands on the floor,
    /// but is as thin as a picture): only these and `hanging` get [`super::planar`]'s depth.
    pub flat: Vec<String>,
    /// Largest interquartile range (m) of the anchor's points along a horizontal axis for
    /// them to count as one plane facing the camera (see [`super::planar`]); 0 disables.
    pub planar_iqr: f64,
    /// Largest depth (m) from such a plane to the wall behind it that makes the two one
    /// object (a door, a window, a box pushed against the wall).
    pub planar_max_depth: f64,
    /// Share of the plane's points a 1 cm layer must hold to count as the object's front
    /// face (the layer nearest the camera wins: a window's frame before its glass); 0 takes
    /// the median of the points, one layer. The layer must also stand out of the readings
    /// between it and the main layer (see `planar::front_layer`): a close-up of a window
    /// shows little of its frame, 3 % of the points in one.
    pub planar_front_share: f64,
    /// Cut the patch of a wall an object's mask leaked onto (see [`super::walls`]).
    pub wall_cut: bool,
    /// Cut the points of an object not flat against a wall that lie on a wall of the
    /// room's box ([`super::walls::cut_room_walls`]; needs `agent.geometry.layout`).
    pub room_wall_cut: bool,
    /// How far (m) from the room's wall one frame's points may show it (the frame's pose
    /// error): the wall cut by `room_wall_cut` is the densest layer of the frame's context
    /// within this distance. Also the widest band cut on either side of it.
    pub room_wall_search: f64,
    /// Keep a point within a wall's band whose colour is unlike the wall's and like the
    /// object's ([`super::wall_colour`]).
    pub room_wall_colour: bool,
    /// When no support is found below, set the bottom on the top of a nearer surface whose
    /// edge hides the object's lower part in every view that shows it, when that edge is
    /// above the camera ([`super::hidden_base`]: a cup on a tall bookshelf seen from below).
    pub hidden_base: bool,
    /// When no support is found below and the room's floor is known, set the bottom on
    /// the floor when every view's 2D box says the object reaches it
    /// ([`super::floor_reach`]: a floor lamp's pole, thinner than a depth pixel).
    pub floor_reach: bool,
    /// When the bottom is still where the points end, lower it to where the chosen view's
    /// 2D box ends at the object's distance ([`super::floor_reach::lower_to_box_edge`]: a
    /// lamp's pole hidden behind a desk).
    pub box_edge: bool,
    /// Least share of the chosen view's box height below the object's lowest measured
    /// pixel for `box_edge` to move the bottom (a detector's box overshoots its object by a
    /// few per cent of its size; a pole or legs depth missed are a large part of it).
    pub box_edge_unmeasured: f64,
}

impl SupportParams {
    /// Does an object of `class` hang on a wall (no downward completion)?
    pub fn hangs(&self, class: &str) -> bool {
        class_in(&self.hanging, class)
    }

    /// Does an object of `class` stand on the floor (and not hang)?
    pub fn stands(&self, class: &str) -> bool {
        class_in(&self.standing, class) && !self.hangs(class)
    }

    /// Is an object of `class` flat against a wall (see [`super::planar`])?
    pub fn is_flat(&self, class: &str) -> bool {
        self.hangs(class) || class_in(&self.flat, class)
    }
}

/// Is `class` in `list`, whole or by its last word, singular or plural?
pub(crate) fn class_in(list: &[String], class: &str) -> bool {
    let c = class.trim().to_lowercase();
    let last = c.split_whitespace().last().unwrap_or("");
    list.iter().any(|h| {
        let h = h.to_lowercase();
        h == c
            || h == last
            || h.strip_suffix('s').is_some_and(|x| x == last)
            || format!("{h}s") == last
    })
}

impl Default for SupportParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_gap_down: 0.9,
            max_gap_column: 2.0,
            column_break: 0.12,
            max_gap_side: 0.1,
            max_gap_far: 0.8,
            max_free: 0.15,
            free_step: 0.05,
            margin_far: 0.3,
            layer: 0.04,
            max_inside: 0.08,
            margin: 0.1,
            min_spread: 0.1,
            min_coverage: 0.15,
            rim: 0.02,
            voxel: 0.02,
            min_points: 12,
            layer_peak: 2.0,
            context_grow: 0.5,
            mask_clearance: 9,
            hanging: [
                "window",
                "picture",
                "painting",
                "poster",
                "photo",
                "frame",
                "mirror",
                "whiteboard",
                "blackboard",
                "board",
                "clock",
                "sign",
            ]
            .map(String::from)
            .to_vec(),
            standing: [
                "table",
                "desk",
                "chair",
                "armchair",
                "stool",
                "sofa",
                "couch",
                "bed",
                "dresser",
                "nightstand",
                "wardrobe",
                "bookshelf",
                "bookcase",
                "refrigerator",
                "toilet",
                "bathtub",
                "piano",
            ]
            .map(String::from)
            .to_vec(),
            flat: ["door", "curtain", "blinds", "shade", "radiator"]
                .map(String::from)
                .to_vec(),
            planar_iqr: 0.05,
            planar_max_depth: 0.15,
            planar_front_share: 0.02,
            wall_cut: true,
            room_wall_cut: true,
            room_wall_search: 0.12,
            room_wall_colour: true,
            hidden_base: true,
            floor_reach: true,
            box_edge: true,
            box_edge_unmeasured: 0.2,
        }
    }
}

/// One face of the box that moved onto a support.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SupportExtension {
    /// "x", "y" or "z".
    pub axis: &'static str,
    /// "min" or "max" face.
    pub side: &'static str,
    pub from: f64,
    pub to: f64,
    /// Occupied voxels of the support layer.
    pub points: usize,
    /// For a far wall: share of the crossed gap's sample points some frame saw empty.
    pub seen_empty: Option<f64>,
}

/// Context points of one view: depth pixels inside the detection box `bbox` (grown by
/// `context_grow`), outside the raw object mask grown by `mask_clearance`, back-projected
/// into the output frame and voxel-downsampled.
pub fn context_points(
    mask: &Mask,
    bbox: [f32; 4],
    cam: &FrameCamera,
    depth: &DepthMap,
    p: &SupportParams,
) -> Result<Vec<Point3<f64>>, ProjectionError> {
    let (bw, bh) = (bbox[2] - bbox[0], bbox[3] - bbox[1]);
    let g = p.context_grow as f32;
    let grown = [
        bbox[0] - g * bw,
        bbox[1] - g * bh,
        bbox[2] + g * bw,
        bbox[3] + g * bh,
    ];
    // The grown box less the dilated mask. Only the box's pixels are dilated, cleared and
    // back-projected: outside it the region is empty (the same points, in the same order,
    // as from the whole frame).
    let [x0, y0, x1, y1] = pixel_box(mask.width, mask.height, grown);
    let (x0, y0) = (x0.min(x1), y0.min(y1));
    let scale = f64::from(mask.width) / 1296.0;
    let clearance = (f64::from(p.mask_clearance) * scale).round() as u32;
    let mut region = Mask::new(mask.width, mask.height);
    if x0 < x1 && y0 < y1 {
        let blocked = dilate_square_within(mask, 2 * clearance + 1, [x0, y0, x1, y1]);
        let (w, bw) = (mask.width as usize, (x1 - x0) as usize);
        for y in y0..y1 {
            let row = y as usize * w;
            let dst = &mut region.data[row + x0 as usize..row + x1 as usize];
            let src = &blocked.data[(y - y0) as usize * bw..(y - y0 + 1) as usize * bw];
            for (r, b) in dst.iter_mut().zip(src) {
                *r = !*b;
            }
        }
    }
    let opts = BackprojectOptions {
        stride: 1,
        voxel: 0.0,
        one_per_depth_pixel: true,
    };
    let pts = backproject_mask_within(&region, [x0, y0, x1, y1], cam, depth, opts)?;
    Ok(voxel_downsample(&pts, p.voxel))
}

/// Per-axis median of `points` (robust to noise, unlike the box centre); `None` when empty.
pub fn median_point(points: &[Point3<f64>]) -> Option<[f64; 3]> {
    if points.is_empty() {
        return None;
    }
    Some([0, 1, 2].map(|i| median(&mut points.iter().map(|p| p[i]).collect::<Vec<f64>>())))
}

/// Share of sample points in `gap` that some frame sees empty: the point lands inside that
/// frame and the depth measured there lies beyond it by more than the visibility tolerance
/// of `params`. Points are a grid of at most 12 per axis, inset by a tenth of the gap's
/// extent on each side (rays grazing the object's own edges prove nothing).
pub fn observed_free_fraction(
    gap: &Aabb,
    views: &[(&FrameCamera, &DepthMap)],
    params: &GeometryParams,
) -> f64 {
    let step = params.support.free_step.max(1e-3);
    let axis_samples = |i: usize| -> Vec<f64> {
        let (lo, hi) = (gap.min[i], gap.max[i]);
        let inset = 0.1 * (hi - lo);
        let n = (((hi - lo) / step).round() as usize).clamp(1, 12);
        (0..n)
            .map(|k| lo + inset + (hi - lo - 2.0 * inset) * (k as f64 + 0.5) / n as f64)
            .collect()
    };
    let (xs, ys, zs) = (axis_samples(0), axis_samples(1), axis_samples(2));
    let mut samples = Vec::with_capacity(xs.len() * ys.len() * zs.len());
    for &x in &xs {
        for &y in &ys {
            samples.extend(zs.iter().map(|&z| Point3::new(x, y, z)));
        }
    }
    let mut free = vec![false; samples.len()];
    for (cam, depth) in views {
        let Ok(proj) = project_points(&samples, cam, depth, params) else {
            continue;
        };
        for (f, q) in free.iter_mut().zip(&proj) {
            if let Some(q) = q {
                *f |= q
                    .measured
                    .is_some_and(|d| d > q.z + params.visibility_tolerance(q.z));
            }
        }
    }
    free.iter().filter(|&&f| f).count() as f64 / samples.len().max(1) as f64
}

/// Do measured points inside the footprint of `b` (x, y) run from the support at height
/// `floor` up to the box's bottom with no vertical break longer than `column_break`?
fn column_joins(b: &Aabb, context: &[Point3<f64>], floor: f64, p: &SupportParams) -> bool {
    let mut zs: Vec<f64> = context
        .iter()
        .filter(|q| {
            (b.min[0]..=b.max[0]).contains(&q.x)
                && (b.min[1]..=b.max[1]).contains(&q.y)
                && q.z > floor + p.layer
                && q.z < b.min[2]
        })
        .map(|q| q.z)
        .collect();
    zs.sort_by(f64::total_cmp);
    let mut last = floor;
    for z in zs.into_iter().chain(std::iter::once(b.min[2])) {
        if z - last > p.column_break {
            return false;
        }
        last = z;
    }
    true
}

/// Move each face of `b` (bottom and the four vertical ones) onto the support found beyond
/// it in `context` (points around the object, not on it), or pull it back onto a support
/// up to `max_inside` within the box (noise behind a wall). A support must lie on the
/// face's side of `bulk` (the object's per-axis median point, see [`median_point`]): the
/// wall behind a thin picture is inside its noisy box, and only the back face may move
/// onto it. A vertical face moves out by more than `layer` (up to `max_gap_side`,
/// and further up to `max_gap_far`) only when the gap it crosses was never seen empty by
/// the frames in `views`. With `down` false (an object that hangs on a wall) the bottom
/// face stays. Returns the new box and the faces that moved.
pub fn extend_to_support(
    b: &Aabb,
    bulk: [f64; 3],
    context: &[Point3<f64>],
    views: &[(&FrameCamera, &DepthMap)],
    down: bool,
    params: &GeometryParams,
) -> (Aabb, Vec<SupportExtension>) {
    let p = &params.support;
    let mut out = *b;
    let mut moved = Vec::new();
    if !p.enabled || context.is_empty() {
        return (out, moved);
    }
    const NAMES: [&str; 3] = ["x", "y", "z"];
    for (axis, sign) in [(2usize, -1.0f64), (0, -1.0), (0, 1.0), (1, -1.0), (1, 1.0)] {
        if axis == 2 && !down {
            continue;
        }
        let face = if sign < 0.0 { b.min[axis] } else { b.max[axis] };
        let near_gap = if axis == 2 {
            p.max_gap_down
        } else {
            p.max_gap_side
        };
        // A near support moves the face out onto it, or back onto it from inside the box.
        let near = find_layer(b, context, (axis, sign), near_gap, p.margin, p)
            .filter(|(c, _)| (c - face).abs() > 1e-9 && sign * (c - bulk[axis]) > 0.0)
            .and_then(|(c, n)| {
                // A side gap wider than a layer is crossed only when it was not seen empty
                // (a lamp standing a hand's width from the wall is not against it).
                if axis == 2 || sign * (c - face) <= p.layer {
                    return Some((c, n, None));
                }
                let mut slab = *b;
                slab.min[axis] = face.min(c);
                slab.max[axis] = face.max(c);
                let free = observed_free_fraction(&slab, views, params);
                (free <= p.max_free).then_some((c, n, Some(free)))
            });
        let found = near.or_else(|| {
            // A floor further down, joined through a column under the box.
            if axis == 2 {
                if p.max_gap_column <= p.max_gap_down {
                    return None;
                }
                let (coord, n) =
                    find_layer(b, context, (axis, sign), p.max_gap_column, p.margin, p)?;
                return (coord < face - p.max_gap_down && column_joins(b, context, coord, p))
                    .then_some((coord, n, None));
            }
            // A wall further back, joined only when no frame saw the gap empty.
            if p.max_gap_far <= p.max_gap_side {
                return None;
            }
            let (coord, n) = find_layer(b, context, (axis, sign), p.max_gap_far, p.margin_far, p)?;
            if sign * (coord - face) <= 0.0 {
                return None;
            }
            let mut slab = *b;
            slab.min[axis] = face.min(coord);
            slab.max[axis] = face.max(coord);
            let free = observed_free_fraction(&slab, views, params);
            (free <= p.max_free).then_some((coord, n, Some(free)))
        });
        let Some((coord, points, seen_empty)) = found else {
            continue;
        };
        if sign < 0.0 {
            out.min[axis] = coord;
        } else {
            out.max[axis] = coord;
        }
        moved.push(SupportExtension {
            axis: NAMES[axis],
            side: if sign < 0.0 { "min" } else { "max" },
            from: face,
            to: coord,
            points,
            seen_empty,
        });
    }
    // Both side faces of one axis pulled back onto what is one surface (the two medians
    // within a layer), with the object's median point between them: that surface runs
    // through the object, and is the object's own (a monitor's back panel seen around
    // its mask), not a support it rests against. Neither face moves.
    for (axis, name) in NAMES.iter().enumerate().take(2) {
        let inward = |side: &str, sign: f64| {
            moved
                .iter()
                .any(|m| m.axis == *name && m.side == side && sign * (m.to - m.from) > 0.0)
        };
        if inward("min", 1.0) && inward("max", -1.0) && out.max[axis] - out.min[axis] < p.layer {
            out.min[axis] = b.min[axis];
            out.max[axis] = b.max[axis];
            moved.retain(|m| m.axis != *name);
        }
    }
    (out, moved)
}

#[cfg(test)]
#[path = "support_tests.rs"]
mod tests;
