//! Objects standing on a level top: a box on a table, a lamp on a nightstand, a pillow on
//! a bed, a monitor on a desk. Depth joins them to what they stand on (nothing separates
//! the box's bottom from the table top it rests on), and colour does not when both are one
//! colour, so the object region holds the two as one.
//!
//! Within an object region, a *top* is a patch of level cells (the surface normal within
//! `top_level_deg` of vertical) at one height, seen from above. The region's cells that
//! rise more than `top_lift` (+ `top_lift_per_m` per metre of depth) above it, over its
//! footprint, form connected pieces; a piece is a candidate of its own when the top
//! reaches past it by `top_inset` on both sides along some horizontal axis of the room.
//! That last rule tells an object standing *on* a top from a part of the same object that
//! rises from the top's edge: a chair's back over its seat, a bed's headboard, a sofa's
//! back. Such a part runs along one edge of the top, and every edge of a rectangle holds
//! the rectangle's extreme corner along each axis, whatever its turn.
//!
//! A piece, or a colour part of a region, can hold several objects side by side (two
//! pillows of one colour on a bed, the nearer hiding part of the other). Each object
//! standing on the top has a level top of its own, and two objects' footprints do not
//! overlap, while the strips one top breaks into at a grazing view do. So the piece's own
//! level tops are grouped by overlapping footprints; with two groups or more, each cell of
//! the piece goes to the group whose footprint lies nearest it (a side face lies on its
//! top's outline), and each group's connected cells are offered beside the piece
//! (`side_by_side`).

use nalgebra::{Point3, Vector3};

use std::collections::BTreeMap;

use crate::geometry::cloud::median;

use super::grid::{components, pairs_from, regions as grid_regions, Grid, Sets};
use super::CandidateParams;

/// Most tops looked at per region (the largest).
const MAX_TOPS: usize = 4;

/// The surface normal of cell `i` of region `k` (`object_of`), from the region's cells
/// two steps to either side (central differences where both are in it, else one-sided);
/// `None` at a region's thin end.
fn normal(g: &Grid, object_of: &[usize], k: usize, i: usize) -> Option<Vector3<f64>> {
    const STEP: isize = 2;
    let (x, y) = (i % g.w, i / g.w);
    let at = |dx: isize, dy: isize| -> Option<usize> {
        let (nx, ny) = (x as isize + dx, y as isize + dy);
        if nx < 0 || ny < 0 || nx as usize >= g.w || ny as usize >= g.h {
            return None;
        }
        let j = ny as usize * g.w + nx as usize;
        (object_of[j] == k).then_some(j)
    };
    let diff = |a: Option<usize>, b: Option<usize>| -> Option<Vector3<f64>> {
        match (a, b) {
            (Some(a), Some(b)) => Some(g.pts[b] - g.pts[a]),
            (None, Some(b)) => Some(g.pts[b] - g.pts[i]),
            (Some(a), None) => Some(g.pts[i] - g.pts[a]),
            (None, None) => None,
        }
    };
    let du = diff(at(-STEP, 0), at(STEP, 0))?;
    let dv = diff(at(0, -STEP), at(0, STEP))?;
    let n = du.cross(&dv);
    let len = n.norm();
    (len > 1e-12).then(|| n / len)
}

/// A point's horizontal coordinates along the room's axes, turned by the angle whose
/// (sine, cosine) is `sc` about +z.
fn room_uv(p: &Point3<f64>, (s, c): (f64, f64)) -> [f64; 2] {
    [c * p.x + s * p.y, -s * p.x + c * p.y]
}

/// Horizontal extent of `pts` along the room's axes ([`room_uv`]): [[u lo, u hi], [v lo,
/// v hi]].
fn extent<'a>(pts: impl Iterator<Item = &'a Point3<f64>>, sc: (f64, f64)) -> [[f64; 2]; 2] {
    let mut e = [[f64::INFINITY, f64::NEG_INFINITY]; 2];
    for p in pts {
        for (a, t) in e.iter_mut().zip(room_uv(p, sc)) {
            a[0] = a[0].min(t);
            a[1] = a[1].max(t);
        }
    }
    e
}

/// The level tops of the regions `which` of `regions` (cell `i` in region `region_of[i]`,
/// or `usize::MAX`), largest first: level cells (the surface normal within `top_level_deg`
/// of vertical) of one region at one height (`top_lift`), neighbours joined where
/// `joins(a, b)` also holds; tops of fewer than `min_cells` are left out. A box's own top
/// is level too, at its height.
fn level_tops<R: AsRef<[usize]>>(
    g: &Grid,
    regions: &[R],
    which: &[usize],
    region_of: &[usize],
    joins: &dyn Fn(usize, usize) -> bool,
    p: &CandidateParams,
) -> Vec<Vec<usize>> {
    let n = g.w * g.h;
    let cos_level = p.top_level_deg.to_radians().cos();
    let mut level = vec![false; n];
    for &k in which {
        for &i in regions[k].as_ref() {
            level[i] = normal(g, region_of, k, i).is_some_and(|v| v.z.abs() >= cos_level);
        }
    }
    let lift = |i: usize| p.top_lift + p.top_lift_per_m * g.z[i];
    let mut sets = Sets::new(n);
    // Only the regions' own cells can be level: the pairs they start are every pair worth
    // looking at, not the whole grid's (this runs once per colour part).
    let cells = which
        .iter()
        .flat_map(|&k| regions[k].as_ref().iter().copied());
    for (a, b) in pairs_from(g.w, g.h, cells) {
        if level[a]
            && level[b]
            && region_of[a] == region_of[b]
            && (g.pts[a].z - g.pts[b].z).abs() < lift(a).min(lift(b))
            && joins(a, b)
        {
            sets.join(a, b);
        }
    }
    let mut tops = grid_regions(&mut sets, |i| level[i], n);
    tops.retain(|t| t.len() >= p.min_cells);
    tops
}

