use super::*;
use crate::geometry::test_scene::{camera, render};

/// A wall: the plane y = 0 (its front face), 10 m wide and 3 m high.
const WALL: ([f64; 3], [f64; 3]) = ([-5.0, 0.0, 0.0], [5.0, 0.1, 3.0]);

#[test]
fn a_wall_beyond_range_gets_the_depth_nearer_views_measured() {
    let far = camera([0.0, -6.0, 1.5], [0.0, 0.0, 1.5]);
    let depth = render(&far, &[WALL], 5.0);
    assert!(
        depth.data.iter().all(|&d| d == 0),
        "the wall is beyond range"
    );
    let near: Vec<FrameCamera> = [[-1.0, -2.0, 1.4], [1.0, -2.5, 1.6], [0.0, -2.6, 1.2]]
        .iter()
        .map(|&e| camera(e, [e[0] * 0.5, 0.0, 1.5]))
        .collect();
    let maps: Vec<DepthMap> = near.iter().map(|c| render(c, &[WALL], 5.0)).collect();
    let others: Vec<(&FrameCamera, &DepthMap)> = near.iter().zip(&maps).collect();
    let p = GeometryParams::default();
    let (filled, stats) =
        fill_depth(&far, &depth, [30.0, 20.0, 50.0, 40.0], &others, None, &p).unwrap();
    // The box reads depth pixels [15, 26) x [10, 21): all missing, all reached.
    let holes: Vec<(u32, u32)> = (10..21)
        .flat_map(|y| (15..26).map(move |x| (x, y)))
        .filter(|&(x, y)| filled.get(x, y) == 0)
        .collect();
    assert_eq!(
        (stats.missing, stats.rays, stats.filled),
        (121, 121, 121),
        "{stats:?} {holes:?}"
    );
    let truth = render(&far, &[WALL], 100.0);
    for y in 10..21 {
        for x in 15..26 {
            let (got, want) = (filled.get(x, y) as f64, truth.get(x, y) as f64);
            assert!(
                (got - want).abs() < 40.0,
                "({x}, {y}): {got} mm, wall at {want} mm"
            );
        }
    }
    // Outside the box nothing is filled.
    assert_eq!((filled.get(0, 0), filled.get(39, 29)), (0, 0));
}

#[test]
fn readings_stay_and_the_nearest_surface_wins() {
    // A cabinet 1 m in front of the wall; the far camera measures the wall's left part
    // itself (a 5.9 m reading is kept as is) but not the cabinet (a blob of no readings).
    let cabinet = ([-0.4, -1.0, 0.0], [0.4, -0.6, 2.0]);
    let far = camera([0.0, -6.0, 1.5], [0.0, 0.0, 1.5]);
    let mut depth = render(&far, &[WALL, cabinet], 100.0);
    let kept = depth.get(2, 15);
    for y in 0..30 {
        for x in 12..40 {
            depth.data[(y * 40 + x) as usize] = 0;
        }
    }
    let near: Vec<FrameCamera> = [[-1.5, -3.0, 1.5], [1.5, -3.0, 1.5], [0.0, -3.5, 1.8]]
        .iter()
        .map(|&e| camera(e, [0.0, -0.8, 1.0]))
        .collect();
    let maps: Vec<DepthMap> = near
        .iter()
        .map(|c| render(c, &[WALL, cabinet], 5.0))
        .collect();
    let others: Vec<(&FrameCamera, &DepthMap)> = near.iter().zip(&maps).collect();
    let (filled, stats) = fill_depth(
        &far,
        &depth,
        [0.0, 0.0, 80.0, 60.0],
        &others,
        None,
        &GeometryParams::default(),
    )
    .unwrap();
    assert!(stats.resolved > 0, "{stats:?}");
    assert_eq!(filled.get(2, 15), kept, "a reading is never replaced");
    // The cabinet's face is 5.0 m away (y = -1): the ray stops there, not at the wall.
    let truth = render(&far, &[WALL, cabinet], 100.0);
    let centre = filled.get(20, 15);
    assert_eq!(truth.get(20, 15), 5000);
    assert!(
        (centre as f64 - 5000.0).abs() < 60.0,
        "cabinet centre filled with {centre} mm"
    );
}

#[test]
fn rays_no_other_view_measures_stay_empty() {
    let far = camera([0.0, -6.0, 1.5], [0.0, 0.0, 1.5]);
    let depth = render(&far, &[WALL], 5.0);
    // One view only: below `min_votes`.
    let near = camera([0.0, -2.0, 1.5], [0.0, 0.0, 1.5]);
    let map = render(&near, &[WALL], 5.0);
    let (filled, stats) = fill_depth(
        &far,
        &depth,
        [0.0, 0.0, 80.0, 60.0],
        &[(&near, &map)],
        None,
        &GeometryParams::default(),
    )
    .unwrap();
    assert_eq!((stats.resolved, stats.filled), (0, 0), "{stats:?}");
    assert!(filled.data.iter().all(|&d| d == 0));
    // A view whose depth does not match its camera is an error, not a panic.
    let bad = DepthMap::new(10, 10, vec![0; 100]);
    assert!(fill_depth(
        &far,
        &bad,
        [0.0, 0.0, 80.0, 60.0],
        &[],
        None,
        &GeometryParams::default()
    )
    .is_err());
}

