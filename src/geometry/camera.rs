//! Camera model shared by every module that touches pixels and points.
//!
//! Conventions (FORMATS.md §1): poses are camera-to-world 4x4 matrices with OpenCV camera
//! axes (x right, y down, z forward); depth is u16 millimetres with 0 meaning "no reading";
//! when colour and depth differ in size and there are no depth intrinsics, a colour pixel
//! (u, v) reads depth at (round(u * Wd / Wc), round(v * Hd / Hc)), clamped, and the 3D point
//! uses the colour K.

use nalgebra::{Matrix3, Matrix4, Point3, Vector3};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Pinhole intrinsics of one image (colour or depth) together with that image's size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// From the top-left 3x3 of a 4x4 (or 3x3) intrinsic matrix.
    pub fn from_matrix(k: &Matrix4<f64>, width: u32, height: u32) -> Self {
        Self {
            fx: k[(0, 0)],
            fy: k[(1, 1)],
            cx: k[(0, 2)],
            cy: k[(1, 2)],
            width,
            height,
        }
    }

    pub fn matrix3(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Camera-space point for pixel (u, v) at depth z metres.
    #[inline]
    pub fn unproject(&self, u: f64, v: f64, z: f64) -> Point3<f64> {
        Point3::new((u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z)
    }

    /// Pixel (u, v) and depth z of a camera-space point; `None` when behind the camera.
    #[inline]
    pub fn project(&self, p: &Point3<f64>) -> Option<(f64, f64, f64)> {
        if p.z <= 1e-9 {
            return None;
        }
        Some((
            self.fx * p.x / p.z + self.cx,
            self.fy * p.y / p.z + self.cy,
            p.z,
        ))
    }

    /// The same camera for an image resized to `width` x `height`.
    pub fn scaled_to(&self, width: u32, height: u32) -> Self {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Self {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            width,
            height,
        }
    }
}

/// A decoded 16-bit depth image in millimetres (0 = no reading), row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    pub width: u32,
    pub height: u32,
    pub data: DepthData,
}

/// The values of a depth image: owned, or a window onto a read-only buffer shared with other
/// images (a scene's depth file mapped into memory, see `scene::depth_file`). Reads as a
/// `[u16]` slice either way; writing to a shared one first copies it.
#[derive(Clone)]
pub enum DepthData {
    Owned(Vec<u16>),
    Shared {
        buf: Arc<dyn AsRef<[u16]> + Send + Sync>,
        start: usize,
        len: usize,
    },
}

impl DepthData {
    /// Whether the values are a window onto a shared buffer (not a copy of their own).
    pub fn is_shared(&self) -> bool {
        matches!(self, DepthData::Shared { .. })
    }

    /// The values as a vector of their own (moved when owned, copied when shared).
    pub fn into_vec(self) -> Vec<u16> {
        match self {
            DepthData::Owned(v) => v,
            shared => shared.to_vec(),
        }
    }
}

impl std::ops::Deref for DepthData {
    type Target = [u16];
    fn deref(&self) -> &[u16] {
        match self {
            DepthData::Owned(v) => v,
            DepthData::Shared { buf, start, len } => &(**buf).as_ref()[*start..*start + *len],
        }
    }
}

impl std::ops::DerefMut for DepthData {
    fn deref_mut(&mut self) -> &mut [u16] {
        if let DepthData::Shared { .. } = self {
            *self = DepthData::Owned(self.to_vec());
        }
        match self {
            DepthData::Owned(v) => v,
            DepthData::Shared { .. } => unreachable!("made owned above"),
        }
    }
}

impl<'a> IntoIterator for &'a DepthData {
    type Item = &'a u16;
    type IntoIter = std::slice::Iter<'a, u16>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

impl From<Vec<u16>> for DepthData {
    fn from(v: Vec<u16>) -> Self {
        DepthData::Owned(v)
    }
}

impl PartialEq for DepthData {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl std::fmt::Debug for DepthData {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kind = if self.is_shared() { "shared" } else { "owned" };
        write!(f, "DepthData({kind}, {} values)", self.len())
    }
}

impl DepthMap {
    pub fn new(width: u32, height: u32, data: Vec<u16>) -> Self {
        debug_assert_eq!(data.len(), width as usize * height as usize);
        Self {
            width,
            height,
            data: DepthData::Owned(data),
        }
    }

    /// A depth image whose values are `buf[start .. start + width * height]`, without a copy;
    /// `None` when the buffer is too short.
    pub fn shared(
        width: u32,
        height: u32,
        buf: Arc<dyn AsRef<[u16]> + Send + Sync>,
        start: usize,
    ) -> Option<Self> {
        let len = width as usize * height as usize;
        if (*buf).as_ref().len() < start.checked_add(len)? {
            return None;
        }
        Some(Self {
            width,
            height,
            data: DepthData::Shared { buf, start, len },
        })
    }

    /// Raw millimetre value at integer pixel (x, y); 0 outside the image.
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> u16 {
        if x >= self.width || y >= self.height {
            return 0;
        }
        self.data[y as usize * self.width as usize + x as usize]
    }
}

/// Everything needed to relate one frame's colour pixels to world points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameCamera {
    /// Colour intrinsics (with the colour image size).
    pub color: Intrinsics,
    /// Depth intrinsics when the scene has them; otherwise depth is looked up by the
    /// size-ratio rule and points use the colour K.
    pub depth: Option<Intrinsics>,
    /// Depth image size (width, height).
    pub depth_size: (u32, u32),
    /// Camera-to-world pose.
    pub pose: Matrix4<f64>,
    /// World -> output frame (axis alignment); identity when the scene has none.
    pub align: Matrix4<f64>,
}

impl FrameCamera {
    /// Camera-to-output-frame transform (align * pose).
    pub fn cam_to_out(&self) -> Matrix4<f64> {
        self.align * self.pose
    }

    /// The camera's centre in the output frame.
    pub fn centre(&self) -> Point3<f64> {
        transform_point(&self.cam_to_out(), &Point3::origin())
    }

    /// Depth pixel that a colour pixel reads (FORMATS §1 rule), clamped to the depth image.
    #[inline]
    pub fn depth_pixel_for_color(&self, u: f64, v: f64) -> (u32, u32) {
        let (wd, hd) = self.depth_size;
        let x = (u * wd as f64 / self.color.width as f64).round();
        let y = (v * hd as f64 / self.color.height as f64).round();
        (
            x.clamp(0.0, (wd - 1) as f64) as u32,
            y.clamp(0.0, (hd - 1) as f64) as u32,
        )
    }
}

/// Apply a 4x4 homogeneous transform to a point.
#[inline]
pub fn transform_point(m: &Matrix4<f64>, p: &Point3<f64>) -> Point3<f64> {
    let v = m * p.to_homogeneous();
    Point3::new(v.x, v.y, v.z)
}

/// True when every entry of the matrix is finite (FORMATS: NaN/inf poses mark a frame unusable).
pub fn is_finite_matrix(m: &Matrix4<f64>) -> bool {
    m.iter().all(|x| x.is_finite())
}

/// Direction helper used by tests and the synthetic renderer.
pub fn look_at_pose(eye: Point3<f64>, target: Point3<f64>, world_up: Vector3<f64>) -> Matrix4<f64> {
    let z = (target - eye).normalize();
    let x = z.cross(&world_up).normalize(); // OpenCV: x right
    let y = z.cross(&x); // y down
    let mut m = Matrix4::identity();
    for r in 0..3 {
        m[(r, 0)] = x[r];
        m[(r, 1)] = y[r];
        m[(r, 2)] = z[r];
        m[(r, 3)] = eye[r];
    }
    m
}
