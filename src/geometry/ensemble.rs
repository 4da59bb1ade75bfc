//! Multi-view ensemble: find the frames that see the anchor's points (reprojection and
//! depth consistency replace the paper's image matching), then fuse the per-view clouds
//! with the paper's chamfer filter, outlier removal and an axis-aligned box.

use nalgebra::Point3;
use serde::Serialize;

use super::cloud::{
    directional_chamfers, outliers_and_neighbours, subsample_even, voxel_downsample,
};
use super::projection::{project_points, Projected, ProjectionError};
use super::{Aabb, DepthMap, FrameCamera, GeometryParams, Mask, RoomLayout};

/// One frame that may join the ensemble.
#[derive(Debug, Clone, Copy)]
pub struct CandidateFrame<'a> {
    /// Caller's frame index (returned unchanged).
    pub index: usize,
    pub camera: &'a FrameCamera,
    pub depth: &'a DepthMap,
}

/// A frame that sees enough of the anchor's points, with their footprint there.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewCandidate {
    pub index: usize,
    /// Visible probe points / probe points.
    pub visible_fraction: f64,
    pub visible_points: usize,
    /// Reprojected 2D box of the visible points in colour pixels: [x1, y1, x2, y2]
    /// (x2, y2 exclusive).
    pub bbox: [f32; 4],
    /// Distinct colour pixels [x, y] hit by visible points.
    #[serde(skip)]
    pub pixels: Vec<[u32; 2]>,
}

impl ViewCandidate {
    /// The projected pixel set as a colour-resolution mask of the given size.
    pub fn footprint_mask(&self, width: u32, height: u32) -> Mask {
        let mut m = Mask::new(width, height);
        for &[x, y] in &self.pixels {
            m.set(x, y, true);
        }
        m
    }
}

