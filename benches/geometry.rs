//! Geometry benchmarks (run: `cargo bench --bench geometry`).
//! * `mask_100k`: post-process + back-project + outlier-filter a ~100k-pixel mask
//!   (1296x968 colour, 640x480 depth, paper parameters). Target < 30 ms.
//! * `ensemble_7_views`: view finding over 11 frames, back-projection of the 6 best views'
//!   masks, chamfer filter, union, outlier removal, box. Target < 100 ms.

#[path = "../tests/suite/geometry_scene.rs"]
mod geometry_scene;

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use grounder::geometry::camera::look_at_pose;
use grounder::geometry::{
    find_views, fuse_views, mask_points, remove_statistical_outliers, CandidateFrame, DepthMap,
    FrameCamera, GeometryParams, Intrinsics, Mask,
};
use nalgebra::{Matrix4, Point3, Vector3};

fn mask_frame() -> (Mask, FrameCamera, DepthMap) {
    let color = Intrinsics {
        fx: 1170.0,
        fy: 1170.0,
        cx: 647.5,
        cy: 483.5,
        width: 1296,
        height: 968,
    };
    let cam = FrameCamera {
        color,
        depth: None,
        depth_size: (640, 480),
        pose: look_at_pose(
            Point3::new(0.0, -2.0, 1.5),
            Point3::new(0.0, 0.0, 0.5),
            Vector3::z(),
        ),
        align: Matrix4::identity(),
    };
    // A slanted, slightly bumpy surface with a few holes.
    let data = (0..640 * 480)
        .map(|i| {
            let (x, y) = ((i % 640) as f64, (i / 640) as f64);
            if i % 97 == 0 {
                0
            } else {
                (1500.0 + 0.8 * y + 10.0 * (x * 0.05).sin()) as u16
            }
        })
        .collect();
    let depth = DepthMap::new(640, 480, data);
    let mut mask = Mask::new(1296, 968);
    let r2 = 185.0f64 * 185.0; // ~107k pixels before erosion
    for y in 0..968u32 {
        for x in 0..1296u32 {
            let (dx, dy) = (x as f64 - 600.0, y as f64 - 500.0);
            if dx * dx + dy * dy < r2 {
                mask.set(x, y, true);
            }
        }
    }
    (mask, cam, depth)
}

fn bench_mask(c: &mut Criterion) {
    let (mask, cam, depth) = mask_frame();
    let p = GeometryParams::default();
    let pts = mask_points(&mask, &cam, &depth, &p).unwrap_or_default();
    println!(
        "mask pixels {}, points after post-processing + back-projection {}",
        mask.count(),
        pts.len()
    );
    let eroded = grounder::geometry::postprocess_mask(&mask, p.erode_kernel, p.keep_components);
    c.bench_function("part_postprocess", |b| {
        b.iter(|| {
            grounder::geometry::postprocess_mask(
                black_box(&mask),
                p.erode_kernel,
                p.keep_components,
            )
        })
    });
    c.bench_function("part_backproject", |b| {
        b.iter(|| {
            grounder::geometry::backproject_mask(black_box(&eroded), &cam, &depth, (&p).into())
        })
    });
    c.bench_function("part_sor", |b| {
        b.iter(|| remove_statistical_outliers(black_box(&pts), p.sor_neighbors, p.sor_std_ratio))
    });
    c.bench_function("mask_100k", |b| {
        b.iter(|| {
            let pts = mask_points(black_box(&mask), &cam, &depth, &p).unwrap_or_default();
            black_box(remove_statistical_outliers(
                &pts,
                p.sor_neighbors,
                p.sor_std_ratio,
            ))
        })
    });
}

fn bench_ensemble(c: &mut Criterion) {
    // ScanNet sizes: colour 1296x968, depth 640x480.
    let scene = geometry_scene::render_scene_sized(5, (1296, 968), (640, 480), 12);
    let p = GeometryParams::default();
    // The object/view whose mask is closest to 100k pixels.
    let mut best_pair = None;
    for ob in &scene.objects {
        for (i, v) in scene.views.iter().enumerate() {
            let d = (v.mask_of(ob.id).count() as i64 - 100_000).abs();
            if best_pair.is_none_or(|(_, _, bd)| d < bd) {
                best_pair = Some((ob.id, i, d));
            }
        }
    }
    let Some((id, best, _)) = best_pair else {
        return;
    };
    let bv = &scene.views[best];
    let anchor_mask = bv.mask_of(id);
    let candidates: Vec<CandidateFrame> = scene
        .views
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != best)
        .map(|(i, v)| CandidateFrame {
            index: i,
            camera: &v.camera,
            depth: &v.depth,
        })
        .collect();
    let masks: Vec<Mask> = scene.views.iter().map(|v| v.mask_of(id)).collect();
    let run = || {
        let anchor = mask_points(&anchor_mask, &bv.camera, &bv.depth, &p).unwrap_or_default();
        let found = find_views(&anchor, &candidates, &p);
        let others: Vec<(usize, Vec<Point3<f64>>)> = found
            .iter()
            .map(|f| {
                let v = &scene.views[f.index];
                (
                    f.index,
                    mask_points(&masks[f.index], &v.camera, &v.depth, &p).unwrap_or_default(),
                )
            })
            .collect();
        fuse_views(&anchor, &others, &p)
    };
    let r = run();
    println!(
        "ensemble: object {id}, anchor {} px / {} pts, {} views, fused {} -> kept {} points",
        anchor_mask.count(),
        r.anchor_points,
        r.views.len(),
        r.fused_points,
        r.kept_points
    );
    c.bench_function("ensemble_7_views", |b| b.iter(|| black_box(run())));
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench_mask, bench_ensemble
}
criterion_main!(benches);
