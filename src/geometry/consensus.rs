//! Multi-view checks on back-projected points (ours; the paper fuses views by a chamfer
//! test alone).
//!
//! A mask that leaks (a wall corner beside a box, the pillow next to the one asked for)
//! leaks differently in each view, and a depth pixel that mixes an object's edge with the
//! wall behind it (a "flying pixel") floats in space another camera looks straight through.
//! Two checks use that:
//!
//! - [`mask_votes`]: every point of one view's cloud is projected into the other segmented
//!   views. A view where the point lies on the measured surface votes for it when its mask
//!   (with a tolerance of a few pixels) covers the pixel and against it when not; a view that sees past the
//!   point votes against it; a view where it is hidden or out of frame abstains. The point's
//!   own view does not vote. A point is dropped when the votes against outnumber the votes
//!   for, or (`anchor_veto`) when the chosen view measures it outside its mask: that mask
//!   comes from the box the VLM picked, the others from boxes matched to it.
//! - [`free_space_votes`]: every fused point is projected into every usable frame; it is
//!   dropped when at least `min_seen_through` frames see past it (every depth pixel around
//!   its projection lies beyond it) and they outnumber the frames that measure it.

use nalgebra::{Matrix4, Point3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::camera::transform_point;
use super::projection::project_one;
use super::{Aabb, DepthMap, FrameCamera, GeometryParams, Mask};

/// Settings of the multi-view checks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ConsensusParams {
    /// Run [`mask_votes`] across the anchor and the views the chamfer test kept.
    pub mask_votes: bool,
    /// Tolerance (pixels at the geometry's `erode_reference_width`, scaled like the erosion
    /// kernel) around each voting mask for pose error and mask borders: the mask is read
    /// in blocks of half this side, a pixel counting as covered when a block next to its
    /// own holds the mask.
    pub mask_dilate: u32,
    /// The first view given to [`mask_votes`] (the agent passes the chosen view) overrules
    /// the others: a point it measures outside its mask is dropped whatever they say.
    pub anchor_veto: bool,
    /// When the chosen view saw a part of the object, a view whose box is only that
    /// part's reprojection (no detection, candidate or VLM box of its own) votes only
    /// inside that box ([`MaskView::region`]): it cannot speak against the rest of the
    /// object that another view's box holds.
    pub footprints_vote_inside: bool,
    /// The box drawn on the chosen image bounds its object when nothing hides part of it
    /// there: the other views' points that project outside it are dropped before the
    /// chamfer test (`geometry::bound`).
    pub anchor_box_bound: bool,
    /// ...widened by this share of the box's width and height on each side (a detector's
    /// or the VLM's box is a little tight or loose), and by the votes' pose tolerance.
    pub anchor_box_margin: f64,
    /// Another view's detection box of the object (matched to the chosen view's points,
    /// not a candidate's or the footprint's) bounds it as the chosen box does, when
    /// nothing hides part of the object in that view: a close-up whose mask ran on over
    /// the wall beside a flush door keeps what projects into the door's box seen from
    /// across the room. Needs `anchor_box_bound`.
    pub detection_bound: bool,
    /// ...when that view sees at least this share of the chosen view's points (the view
    /// search's `visible_fraction`): a detector boxes what it sees, and where something
    /// hides part of what the chosen view saw (a sofa before the chair's back), the box
    /// holds only the rest.
    pub detection_bound_seen: f64,
    /// Run [`free_space_votes`] on the fused cloud with every usable frame.
    pub free_space: bool,
    /// Frames that must see past a point before it can be dropped.
    pub min_seen_through: usize,
    /// At most this many of the frames that see the points' box are used (evenly spread
    /// over the scan; 0 = all): the cost is one projection per point and frame.
    pub max_carve_frames: usize,
    /// With `free_space`: a detached cluster the fusion would drop as a stray stays when
    /// no frame has seen the gap between it and the object empty (`geometry::bridge`): a
    /// chair's legs below the table top that hides its seat from every view.
    pub bridge_unseen: bool,
    /// When the chosen view saw only part of its object, a view the chamfer test dropped
    /// is kept when the chosen frame agrees with it (`geometry::complement`): of the view's
    /// points that frame sees ([`anchor_agreement`]), at least this share lies on its mask,
    /// or most of the view lies past the frame's edge where the chosen mask meets it. The
    /// view then holds a part the chosen frame could not see (beyond its edge, hidden): a
    /// floor lamp's shade above a close-up of its pole. 0 turns it off.
    pub complement_agree: f64,
}

