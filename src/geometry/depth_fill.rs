//! Depth completion from other views (ours, not the paper's): a frame's pixels without a
//! depth reading (beyond the sensor's range, glass, dark or grazing surfaces) get the depth
//! at which their viewing ray meets a surface that other frames measured.
//!
//! Each ray is walked from near to far in steps proportional to depth. At every step the
//! point is projected into the other frames: a frame whose reading there agrees with the
//! point's depth (a tolerance tighter than the visibility test's) votes "surface"; one
//! that reads farther sees through the point and votes "free". The first run of steps with at least
//! `min_votes` surface votes and more surface than free votes is the surface; its depth
//! is the vote-weighted mean over that run. Rays are cast on a grid of cells over the
//! region, through the centroid of each cell's empty pixels, which take the ray's depth.
//!
//! When the region stays mostly unmeasured (under `layout.max_measured` read or filled), a
//! ray that met nothing may be given the room's layout ([`super::layout`]): where it leaves
//! the room, if that lies beyond the sensor's range (the one reason a wall returns no
//! reading from anywhere). The caller decides for which objects that holds (those flat
//! against a wall).

use nalgebra::{Matrix4, Point3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::camera::transform_point;
use super::consensus::Probe;
use super::projection::{project_one, ProjectionError};
use super::{DepthMap, FrameCamera, GeometryParams, RoomLayout};

/// Settings of [`fill_depth`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthFillParams {
    /// Fill the chosen view's empty depth pixels inside the chosen box before segmenting.
    pub enabled: bool,
    /// Only when at least this fraction of the box's depth pixels has no reading.
    pub min_missing_fraction: f64,
    /// At most this many rays per box (cells grow to fit).
    pub max_rays: usize,
    /// Nearest and farthest depth (m) a ray is walked over.
    pub near: f64,
    pub far: f64,
    /// Step between samples, as a fraction of the sample's depth.
    pub step: f64,
    /// Frames that must agree on a surface.
    pub min_votes: usize,
    /// A frame agrees when its reading is within `tol_abs + tol_rel * z` of the point's
    /// depth z in that frame. Tighter than the visibility tolerance: the vote-weighted mean
    /// over a wide band drifts toward whichever side more views happen to cover.
    pub tol_abs: f64,
    pub tol_rel: f64,
}

impl Default for DepthFillParams {
    fn default() -> Self {
        Self {
            enabled: true,
            min_missing_fraction: 0.1,
            max_rays: 1500,
            near: 0.3,
            far: 12.0,
            step: 0.01,
            min_votes: 2,
            tol_abs: 0.02,
            tol_rel: 0.01,
        }
    }
}

/// What [`fill_depth`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct DepthFillStats {
    /// Depth pixels in the region without a reading.
    pub missing: usize,
    /// Rays cast, and those that met a surface.
    pub rays: usize,
    pub resolved: usize,
    /// Rays ended on the room's layout (not counted in `resolved`).
    pub placed: usize,
    /// Pixels given a depth.
    pub filled: usize,
    /// Cell side in depth pixels.
    pub cell: u32,
}

