//! Views that complement a partly seen anchor: the chamfer test drops a view that holds
//! another part of the object than the chosen view does (a floor lamp's shade above a
//! close-up of its pole), since the two clouds lie far apart. Such a view is kept again
//! when the chosen frame agrees with it, in one of two ways:
//!
//! - **seen and on the mask**: of the view's points that the chosen frame sees (on its
//!   measured surface, or through empty space), at least `consensus.complement_agree` lie
//!   on its mask; what the frame cannot see (hidden, no reading) says nothing against it.
//! - **beyond the cut**: the chosen mask meets the frame's edge, and most of the view's
//!   points project past that edge, over the stretch of it the mask meets: the rest of
//!   the object the frame cut off. The view's points must come within
//!   [`super::bridge::MAX_GAP`] of the chosen view's, and what of them the frame does see
//!   must still agree as above.

use nalgebra::Point3;
use rayon::prelude::*;

use super::camera::transform_point;
use super::cloud::voxel_downsample;
use super::consensus::{inside, scaled_kernel, CoarseMask, MaskView, Probe, Seen};
use super::ensemble::ViewDecision;
use super::knn::build_tree;
use super::{GeometryParams, Mask};

/// Fewest points of a view the anchor's frame must see (or find past its cut) to judge it.
const MIN_SEEN: usize = 8;

/// Share of a view's points that must lie past the anchor's cut edge for the view to be
/// the part the frame cut off: most of it.
const BEYOND_SHARE: f64 = 0.5;

/// Keep the views the chamfer test dropped that complement a partly seen anchor (the
/// module documentation). `anchor_ds`: the anchor's points, voxel-downsampled at
/// `fusion_voxel`; `border_frac`: the partial rule's, for where its mask meets the frame's
/// edge; `clouds`: every other view's points, in the order of `decisions`. The
/// dropped views' points are downsampled the same way into `sampled` (by view), so that
/// the fusion need not do it again for those it keeps.
pub(super) fn complements(
    decisions: &mut [ViewDecision],
    clouds: &[(usize, &[Point3<f64>])],
    anchor: &MaskView<'_>,
    border_frac: f64,
    anchor_ds: &[Point3<f64>],
    sampled: &mut [Option<Vec<Point3<f64>>>],
    params: &GeometryParams,
) {
    let agree = params.consensus.complement_agree;
    if agree <= 0.0 {
        return;
    }
    let dropped: Vec<usize> = (0..decisions.len())
        .filter(|&i| !decisions[i].kept)
        .collect();
    if dropped.is_empty() {
        return;
    }
    for &i in &dropped {
        sampled[i] = Some(voxel_downsample(clouds[i].1, params.fusion_voxel));
    }
    let refs: Vec<&[Point3<f64>]> = dropped
        .iter()
        .map(|&i| sampled[i].as_deref().unwrap_or_default())
        .collect();
    let judged = anchor_agreement(&refs, anchor, params);
    let margin = (border_frac * f64::from(anchor.mask.width)).ceil();
    let cut = cut_edges(anchor.mask, margin.max(1.0) as u32);
    let anchor_tree =
        (!anchor_ds.is_empty() && cut.iter().any(Option::is_some)).then(|| build_tree(anchor_ds));
    for (k, &i) in dropped.iter().enumerate() {
        let [seen, on] = judged[k];
        let agrees = on as f64 >= agree * seen as f64;
        let d = &mut decisions[i];
        d.agreement = Some([seen, on]);
        if seen >= MIN_SEEN && agrees {
            d.kept = true;
            d.complements = true;
            continue;
        }
        let Some(tree) = anchor_tree.as_ref() else {
            continue;
        };
        let pts = refs[k];
        let beyond = beyond_cut(pts, anchor, &cut);
        d.beyond_cut = Some(beyond);
        if beyond < MIN_SEEN || (beyond as f64) < BEYOND_SHARE * pts.len() as f64 {
            continue;
        }
        let near = pts.iter().any(|p| {
            let n = tree.nearest_one::<kiddo::SquaredEuclidean>(&[p.x, p.y, p.z]);
            n.distance.sqrt() <= super::bridge::MAX_GAP
        });
        if near && (seen < MIN_SEEN || agrees) {
            d.kept = true;
            d.complements = true;
        }
    }
}