/// Rank `candidates` by the fraction of `anchor_points` they see (visible = in image and
/// consistent with that frame's depth, see [`project_points`]); keep those with at least
/// `params.min_visible_fraction`, best first (ties: lower index), at most
/// `params.max_views - 1`. The anchor frame itself should not be among the candidates.
/// Frames with an unusable pose or a depth map of the wrong size are skipped.
pub fn find_views(
    anchor_points: &[Point3<f64>],
    candidates: &[CandidateFrame<'_>],
    params: &GeometryParams,
) -> Vec<ViewCandidate> {
    find_views_with_room(anchor_points, candidates, None, params)
}

/// [`find_views`] for an anchor whose points depth completion ended on the room's box
/// (no frame measured the object: it lies beyond the sensor's range). A point a frame has
/// no reading for also counts as seen there when the frame's ray through it leaves the
/// `room` at the point's depth (within the visibility tolerance), beyond the range: the
/// frame would have put it in the same place.
pub fn find_views_with_room(
    anchor_points: &[Point3<f64>],
    candidates: &[CandidateFrame<'_>],
    room: Option<&RoomLayout>,
    params: &GeometryParams,
) -> Vec<ViewCandidate> {
    if anchor_points.is_empty() {
        return Vec::new();
    }
    let probe = subsample_even(anchor_points, params.max_probe_points);
    let mut out: Vec<ViewCandidate> = candidates
        .iter()
        .filter_map(|c| {
            let proj = project_points(&probe, c.camera, c.depth, params).ok()?;
            let (w, h) = (c.camera.color.width, c.camera.color.height);
            let cam_to_out = c.camera.cam_to_out();
            let on_room = |q: &Projected| {
                let Some(room) = room.filter(|_| q.inside && q.measured.is_none()) else {
                    return false;
                };
                room.exit_depth(c.camera, &cam_to_out, q.u, q.v)
                    .is_some_and(|e| {
                        room.beyond_range(e, &params.layout)
                            && (e - q.z).abs() <= params.visibility_tolerance(q.z)
                    })
            };
            let mut hits: Vec<[u32; 2]> = Vec::new();
            let (mut x1, mut y1, mut x2, mut y2) = (u32::MAX, u32::MAX, 0u32, 0u32);
            for q in proj.iter().flatten().filter(|q| q.visible || on_room(q)) {
                let x = (q.u.round().max(0.0) as u32).min(w - 1);
                let y = (q.v.round().max(0.0) as u32).min(h - 1);
                x1 = x1.min(x);
                y1 = y1.min(y);
                x2 = x2.max(x + 1);
                y2 = y2.max(y + 1);
                hits.push([x, y]);
            }
            let n = hits.len();
            let frac = n as f64 / probe.len() as f64;
            if n == 0 || frac < params.min_visible_fraction {
                return None;
            }
            // Distinct pixels in order of first hit, marked over the hits' box only.
            let bw = (x2 - x1) as usize;
            let mut seen = vec![false; bw * (y2 - y1) as usize];
            hits.retain(|&[x, y]| {
                let i = (y - y1) as usize * bw + (x - x1) as usize;
                !std::mem::replace(&mut seen[i], true)
            });
            Some(ViewCandidate {
                index: c.index,
                visible_fraction: frac,
                visible_points: n,
                bbox: [x1 as f32, y1 as f32, x2 as f32, y2 as f32],
                pixels: hits,
            })
        })
        .collect();
    out.sort_by(|a, b| {
        b.visible_fraction
            .total_cmp(&a.visible_fraction)
            .then(a.index.cmp(&b.index))
    });
    out.truncate(params.max_views.saturating_sub(1));
    out
}

/// What happened to one non-anchor view during fusion.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewDecision {
    pub index: usize,
    /// Chamfer distance (m^2) to the anchor cloud; `None` when a cloud was empty.
    pub chamfer: Option<f64>,
    /// Its anchor-to-view term (m^2): how far the anchor's points lie from the view's, the
    /// part that stays small when the view sees the anchor's part and more of the object.
    pub cover: Option<f64>,
    pub kept: bool,
    pub points: usize,
    /// Kept though the chamfer test dropped it: the chosen view saw a part of the object,
    /// and where its frame sees this view's points they lie on its mask, or the view lies
    /// past the edge that cut the chosen mask (`geometry::complement`).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub complements: bool,
    /// When the rule was tried: `[seen, on_mask]`, the view's points the chosen frame
    /// sees and those of them on its mask.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub agreement: Option<[usize; 2]>,
    /// When the chosen mask met the frame's edge: the view's points that project past it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub beyond_cut: Option<usize>,
}

/// Result of [`fuse_views`], serialisable for the agent's trace.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FusionResult {
    /// Box of the fused, outlier-filtered points; `None` when nothing was left.
    pub aabb: Option<Aabb>,
    /// Axes ("x", "y", "z") on which the points were a noisy plane and the box was narrowed
    /// to their interquartile range (see [`flatten_noisy_planes`]).
    pub flattened: Vec<&'static str>,
    pub anchor_points: usize,
    /// Points after union (and fusion voxel downsampling), before outlier removal.
    pub fused_points: usize,
    /// Points of the union that free-space carving dropped (0 when it did not run).
    pub carved_points: usize,
    /// Points after outlier removal.
    pub kept_points: usize,
    /// Those points (the object's fused points).
    #[serde(skip)]
    pub kept: Vec<Point3<f64>>,
    /// Voxel size (m) finally used on the union (0 = none).
    pub fusion_voxel: f64,
    pub views: Vec<ViewDecision>,
}

/// Fuse the anchor's points with other views' points (index, points):
/// 1. [`chamfer_decisions`]: drop a view whose chamfer distance to the anchor exceeds
///    `params.chamfer_threshold` (or when either cloud is empty);
/// 2. union of the anchor and kept views, downsampled by `params.fusion_voxel` (doubled
///    until at most `params.max_fused_points` remain);
/// 3. statistical outlier removal (`sor_neighbors`, `sor_std_ratio`); 4. AABB.
pub fn fuse_views(
    anchor: &[Point3<f64>],
    others: &[(usize, Vec<Point3<f64>>)],
    params: &GeometryParams,
) -> FusionResult {
    let views = chamfer_decisions(anchor, others, false, params);
    let mut clouds: Vec<&[Point3<f64>]> = vec![anchor];
    clouds.extend(
        others
            .iter()
            .zip(&views)
            .filter(|(_, d)| d.kept)
            .map(|((_, p), _)| p.as_slice()),
    );
    fuse_clouds(anchor.len(), &clouds, views, None, params)
}