#[test]
fn rays_nothing_measured_end_on_the_room_only_beyond_range() {
    use crate::geometry::{estimate_room, LayoutParams};
    // A 12 m long room; the cameras of two rings measure all of it, the anchor at x = 3
    // looks down its length at the far wall (x = 12, beyond the 5 m range).
    let slab = |a: [f64; 3], b: [f64; 3]| (a, b);
    let room = [
        slab([-0.1, -0.1, -0.1], [12.1, 5.1, 0.0]),
        slab([-0.1, -0.1, 2.7], [12.1, 5.1, 2.8]),
        slab([-0.1, -0.1, 0.0], [0.0, 5.1, 2.7]),
        slab([12.0, -0.1, 0.0], [12.1, 5.1, 2.7]),
        slab([-0.1, -0.1, 0.0], [12.1, 0.0, 2.7]),
        slab([-0.1, 5.0, 0.0], [12.1, 5.1, 2.7]),
    ];
    let mut cams = Vec::new();
    for cx in [3.0, 9.0] {
        for k in 0..12 {
            let a = f64::from(k) * 30f64.to_radians();
            cams.push(camera(
                [cx + 0.6 * a.cos(), 2.5 + 0.6 * a.sin(), 1.5],
                [
                    cx + 3.0 * a.cos(),
                    2.5 + 3.0 * a.sin(),
                    if k % 2 == 0 { 1.0 } else { 2.3 },
                ],
            ));
        }
    }
    let maps: Vec<DepthMap> = cams.iter().map(|c| render(c, &room, 5.0)).collect();
    let frames: Vec<(&FrameCamera, &DepthMap)> = cams.iter().zip(&maps).collect();
    let layout = estimate_room(
        &frames,
        &LayoutParams {
            sample_step: 1,
            ..LayoutParams::default()
        },
    )
    .expect("a layout");
    let anchor = camera([3.0, 2.5, 1.5], [12.0, 2.5, 1.5]);
    let depth = render(&anchor, &room, 5.0);
    let p = GeometryParams::default();
    // The box's pixels all look at the far wall, 9 m away: no reading, no voter.
    let region = [30.0, 20.0, 50.0, 40.0];
    let (same, stats) = fill_depth(&anchor, &depth, region, &[], None, &p).unwrap();
    assert_eq!(
        (stats.placed, stats.filled),
        (0, 0),
        "without the layout nothing is filled"
    );
    assert_eq!(same, depth);
    let (filled, stats) = fill_depth(&anchor, &depth, region, &[], Some(&layout), &p).unwrap();
    assert_eq!(
        (stats.resolved, stats.placed, stats.filled),
        (0, 121, 121),
        "{stats:?}"
    );
    let truth = render(&anchor, &room, 100.0);
    for (x, y) in [(15, 10), (20, 15), (25, 20)] {
        let (got, want) = (f64::from(filled.get(x, y)), f64::from(truth.get(x, y)));
        assert!(
            (got - want).abs() < 60.0,
            "({x}, {y}): {got} mm, the wall is at {want} mm"
        );
    }
    // Coarse cells (4 rays for the region) on a wall seen at a slant: every pixel still
    // gets its own exit, so the filled depth follows the wall, not one depth per cell.
    let slanted = camera([3.0, 2.5, 1.5], [12.0, 0.8, 1.5]);
    let sd = render(&slanted, &room, 5.0);
    let coarse = GeometryParams {
        depth_fill: DepthFillParams {
            max_rays: 4,
            ..DepthFillParams::default()
        },
        ..GeometryParams::default()
    };
    let (filled, stats) = fill_depth(&slanted, &sd, region, &[], Some(&layout), &coarse).unwrap();
    assert!(stats.cell >= 5 && stats.placed > 0, "{stats:?}");
    let truth = render(&slanted, &room, 100.0);
    let (x0, y0) = (15u32, 10u32);
    assert!(
        f64::from(truth.get(x0, y0)) - f64::from(truth.get(x0 + 10, y0)) > 150.0,
        "the wall is slanted in view"
    );
    for y in 10..21 {
        for x in 15..26 {
            if sd.get(x, y) == 0 && filled.get(x, y) > 0 {
                let (got, want) = (f64::from(filled.get(x, y)), f64::from(truth.get(x, y)));
                assert!(
                    (got - want).abs() < 60.0,
                    "({x}, {y}): {got} mm, the wall is at {want} mm"
                );
            }
        }
    }
    // A region mostly read (a wall 3 m away fills its left part) is an object that was
    // measured: its empty part is not put on the wall behind.
    let mut half = depth.clone();
    for y in 10..21 {
        for x in 15..22 {
            half.data[(y * 40 + x) as usize] = 3000;
        }
    }
    let (_, stats) = fill_depth(&anchor, &half, region, &[], Some(&layout), &p).unwrap();
    assert_eq!((stats.missing, stats.placed), (44, 0), "{stats:?}");
    // A hole where the side wall is 2.5 m away is no sign of distance: it stays.
    let side = camera([3.0, 2.5, 1.5], [3.0, 0.0, 1.5]);
    let mut holed = render(&side, &room, 5.0);
    holed.data.iter_mut().for_each(|d| *d = 0);
    let (_, stats) = fill_depth(&side, &holed, region, &[], Some(&layout), &p).unwrap();
    assert_eq!((stats.placed, stats.filled), (0, 0), "{stats:?}");
}
