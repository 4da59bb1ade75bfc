//! Placing a wall that no reading reached (ours, not the paper's).
//!
//! The room's box (`geometry::layout`) puts a wall that was beyond the sensor's range in
//! every frame where the readings end: the true wall lies at least that far, by an
//! unknown amount. What hangs on it (a picture, a window, a door) has no depth either, so
//! its pixels were ended on that estimate. Its colours, though, were seen from several
//! posed cameras: placed on the true plane they land on the same colours in every frame,
//! placed on a wrong one they slide against their surroundings (parallax). A plane sweep
//! finds the shift: the wall is moved outward in steps, the object's patch (its box and a
//! margin of wall around it) is laid on the moved plane and projected into the other
//! frames, and each frame's colours are compared with the chosen frame's by normalised
//! cross-correlation (indifferent to exposure). The shift with the best mean correlation
//! wins when it beats the unmoved wall by a margin; a patch without contrast says nothing.

use image::RgbImage;
use nalgebra::{Matrix4, Point3};
use serde::{Deserialize, Serialize};

use super::camera::transform_point;
use super::{FrameCamera, RoomLayout};

/// Settings of [`sweep_wall`] (file section `[agent.geometry.wall_sweep]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WallSweepParams {
    /// Move a wall no frame faced to where the object on it is consistent across frames.
    pub enabled: bool,
    /// Farthest outward shift tried (m).
    pub max_shift: f64,
    /// Step between shifts (m).
    pub step: f64,
    /// Samples across the patch in each direction.
    pub samples: u32,
    /// The patch is the object's box grown by this fraction of its size on every side
    /// (the wall around it is what the object slides against).
    pub grow: f64,
    /// Frames whose view of the patch must be compared.
    pub min_views: usize,
    /// At most this many frames are decoded and compared (spread over the scan).
    pub max_views: usize,
    /// A frame is compared only when this share of the samples falls inside it.
    pub min_inside: f64,
    /// The best shift must beat the unmoved wall's mean correlation by this much.
    pub min_gain: f64,
    /// Least standard deviation of the patch's grey levels (0–255) to say anything.
    pub min_contrast: f64,
}

impl Default for WallSweepParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_shift: 1.5,
            step: 0.02,
            samples: 24,
            grow: 0.25,
            min_views: 2,
            max_views: 12,
            min_inside: 0.8,
            min_gain: 0.1,
            min_contrast: 4.0,
        }
    }
}

/// What [`sweep_wall`] found (kept in the job's trace).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WallSweep {
    /// The side moved: 0–3 for the walls u low, u high, v low, v high (`RoomLayout`).
    pub side: usize,
    /// Outward shift (m) with the best mean correlation; 0 when the unmoved wall stays.
    pub shift: f64,
    /// Mean correlation at that shift and at the unmoved wall.
    pub score: f64,
    pub score_unmoved: f64,
    /// Frames compared.
    pub views: usize,
}

/// `layout` with wall `side` (0–3) moved outward by `shift` metres.
pub fn wall_moved(layout: &RoomLayout, side: usize, shift: f64) -> RoomLayout {
    let mut out = layout.clone();
    match side {
        0 => out.u[0] = out.u[0].map(|w| w - shift),
        1 => out.u[1] = out.u[1].map(|w| w + shift),
        2 => out.v[0] = out.v[0].map(|w| w - shift),
        3 => out.v[1] = out.v[1].map(|w| w + shift),
        _ => {}
    }
    out
}

/// One sample of the patch: its ray in the room's turned frame and its grey level.
struct Ray {
    o: Point3<f64>,
    d: nalgebra::Vector3<f64>,
    grey: f64,
}

fn grey(p: &image::Rgb<u8>) -> f64 {
    0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2])
}

