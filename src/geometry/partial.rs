//! Did a view see the whole object, or a part of it? (ours, not the paper's)
//!
//! A mask is evidence of a part only when something in the image says so:
//! - **border**: the mask reaches the edge of the frame, so the object may go on beyond it;
//! - **occluded**: along part of its outline, the surface just outside the mask is much
//!   nearer the camera than the mask's own edge (a table's edge in front of a chair's
//!   seat): the object may go on behind that surface;
//! - **no depth**: many of the mask's pixels have no depth reading (a black or glossy
//!   object), so its points cover only part of it;
//! - **one face** ([`face_depth_ratio`]): the points of a solid object make a slab a few
//!   centimetres thin however wide and tall it is (that face hides the rest).
//!
//! The agent uses it to decide whether the other views may widen the object beyond what
//! the chosen view segmented (see `agent::projection`).

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::morph::bounds;
use super::support_layer::percentile;
use super::{DepthMap, FrameCamera, Mask};

/// Thresholds of [`partial_view`] (file section `[agent.candidates.partial]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PartialParams {
    /// A mask pixel this close to the frame's edge, as a fraction of the image's width,
    /// touches the border.
    pub border_frac: f64,
    /// Depth pixels between a mask's edge pixel and the pixel outside it that is compared.
    pub reach: u32,
    /// A surface nearer than the mask's edge by more than this (m)...
    pub occluder_step: f64,
    /// ...plus this much per metre of depth hides part of the object.
    pub occluder_per_m: f64,
    /// Share of the outline (edge pixels with a reading) that must be hidden so.
    pub min_occluded: f64,
    /// Share of the mask's pixels without a depth reading that makes it a part.
    pub min_missing: f64,
    /// Share of a side of the object's box (just inside it) that a nearer surface must
    /// cover for the object to go on past that side (see [`hidden_sides`]); above 1 no
    /// side is ever open.
    pub min_side_occluded: f64,
    /// A view whose points of a solid object (not hanging, not flat) are thinner than this
    /// share of their narrower other extent saw one face of it (see [`face_depth_ratio`]);
    /// 0 turns it off.
    pub face_depth_ratio: f64,
}

impl Default for PartialParams {
    fn default() -> Self {
        Self {
            border_frac: 0.01,
            reach: 2,
            occluder_step: 0.15,
            occluder_per_m: 0.03,
            min_occluded: 0.1,
            min_missing: 0.25,
            min_side_occluded: 0.3,
            face_depth_ratio: 0.25,
        }
    }
}

/// What [`partial_view`] found (kept in the job's trace).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PartialView {
    /// The mask reaches the frame's edge.
    pub border: bool,
    /// Share of the outline hidden by a nearer surface.
    pub occluded: f64,
    /// Share of the mask's pixels without a depth reading.
    pub missing: f64,
    /// Any of the three says the view saw a part.
    pub partial: bool,
}