/// Step 1 of [`fuse_views`]: the chamfer distance of each view to the anchor, both clouds
/// voxel-downsampled by `params.chamfer_voxel`, and whether it passes the threshold. When
/// the anchor saw only part of its object (`anchor_partial`), a view also passes when its
/// anchor-to-view term alone is within `params.chamfer_cover_threshold`: it holds what the
/// anchor saw, and what it holds beyond is the rest of the object, not a reason to drop it.
pub fn chamfer_decisions<P: AsRef<[Point3<f64>]>>(
    anchor: &[Point3<f64>],
    others: &[(usize, P)],
    anchor_partial: bool,
    params: &GeometryParams,
) -> Vec<ViewDecision> {
    // No views (the single-view box, an anchor no frame sees): nothing to compare with.
    if others.is_empty() {
        return Vec::new();
    }
    let anchor_ds = voxel_downsample(anchor, params.chamfer_voxel);
    let views_ds: Vec<Vec<Point3<f64>>> = others
        .iter()
        .map(|(_, pts)| voxel_downsample(pts.as_ref(), params.chamfer_voxel))
        .collect();
    let cover_max = Some(params.chamfer_cover_threshold).filter(|&t| anchor_partial && t > 0.0);
    // The anchor's tree is built once for all the views.
    let terms = directional_chamfers(&anchor_ds, &views_ds);
    others
        .iter()
        .zip(terms)
        .map(|((index, pts), t)| {
            let chamfer = t.map(|[ab, ba]| ab + ba);
            let cover = t.map(|[ab, _]| ab);
            let within = |d: Option<f64>, t: f64| d.is_some_and(|c| c <= t);
            let covers = cover_max.is_some_and(|t| within(cover, t));
            ViewDecision {
                index: *index,
                chamfer,
                cover,
                kept: within(chamfer, params.chamfer_threshold) || covers,
                points: pts.as_ref().len(),
                complements: false,
                agreement: None,
                beyond_cut: None,
            }
        })
        .collect()
}

/// Keep-flags for the points of a fused cloud (see [`super::free_space_votes`]).
pub type Carve<'a> = &'a (dyn Fn(&[Point3<f64>]) -> Vec<bool> + Sync);

/// Steps 2-4 of [`fuse_views`] on the clouds to fuse (the anchor's and the kept views'):
/// union, voxel downsampling, then `carve` (when given) drops points before outlier
/// removal and the box.
pub fn fuse_clouds(
    anchor_points: usize,
    clouds: &[&[Point3<f64>]],
    views: Vec<ViewDecision>,
    carve: Option<Carve<'_>>,
    params: &GeometryParams,
) -> FusionResult {
    let union: Vec<Point3<f64>> = clouds.iter().flat_map(|c| c.iter().copied()).collect();
    let mut voxel = params.fusion_voxel;
    let mut fused = voxel_downsample(&union, voxel);
    if params.max_fused_points > 0 && voxel > 0.0 {
        // Coarsen the already-downsampled cloud (centroids of centroids: cheap, and
        // within a voxel of the exact result).
        while fused.len() > params.max_fused_points {
            voxel *= 2.0;
            fused = voxel_downsample(&fused, voxel);
        }
    }
    let fused_points = fused.len();
    let mut carved_points = 0;
    if let Some(carve) = carve {
        let keep = carve(&fused);
        if keep.len() == fused.len() {
            fused = super::consensus::retain(&fused, &keep);
            carved_points = fused_points - fused.len();
        }
    }
    let (kept_idx, nn) =
        outliers_and_neighbours(&fused, params.sor_neighbors, params.sor_std_ratio);
    let kept: Vec<Point3<f64>> = kept_idx.iter().map(|&i| fused[i]).collect();
    // The outlier removal's neighbours serve the spacing of `drop_detached` (same count).
    let spacing_from = nn
        .as_deref()
        .filter(|_| params.sor_neighbors >= 2)
        .map(|nn| (fused.as_slice(), kept_idx.as_slice(), nn));
    let kept = super::bridge::drop_detached(kept, spacing_from, carve, params);
    let (aabb, flattened) = match trimmed_box(&kept, params.box_trim) {
        Some(b) => {
            let (b, axes) = flatten_noisy_planes(b, &kept, params.plane_iqr);
            (Some(b), axes)
        }
        None => (None, Vec::new()),
    };
    FusionResult {
        aabb,
        flattened,
        anchor_points,
        fused_points,
        carved_points,
        kept_points: kept.len(),
        kept,
        fusion_voxel: voxel.max(0.0),
        views,
    }
}