impl Default for ConsensusParams {
    fn default() -> Self {
        Self {
            mask_votes: true,
            mask_dilate: 15,
            anchor_veto: true,
            footprints_vote_inside: true,
            anchor_box_bound: true,
            anchor_box_margin: 0.1,
            detection_bound: true,
            detection_bound_seen: 0.9,
            free_space: true,
            min_seen_through: 2,
            max_carve_frames: 20,
            bridge_unseen: true,
            complement_agree: 0.8,
        }
    }
}

/// One segmented view: its camera, depth and the raw mask its segmenter returned.
#[derive(Debug, Clone, Copy)]
pub struct MaskView<'a> {
    pub camera: &'a FrameCamera,
    pub depth: &'a DepthMap,
    pub mask: &'a Mask,
    /// The part of the frame (colour pixels, [x0, y0, x1, y1]) the mask speaks for:
    /// outside it the view does not vote. `None`: the whole frame. A view that segmented
    /// only the box of the chosen view's reprojected part, when that part is known to be
    /// incomplete, knows nothing of what lies beyond that box.
    pub region: Option<[f32; 4]>,
}

/// What one frame says about one point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Seen {
    /// Out of frame, behind the camera, no depth reading, or hidden behind a nearer surface.
    Nothing,
    /// On the measured surface, at colour pixel (x, y).
    OnSurface(u32, u32),
    /// Every depth pixel around the projection lies beyond the point.
    Through,
}

/// A frame prepared for projection (the world → camera transform computed once; also used
/// by `depth_fill`).
pub(crate) struct Probe<'a> {
    pub(crate) cam: &'a FrameCamera,
    pub(crate) depth: &'a DepthMap,
    pub(crate) to_cam: Matrix4<f64>,
}

impl<'a> Probe<'a> {
    /// `None` when the depth map does not fit the camera or the pose is unusable.
    pub(crate) fn new(cam: &'a FrameCamera, depth: &'a DepthMap) -> Option<Self> {
        cam.check_depth(depth).ok()?;
        Some(Self {
            cam,
            depth,
            to_cam: cam.out_to_cam().ok()?,
        })
    }

    pub(super) fn look(&self, p: &Point3<f64>, params: &GeometryParams) -> Seen {
        let Some(q) = project_one(p, &self.to_cam, self.cam, self.depth, params) else {
            return Seen::Nothing;
        };
        let Some(d) = q.measured else {
            return Seen::Nothing;
        };
        let (x, y) = (q.u.round().max(0.0) as u32, q.v.round().max(0.0) as u32);
        if q.visible {
            return Seen::OnSurface(x, y);
        }
        let beyond = q.z + params.visibility_tolerance(q.z);
        if d > beyond && self.neighbourhood_beyond(x, y, beyond) {
            return Seen::Through;
        }
        Seen::Nothing
    }

    /// True when every depth pixel in the 3x3 around the one colour pixel (x, y) reads
    /// has a reading beyond `z` (conservative at silhouettes and under pose error).
    fn neighbourhood_beyond(&self, x: u32, y: u32, z: f64) -> bool {
        let (dx, dy) = self.cam.depth_lookup_pixel(x as f64, y as f64);
        let (wd, hd) = (self.depth.width as i64, self.depth.height as i64);
        for oy in -1i64..=1 {
            for ox in -1i64..=1 {
                let (nx, ny) = (dx as i64 + ox, dy as i64 + oy);
                if nx < 0 || ny < 0 || nx >= wd || ny >= hd {
                    continue;
                }
                let mm = self.depth.get(nx as u32, ny as u32);
                if mm == 0 || (mm as f64) * 0.001 <= z {
                    return false;
                }
            }
        }
        true
    }
}

/// A mask coarsened into square blocks: a pixel counts as covered when its block or one
/// of the eight around it holds a mask pixel (a dilation by one to two block sides, built
/// in one pass over the mask).
pub(super) struct CoarseMask {
    block: u32,
    w: usize,
    h: usize,
    occupied: Vec<bool>,
}

impl CoarseMask {
    pub(super) fn new(mask: &Mask, block: u32) -> Self {
        let block = block.max(1);
        let w = mask.width.div_ceil(block) as usize;
        let h = mask.height.div_ceil(block) as usize;
        let mut occupied = vec![false; w * h];
        for y in 0..mask.height as usize {
            let row = &mask.data[y * mask.width as usize..(y + 1) * mask.width as usize];
            let by = y / block as usize;
            for (x, _) in row.iter().enumerate().filter(|(_, &m)| m) {
                occupied[by * w + x / block as usize] = true;
            }
        }
        Self {
            block,
            w,
            h,
            occupied,
        }
    }