/// Fill the empty depth pixels of `depth` (the depth image of `cam`) inside `region`, a box
/// in colour pixels `[x0, y0, x1, y1]`, from the readings of `others`, and where none
/// meets a surface, from `layout` (when given). Returns the completed depth map (a copy;
/// pixels with a reading are never changed) and what was done.
pub fn fill_depth(
    cam: &FrameCamera,
    depth: &DepthMap,
    region: [f32; 4],
    others: &[(&FrameCamera, &DepthMap)],
    layout: Option<&RoomLayout>,
    params: &GeometryParams,
) -> Result<(DepthMap, DepthFillStats), ProjectionError> {
    let fp = &params.depth_fill;
    cam.check_depth(depth)?;
    let cam_to_out = cam.cam_to_out();
    if !super::camera::is_finite_matrix(&cam_to_out) {
        return Err(ProjectionError::BadPose);
    }
    let mut out = depth.clone();
    let (x0, y0, x1, y1) = depth_rect(cam, region);
    let mut stats = DepthFillStats::default();
    let w = depth.width as usize;
    for y in y0..y1 {
        stats.missing += (x0..x1)
            .filter(|&x| depth.data[y as usize * w + x as usize] == 0)
            .count();
    }
    let area = (x1 - x0) as f64 * (y1 - y0) as f64;
    if stats.missing == 0 || (stats.missing as f64) < fp.min_missing_fraction * area {
        return Ok((out, stats));
    }
    let views: Vec<Probe> = others
        .iter()
        .filter_map(|&(c, d)| Probe::new(c, d))
        .collect();
    let cell = ((stats.missing as f64 / fp.max_rays.max(1) as f64)
        .sqrt()
        .ceil() as u32)
        .max(1);
    stats.cell = cell;
    let samples = depth_samples(fp.near, fp.far, fp.step);
    // The cells' empty pixels, then one ray per cell (in parallel: rays are independent).
    let mut cells: Vec<Vec<(u32, u32)>> = Vec::new();
    for cy in (y0..y1).step_by(cell as usize) {
        for cx in (x0..x1).step_by(cell as usize) {
            let (ex, ey) = ((cx + cell).min(x1), (cy + cell).min(y1));
            let empty: Vec<(u32, u32)> = (cy..ey)
                .flat_map(|y| (cx..ex).map(move |x| (x, y)))
                .filter(|&(x, y)| depth.get(x, y) == 0)
                .collect();
            if !empty.is_empty() {
                cells.push(empty);
            }
        }
    }
    let depths: Vec<(Option<f64>, (f64, f64))> = cells
        .par_iter()
        .map(|empty| {
            // The ray through the centroid of the cell's empty pixels (not the cell's centre,
            // which at an object's outline may lie on the measured side), in colour pixels.
            let n = empty.len() as f64;
            let (mx, my) = empty.iter().fold((0.0, 0.0), |(a, b), &(x, y)| {
                (a + x as f64 / n, b + y as f64 / n)
            });
            let (u, v) = color_pixel(cam, mx, my);
            (
                cast(cam, &cam_to_out, u, v, &samples, &views, params),
                (u, v),
            )
        })
        .collect();
    // Rays nothing met, ended on the room's box when the region is mostly unmeasured.
    let voted: usize = cells
        .iter()
        .zip(&depths)
        .filter(|(_, d)| d.0.is_some())
        .map(|(c, _)| c.len())
        .sum();
    let measured = (area - stats.missing as f64 + voted as f64) / area.max(1.0);
    let room = layout.filter(|_| measured < params.layout.max_measured);
    let depths: Vec<Option<(f64, bool)>> = depths
        .into_iter()
        .map(|(z, (u, v))| {
            z.map(|z| (z, false)).or_else(|| {
                let z = room?.exit_depth(cam, &cam_to_out, u, v)?;
                (room?.beyond_range(z, &params.layout) && z <= fp.far).then_some((z, true))
            })
        })
        .collect();
    stats.rays = cells.len();
    for (empty, z) in cells.iter().zip(depths) {
        let Some((z, placed)) = z else { continue };
        if placed {
            stats.placed += 1;
        } else {
            stats.resolved += 1;
        }
        let mm = |z: f64| (z * 1000.0).round().clamp(1.0, u16::MAX as f64) as u16;
        for &(x, y) in empty {
            // A ray ended on the room's box: each pixel gets its own exit, so the points lie
            // on the wall (the cell's one depth would tilt them off it by the wall's slant).
            let z = match room.filter(|_| placed) {
                Some(room) => {
                    let (u, v) = color_pixel(cam, x as f64, y as f64);
                    room.exit_depth(cam, &cam_to_out, u, v)
                        .filter(|e| room.beyond_range(*e, &params.layout) && *e <= fp.far)
                        .unwrap_or(z)
                }
                None => z,
            };
            out.data[y as usize * w + x as usize] = mm(z);
            stats.filled += 1;
        }
    }
    Ok((out, stats))
}