/// The points' box, each side moved in past the `trim` fraction of the points most beyond
/// it (per axis; 0 = the plain min–max box). Extremes of a noisy cloud overshoot the
/// surface they sample by a few noise widths on every side.
pub fn trimmed_box(points: &[Point3<f64>], trim: f64) -> Option<Aabb> {
    let b = Aabb::from_points(points)?;
    let k = (points.len() as f64 * trim.clamp(0.0, 0.25)).floor() as usize;
    if k == 0 {
        return Some(b);
    }
    let mut out = b;
    for a in 0..3 {
        let mut v: Vec<f64> = points.iter().map(|p| p[a]).collect();
        v.sort_by(f64::total_cmp);
        out.min[a] = v[k];
        out.max[a] = v[v.len() - 1 - k];
    }
    Some(out)
}

/// On a horizontal axis where the points are a plane blurred by depth noise (interquartile range at
/// most `max_iqr`, at least 4 times smaller than on both other axes, and a min–max extent
/// within 8 of it, as a blur gives and a second surface does not: a window, a picture),
/// the min–max extent measures the noise, not the object. There the
/// box is narrowed to the points' interquartile range; support completion then carries
/// the back face to the wall or floor. `max_iqr` 0 disables it.
pub fn flatten_noisy_planes(
    b: Aabb,
    points: &[Point3<f64>],
    max_iqr: f64,
) -> (Aabb, Vec<&'static str>) {
    const NAMES: [&str; 3] = ["x", "y", "z"];
    let mut out = b;
    let mut axes = Vec::new();
    if max_iqr <= 0.0 || points.len() < 20 {
        return (out, axes);
    }
    let quartiles = |a: usize| {
        let mut v: Vec<f64> = points.iter().map(|p| p[a]).collect();
        v.sort_by(f64::total_cmp);
        let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
        (q(0.25), q(0.75))
    };
    let qs = [quartiles(0), quartiles(1), quartiles(2)];
    // Horizontal axes only: a thin extent along gravity (a pillow, a table top) is the
    // object's real height, not noise around a wall-hung plane.
    for a in 0..2 {
        let iqr = qs[a].1 - qs[a].0;
        let others = [(a + 1) % 3, (a + 2) % 3];
        let extent = b.max[a] - b.min[a];
        if iqr <= max_iqr
            && extent <= 8.0 * iqr.max(0.005)
            && iqr < extent
            && others
                .iter()
                .all(|&o| qs[o].1 - qs[o].0 >= 4.0 * iqr.max(0.005))
        {
            out.min[a] = qs[a].0;
            out.max[a] = qs[a].1;
            axes.push(NAMES[a]);
        }
    }
    (out, axes)
}

/// Single-view box: outlier removal of one cloud (fusion voxel applied first), then AABB.
pub fn single_view_box(points: &[Point3<f64>], params: &GeometryParams) -> Option<Aabb> {
    fuse_views(points, &[], params).aabb
}

