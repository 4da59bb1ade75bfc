//! Property tests of the geometry primitives.

use grounder::geometry::camera::look_at_pose;
use grounder::geometry::{
    backproject_mask, chamfer_distance, project_points, statistical_outlier_indices,
    voxel_downsample, Aabb, BackprojectOptions, DepthMap, FrameCamera, GeometryParams, Intrinsics,
    Mask,
};
use nalgebra::{Matrix4, Point3, Rotation3, Vector3};
use proptest::prelude::*;

fn aabb() -> impl Strategy<Value = Aabb> {
    (
        prop::array::uniform3(-5.0f64..5.0),
        prop::array::uniform3(0.01f64..3.0),
    )
        .prop_map(|(lo, s)| Aabb::new(lo, [lo[0] + s[0], lo[1] + s[1], lo[2] + s[2]]))
}

fn cloud(max: usize) -> impl Strategy<Value = Vec<Point3<f64>>> {
    prop::collection::vec(prop::array::uniform3(-2.0f64..2.0), 1..max).prop_map(|v| {
        v.into_iter()
            .map(|p| Point3::new(p[0], p[1], p[2]))
            .collect()
    })
}

proptest! {
    #[test]
    fn iou_symmetric_bounded_and_one_for_equal(a in aabb(), b in aabb()) {
        let (ab, ba) = (a.iou(&b), b.iou(&a));
        prop_assert!((ab - ba).abs() < 1e-12);
        prop_assert!((0.0..=1.0 + 1e-12).contains(&ab));
        prop_assert!((a.iou(&a) - 1.0).abs() < 1e-12);
        prop_assert!((a.center_distance(&b) - b.center_distance(&a)).abs() < 1e-12);
    }

    #[test]
    fn aabb_contains_its_points(pts in cloud(50)) {
        let b = Aabb::from_points(&pts);
        prop_assert!(b.is_some());
        let b = b.unwrap_or(Aabb::new([0.0; 3], [0.0; 3]));
        prop_assert!(pts.iter().all(|p| b.contains(p, 1e-12)));
    }

    #[test]
    fn chamfer_symmetric_nonnegative_zero_on_self(a in cloud(40), b in cloud(40)) {
        let ab = chamfer_distance(&a, &b).unwrap_or(f64::NAN);
        let ba = chamfer_distance(&b, &a).unwrap_or(f64::NAN);
        prop_assert!(ab >= 0.0 && (ab - ba).abs() < 1e-9);
        prop_assert_eq!(chamfer_distance(&a, &a), Some(0.0));
    }

    #[test]
    fn voxel_downsample_stays_within_bounds(pts in cloud(200), voxel in 0.05f64..1.0) {
        let d = voxel_downsample(&pts, voxel);
        prop_assert!(!d.is_empty() && d.len() <= pts.len());
        let (b, bd) = (Aabb::from_points(&pts), Aabb::from_points(&d));
        prop_assert!(bd.zip(b).is_some_and(|(bd, b)| (0..3).all(|i| bd.min[i] >= b.min[i] - 1e-9 && bd.max[i] <= b.max[i] + 1e-9)));
    }

    #[test]
    fn sor_keeps_subset_in_order(pts in cloud(120), nb in 2usize..8, ratio in 0.5f64..3.0) {
        let kept = statistical_outlier_indices(&pts, nb, ratio);
        prop_assert!(kept.windows(2).all(|w| w[0] < w[1]));
        prop_assert!(kept.iter().all(|&i| i < pts.len()));
    }

    /// A world point seen by a camera, written into that camera's depth map, back-projects
    /// to itself within the depth quantisation (1 mm) and the pixel quantisation.
    #[test]
    fn project_then_backproject_is_identity(
        eye in prop::array::uniform3(-2.0f64..2.0),
        yaw in -3.0f64..3.0,
        rel in prop::array::uniform3(-0.3f64..0.3),
        dist in 0.8f64..4.0,
    ) {
        let eye = Point3::new(eye[0], eye[1], eye[2] + 1.0);
        let target = eye + Vector3::new(yaw.cos(), yaw.sin(), -0.3) * dist;
        let color = Intrinsics { fx: 300.0, fy: 300.0, cx: 159.5, cy: 119.5, width: 320, height: 240 };
        let align = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.4).to_homogeneous();
        let cam = FrameCamera {
            color,
            depth: None,
            depth_size: (320, 240),
            pose: align.try_inverse().unwrap_or_else(Matrix4::identity) * look_at_pose(eye, target, Vector3::z()),
            align,
        };
        let world = target + Vector3::new(rel[0], rel[1], rel[2]);
        let p = GeometryParams::default();
        let empty = DepthMap::new(320, 240, vec![0; 320 * 240]);
        let pr = project_points(&[world], &cam, &empty, &p);
        prop_assert!(pr.is_ok());
        let Some(Some(q)) = pr.unwrap_or_default().first().copied() else { return Ok(()); };
        prop_assume!(q.u >= 0.0 && q.v >= 0.0 && q.u <= 319.0 && q.v <= 239.0);
        prop_assert!(!q.visible); // no depth reading there
        let (x, y) = (q.u.round() as u32, q.v.round() as u32);
        let mut depth = empty.clone();
        depth.data[(y * 320 + x) as usize] = (q.z * 1000.0).round() as u16;
        let again = project_points(&[world], &cam, &depth, &p).unwrap_or_default();
        prop_assert!(again.first().copied().flatten().is_some_and(|q| q.visible));
        let mut mask = Mask::new(320, 240);
        mask.set(x, y, true);
        let back = backproject_mask(&mask, &cam, &depth, BackprojectOptions::default()).unwrap_or_default();
        prop_assert_eq!(back.len(), 1);
        // Error bound: 0.5 mm depth rounding plus half a pixel at that depth.
        let bound = 0.0005 * 1.5 + 0.5 * std::f64::consts::SQRT_2 * q.z / 300.0 + 1e-9;
        prop_assert!((back[0] - world).norm() <= bound, "{} vs {} (bound {bound})", back[0], world);
    }
}