/// The evidence that `mask` (colour pixels of `camera`) holds only part of its object,
/// read from the frame's own `depth` (not a completed one: a missing reading is what is
/// looked for). An empty mask is not partial.
pub fn partial_view(
    mask: &Mask,
    camera: &FrameCamera,
    depth: &DepthMap,
    params: &PartialParams,
) -> PartialView {
    let (w, h) = (mask.width, mask.height);
    let margin = (params.border_frac * f64::from(w)).ceil().max(0.0) as u32;
    let (mut pixels, mut missing) = (0usize, 0usize);
    let mut border = false;
    // Depth pixels on the mask's outline, and which of them look onto a nearer surface.
    let (wd, hd) = (depth.width, depth.height);
    let mut in_mask = vec![false; wd as usize * hd as usize];
    // Only the mask's bounding box holds mask pixels, and only the depth pixels they read
    // can be on its outline.
    let Some([bx0, by0, bx1, by1]) = bounds(mask, 0) else {
        return PartialView {
            border: false,
            occluded: 0.0,
            missing: 0.0,
            partial: false,
        };
    };
    let corner = |x: u32, y: u32| camera.depth_pixel_for_color(f64::from(x), f64::from(y));
    let ((dx0, dy0), (dx1, dy1)) = (corner(bx0, by0), corner(bx1 - 1, by1 - 1));
    for y in by0..by1 {
        for x in bx0..bx1 {
            if !mask.get(x, y) {
                continue;
            }
            pixels += 1;
            border |= x < margin || y < margin || x + margin >= w || y + margin >= h;
            let (dx, dy) = camera.depth_pixel_for_color(f64::from(x), f64::from(y));
            if dx < wd && dy < hd {
                in_mask[(dy * wd + dx) as usize] = true;
                missing += usize::from(depth.get(dx, dy) == 0);
            } else {
                missing += 1;
            }
        }
    }
    let inside = |x: i64, y: i64| {
        x >= 0
            && y >= 0
            && x < i64::from(wd)
            && y < i64::from(hd)
            && in_mask[(y * i64::from(wd) + x) as usize]
    };
    let reach = i64::from(params.reach.max(1));
    let (mut outline, mut hidden) = (0usize, 0usize);
    for y in i64::from(dy0)..=i64::from(dy1) {
        for x in i64::from(dx0)..=i64::from(dx1) {
            if !inside(x, y) {
                continue;
            }
            let d = depth.get(x as u32, y as u32);
            if d == 0 {
                continue;
            }
            let mut open = [(1, 0), (-1, 0), (0, 1), (0, -1)]
                .into_iter()
                .filter(|(ox, oy)| !inside(x + ox, y + oy))
                .peekable();
            if open.peek().is_none() {
                continue;
            }
            outline += 1;
            let z = f64::from(d) / 1000.0;
            let step = params.occluder_step + params.occluder_per_m * z;
            let nearer = open.any(|(ox, oy)| {
                let (qx, qy) = (x + ox * reach, y + oy * reach);
                if qx < 0 || qy < 0 || qx >= i64::from(wd) || qy >= i64::from(hd) || inside(qx, qy)
                {
                    return false;
                }
                let q = depth.get(qx as u32, qy as u32);
                q != 0 && z - f64::from(q) / 1000.0 > step
            });
            hidden += usize::from(nearer);
        }
    }
    let occluded = if outline == 0 {
        0.0
    } else {
        hidden as f64 / outline as f64
    };
    let missing = missing as f64 / pixels as f64;
    PartialView {
        border,
        occluded,
        missing,
        partial: border || occluded >= params.min_occluded || missing >= params.min_missing,
    }
}

/// For each side of `bbox` (colour pixels of `camera`: left, top, right, bottom), the share
/// of the depth readings along a line just inside it (an inset of 3 % of the box's size, at
/// least 2 pixels) that lie nearer than the object by more than the occluder step. The
/// object's depth is the 10th percentile of the readings under `mask` (its near part). A
/// table top across a chair behind it crosses the chair's box: the chair may go on past
/// that side, hidden, and the box does not bound it there. A door seen whole across the
/// room has its own wall along its box's sides, at its depth. All zero without readings.
pub fn hidden_sides(
    bbox: [f32; 4],
    mask: &Mask,
    camera: &FrameCamera,
    depth: &DepthMap,
    params: &PartialParams,
) -> [f64; 4] {
    const SAMPLES: u32 = 64;
    let (wd, hd) = (depth.width, depth.height);
    let read = |x: f64, y: f64| {
        let (dx, dy) = camera.depth_pixel_for_color(x.max(0.0), y.max(0.0));
        (dx < wd && dy < hd)
            .then(|| depth.get(dx, dy))
            .filter(|d| *d != 0)
            .map(|d| f64::from(d) / 1000.0)
    };
    let b = bbox.map(f64::from);
    if !b.iter().all(|v| v.is_finite()) || b[2] <= b[0] || b[3] <= b[1] {
        return [0.0; 4];
    }
    // The object's readings, on a grid of at most about 64 x 64 over the mask's box.
    let Some([mx0, my0, mx1, my1]) = bounds(mask, 0) else {
        return [0.0; 4];
    };
    let stride = ((mx1 - mx0).max(my1 - my0) / SAMPLES).max(1);
    let mut zs: Vec<f64> = (my0..my1)
        .step_by(stride as usize)
        .flat_map(|y| (mx0..mx1).step_by(stride as usize).map(move |x| (x, y)))
        .filter(|&(x, y)| mask.get(x, y))
        .filter_map(|(x, y)| read(f64::from(x), f64::from(y)))
        .collect();
    if zs.is_empty() {
        return [0.0; 4];
    }
    zs.sort_by(f64::total_cmp);
    let z = zs[zs.len() / 10];
    let step = params.occluder_step + params.occluder_per_m * z;
    let (w, h) = (b[2] - b[0], b[3] - b[1]);
    let (ix, iy) = ((0.03 * w).max(2.0), (0.03 * h).max(2.0));
    let along = |k: u32, lo: f64, len: f64| lo + len * (f64::from(k) + 0.5) / f64::from(SAMPLES);
    let side = |at: &dyn Fn(u32) -> (f64, f64)| {
        let (mut seen, mut nearer) = (0usize, 0usize);
        for k in 0..SAMPLES {
            let (x, y) = at(k);
            if let Some(d) = read(x, y) {
                seen += 1;
                nearer += usize::from(z - d > step);
            }
        }
        if seen == 0 {
            0.0
        } else {
            nearer as f64 / seen as f64
        }
    };
    [
        side(&|k| (b[0] + ix, along(k, b[1], h))),
        side(&|k| (along(k, b[0], w), b[1] + iy)),
        side(&|k| (b[2] - ix, along(k, b[1], h))),
        side(&|k| (along(k, b[0], w), b[3] - iy)),
    ]
}

