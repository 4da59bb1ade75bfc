//! Mask → world points through depth and pose, and world points → pixels of any frame
//! with a depth-consistency visibility test.

use nalgebra::{Matrix4, Point3};

use super::camera::transform_point;
use super::cloud::voxel_downsample;
use super::{DepthMap, FrameCamera, GeometryParams, Mask};

/// Errors of the projection functions (inputs that do not fit together).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ProjectionError {
    #[error("mask is {got:?} but the frame's colour image is {want:?}")]
    MaskSize { got: (u32, u32), want: (u32, u32) },
    #[error("depth map is {got:?} but the frame camera expects {want:?}")]
    DepthSize { got: (u32, u32), want: (u32, u32) },
    #[error("frame pose or alignment is not finite or not invertible")]
    BadPose,
}

/// How back-projection samples a mask.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BackprojectOptions {
    /// Use every n-th pixel in x and y (1 = all).
    pub stride: u32,
    /// Voxel size (m) for downsampling the resulting points (0 = off).
    pub voxel: f64,
    /// Emit at most one point per depth pixel (the first mask pixel that reads it). When
    /// colour is larger than depth (ScanNet: ~2x), several colour pixels read the same
    /// depth value; this keeps one point per measurement, and samples the mask every
    /// ⌊colour/depth⌋ pixels (which still reaches every depth pixel).
    pub one_per_depth_pixel: bool,
}

impl Default for BackprojectOptions {
    fn default() -> Self {
        Self {
            stride: 1,
            voxel: 0.0,
            one_per_depth_pixel: false,
        }
    }
}

impl From<&GeometryParams> for BackprojectOptions {
    fn from(p: &GeometryParams) -> Self {
        Self {
            stride: p.pixel_stride.max(1),
            voxel: p.mask_voxel,
            one_per_depth_pixel: p.one_point_per_depth_pixel,
        }
    }
}

impl FrameCamera {
    /// Depth pixel read for colour pixel (u, v): through the depth K when the frame has
    /// one (same optical centre assumed), else the FORMATS §1 size-ratio rule; clamped.
    #[inline]
    pub fn depth_lookup_pixel(&self, u: f64, v: f64) -> (u32, u32) {
        match &self.depth {
            Some(d) => {
                let (wd, hd) = self.depth_size;
                let x = ((u - self.color.cx) / self.color.fx * d.fx + d.cx).round();
                let y = ((v - self.color.cy) / self.color.fy * d.fy + d.cy).round();
                (
                    x.clamp(0.0, wd.saturating_sub(1) as f64) as u32,
                    y.clamp(0.0, hd.saturating_sub(1) as f64) as u32,
                )
            }
            None => self.depth_pixel_for_color(u, v),
        }
    }

    /// Depth (m) read for colour pixel (u, v); `None` for no reading.
    #[inline]
    pub fn depth_at_color(&self, depth: &DepthMap, u: f64, v: f64) -> Option<f64> {
        let (x, y) = self.depth_lookup_pixel(u, v);
        match depth.get(x, y) {
            0 => None,
            mm => Some(mm as f64 * 0.001),
        }
    }

    /// Output-frame → camera transform (inverse of align * pose).
    pub fn out_to_cam(&self) -> Result<Matrix4<f64>, ProjectionError> {
        let m = self.cam_to_out();
        if !super::camera::is_finite_matrix(&m) {
            return Err(ProjectionError::BadPose);
        }
        m.try_inverse().ok_or(ProjectionError::BadPose)
    }

    pub(crate) fn check_depth(&self, depth: &DepthMap) -> Result<(), ProjectionError> {
        if (depth.width, depth.height) != self.depth_size
            || depth.data.len() != (depth.width * depth.height) as usize
        {
            return Err(ProjectionError::DepthSize {
                got: (depth.width, depth.height),
                want: self.depth_size,
            });
        }
        Ok(())
    }
}

/// Back-project the pixels of a colour-resolution `mask` into output-frame points: depth
/// from the frame's depth map (pixels without a reading are skipped), colour K, pose, then
/// axis alignment. Pixel centres are at integer coordinates (as the reference code does).
pub fn backproject_mask(
    mask: &Mask,
    cam: &FrameCamera,
    depth: &DepthMap,
    opts: BackprojectOptions,
) -> Result<Vec<Point3<f64>>, ProjectionError> {
    backproject_mask_within(mask, [0, 0, mask.width, mask.height], cam, depth, opts)
}