/// Mask post-processing (erosion + largest components) then back-projection, with the
/// stride and voxel of `params`: the per-view step before [`find_views`] / [`fuse_views`].
///
/// Erosion trims unreliable border pixels; when it leaves no point at all (a thin or
/// distant object: a picture seen edge-on), the kernel is halved (15 → 7 → 3 → 1) until
/// some point survives, since the untrimmed mask is then the only evidence there is.
pub fn mask_points(
    mask: &Mask,
    cam: &FrameCamera,
    depth: &DepthMap,
    params: &GeometryParams,
) -> Result<Vec<Point3<f64>>, ProjectionError> {
    let mut kernel = params.erode_kernel_for(mask.width);
    loop {
        let m = super::morph::postprocess_mask(mask, kernel, params.keep_components);
        let pts = super::projection::backproject_mask(&m, cam, depth, params.into())?;
        if !pts.is_empty() || kernel <= 1 {
            return Ok(pts);
        }
        kernel = (kernel / 2) | 1;
    }
}

#[cfg(test)]
#[path = "ensemble_views_tests.rs"]
mod views_tests;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_trimmed_box_lets_out_a_few_stray_points_per_side() {
        // 1000 points filling [0, 1]^3 on a 10^3 grid, plus 5 strays beyond x = 1 and one
        // far below z = 0.
        let mut pts: Vec<Point3<f64>> = (0..1000)
            .map(|i| {
                Point3::new(
                    (i % 10) as f64 / 9.0,
                    (i / 10 % 10) as f64 / 9.0,
                    (i / 100) as f64 / 9.0,
                )
            })
            .collect();
        pts.extend((0..5).map(|k| Point3::new(1.1 + 0.1 * k as f64, 0.5, 0.5)));
        pts.push(Point3::new(0.5, 0.5, -3.0));
        let plain = trimmed_box(&pts, 0.0).unwrap();
        assert_eq!((plain.max[0], plain.min[2]), (1.5, -3.0));
        // 1 % of 1006 points: 10 let out per side; the grid's faces (100 points each) stay.
        let b = trimmed_box(&pts, 0.01).unwrap();
        assert_eq!((b.min, b.max), ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]));
        assert!(trimmed_box(&[], 0.01).is_none());
    }

    #[test]
    fn a_noisy_window_is_flattened_a_pillow_is_not() {
        // Window face at y = 6.05, blurred by ~2.5 cm of deterministic pseudo-noise.
        let noise =
            |k: usize| 0.05 * ((k as f64 * 12.9898).sin() * 43758.5453).fract().abs() - 0.025;
        let mut window = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                window.push(Point3::new(
                    0.7 + 0.03 * i as f64,
                    6.05 + noise(i * 40 + j),
                    1.0 + 0.03 * j as f64,
                ));
            }
        }
        let b = Aabb::from_points(&window).unwrap();
        let (f, axes) = flatten_noisy_planes(b, &window, 0.05);
        assert_eq!(axes, vec!["y"]);
        assert!(f.max[1] - f.min[1] < 0.6 * (b.max[1] - b.min[1]), "{f:?}");
        assert!(f.min[1] < 6.05 && f.max[1] > 6.05);
        assert_eq!((f.min[0], f.max[2]), (b.min[0], b.max[2]));
        // A pillow: mostly its front face, plus its top 0.3 m deep: a second surface.
        let mut pillow: Vec<Point3<f64>> = window
            .iter()
            .map(|p| Point3::new(p.x, 4.75, p.z * 0.2))
            .collect();
        for i in 0..40 {
            for j in 0..8 {
                pillow.push(Point3::new(
                    0.7 + 0.03 * i as f64,
                    4.75 + 0.04 * j as f64,
                    0.44,
                ));
            }
        }
        let b = Aabb::from_points(&pillow).unwrap();
        assert_eq!(flatten_noisy_planes(b, &pillow, 0.05), (b, vec![]));
        // Off.
        let b = Aabb::from_points(&window).unwrap();
        assert_eq!(flatten_noisy_planes(b, &window, 0.0), (b, vec![]));
    }

    fn blob(cx: f64, n: usize) -> Vec<Point3<f64>> {
        (0..n)
            .map(|i| {
                let t = i as f64;
                Point3::new(
                    cx + 0.1 * (t * 0.37).sin(),
                    0.1 * (t * 0.71).cos(),
                    0.1 * ((t * 1.3).sin()),
                )
            })
            .collect()
    }

    #[test]
    fn chamfer_filter_keeps_same_object_drops_other() {
        let p = GeometryParams::default();
        let anchor = blob(0.0, 300);
        let same = blob(0.01, 250);
        let other = blob(1.5, 250);
        let r = fuse_views(&anchor, &[(3, same), (5, other), (7, vec![])], &p);
        assert_eq!(r.views.len(), 3);
        assert!(r.views[0].kept && r.views[0].chamfer.is_some_and(|c| c < 0.01));
        assert!(!r.views[1].kept && r.views[1].chamfer.is_some_and(|c| c > 1.0));
        assert!(!r.views[2].kept && r.views[2].chamfer.is_none());
        let b = r.aabb.unwrap_or(Aabb::new([0.0; 3], [0.0; 3]));
        assert!(b.max[0] < 0.2 && b.min[0] > -0.2, "{b:?}");
        let json = serde_json::to_string(&r).unwrap_or_default();
        assert!(json.contains("\"chamfer\""));
    }

    #[test]
    fn erosion_that_would_delete_a_thin_mask_is_halved_until_points_survive() {
        use crate::geometry::camera::look_at_pose;
        use crate::geometry::Intrinsics;
        use nalgebra::{Matrix4, Vector3};
        let color = Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: 39.5,
            cy: 29.5,
            width: 80,
            height: 60,
        };
        let pose = look_at_pose(
            Point3::new(0.0, -2.0, 1.0),
            Point3::new(0.0, 0.0, 1.0),
            Vector3::z(),
        );
        let cam = FrameCamera {
            color,
            depth: None,
            depth_size: (80, 60),
            pose,
            align: Matrix4::identity(),
        };
        let depth = DepthMap::new(80, 60, vec![2000; 80 * 60]);
        // A 5-pixel-wide stripe: a fixed 15x15 erosion deletes it, a 3x3 one keeps its core.
        let mut stripe = Mask::new(80, 60);
        for y in 10..50 {
            for x in 38..43 {
                stripe.set(x, y, true);
            }
        }
        let p = GeometryParams {
            erode_reference_width: 0,
            ..GeometryParams::default()
        };
        assert_eq!(crate::geometry::postprocess_mask(&stripe, 15, 2).count(), 0);
        let pts = mask_points(&stripe, &cam, &depth, &p).unwrap_or_default();
        // 3x3 erosion: 3 columns x 38 rows survive.
        assert_eq!(pts.len(), 3 * 38);
        // A wide mask keeps the full erosion: 30x30 square eroded by 15 leaves 16x16.
        let mut square = Mask::new(80, 60);
        for y in 15..45 {
            for x in 25..55 {
                square.set(x, y, true);
            }
        }
        assert_eq!(
            mask_points(&square, &cam, &depth, &p)
                .map(|v| v.len())
                .unwrap_or(0),
            16 * 16
        );
        // Nothing to find: an empty mask stays empty.
        assert!(mask_points(&Mask::new(80, 60), &cam, &depth, &p)
            .unwrap_or_default()
            .is_empty());
    }

    #[test]
    fn empty_anchor_gives_no_box() {
        let r = fuse_views(&[], &[(1, blob(0.0, 10))], &GeometryParams::default());
        assert!(r.aabb.is_none() && !r.views[0].kept);
        assert!(find_views(&[], &[], &GeometryParams::default()).is_empty());
    }
}

#[cfg(test)]
#[path = "ensemble_room_tests.rs"]
mod room_tests;