/// How thin `points` (output frame, +z up) are across their narrowest level direction, as
/// a share of the narrower of their other two extents: level and square to it, and
/// vertical (each the spread between the 5th and the 95th percentile; the directions are
/// the principal axes of the points' level spread). A solid object is about as deep as it
/// is wide, while a view of one face of it measures a slab of a few centimetres however
/// wide and tall the face is, from whatever side it looks: a chair seen from behind, its
/// back hiding the seat. Such a view saw part of the object even when nothing else hides
/// it. None with fewer than 20 points.
pub fn face_depth_ratio(points: &[Point3<f64>]) -> Option<f64> {
    if points.len() < 20 {
        return None;
    }
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.x / n, b + p.y / n));
    let (mut cxx, mut cyy, mut cxy) = (0.0, 0.0, 0.0);
    for p in points {
        let (dx, dy) = (p.x - mx, p.y - my);
        cxx += dx * dx;
        cyy += dy * dy;
        cxy += dx * dy;
    }
    // The level direction of the largest spread; the thin one is square to it.
    let t = 0.5 * (2.0 * cxy).atan2(cxx - cyy);
    let (ax, ay) = (t.cos(), t.sin());
    let spread = |f: &dyn Fn(&Point3<f64>) -> f64| {
        let mut v: Vec<f64> = points.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        percentile(&v, 0.95) - percentile(&v, 0.05)
    };
    let thin = spread(&|p| p.y * ax - p.x * ay);
    let across = spread(&|p| p.x * ax + p.y * ay).min(spread(&|p| p.z));
    (across.is_finite() && across > 0.0).then(|| thin / across)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Intrinsics;
    use nalgebra::Matrix4;

    fn camera(w: u32, h: u32) -> FrameCamera {
        let k = Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: f64::from(w) / 2.0,
            cy: f64::from(h) / 2.0,
            width: w,
            height: h,
        };
        FrameCamera {
            color: k,
            depth: None,
            depth_size: (w, h),
            pose: Matrix4::identity(),
            align: Matrix4::identity(),
        }
    }

    /// A 100x80 frame: wall at 3 m, an object at 2 m in the box [30, 20, 70, 60).
    fn scene() -> (Mask, DepthMap) {
        let (w, h) = (100, 80);
        let mut mask = Mask::new(w, h);
        let mut d = vec![3000u16; (w * h) as usize];
        for y in 20..60 {
            for x in 30..70 {
                mask.set(x, y, true);
                d[(y * w + x) as usize] = 2000;
            }
        }
        (mask, DepthMap::new(w, h, d))
    }

    #[test]
    fn a_whole_object_before_a_wall_is_not_partial() {
        let (mask, depth) = scene();
        let p = partial_view(&mask, &camera(100, 80), &depth, &PartialParams::default());
        assert!(!p.partial && !p.border, "{p:?}");
        assert_eq!((p.occluded, p.missing), (0.0, 0.0));
    }

    #[test]
    fn an_object_behind_a_nearer_edge_is_partial() {
        // A table's edge at 1.2 m covers the rows below the object's visible part.
        let (mut mask, mut depth) = scene();
        let DepthMap { width: w, .. } = depth;
        let mut d = depth.data.to_vec();
        for y in 45..80 {
            for x in 0..100 {
                d[(y * w + x) as usize] = 1200;
                mask.set(x, y, false);
            }
        }
        depth = DepthMap::new(w, 80, d);
        let p = partial_view(&mask, &camera(100, 80), &depth, &PartialParams::default());
        assert!(p.partial && !p.border && p.occluded > 0.2, "{p:?}");
        // A surface only slightly nearer (the top of what the object stands on) hides nothing.
        let mut d = depth.data.to_vec();
        for v in d.iter_mut().filter(|v| **v == 1200) {
            *v = 1950;
        }
        let p = partial_view(
            &mask,
            &camera(100, 80),
            &DepthMap::new(w, 80, d),
            &PartialParams::default(),
        );
        assert!(!p.partial && p.occluded == 0.0, "{p:?}");
    }

    #[test]
    fn an_object_at_the_frame_edge_or_without_depth_is_partial() {
        let (mut mask, depth) = scene();
        for y in 20..60 {
            mask.set(0, y, true);
        }
        let p = partial_view(&mask, &camera(100, 80), &depth, &PartialParams::default());
        assert!(p.partial && p.border, "{p:?}");
        // Half of the object has no reading.
        let (mask, depth) = scene();
        let mut d = depth.data.to_vec();
        for y in 20..60 {
            for x in 30..50 {
                d[(y * 100 + x) as usize] = 0;
            }
        }
        let p = partial_view(
            &mask,
            &camera(100, 80),
            &DepthMap::new(100, 80, d),
            &PartialParams::default(),
        );
        assert!(
            p.partial && !p.border && (p.missing - 0.5).abs() < 1e-9,
            "{p:?}"
        );
        // An empty mask says nothing.
        let p = partial_view(
            &Mask::new(100, 80),
            &camera(100, 80),
            &depth,
            &PartialParams::default(),
        );
        assert!(!p.partial, "{p:?}");
    }

    #[test]
    fn a_nearer_surface_across_a_side_of_the_box_opens_that_side() {
        // The object at 2 m in the box [30, 20, 70, 60); a table's top at 1.2 m covers
        // the columns left of x = 40 from row 30 down, crossing the box's left side.
        let (mut mask, depth) = scene();
        let whole = mask.clone();
        let mut d = depth.data.to_vec();
        for y in 30..80 {
            for x in 0..40 {
                d[(y * 100 + x) as usize] = 1200;
                mask.set(x, y, false);
            }
        }
        let table = DepthMap::new(100, 80, d);
        let cam = camera(100, 80);
        let rule = PartialParams::default();
        let bx = [30.0, 20.0, 70.0, 60.0];
        let sides = hidden_sides(bx, &mask, &cam, &table, &rule);
        assert!(sides[0] > 0.6, "{sides:?}");
        assert!(sides[3] > 0.15 && sides[3] < 0.3, "{sides:?}");
        assert_eq!((sides[1], sides[2]), (0.0, 0.0), "{sides:?}");
        // Seen whole before its wall, no side is hidden; nor without the object's depth.
        assert_eq!(hidden_sides(bx, &whole, &cam, &depth, &rule), [0.0; 4]);
        let empty = Mask::new(100, 80);
        assert_eq!(hidden_sides(bx, &empty, &cam, &table, &rule), [0.0; 4]);
    }

    #[test]
    fn one_face_of_a_solid_object_is_a_thin_slab() {
        // A chair's back, 44 cm wide and 90 cm tall, measured with a centimetre of noise
        // (what a view from behind sees), and the whole chair, 45 cm deep; both turned
        // about the vertical by several angles.
        let mut back = Vec::new();
        let mut chair = Vec::new();
        for i in 0..45 {
            for j in 0..31 {
                let (x, z) = (-0.22 + 0.01 * f64::from(i), 0.03 * f64::from(j));
                let noise = 0.01 * f64::from((i * 7 + j * 13) % 5) / 4.0 - 0.005;
                back.push(Point3::new(x, 3.0 + noise, z));
                for k in 0..10 {
                    chair.push(Point3::new(x, 3.0 + 0.05 * f64::from(k), z));
                }
            }
        }
        let turn = |pts: &[Point3<f64>], deg: f64| -> Vec<Point3<f64>> {
            let (c, s) = (deg.to_radians().cos(), deg.to_radians().sin());
            pts.iter()
                .map(|p| Point3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z))
                .collect()
        };
        for deg in [0.0, 30.0, 45.0, 90.0, 160.0] {
            let face = face_depth_ratio(&turn(&back, deg)).unwrap_or(1.0);
            assert!(face < 0.1, "{deg}: {face}");
            let whole = face_depth_ratio(&turn(&chair, deg)).unwrap_or(0.0);
            assert!(whole > 0.8, "{deg}: {whole}");
        }
        // Too few points: nothing is said.
        assert_eq!(face_depth_ratio(&back[..10]), None);
    }
}
