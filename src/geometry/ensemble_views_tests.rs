//! [`find_views`] against the loop it replaced (a whole-frame bitmap per candidate frame):
//! the same candidates, with the same distinct pixels in the same order.

use nalgebra::Point3;

use super::*;
use crate::geometry::test_scene::{camera, render};

/// The view search as it was: every candidate frame's pixels deduplicated on a bitmap of
/// the whole colour frame (no room).
fn find_views_whole_frame(
    anchor_points: &[Point3<f64>],
    candidates: &[CandidateFrame<'_>],
    params: &GeometryParams,
) -> Vec<ViewCandidate> {
    let probe = subsample_even(anchor_points, params.max_probe_points);
    let mut out: Vec<ViewCandidate> = candidates
        .iter()
        .filter_map(|c| {
            let proj = project_points(&probe, c.camera, c.depth, params).ok()?;
            let (w, h) = (c.camera.color.width, c.camera.color.height);
            let mut seen = vec![false; w as usize * h as usize];
            let mut pixels = Vec::new();
            let (mut x1, mut y1, mut x2, mut y2) = (u32::MAX, u32::MAX, 0u32, 0u32);
            let mut n = 0usize;
            for q in proj.iter().flatten().filter(|q| q.visible) {
                n += 1;
                let x = (q.u.round().max(0.0) as u32).min(w - 1);
                let y = (q.v.round().max(0.0) as u32).min(h - 1);
                x1 = x1.min(x);
                y1 = y1.min(y);
                x2 = x2.max(x + 1);
                y2 = y2.max(y + 1);
                let i = y as usize * w as usize + x as usize;
                if !seen[i] {
                    seen[i] = true;
                    pixels.push([x, y]);
                }
            }
            let frac = n as f64 / probe.len() as f64;
            (n > 0 && frac >= params.min_visible_fraction).then_some(ViewCandidate {
                index: c.index,
                visible_fraction: frac,
                visible_points: n,
                bbox: [x1 as f32, y1 as f32, x2 as f32, y2 as f32],
                pixels,
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

#[test]
fn views_and_their_pixels_equal_the_whole_frame_search() {
    // A box on the floor of a walled room, seen from a ring of cameras (some see it whole,
    // some part of it at the frame's edge, some not at all: it is behind them).
    let scene = [
        ([-2.0, -2.0, -0.1], [6.0, 6.0, 0.0]),
        ([-2.0, 5.0, 0.0], [6.0, 5.1, 3.0]),
        ([1.5, 1.8, 0.0], [2.3, 2.4, 0.7]),
    ];
    let target = [1.9, 2.1, 0.35];
    let cams: Vec<FrameCamera> = (0..12)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 12.0;
            let eye = [1.9 + 2.5 * a.cos(), 2.1 + 2.5 * a.sin(), 1.3];
            // Some look past the box (it lands near the edge or outside the frame).
            let look = [
                target[0] + (k % 3) as f64 * 0.6 * a.sin(),
                target[1] - (k % 3) as f64 * 0.6 * a.cos(),
                target[2],
            ];
            camera(eye, look)
        })
        .collect();
    let depths: Vec<DepthMap> = cams.iter().map(|c| render(c, &scene, 8.0)).collect();
    // The anchor: the box's visible surface points from camera 0, and a few far strays.
    let mut anchor = Vec::new();
    for i in 0..=16 {
        for j in 0..=14 {
            let (x, y) = (1.5 + 0.05 * i as f64, 1.8 + 0.04 * j as f64);
            anchor.push(Point3::new(x, y, 0.7));
            anchor.push(Point3::new(x, 1.8, 0.05 * j as f64));
        }
    }
    anchor.push(Point3::new(4.0, 0.5, 1.0));
    let candidates: Vec<CandidateFrame> = cams
        .iter()
        .zip(&depths)
        .enumerate()
        .skip(1)
        .map(|(index, (camera, depth))| CandidateFrame {
            index,
            camera,
            depth,
        })
        .collect();
    let mut params = GeometryParams {
        max_views: 20,
        ..GeometryParams::default()
    };
    for min_visible in [0.0, 0.05, 0.3, 0.8] {
        params.min_visible_fraction = min_visible;
        let want = find_views_whole_frame(&anchor, &candidates, &params);
        let got = find_views(&anchor, &candidates, &params);
        assert_eq!(got, want, "min_visible_fraction {min_visible}");
        assert_eq!(
            got.iter().map(|v| &v.pixels).collect::<Vec<_>>(),
            want.iter().map(|v| &v.pixels).collect::<Vec<_>>()
        );
        if min_visible == 0.05 {
            assert!(
                want.len() >= 3 && want.iter().any(|v| v.pixels.len() > 20),
                "{want:?}"
            );
        }
    }
}