/// Where `mask` meets the frame's edges, per side (left, top, right, bottom): the range
/// along that edge (rows for left and right, columns for top and bottom) of the mask's
/// pixels within `margin` of it.
fn cut_edges(mask: &Mask, margin: u32) -> [Option<(u32, u32)>; 4] {
    let (w, h) = (mask.width, mask.height);
    let mut cut: [Option<(u32, u32)>; 4] = [None; 4];
    let mut widen = |side: usize, at: u32| {
        cut[side] = Some(cut[side].map_or((at, at), |(a, b)| (a.min(at), b.max(at))));
    };
    for y in 0..h {
        for x in 0..w {
            if !mask.get(x, y) {
                continue;
            }
            if x < margin {
                widen(0, y);
            }
            if y < margin {
                widen(1, x);
            }
            if x + margin >= w {
                widen(2, y);
            }
            if y + margin >= h {
                widen(3, x);
            }
        }
    }
    cut
}

/// How many of `points` project past a side of the anchor's image that its mask meets
/// (`cut`), in the stretch of that side the mask meets. The stretch is compared with the
/// range the points beyond that side span, not point by point: a lamp's shade is wider
/// than the pole a close-up cut.
fn beyond_cut(
    points: &[Point3<f64>],
    anchor: &MaskView<'_>,
    cut: &[Option<(u32, u32)>; 4],
) -> usize {
    let cam = anchor.camera;
    let Ok(to_cam) = cam.out_to_cam() else {
        return 0;
    };
    let (w, h) = (f64::from(cam.color.width), f64::from(cam.color.height));
    // Per side: how many points lie past it, and the range along it they span.
    let mut past = [(0usize, f64::INFINITY, f64::NEG_INFINITY); 4];
    for p in points {
        let Some((u, v, _)) = cam.color.project(&transform_point(&to_cam, p)) else {
            continue;
        };
        let sides = [
            (u < -0.5, v),
            (v < -0.5, u),
            (u >= w - 0.5, v),
            (v >= h - 0.5, u),
        ];
        for (s, (out, along)) in sides.into_iter().enumerate() {
            if out && cut[s].is_some() {
                let e = &mut past[s];
                *e = (e.0 + 1, e.1.min(along), e.2.max(along));
                break;
            }
        }
    }
    past.iter()
        .zip(cut)
        .filter_map(|(&(n, lo, hi), c)| {
            let (a, b) = (*c)?;
            (n > 0 && lo <= f64::from(b) + 0.5 && hi >= f64::from(a) - 0.5).then_some(n)
        })
        .sum()
}

/// How the chosen view's frame (`anchor`) judges other views' clouds: per cloud
/// `[seen, on_mask]`, the points it sees (on its measured surface, or seen through: it saw
/// empty space there) and those of them on its mask (with the votes' tolerance). What the
/// frame cannot see (beyond its image's edge or its mask's `region`, hidden behind a
/// nearer surface, no depth reading) it says nothing about: the rest of a partly seen
/// object.
fn anchor_agreement(
    clouds: &[&[Point3<f64>]],
    anchor: &MaskView<'_>,
    params: &GeometryParams,
) -> Vec<[usize; 2]> {
    let Some(probe) = Probe::new(anchor.camera, anchor.depth) else {
        return vec![[0, 0]; clouds.len()];
    };
    let coarse = CoarseMask::new(
        anchor.mask,
        scaled_kernel(params, params.consensus.mask_dilate, anchor.mask.width) / 2,
    );
    let judge = |p: &Point3<f64>| match probe.look(p, params) {
        Seen::OnSurface(x, y) if !inside(anchor.region, x, y) => [0, 0],
        Seen::OnSurface(x, y) => [1, usize::from(coarse.covers(x, y))],
        Seen::Through => [1, 0],
        Seen::Nothing => [0, 0],
    };
    clouds
        .iter()
        .map(|pts| {
            pts.par_iter()
                .map(judge)
                .reduce(|| [0, 0], |a, b| [a[0] + b[0], a[1] + b[1]])
        })
        .collect()
}