/// Bilinear grey level of `img` at (x, y) in its own pixels; `None` outside.
fn sample(img: &RgbImage, x: f64, y: f64) -> Option<f64> {
    let (w, h) = (f64::from(img.width()), f64::from(img.height()));
    if !(x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0) {
        return None;
    }
    let (x0, y0) = (x.floor() as u32, y.floor() as u32);
    let (x1, y1) = (
        (x0 + 1).min(img.width() - 1),
        (y0 + 1).min(img.height() - 1),
    );
    let (fx, fy) = (x - f64::from(x0), y - f64::from(y0));
    let g = |x, y| grey(img.get_pixel(x, y));
    let top = g(x0, y0) * (1.0 - fx) + g(x1, y0) * fx;
    let bottom = g(x0, y1) * (1.0 - fx) + g(x1, y1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// Normalised cross-correlation of two equally long series (0 when either is flat).
fn ncc(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    if a.len() < 2 || a.len() != b.len() {
        return 0.0;
    }
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    if saa <= 1e-9 || sbb <= 1e-9 {
        return 0.0;
    }
    sab / (saa * sbb).sqrt()
}

/// The shift of the wall that the patch `region` (colour pixels of `cam`, whose image is
/// `image`) ends on, when its rays leave the room through a wall no frame faced; compared
/// in `others` (camera and colour image; images may be any size, pixels are scaled).
/// `None` when the patch does not end on such a wall, has no contrast, or too few frames
/// see it.
pub fn sweep_wall(
    cam: &FrameCamera,
    image: &RgbImage,
    region: [f32; 4],
    layout: &RoomLayout,
    others: &[(&FrameCamera, &RgbImage)],
    p: &WallSweepParams,
) -> Option<WallSweep> {
    let to_out = cam.cam_to_out();
    let o = cam.centre();
    let (bw, bh) = (
        f64::from(region[2] - region[0]),
        f64::from(region[3] - region[1]),
    );
    if !(bw > 0.0 && bh > 0.0) || p.samples < 2 || p.step <= 0.0 {
        return None;
    }
    let (sx, sy) = (
        f64::from(image.width()) / f64::from(cam.color.width),
        f64::from(image.height()) / f64::from(cam.color.height),
    );
    let (x0, y0) = (
        f64::from(region[0]) - p.grow * bw,
        f64::from(region[1]) - p.grow * bh,
    );
    let (gw, gh) = (bw * (1.0 + 2.0 * p.grow), bh * (1.0 + 2.0 * p.grow));
    let n = p.samples;
    let mut rays = Vec::new();
    let mut sides = [0usize; 6];
    for j in 0..n {
        for i in 0..n {
            let u = x0 + gw * (f64::from(i) + 0.5) / f64::from(n);
            let v = y0 + gh * (f64::from(j) + 0.5) / f64::from(n);
            let Some(grey) = sample(image, u * sx, v * sy) else {
                continue;
            };
            let d = transform_point(&to_out, &cam.color.unproject(u, v, 1.0)) - o;
            let Some(t) = layout.exit(&o, &d) else {
                continue;
            };
            if let Some((side, _)) = layout.nearest_side(&(o + d * t)) {
                sides[side] += 1;
                rays.push((side, Ray { o, d, grey }));
            }
        }
    }
    // The wall most of the patch ends on; it must be a wall placed where readings end.
    let side = (0..4).max_by_key(|&s| sides[s])?;
    if sides[side] * 2 < rays.len().max(1) || layout.faced[side] {
        return None;
    }
    let rays: Vec<Ray> = rays
        .into_iter()
        .filter_map(|(s, r)| (s == side).then_some(r))
        .collect();
    let greys: Vec<f64> = rays.iter().map(|r| r.grey).collect();
    let mean = greys.iter().sum::<f64>() / greys.len().max(1) as f64;
    let var = greys.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / greys.len().max(1) as f64;
    if rays.len() < 16 || var.sqrt() < p.min_contrast {
        return None;
    }
    let wall_at = |shift: f64| {
        let moved = wall_moved(layout, side, shift);
        match side {
            0 | 1 => moved.u[side],
            _ => moved.v[side - 2],
        }
    };
    let views: Vec<(Matrix4<f64>, &FrameCamera, &RgbImage)> = others
        .iter()
        .filter_map(|&(c, img)| {
            let inv = c.cam_to_out().try_inverse()?;
            Some((inv, c, img))
        })
        .collect();
    let steps = (p.max_shift / p.step).floor().max(0.0) as usize;
    // A point's coordinate across the wall (the room's turn is a rotation: directions too).
    let along = |x: f64, y: f64| {
        let (u, v) = layout.turn(x, y);
        if side < 2 {
            u
        } else {
            v
        }
    };
    // Mean correlation over the frames that see the patch, and how many did.
    let score = |shift: f64| -> Option<(f64, usize)> {
        let wall = wall_at(shift)?;
        let pts: Vec<Option<Point3<f64>>> = rays
            .iter()
            .map(|r| {
                let (ou, du) = (along(r.o.x, r.o.y), along(r.d.x, r.d.y));
                (du.abs() > 1e-9)
                    .then(|| (wall - ou) / du)
                    .filter(|t| *t > 0.0)
                    .map(|t| r.o + r.d * t)
            })
            .collect();
        let (mut sum, mut used) = (0.0, 0usize);
        for (inv, c, img) in &views {
            let (vx, vy) = (
                f64::from(img.width()) / f64::from(c.color.width),
                f64::from(img.height()) / f64::from(c.color.height),
            );
            let (mut a, mut b) = (Vec::new(), Vec::new());
            for (r, q) in rays.iter().zip(&pts) {
                let Some(q) = q else { continue };
                let Some((x, y, _)) = c.color.project(&transform_point(inv, q)) else {
                    continue;
                };
                if let Some(g) = sample(img, x * vx, y * vy) {
                    a.push(r.grey);
                    b.push(g);
                }
            }
            if a.len() as f64 >= p.min_inside * rays.len() as f64 {
                sum += ncc(&a, &b);
                used += 1;
            }
        }
        (used >= p.min_views).then(|| (sum / used as f64, used))
    };
    let (unmoved, seen) = score(0.0)?;
    let (best_shift, best, views) = (1..=steps)
        .filter_map(|k| {
            let s = k as f64 * p.step;
            score(s).map(|(v, n)| (s, v, n))
        })
        .fold(
            (0.0, unmoved, seen),
            |acc, x| if x.1 > acc.1 { x } else { acc },
        );
    let moved = best - unmoved >= p.min_gain;
    Some(WallSweep {
        side,
        shift: if moved { best_shift } else { 0.0 },
        score: if moved { best } else { unmoved },
        score_unmoved: unmoved,
        views,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::camera::look_at_pose;
    use crate::geometry::Intrinsics;
    use nalgebra::Vector3;

    /// The true wall is at x = 6; a dark picture hangs on it over y 2.2–3.0, z 1.2–1.8.
    const WALL: f64 = 6.0;

    fn camera(eye: Point3<f64>, target: Point3<f64>) -> FrameCamera {
        FrameCamera {
            color: Intrinsics {
                fx: 130.0,
                fy: 130.0,
                cx: 80.0,
                cy: 60.0,
                width: 160,
                height: 120,
            },
            depth: None,
            depth_size: (160, 120),
            pose: look_at_pose(eye, target, Vector3::z()),
            align: Matrix4::identity(),
        }
    }

    /// What `c` sees of the wall at x = `WALL` (every ray from inside meets it).
    fn render(c: &FrameCamera) -> RgbImage {
        let to_out = c.cam_to_out();
        let o = transform_point(&to_out, &Point3::origin());
        RgbImage::from_fn(160, 120, |u, v| {
            let d =
                transform_point(&to_out, &c.color.unproject(f64::from(u), f64::from(v), 1.0)) - o;
            let t = (WALL - o.x) / d.x;
            let q = o + d * t;
            if t > 0.0 && (2.2..3.0).contains(&q.y) && (1.2..1.8).contains(&q.z) {
                image::Rgb([40, 30, 60])
            } else {
                image::Rgb([200, 200, 190])
            }
        })
    }

    /// The room's box with the far wall (u high) placed `short` metres before the true one,
    /// as the layout does when no reading reached it.
    fn layout(short: f64, faced: bool) -> RoomLayout {
        RoomLayout {
            angle_deg: 0.0,
            u: [Some(0.0), Some(WALL - short)],
            v: [Some(0.0), Some(5.0)],
            faced: [true, faced, true, true],
            floor: Some(0.0),
            ceiling: Some(3.0),
            range: 4.0,
            reach: [[0.0, WALL - short], [0.0, 5.0], [0.0, 3.0]],
            points: 0,
        }
    }

    fn views() -> Vec<FrameCamera> {
        let target = Point3::new(WALL, 2.6, 1.5);
        [[1.0, 1.0], [1.2, 4.0], [0.8, 2.5]]
            .iter()
            .map(|[x, y]| camera(Point3::new(*x, *y, 1.4), target))
            .collect()
    }

    /// The picture's box in the chosen frame's pixels (the projection of its corners).
    fn picture_box(c: &FrameCamera) -> [f32; 4] {
        let inv = c.cam_to_out().try_inverse().unwrap();
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        for (y, z) in [(2.2, 1.2), (3.0, 1.2), (2.2, 1.8), (3.0, 1.8)] {
            let (u, v, _) = c
                .color
                .project(&transform_point(&inv, &Point3::new(WALL, y, z)))
                .unwrap();
            lo = [lo[0].min(u), lo[1].min(v)];
            hi = [hi[0].max(u), hi[1].max(v)];
        }
        [lo[0] as f32, lo[1] as f32, hi[0] as f32, hi[1] as f32]
    }

    #[test]
    fn a_wall_placed_short_is_moved_to_where_the_picture_on_it_agrees() {
        let cams = views();
        let imgs: Vec<RgbImage> = cams.iter().map(render).collect();
        let others: Vec<(&FrameCamera, &RgbImage)> = cams[1..].iter().zip(&imgs[1..]).collect();
        let region = picture_box(&cams[0]);
        let p = WallSweepParams::default();
        let s = sweep_wall(
            &cams[0],
            &imgs[0],
            region,
            &layout(0.44, false),
            &others,
            &p,
        )
        .expect("the patch ends on the unfaced wall");
        assert_eq!(s.side, 1);
        assert!((s.shift - 0.44).abs() <= 0.05, "{s:?}");
        assert!(s.views >= 2 && s.score > s.score_unmoved, "{s:?}");
        // Already at the right place: it stays.
        let s = sweep_wall(&cams[0], &imgs[0], region, &layout(0.0, false), &others, &p)
            .expect("the patch ends on the unfaced wall");
        assert!(s.shift <= 0.04, "{s:?}");
        // A wall a camera faced is left alone, and so is a patch without contrast.
        assert!(sweep_wall(&cams[0], &imgs[0], region, &layout(0.44, true), &others, &p).is_none());
        let flat = RgbImage::from_pixel(160, 120, image::Rgb([200, 200, 190]));
        assert!(sweep_wall(&cams[0], &flat, region, &layout(0.44, false), &others, &p).is_none());
    }

    #[test]
    fn moving_a_wall_moves_that_side_only() {
        let l = layout(0.44, false);
        let m = wall_moved(&l, 1, 0.44);
        assert!((m.u[1].unwrap() - WALL).abs() < 1e-12);
        assert_eq!((m.u[0], m.v), (l.u[0], l.v));
        let m = wall_moved(&l, 2, 0.5);
        assert_eq!(m.v[0], Some(-0.5));
    }
}