    pub(super) fn covers(&self, x: u32, y: u32) -> bool {
        let (bx, by) = ((x / self.block) as i64, (y / self.block) as i64);
        (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                let (nx, ny) = (bx + dx, by + dy);
                nx >= 0
                    && ny >= 0
                    && (nx as usize) < self.w
                    && (ny as usize) < self.h
                    && self.occupied[ny as usize * self.w + nx as usize]
            })
        })
    }
}

/// Mask consensus. `clouds[i]` are the points back-projected from `views[i]`'s mask.
/// Returns, per cloud, which points to keep (see the module documentation).
pub fn mask_votes(
    clouds: &[&[Point3<f64>]],
    views: &[MaskView<'_>],
    params: &GeometryParams,
) -> Vec<Vec<bool>> {
    let coarse: Vec<CoarseMask> = views
        .iter()
        .map(|v| {
            CoarseMask::new(
                v.mask,
                scaled_kernel(params, params.consensus.mask_dilate, v.mask.width) / 2,
            )
        })
        .collect();
    let probes: Vec<Option<Probe<'_>>> = views
        .iter()
        .map(|v| Probe::new(v.camera, v.depth))
        .collect();
    clouds
        .iter()
        .enumerate()
        .map(|(own, pts)| {
            pts.par_iter()
                .map(|p| {
                    let (mut pro, mut con) = (0usize, 0usize);
                    for (k, probe) in probes.iter().enumerate() {
                        let Some(probe) = probe.as_ref().filter(|_| k != own) else {
                            continue;
                        };
                        match probe.look(p, params) {
                            Seen::OnSurface(x, y) if !inside(views[k].region, x, y) => {}
                            Seen::OnSurface(x, y) if coarse[k].covers(x, y) => pro += 1,
                            Seen::OnSurface(..) if k == 0 && params.consensus.anchor_veto => {
                                return false
                            }
                            Seen::OnSurface(..) | Seen::Through => con += 1,
                            Seen::Nothing => {}
                        }
                    }
                    con <= pro
                })
                .collect()
        })
        .collect()
}

/// Whether colour pixel (x, y) lies in `region` (everywhere when `None`).
pub(super) fn inside(region: Option<[f32; 4]>, x: u32, y: u32) -> bool {
    region.is_none_or(|b| {
        let (x, y) = (x as f32 + 0.5, y as f32 + 0.5);
        x >= b[0] && x < b[2] && y >= b[1] && y < b[3]
    })
}

/// Free-space carving of `points` with the frames in `frames` (camera, depth). Frames that
/// cannot see the points' box at all are skipped up front, and at most
/// `consensus.max_carve_frames` of the rest are used. Returns which points to keep.
pub fn free_space_votes(
    points: &[Point3<f64>],
    frames: &[(&FrameCamera, &DepthMap)],
    params: &GeometryParams,
) -> Vec<bool> {
    let Some(bbox) = Aabb::from_points(points) else {
        return Vec::new();
    };
    let mut probes: Vec<Probe<'_>> = frames
        .iter()
        .filter_map(|(c, d)| Probe::new(c, d))
        .filter(|p| sees_box(p, &bbox))
        .collect();
    let cap = params.consensus.max_carve_frames;
    if cap > 0 && probes.len() > cap {
        let n = probes.len();
        let picked: Vec<usize> = (0..cap).map(|k| k * n / cap).collect();
        let mut k = 0;
        probes.retain(|_| {
            let keep = picked.binary_search(&k).is_ok();
            k += 1;
            keep
        });
    }
    let need = params.consensus.min_seen_through.max(1);
    points
        .par_iter()
        .map(|p| {
            let (mut through, mut on) = (0usize, 0usize);
            for probe in &probes {
                match probe.look(p, params) {
                    Seen::OnSurface(..) => on += 1,
                    Seen::Through => through += 1,
                    Seen::Nothing => {}
                }
            }
            !(through >= need && through > on)
        })
        .collect()
}

/// Whether any corner of `b` projects in front of the camera inside its image (or the box
/// surrounds the camera); a cheap cull, generous by design.
fn sees_box(p: &Probe<'_>, b: &Aabb) -> bool {
    let (w, h) = (p.cam.color.width as f64, p.cam.color.height as f64);
    let mut in_front = 0;
    let (mut u0, mut v0, mut u1, mut v1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for i in 0..8 {
        let c = Point3::new(
            if i & 1 == 0 { b.min[0] } else { b.max[0] },
            if i & 2 == 0 { b.min[1] } else { b.max[1] },
            if i & 4 == 0 { b.min[2] } else { b.max[2] },
        );
        match p.cam.color.project(&transform_point(&p.to_cam, &c)) {
            Some((u, v, _)) => {
                in_front += 1;
                (u0, v0, u1, v1) = (u0.min(u), v0.min(v), u1.max(u), v1.max(v));
            }
            None => return true, // the box straddles the camera plane: keep the frame
        }
    }
    in_front > 0 && u1 >= 0.0 && v1 >= 0.0 && u0 < w && v0 < h
}

/// Pixels (in an image `width` wide) by which [`mask_votes`] lets a point miss a mask, for
/// pose error and mask borders.
pub(crate) fn pose_tolerance_px(params: &GeometryParams, width: u32) -> u32 {
    scaled_kernel(params, params.consensus.mask_dilate, width) / 2
}

/// `kernel` (pixels at the reference width) scaled to a mask `width` pixels wide, odd.
pub(super) fn scaled_kernel(params: &GeometryParams, kernel: u32, width: u32) -> u32 {
    GeometryParams {
        erode_kernel: kernel,
        erode_reference_width: params.erode_reference_width,
        ..GeometryParams::default()
    }
    .erode_kernel_for(width)
}

/// Keep the points whose flag is true.
pub fn retain(points: &[Point3<f64>], keep: &[bool]) -> Vec<Point3<f64>> {
    points
        .iter()
        .zip(keep)
        .filter(|(_, &k)| k)
        .map(|(p, _)| *p)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::camera::look_at_pose;
    use crate::geometry::Intrinsics;
    use nalgebra::Vector3;

    /// 80x60 camera at `eye` looking at `target`, depth = colour size.
    fn cam(eye: Point3<f64>, target: Point3<f64>) -> FrameCamera {
        let color = Intrinsics {
            fx: 60.0,
            fy: 60.0,
            cx: 39.5,
            cy: 29.5,
            width: 80,
            height: 60,
        };
        FrameCamera {
            color,
            depth: None,
            depth_size: (80, 60),
            pose: look_at_pose(eye, target, Vector3::z()),
            align: Matrix4::identity(),
        }
    }

    /// Depth image of the plane y = `wall` and an optional cube [x0,x1]x[y0,y1]x[0,1] seen by `c`, by ray casting.
    fn render(c: &FrameCamera, wall: f64, cube: Option<([f64; 2], [f64; 2])>) -> DepthMap {
        let to_out = c.cam_to_out();
        let eye = Point3::new(to_out[(0, 3)], to_out[(1, 3)], to_out[(2, 3)]);
        let mut data = vec![0u16; 80 * 60];
        for y in 0..60 {
            for x in 0..80 {
                let pc = c.color.unproject(x as f64, y as f64, 1.0);
                let dir = transform_point(&to_out, &pc) - eye; // camera z = 1 along this ray
                let mut t_hit = if dir.y > 1e-9 {
                    (wall - eye.y) / dir.y
                } else {
                    f64::INFINITY
                };
                if let Some(([x0, x1], [y0, y1])) = cube {
                    // slab test
                    let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
                    for (o, d, a, b) in [
                        (eye.x, dir.x, x0, x1),
                        (eye.y, dir.y, y0, y1),
                        (eye.z, dir.z, 0.0, 1.0),
                    ] {
                        if d.abs() < 1e-12 {
                            if o < a || o > b {
                                hi = -1.0;
                            }
                            continue;
                        }
                        let (t0, t1) = ((a - o) / d, (b - o) / d);
                        lo = lo.max(t0.min(t1));
                        hi = hi.min(t0.max(t1));
                    }
                    if lo <= hi && lo > 0.0 {
                        t_hit = t_hit.min(lo);
                    }
                }
                if t_hit.is_finite() && t_hit > 0.0 {
                    data[y * 80 + x] = (t_hit * 1000.0).round() as u16;
                }
            }
        }
        DepthMap::new(80, 60, data)
    }

    #[test]
    fn a_point_another_camera_sees_through_is_carved_a_surface_point_is_not() {
        // A wall at y = 3, a cube x in [-0.3, 0.3], y in [1, 1.6] in front of it.
        let cube = Some(([-0.3, 0.3], [1.0, 1.6]));
        let views: Vec<FrameCamera> = [(-1.5, -1.0), (1.5, -1.0), (0.0, -1.5)]
            .iter()
            .map(|&(x, y)| cam(Point3::new(x, y, 0.8), Point3::new(0.0, 1.3, 0.5)))
            .collect();
        let depths: Vec<DepthMap> = views.iter().map(|c| render(c, 3.0, cube)).collect();
        let frames: Vec<(&FrameCamera, &DepthMap)> = views.iter().zip(&depths).collect();
        let p = GeometryParams::default();
        let front = Point3::new(0.0, 1.0, 0.5); // on the cube's front face
        let flying = Point3::new(0.5, 1.8, 0.5); // beside the cube, between it and the wall
        let keep = free_space_votes(&[front, flying], &frames, &p);
        assert_eq!(keep, vec![true, false]);
        // One frame is not enough evidence with min_seen_through = 2.
        let keep = free_space_votes(&[front, flying], &frames[2..], &p);
        assert_eq!(keep, vec![true, true]);
    }

    #[test]
    fn a_wall_point_outside_other_masks_is_voted_out() {
        let cube = Some(([-0.3, 0.3], [1.0, 1.6]));
        let cams: Vec<FrameCamera> = [(-1.2, -1.0), (1.2, -1.0), (0.0, -1.5)]
            .iter()
            .map(|&(x, y)| cam(Point3::new(x, y, 0.8), Point3::new(0.0, 1.3, 0.5)))
            .collect();
        let depths: Vec<DepthMap> = cams.iter().map(|c| render(c, 3.0, cube)).collect();
        // Each view's mask: the pixels whose depth hits the cube (nearer than the wall).
        let masks: Vec<Mask> = cams
            .iter()
            .zip(&depths)
            .map(|(c, d)| {
                let wall_only = render(c, 3.0, None);
                let mut m = Mask::new(80, 60);
                for (i, (&a, &b)) in d.data.iter().zip(&wall_only.data).enumerate() {
                    m.data[i] = a > 0 && a + 20 < b;
                }
                m
            })
            .collect();
        let views: Vec<MaskView> = cams
            .iter()
            .zip(&depths)
            .zip(&masks)
            .map(|((c, d), m)| MaskView {
                camera: c,
                depth: d,
                mask: m,
                region: None,
            })
            .collect();
        let p = GeometryParams::default();
        // View 0's cloud: a cube point, and a wall point its leaking mask let in.
        let leak = Point3::new(1.0, 3.0, 0.5);
        let cloud0 = [Point3::new(0.0, 1.0, 0.5), leak];
        let keep = mask_votes(&[&cloud0, &[], &[]], &views, &p);
        assert_eq!(keep[0], vec![true, false]);
        // Views whose masks speak only for a region: outside it they do not vote, so the
        // leak stays when it falls outside (here an empty region); a region holding the
        // whole frame is the whole frame.
        for (region, kept) in [
            ([0.0, 0.0, 0.0, 0.0], true),
            ([0.0, 0.0, 80.0, 60.0], false),
        ] {
            let regional: Vec<MaskView> = views
                .iter()
                .enumerate()
                .map(|(i, v)| MaskView {
                    region: (i > 0).then_some(region),
                    ..*v
                })
                .collect();
            let keep = mask_votes(&[&cloud0, &[], &[]], &regional, &p);
            assert_eq!(keep[0], vec![true, kept], "{region:?}");
        }
        // With the other views' masks covering everything, the leak stays.
        let full = Mask::from_box(80, 60, [0.0, 0.0, 80.0, 60.0]);
        let lax: Vec<MaskView> = views
            .iter()
            .enumerate()
            .map(|(i, v)| MaskView {
                mask: if i == 0 { v.mask } else { &full },
                ..*v
            })
            .collect();
        assert_eq!(
            mask_votes(&[&cloud0, &[], &[]], &lax, &p)[0],
            vec![true, true]
        );
        assert_eq!(retain(&cloud0, &[true, false]), vec![cloud0[0]]);

        // A wall point in view 1's cloud, seen by the anchor (view 0, cube mask: against) and
        // view 2 (a mask covering everything: for). A tie keeps it, unless the anchor overrules.
        let tie: Vec<MaskView> = views
            .iter()
            .enumerate()
            .map(|(i, v)| MaskView {
                mask: if i == 2 { &full } else { v.mask },
                ..*v
            })
            .collect();
        let cloud1 = [Point3::new(0.0, 1.0, 0.5), Point3::new(-1.0, 3.0, 0.5)];
        let lenient = GeometryParams {
            consensus: ConsensusParams {
                anchor_veto: false,
                ..Default::default()
            },
            ..p.clone()
        };
        assert_eq!(
            mask_votes(&[&[], &cloud1, &[]], &tie, &lenient)[1],
            vec![true, true]
        );
        assert_eq!(
            mask_votes(&[&[], &cloud1, &[]], &tie, &p)[1],
            vec![true, false]
        );
    }
}