/// The pieces of the object regions `regions` (cell `i` in region `object_of[i]`, or
/// `usize::MAX`) that stand on one of their level tops (see the module docs), as cell
/// lists. Only regions of at least `2 * min_cells` are looked at. `eye_z` is the camera's
/// height (a top must be seen from above: a shelf board seen from below shows its
/// underside), `angle_deg` the turn of the room's axes.
pub(super) fn on_tops(
    g: &Grid,
    regions: &[Vec<usize>],
    object_of: &[usize],
    eye_z: f64,
    angle_deg: f64,
    p: &CandidateParams,
) -> Vec<Vec<usize>> {
    let big: Vec<usize> = (0..regions.len())
        .filter(|&k| regions[k].len() >= 2 * p.min_cells)
        .collect();
    // Largest first (`level_tops`), so each region's list is too.
    let mut tops_of: BTreeMap<usize, Vec<Vec<usize>>> = BTreeMap::new();
    for top in level_tops(g, regions, &big, object_of, &|_, _| true, p) {
        tops_of.entry(object_of[top[0]]).or_default().push(top);
    }
    let mut out = Vec::new();
    for (k, tops) in tops_of {
        let region = &regions[k];
        for top in tops.iter().take(MAX_TOPS) {
            out.extend(standing_on(g, region, top, eye_z, angle_deg, p));
        }
    }
    out
}

/// Distance (m) from horizontal point `uv` to the footprint `e` ([`extent`]).
fn rect_distance(uv: [f64; 2], e: &[[f64; 2]; 2]) -> f64 {
    let d = |a: usize| (e[a][0] - uv[a]).max(uv[a] - e[a][1]).max(0.0);
    d(0).hypot(d(1))
}

/// Do footprints `a` and `b` overlap along both axes?
fn overlap(a: &[[f64; 2]; 2], b: &[[f64; 2]; 2]) -> bool {
    (0..2).all(|k| a[k][0] <= b[k][1] && b[k][0] <= a[k][1])
}

/// The objects side by side in `piece` (a colour part, or a piece standing on a top: see
/// the module docs), as cell lists; empty when its level tops form one group. `near(a,
/// b)`: neighbouring cells `a`, `b` lie on one surface (the object regions' depth-step
/// rule); `angle_deg` the turn of the room's axes.
pub(super) fn side_by_side(
    g: &Grid,
    piece: &[usize],
    angle_deg: f64,
    near: &dyn Fn(usize, usize) -> bool,
    p: &CandidateParams,
) -> Vec<Vec<usize>> {
    let sc = angle_deg.to_radians().sin_cos();
    let mut member = vec![usize::MAX; g.w * g.h];
    for &i in piece {
        member[i] = 0;
    }
    let tops: Vec<[[f64; 2]; 2]> = level_tops(g, &[piece], &[0], &member, near, p)
        .iter()
        .map(|t| extent(t.iter().map(|&i| &g.pts[i]), sc))
        .collect();
    if tops.len() < 2 {
        return Vec::new();
    }
    // Tops whose footprints overlap are one object's (the strips of one top).
    let mut groups = Sets::new(tops.len());
    for a in 0..tops.len() {
        for b in a + 1..tops.len() {
            if overlap(&tops[a], &tops[b]) {
                groups.join(a, b);
            }
        }
    }
    let group: Vec<usize> = (0..tops.len()).map(|t| groups.find(t)).collect();
    if group.iter().all(|&k| k == group[0]) {
        return Vec::new();
    }
    let mut of_group: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for &i in piece {
        let uv = room_uv(&g.pts[i], sc);
        let nearest = tops
            .iter()
            .enumerate()
            .map(|(t, e)| (rect_distance(uv, e), group[t]))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((_, k)) = nearest {
            of_group.entry(k).or_default().push(i);
        }
    }
    of_group
        .values()
        .flat_map(|cells| components(g, cells))
        .filter(|c| c.len() >= p.min_cells && c.len() * 10 < piece.len() * 9)
        .collect()
}

/// The pieces of `region` that stand on its level `top` (see the module docs).
fn standing_on(
    g: &Grid,
    region: &[usize],
    top: &[usize],
    eye_z: f64,
    angle_deg: f64,
    p: &CandidateParams,
) -> Vec<Vec<usize>> {
    let h = median(&mut top.iter().map(|&i| g.pts[i].z).collect::<Vec<f64>>());
    if eye_z <= h + p.top_lift {
        return Vec::new();
    }
    let lift = |i: usize| p.top_lift + p.top_lift_per_m * g.z[i];
    let sc = angle_deg.to_radians().sin_cos();
    let te = extent(top.iter().map(|&i| &g.pts[i]), sc);
    let over = |q: &Point3<f64>| {
        let uv = room_uv(q, sc);
        (0..2).all(|a| uv[a] >= te[a][0] - p.top_inset && uv[a] <= te[a][1] + p.top_inset)
    };
    let above: Vec<usize> = region
        .iter()
        .copied()
        .filter(|&i| g.pts[i].z > h + lift(i) && over(&g.pts[i]))
        .collect();
    components(g, &above)
        .into_iter()
        .filter(|piece| {
            if piece.len() < p.min_cells || piece.len() * 10 >= region.len() * 9 {
                return false;
            }
            let pe = extent(piece.iter().map(|&i| &g.pts[i]), sc);
            (0..2).any(|a| pe[a][0] >= te[a][0] + p.top_inset && pe[a][1] <= te[a][1] - p.top_inset)
        })
        .collect()
}
