//! What the exports need from geometry: a box's corners (in the output frame and back in the
//! scene's own frame), a frame's depth as coloured points, coloured voxel downsampling and
//! the binary PLY encoding of a coloured point cloud. Pure functions.

use nalgebra::{Matrix4, Point3};
use serde::Serialize;
use std::collections::HashMap;

use super::camera::{is_finite_matrix, transform_point, DepthMap, FrameCamera};
use super::Aabb;

/// A point with its colour.
pub type ColoredPoint = (Point3<f64>, [u8; 3]);

/// The 8 corners of a box: bit 0 of the index picks max x, bit 1 max y, bit 2 max z
/// (so corner 0 is `min` and corner 7 is `max`).
pub fn corners(b: &Aabb) -> [[f64; 3]; 8] {
    std::array::from_fn(|i| {
        std::array::from_fn(|a| if i >> a & 1 == 1 { b.max[a] } else { b.min[a] })
    })
}

/// A box of the output (axis-aligned) frame seen in the scene's own frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SceneFrameBox {
    /// The 8 corners (same order as [`corners`]) mapped back through the inverse of the
    /// axis alignment: a turned box in the scene's frame.
    pub corners: [[f64; 3]; 8],
    /// The axis-aligned box holding those corners in the scene's frame.
    pub min: [f64; 3],
    pub max: [f64; 3],
}

/// `b` (output frame) in the scene's frame, given `align` (scene → output frame). `None`
/// when `align` cannot be inverted.
pub fn box_in_scene_frame(b: &Aabb, align: &Matrix4<f64>) -> Option<SceneFrameBox> {
    let inv = align.try_inverse().filter(is_finite_matrix)?;
    let cs = corners(b).map(|c| {
        let p = transform_point(&inv, &Point3::new(c[0], c[1], c[2]));
        [p.x, p.y, p.z]
    });
    let pts: Vec<Point3<f64>> = cs.iter().map(|c| Point3::new(c[0], c[1], c[2])).collect();
    let bb = Aabb::from_points(&pts)?;
    Some(SceneFrameBox {
        corners: cs,
        min: bb.min,
        max: bb.max,
    })
}

/// One frame's depth as coloured points in the output frame: every `stride`-th colour pixel
/// (each axis) that has a depth reading. `color` is the frame's colour image at any size
/// (a preview is fine: pixels are looked up proportionally); grey without it. Frames with a
/// non-finite pose give nothing.
pub fn frame_points(
    cam: &FrameCamera,
    depth: &DepthMap,
    color: Option<&image::RgbImage>,
    stride: u32,
) -> Vec<ColoredPoint> {
    let m = cam.cam_to_out();
    if !is_finite_matrix(&m) || cam.check_depth(depth).is_err() {
        return Vec::new();
    }
    let (w, h) = (cam.color.width, cam.color.height);
    let stride = stride.max(1) as usize;
    let mut out = Vec::new();
    for y in (0..h).step_by(stride) {
        for x in (0..w).step_by(stride) {
            let (u, v) = (x as f64, y as f64);
            let Some(z) = cam.depth_at_color(depth, u, v) else {
                continue;
            };
            let rgb = match color {
                Some(img) if img.width() > 0 && img.height() > 0 => {
                    let cx = (x as u64 * img.width() as u64 / w as u64) as u32;
                    let cy = (y as u64 * img.height() as u64 / h as u64) as u32;
                    img.get_pixel(cx.min(img.width() - 1), cy.min(img.height() - 1))
                        .0
                }
                _ => [160, 160, 160],
            };
            out.push((transform_point(&m, &cam.color.unproject(u, v, z)), rgb));
        }
    }
    out
}

/// `points` coloured from what `cam` saw of them in `color` (an image of any size, looked
/// up proportionally); points outside that view, or behind it, get `fallback`.
pub fn color_points(
    points: &[Point3<f64>],
    cam: &FrameCamera,
    color: &image::RgbImage,
    fallback: [u8; 3],
) -> Vec<ColoredPoint> {
    points
        .iter()
        .copied()
        .zip(point_colours(points, cam, color, fallback))
        .collect()
}