/// [`backproject_mask`] for a mask whose set pixels all lie in `r` = [x0, y0, x1, y1):
/// only those pixels are read. The samples are those of the whole frame's stride grid that
/// fall in `r`, in the same order, so the points are the same.
pub(crate) fn backproject_mask_within(
    mask: &Mask,
    r: [u32; 4],
    cam: &FrameCamera,
    depth: &DepthMap,
    opts: BackprojectOptions,
) -> Result<Vec<Point3<f64>>, ProjectionError> {
    if (mask.width, mask.height) != (cam.color.width, cam.color.height) {
        return Err(ProjectionError::MaskSize {
            got: (mask.width, mask.height),
            want: (cam.color.width, cam.color.height),
        });
    }
    cam.check_depth(depth)?;
    let m = cam.cam_to_out();
    if !super::camera::is_finite_matrix(&m) {
        return Err(ProjectionError::BadPose);
    }
    let mut stride = opts.stride.max(1) as usize;
    if opts.one_per_depth_pixel {
        // No finer than the depth image: consecutive samples `ratio` colour pixels apart
        // still land on every depth pixel, and the skipped ones would read the same values.
        let ratio = (cam.color.width / cam.depth_size.0.max(1))
            .min(cam.color.height / cam.depth_size.1.max(1));
        stride = stride.max(ratio.max(1) as usize);
    }
    let w = mask.width as usize;
    let mut out = Vec::new();
    let dw = cam.depth_size.0 as usize;
    let mut used = if opts.one_per_depth_pixel {
        vec![false; depth.data.len()]
    } else {
        Vec::new()
    };
    // The first multiples of the stride at or after the box's corner (the grid of the
    // whole frame starts at 0).
    let first = |a: u32| (a as usize).div_ceil(stride) * stride;
    let (x1, y1) = (
        (r[2].min(mask.width)) as usize,
        (r[3].min(mask.height)) as usize,
    );
    for y in (first(r[1])..y1).step_by(stride) {
        let row = &mask.data[y * w..(y + 1) * w];
        for x in (first(r[0])..x1).step_by(stride) {
            if !row[x] {
                continue;
            }
            let (u, v) = (x as f64, y as f64);
            if opts.one_per_depth_pixel {
                let (dx, dy) = cam.depth_lookup_pixel(u, v);
                let i = dy as usize * dw + dx as usize;
                if used[i] {
                    continue;
                }
                used[i] = true;
            }
            if let Some(z) = cam.depth_at_color(depth, u, v) {
                out.push(transform_point(&m, &cam.color.unproject(u, v, z)));
            }
        }
    }
    Ok(if opts.voxel > 0.0 {
        voxel_downsample(&out, opts.voxel)
    } else {
        out
    })
}

/// Where one output-frame point lands in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projected {
    /// Colour pixel coordinates (continuous).
    pub u: f64,
    pub v: f64,
    /// Depth of the point in that camera (m).
    pub z: f64,
    /// Inside the image.
    pub inside: bool,
    /// Depth measured there (m), if any.
    pub measured: Option<f64>,
    /// Inside the image, in front of the camera and consistent with the measured depth.
    pub visible: bool,
}

/// Project output-frame points into a frame; a point is visible when it falls inside the
/// colour image, in front of the camera, and `|z - measured| <= tol_abs + tol_rel * z`.
/// Points with no depth reading at their pixel are not visible. `None` entries are points
/// behind the camera.
pub fn project_points(
    points: &[Point3<f64>],
    cam: &FrameCamera,
    depth: &DepthMap,
    params: &GeometryParams,
) -> Result<Vec<Option<Projected>>, ProjectionError> {
    cam.check_depth(depth)?;
    let to_cam = cam.out_to_cam()?;
    Ok(points
        .iter()
        .map(|p| project_one(p, &to_cam, cam, depth, params))
        .collect())
}