/// The depth-pixel rectangle `[x0, x1) x [y0, y1)` under a colour box, clamped.
fn depth_rect(cam: &FrameCamera, b: [f32; 4]) -> (u32, u32, u32, u32) {
    let (a0, a1) = cam.depth_lookup_pixel(b[0].max(0.0) as f64, b[1].max(0.0) as f64);
    let (c0, c1) =
        cam.depth_lookup_pixel((b[2] as f64 - 1.0).max(0.0), (b[3] as f64 - 1.0).max(0.0));
    (a0, a1, (c0 + 1).max(a0), (c1 + 1).max(a1))
}

/// The colour pixel that reads depth pixel (x, y) (the inverse of `depth_lookup_pixel`).
pub(crate) fn color_pixel(cam: &FrameCamera, x: f64, y: f64) -> (f64, f64) {
    match &cam.depth {
        Some(d) => (
            (x - d.cx) / d.fx * cam.color.fx + cam.color.cx,
            (y - d.cy) / d.fy * cam.color.fy + cam.color.cy,
        ),
        None => (
            x * cam.color.width as f64 / cam.depth_size.0 as f64,
            y * cam.color.height as f64 / cam.depth_size.1 as f64,
        ),
    }
}

/// Depths from `near` to `far`, each `step` (relative) beyond the last.
fn depth_samples(near: f64, far: f64, step: f64) -> Vec<f64> {
    let (mut z, mut v) = (near.max(0.01), Vec::new());
    while z <= far && v.len() < 100_000 {
        v.push(z);
        z *= 1.0 + step.max(1e-3);
    }
    v
}

/// Depth along the ray through colour pixel (u, v) at which other views agree on a surface.
fn cast(
    cam: &FrameCamera,
    cam_to_out: &Matrix4<f64>,
    u: f64,
    v: f64,
    samples: &[f64],
    views: &[Probe],
    params: &GeometryParams,
) -> Option<f64> {
    let fp = &params.depth_fill;
    let (Some(&near), Some(&far)) = (samples.first(), samples.last()) else {
        return None;
    };
    let at = |z: f64| transform_point(cam_to_out, &cam.color.unproject(u, v, z));
    let (pn, pf) = (at(near), at(far));
    // Only the views the ray's segment can appear in.
    let seen: Vec<&Probe> = views
        .iter()
        .filter(|vw| segment_may_be_seen(vw, &pn, &pf))
        .collect();
    if seen.len() < fp.min_votes {
        return None;
    }
    let (mut run_w, mut run_z) = (0.0, 0.0);
    for &z in samples {
        let p = at(z);
        let (mut surface, mut free) = (0usize, 0usize);
        for vw in &seen {
            let Some(pr) = project_one(&p, &vw.to_cam, vw.cam, vw.depth, params) else {
                continue;
            };
            match pr.measured {
                Some(d) if (d - pr.z).abs() <= fp.tol_abs + fp.tol_rel * pr.z => surface += 1,
                Some(d) if d > pr.z => free += 1,
                _ => {}
            }
        }
        if surface >= fp.min_votes && surface > free {
            run_w += surface as f64;
            run_z += surface as f64 * z;
        } else if run_w > 0.0 {
            break;
        }
    }
    (run_w > 0.0).then(|| run_z / run_w)
}

/// False when the segment from `a` to `b` is certainly outside the view's image: both ends
/// behind the camera, or both in front and their pixel box misses the image.
fn segment_may_be_seen(vw: &Probe, a: &Point3<f64>, b: &Point3<f64>) -> bool {
    let (ca, cb) = (
        transform_point(&vw.to_cam, a),
        transform_point(&vw.to_cam, b),
    );
    match (vw.cam.color.project(&ca), vw.cam.color.project(&cb)) {
        (None, None) => false,
        (Some((ua, va, _)), Some((ub, vb, _))) => {
            let (w, h) = (vw.cam.color.width as f64, vw.cam.color.height as f64);
            ua.max(ub) >= -0.5 && va.max(vb) >= -0.5 && ua.min(ub) < w - 0.5 && va.min(vb) < h - 0.5
        }
        _ => true,
    }
}

#[cfg(test)]
mod tests;