/// The colour of each of `points` (see [`color_points`]), in their order.
pub fn point_colours(
    points: &[Point3<f64>],
    cam: &FrameCamera,
    color: &image::RgbImage,
    fallback: [u8; 3],
) -> Vec<[u8; 3]> {
    let to_cam = cam
        .cam_to_out()
        .try_inverse()
        .filter(is_finite_matrix)
        .filter(|_| color.width() > 0 && color.height() > 0);
    let (w, h) = (cam.color.width as f64, cam.color.height as f64);
    points
        .iter()
        .map(|p| {
            to_cam
                .and_then(|m| cam.color.project(&transform_point(&m, p)))
                .filter(|&(u, v, _)| u >= -0.5 && v >= -0.5 && u < w - 0.5 && v < h - 0.5)
                .map(|(u, v, _)| {
                    // Pixel x sits at u = x (see `backproject_mask`): a point back-projected
                    // from it comes back a hair either side, so round, not truncate.
                    let x = (u / w * color.width() as f64).round() as u32;
                    let y = (v / h * color.height() as f64).round() as u32;
                    color
                        .get_pixel(
                            x.min(color.width().saturating_sub(1)),
                            y.min(color.height().saturating_sub(1)),
                        )
                        .0
                })
                .unwrap_or(fallback)
        })
        .collect()
}

/// A voxel's first point index (for a stable order), position sum, colour sum and count.
type VoxelSums = (usize, [f64; 3], [u64; 3], u64);

/// One point per occupied voxel of side `voxel` (m): the mean position and mean colour of
/// the points in it, in a deterministic order. `voxel <= 0` returns the points unchanged.
pub fn voxel_downsample_colored(points: &[ColoredPoint], voxel: f64) -> Vec<ColoredPoint> {
    if voxel <= 0.0 || !voxel.is_finite() {
        return points.to_vec();
    }
    let mut cells: HashMap<(i64, i64, i64), VoxelSums> = HashMap::new();
    for (k, (p, c)) in points.iter().enumerate() {
        let key = (
            (p.x / voxel).floor() as i64,
            (p.y / voxel).floor() as i64,
            (p.z / voxel).floor() as i64,
        );
        let e = cells.entry(key).or_insert((k, [0.0; 3], [0; 3], 0));
        for a in 0..3 {
            e.1[a] += p[a];
            e.2[a] += c[a] as u64;
        }
        e.3 += 1;
    }
    let mut cells: Vec<_> = cells.into_values().collect();
    cells.sort_by_key(|c| c.0);
    cells
        .into_iter()
        .map(|(_, s, c, n)| {
            let nf = n as f64;
            (
                Point3::new(s[0] / nf, s[1] / nf, s[2] / nf),
                [0, 1, 2].map(|a| (c[a] / n) as u8),
            )
        })
        .collect()
}

/// Binary little-endian PLY: `x y z` as float, `red green blue` as uchar, one vertex per
/// point; `comment` lines go into the header (newlines are replaced by spaces).
pub fn encode_ply(points: &[ColoredPoint], comments: &[String]) -> Vec<u8> {
    let mut out = Vec::with_capacity(256 + points.len() * 15);
    // Writing into a vector cannot fail.
    let _ = write_ply(&mut out, points, comments);
    out
}

