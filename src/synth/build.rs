//! Pieces both scene families' world builders use: unions and overlap tests of boxes, the
//! world <-> aligned transforms, and a camera pose from a heading.

use crate::geometry::camera::look_at_pose;
use crate::geometry::Aabb;
use nalgebra::{Matrix4, Point3, Rotation3, Vector3};

/// The bounds of a non-empty set of boxes.
pub(crate) fn union(parts: &[Aabb]) -> Aabb {
    let mut b = parts[0];
    for p in &parts[1..] {
        for i in 0..3 {
            b.min[i] = b.min[i].min(p.min[i]);
            b.max[i] = b.max[i].max(p.max[i]);
        }
    }
    b
}

/// Whether two boxes overlap once each is grown by `margin` (negative: shrunk).
pub(crate) fn overlaps(a: &Aabb, b: &Aabb, margin: f64) -> bool {
    (0..3).all(|i| a.min[i] < b.max[i] + margin && b.min[i] < a.max[i] + margin)
}

/// World -> aligned (a turn by `theta` about z, then the offset `t`) and its inverse.
pub(crate) fn alignment(theta: f64, t: Vector3<f64>) -> (Matrix4<f64>, Matrix4<f64>) {
    let rot = Rotation3::from_axis_angle(&Vector3::z_axis(), theta);
    let mut align = Matrix4::identity();
    align.fixed_view_mut::<3, 3>(0, 0).copy_from(rot.matrix());
    align.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
    let mut align_inv = Matrix4::identity();
    let rt = rot.matrix().transpose();
    align_inv.fixed_view_mut::<3, 3>(0, 0).copy_from(&rt);
    align_inv
        .fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&(-(rt * t)));
    (align, align_inv)
}

/// Camera-to-world pose of a camera at `eye` looking along `yaw` (about z, from +x) and
/// `pitch` (up from the horizontal), z up.
pub(crate) fn look_along(eye: Point3<f64>, yaw: f64, pitch: f64) -> Matrix4<f64> {
    let dir = Vector3::new(
        yaw.cos() * pitch.cos(),
        yaw.sin() * pitch.cos(),
        pitch.sin(),
    );
    look_at_pose(eye, eye + dir, Vector3::z())
}