/// One point of [`project_points`], with the world → camera transform already inverted
/// (`to_cam`) and the depth map's size already checked.
pub(crate) fn project_one(
    p: &Point3<f64>,
    to_cam: &Matrix4<f64>,
    cam: &FrameCamera,
    depth: &DepthMap,
    params: &GeometryParams,
) -> Option<Projected> {
    let pc = transform_point(to_cam, p);
    let (u, v, z) = cam.color.project(&pc)?;
    let (w, h) = (cam.color.width as f64, cam.color.height as f64);
    // Pixel centres sit at integer coordinates: the image spans [-0.5, w - 0.5).
    let inside = u >= -0.5 && v >= -0.5 && u < w - 0.5 && v < h - 0.5;
    let measured = if inside {
        cam.depth_at_color(depth, u.round().max(0.0), v.round().max(0.0))
    } else {
        None
    };
    let visible = measured.is_some_and(|d| (d - z).abs() <= params.visibility_tolerance(z));
    Some(Projected {
        u,
        v,
        z,
        inside,
        measured,
        visible,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::camera::look_at_pose;
    use crate::geometry::Intrinsics;
    use nalgebra::Vector3;

    fn cam(depth_k: bool) -> FrameCamera {
        let color = Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: 39.5,
            cy: 29.5,
            width: 80,
            height: 60,
        };
        FrameCamera {
            color,
            depth: depth_k.then(|| color.scaled_to(40, 30)),
            depth_size: (40, 30),
            pose: look_at_pose(
                Point3::new(0.0, -2.0, 1.0),
                Point3::new(0.0, 0.0, 1.0),
                Vector3::z(),
            ),
            align: Matrix4::identity(),
        }
    }

    #[test]
    fn flat_wall_backprojects_to_plane() {
        // Camera at y=-2 looking +y: a wall at depth 2 m is the plane y = 0.
        let c = cam(false);
        let depth = DepthMap::new(40, 30, vec![2000; 1200]);
        let mut mask = Mask::new(80, 60);
        mask.set(39, 29, true);
        mask.set(79, 0, true);
        let pts =
            backproject_mask(&mask, &c, &depth, BackprojectOptions::default()).unwrap_or_default();
        assert_eq!(pts.len(), 2);
        for p in &pts {
            assert!(p.y.abs() < 1e-9, "{p}");
        }
        // Pixel (79, 0): x = (79 - 39.5) * 2 / 100 = 0.79 right, z up = 1 + 29.5 * 2 / 100.
        // Row-major order: (79, 0) comes first.
        assert!(
            (pts[0].x - 0.79).abs() < 1e-9 && (pts[0].z - 1.59).abs() < 1e-9,
            "{}",
            pts[0]
        );
        assert!(
            (pts[1].x + 0.01).abs() < 1e-9 && (pts[1].z - 1.01).abs() < 1e-9,
            "{}",
            pts[1]
        );
    }

    #[test]
    fn one_point_per_depth_pixel() {
        let c = cam(false); // colour 80x60, depth 40x30
        let depth = DepthMap::new(40, 30, vec![2000; 1200]);
        let mask = Mask::from_box(80, 60, [0.0, 0.0, 80.0, 60.0]);
        let all =
            backproject_mask(&mask, &c, &depth, BackprojectOptions::default()).unwrap_or_default();
        let opts = BackprojectOptions {
            one_per_depth_pixel: true,
            ..Default::default()
        };
        let one = backproject_mask(&mask, &c, &depth, opts).unwrap_or_default();
        assert_eq!((all.len(), one.len()), (4800, 1200));
    }

    #[test]
    fn size_checks_and_holes() {
        let c = cam(false);
        let depth = DepthMap::new(40, 30, vec![0; 1200]);
        let mask = Mask::from_box(80, 60, [0.0, 0.0, 80.0, 60.0]);
        assert_eq!(
            backproject_mask(&mask, &c, &depth, BackprojectOptions::default()),
            Ok(vec![])
        );
        let small = Mask::new(10, 10);
        assert!(matches!(
            backproject_mask(&small, &c, &depth, BackprojectOptions::default()),
            Err(ProjectionError::MaskSize { .. })
        ));
        let bad = DepthMap {
            width: 40,
            height: 29,
            data: vec![0; 1160].into(),
        };
        assert!(project_points(&[], &c, &bad, &GeometryParams::default()).is_err());
    }

    #[test]
    fn depth_intrinsics_lookup_matches_ratio_rule_for_scaled_camera() {
        let (a, b) = (cam(false), cam(true));
        for (u, v) in [(0.0, 0.0), (39.0, 29.0), (79.0, 59.0), (10.0, 50.0)] {
            let (pa, pb) = (a.depth_lookup_pixel(u, v), b.depth_lookup_pixel(u, v));
            assert!(
                (pa.0 as i32 - pb.0 as i32).abs() <= 1 && (pa.1 as i32 - pb.1 as i32).abs() <= 1
            );
        }
    }

    #[test]
    fn occluded_point_not_visible() {
        let c = cam(true);
        let depth = DepthMap::new(40, 30, vec![2000; 1200]);
        let p = GeometryParams::default();
        let pts = [
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(0.0, 1.0, 1.0),
            Point3::new(0.0, -3.0, 1.0),
        ];
        let pr = project_points(&pts, &c, &depth, &p).unwrap_or_default();
        assert!(pr[0].is_some_and(|q| q.visible && (q.u - 39.5).abs() < 1e-9));
        assert!(pr[1].is_some_and(|q| !q.visible && (q.z - 3.0).abs() < 1e-9));
        assert!(pr[2].is_none());
    }
}