/// [`encode_ply`] into a writer (a file, as the points are encoded).
pub fn write_ply(
    out: &mut dyn std::io::Write,
    points: &[ColoredPoint],
    comments: &[String],
) -> std::io::Result<()> {
    let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
    for c in comments {
        header.push_str("comment ");
        header.push_str(&c.replace(['\n', '\r'], " "));
        header.push('\n');
    }
    header.push_str(&format!(
        "element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    ));
    out.write_all(header.as_bytes())?;
    let mut rec = [0u8; 15];
    for (p, c) in points {
        for a in 0..3 {
            rec[a * 4..a * 4 + 4].copy_from_slice(&(p[a] as f32).to_le_bytes());
        }
        rec[12..].copy_from_slice(c);
        out.write_all(&rec)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_back_projected_from_a_pixel_gets_that_pixel_s_colour() {
        // Every pixel of a 80x60 view back-projected at 2.3 m (a turned camera, so the
        // round trip is off by a hair) and looked up again: its own colour, never the
        // neighbour's, which truncating the projected coordinate would give.
        let cam = crate::geometry::test_scene::camera([0.3, -1.0, 1.2], [1.0, 2.0, 0.4]);
        let img = image::RgbImage::from_fn(80, 60, |x, y| image::Rgb([x as u8, y as u8, 7]));
        let m = cam.cam_to_out();
        let pts: Vec<Point3<f64>> = (0..60)
            .flat_map(|y| (0..80).map(move |x| (x, y)))
            .map(|(x, y)| transform_point(&m, &cam.color.unproject(x as f64, y as f64, 2.3)))
            .collect();
        for (i, (_, rgb)) in color_points(&pts, &cam, &img, [0, 0, 255])
            .iter()
            .enumerate()
        {
            assert_eq!(*rgb, [(i % 80) as u8, (i / 80) as u8, 7], "pixel {i}");
        }
    }

    #[test]
    fn corners_span_the_box() {
        let b = Aabb::new([0.0, 1.0, 2.0], [3.0, 4.0, 5.0]);
        let c = corners(&b);
        assert_eq!(c[0], b.min);
        assert_eq!(c[7], b.max);
        assert_eq!(c[1], [3.0, 1.0, 2.0]);
        assert_eq!(c[6], [0.0, 4.0, 5.0]);
        let distinct: std::collections::HashSet<String> =
            c.iter().map(|p| format!("{p:?}")).collect();
        assert_eq!(distinct.len(), 8);
    }

    #[test]
    fn scene_frame_box_undoes_the_alignment() {
        // Output = scene turned 90 degrees about z, then shifted by (1, 2, 3).
        let align = Matrix4::new(
            0.0, -1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 1.0,
        );
        let b = Aabb::new([1.0, 2.0, 3.0], [2.0, 4.0, 4.0]);
        let s = box_in_scene_frame(&b, &align).unwrap();
        // Scene point (x, y, z) -> output (1 - y, 2 + x, 3 + z); the box's min corner
        // (1, 2, 3) comes from scene (0, 0, 0), its max (2, 4, 4) from (2, -1, 1).
        for (k, c) in s.corners.iter().enumerate() {
            let back = transform_point(&align, &Point3::new(c[0], c[1], c[2]));
            let want = corners(&b)[k];
            for a in 0..3 {
                assert!((back[a] - want[a]).abs() < 1e-9, "corner {k}");
            }
        }
        for a in 0..3 {
            assert!((s.min[a] - [0.0, -1.0, 0.0][a]).abs() < 1e-9);
            assert!((s.max[a] - [2.0, 0.0, 1.0][a]).abs() < 1e-9);
        }
        let singular = Matrix4::zeros();
        assert!(box_in_scene_frame(&b, &singular).is_none());
    }

    #[test]
    fn voxels_average_position_and_colour() {
        let pts = vec![
            (Point3::new(0.01, 0.01, 0.01), [0, 0, 0]),
            (Point3::new(0.03, 0.03, 0.03), [200, 100, 50]),
            (Point3::new(0.51, 0.0, 0.0), [9, 9, 9]),
        ];
        let d = voxel_downsample_colored(&pts, 0.1);
        assert_eq!(d.len(), 2);
        assert!((d[0].0.x - 0.02).abs() < 1e-12);
        assert_eq!(d[0].1, [100, 50, 25]);
        assert_eq!(d[1].1, [9, 9, 9]);
        assert_eq!(voxel_downsample_colored(&pts, 0.0).len(), 3);
    }

    #[test]
    fn ply_header_and_body_sizes_agree() {
        let pts = vec![(Point3::new(1.0, 2.0, 3.0), [1, 2, 3]); 4];
        let bytes = encode_ply(&pts, &["frame: output\nsecond".into()]);
        let end = b"end_header\n";
        let at = bytes
            .windows(end.len())
            .position(|w| w == end)
            .expect("header end")
            + end.len();
        let header = std::str::from_utf8(&bytes[..at]).unwrap();
        assert!(header.contains("element vertex 4\n"));
        assert!(header.contains("comment frame: output second\n"));
        assert_eq!(bytes.len() - at, 4 * 15);
        assert_eq!(&bytes[at..at + 4], &1.0f32.to_le_bytes());
        assert_eq!(&bytes[at + 12..at + 15], &[1, 2, 3]);
    }
}
