//! Tests of [`super`].

use super::*;
use crate::geometry::camera::look_at_pose;
use crate::geometry::Intrinsics;
use nalgebra::{Matrix4, Vector3};

fn gp() -> GeometryParams {
    GeometryParams::default()
}

/// Points on a grid over [a0, a1] x [b0, b1] along axes (i, j), constant `c` on axis k.
fn plane(
    k: usize,
    c: f64,
    (i, a0, a1): (usize, f64, f64),
    (j, b0, b1): (usize, f64, f64),
    step: f64,
) -> Vec<Point3<f64>> {
    crate::geometry::test_grid::grid((a0, a1), (b0, b1), step, |a, b| {
        let mut p = Point3::origin();
        p[k] = c;
        p[i] = a;
        p[j] = b;
        p
    })
}

#[test]
fn chair_seat_extends_to_the_floor_below() {
    // Seat box 0.45..0.9 m high; floor at z = 0 visible around and under it.
    let b = Aabb::new([1.0, 1.0, 0.45], [1.5, 1.5, 0.9]);
    let floor = plane(2, 0.0, (0, 0.8, 1.7), (1, 0.8, 1.7), 0.02);
    let (e, moved) = extend_to_support(&b, b.center(), &floor, &[], true, &gp());
    assert!((e.min[2] - 0.0).abs() < 1e-9, "{e:?}");
    assert_eq!(moved.len(), 1);
    assert_eq!((moved[0].axis, moved[0].side), ("z", "min"));
    assert_eq!((e.min[0], e.max[0], e.max[2]), (1.0, 1.5, 0.9));
}

#[test]
fn a_floor_lamps_shade_reaches_the_floor_through_its_pole_and_nothing_else_does() {
    // Shade 1.3..1.65 m high; the floor around; a 3 cm pole under the shade's centre.
    let b = Aabb::new([1.0, 1.0, 1.3], [1.4, 1.4, 1.65]);
    let floor = plane(2, 0.0, (0, 0.6, 1.8), (1, 0.6, 1.8), 0.02);
    let mut pole = Vec::new();
    let mut z = 0.02;
    while z < 1.3 {
        if !(1.2..1.26).contains(&z) {
            pole.push(Point3::new(1.2, 1.2, z));
            pole.push(Point3::new(1.22, 1.2, z));
        }
        z += 0.02;
    }
    let with_pole: Vec<_> = floor.iter().chain(&pole).copied().collect();
    let (e, moved) = extend_to_support(&b, b.center(), &with_pole, &[], true, &gp());
    assert!(e.min[2].abs() < 1e-9 && moved.len() == 1, "{e:?} {moved:?}");
    // Without the pole (a shade on a wall bracket, a pendant), the floor is too far.
    let (e, moved) = extend_to_support(&b, b.center(), &floor, &[], true, &gp());
    assert_eq!((e, moved.len()), (b, 0));
    // A pole broken for 30 cm does not join.
    let broken: Vec<_> = with_pole
        .iter()
        .filter(|q| !(0.5..0.8).contains(&q.z))
        .copied()
        .collect();
    assert_eq!(
        extend_to_support(&b, b.center(), &broken, &[], true, &gp()).0,
        b
    );
    // Off: no column rule.
    let mut off = gp();
    off.support.max_gap_column = 0.0;
    assert_eq!(
        extend_to_support(&b, b.center(), &with_pole, &[], true, &off).0,
        b
    );
}

#[test]
fn picture_extends_back_to_its_wall_not_down() {
    // Picture front face at y = 2.97 (a zero-thickness slab), wall at y = 3.0 around it.
    let b = Aabb::new([1.0, 2.97, 1.2], [1.6, 2.97, 1.7]);
    let mut wall = plane(1, 3.0, (0, 0.8, 1.8), (2, 1.0, 1.9), 0.02);
    wall.retain(|q| !(q.x > 1.0 && q.x < 1.6 && q.z > 1.2 && q.z < 1.7));
    let (e, moved) = extend_to_support(&b, b.center(), &wall, &[], true, &gp());
    assert!((e.max[1] - 3.0).abs() < 1e-9, "{e:?}");
    assert_eq!(
        e.min, b.min,
        "the wall below the picture is no floor: {moved:?}"
    );
    assert_eq!(moved.len(), 1);
}

#[test]
fn leg_slices_far_walls_and_tiny_patches_are_not_supports() {
    let b = Aabb::new([1.0, 1.0, 0.45], [1.5, 1.5, 0.9]);
    // Four legs: vertical lines of points at the corners, no floor.
    let mut legs = Vec::new();
    for (x, y) in [(1.02, 1.02), (1.48, 1.02), (1.02, 1.48), (1.48, 1.48)] {
        let mut z = 0.0;
        while z < 0.45 {
            for (dx, dy) in [(0.0, 0.0), (0.02, 0.0), (0.0, 0.02), (0.02, 0.02)] {
                legs.push(Point3::new(x + dx, y + dy, z));
            }
            z += 0.02;
        }
    }
    let (e, moved) = extend_to_support(&b, b.center(), &legs, &[], true, &gp());
    assert_eq!((e, moved.len()), (b, 0));
    // A wall 0.9 m behind the box is beyond even the far gap.
    let wall = plane(1, 2.4, (0, 0.9, 1.6), (2, 0.4, 1.0), 0.02);
    assert_eq!(
        extend_to_support(&b, b.center(), &wall, &[], true, &gp()).0,
        b
    );
    // A floor patch of a few points is not enough.
    let patch = plane(2, 0.0, (0, 1.1, 1.14), (1, 1.1, 1.14), 0.02);
    assert_eq!(
        extend_to_support(&b, b.center(), &patch, &[], true, &gp()).0,
        b
    );
    // Disabled: nothing moves.
    let floor = plane(2, 0.0, (0, 0.8, 1.7), (1, 0.8, 1.7), 0.02);
    let mut off = gp();
    off.support.enabled = false;
    assert_eq!(
        extend_to_support(&b, b.center(), &floor, &[], true, &off).0,
        b
    );
}

/// An 80x60 pinhole camera at `eye` looking at `target`, depth everywhere `depth_m`.
fn view(eye: [f64; 3], target: [f64; 3], depth_m: f64) -> (FrameCamera, DepthMap) {
    let color = Intrinsics {
        fx: 100.0,
        fy: 100.0,
        cx: 39.5,
        cy: 29.5,
        width: 80,
        height: 60,
    };
    let pose = look_at_pose(Point3::from(eye), Point3::from(target), Vector3::z());
    let cam = FrameCamera {
        color,
        depth: None,
        depth_size: (80, 60),
        pose,
        align: Matrix4::identity(),
    };
    (
        cam,
        DepthMap::new(80, 60, vec![(depth_m * 1000.0) as u16; 80 * 60]),
    )
}

#[test]
fn far_wall_is_joined_only_when_no_frame_saw_the_gap_empty() {
    // A cabinet whose front (y = 1.0) is all that was seen; a wall at y = 1.5 around it.
    let b = Aabb::new([1.0, 1.0, 0.1], [1.6, 1.02, 0.9]);
    let mut wall = plane(1, 1.5, (0, 0.8, 1.8), (2, 0.0, 1.1), 0.02);
    wall.retain(|q| !(q.x > 1.0 && q.x < 1.6 && q.z < 0.9));
    // From the front the depth stops at the cabinet face (2 m away): the gap is hidden.
    let front = view([1.3, -1.0, 0.5], [1.3, 1.0, 0.5], 2.0);
    // From the side, looking along +x through the gap, the depth reads 5 m.
    let side = view([-1.0, 1.25, 0.5], [1.3, 1.25, 0.5], 5.0);
    let hidden = [(&front.0, &front.1)];
    let (e, moved) = extend_to_support(&b, b.center(), &wall, &hidden, true, &gp());
    assert!((e.max[1] - 1.5).abs() < 1e-9, "{e:?} {moved:?}");
    let mut slab = b;
    slab.min[1] = 1.02;
    slab.max[1] = 1.5;
    assert_eq!(observed_free_fraction(&slab, &hidden, &gp()), 0.0);
    let seen = [(&front.0, &front.1), (&side.0, &side.1)];
    assert!(observed_free_fraction(&slab, &seen, &gp()) > 0.9);
    assert_eq!(
        extend_to_support(&b, b.center(), &wall, &seen, true, &gp()).0,
        b
    );
    // With the far gap off, the front view alone moves nothing either.
    let mut near_only = gp();
    near_only.support.max_gap_far = 0.0;
    assert_eq!(
        extend_to_support(&b, b.center(), &wall, &hidden, true, &near_only).0,
        b
    );
}

#[test]
fn a_near_side_gap_seen_empty_is_not_crossed() {
    // A lamp 9 cm in front of the wall y = 0 (its back face at y = 0.09).
    let b = Aabb::new([1.0, 0.09, 0.55], [1.3, 0.35, 0.95]);
    let mut wall = plane(1, 0.0, (0, 0.8, 1.5), (2, 0.4, 1.2), 0.02);
    wall.retain(|q| !(q.x > 1.0 && q.x < 1.3 && q.z > 0.55 && q.z < 0.95));
    // Unobserved gap: the back face moves onto the wall.
    let (e, _) = extend_to_support(&b, b.center(), &wall, &[], true, &gp());
    assert!(e.min[1].abs() < 1e-9, "{e:?}");
    // A frame looking along the wall through the gap reads the far end of the room.
    let side = view([-1.0, 0.045, 0.75], [1.15, 0.045, 0.75], 6.0);
    let (e, moved) = extend_to_support(&b, b.center(), &wall, &[(&side.0, &side.1)], true, &gp());
    assert_eq!(e.min[1], 0.09, "{moved:?}");
    // A gap within one layer is noise and is closed whatever the frames saw.
    let touching = Aabb::new([1.0, 0.03, 0.55], [1.3, 0.35, 0.95]);
    assert!(
        extend_to_support(
            &touching,
            touching.center(),
            &wall,
            &[(&side.0, &side.1)],
            true,
            &gp()
        )
        .0
        .min[1]
            .abs()
            < 1e-9
    );
}

#[test]
fn nearest_support_wins_and_a_support_inside_the_box_changes_nothing() {
    // A lamp on a nightstand top (z = 0.6) above the floor (z = 0).
    let b = Aabb::new([1.1, 1.1, 0.62], [1.3, 1.3, 1.1]);
    let mut ctx = plane(2, 0.6, (0, 0.95, 1.45), (1, 0.95, 1.45), 0.02);
    ctx.extend(plane(2, 0.0, (0, 0.9, 1.5), (1, 0.9, 1.5), 0.02));
    let (e, _) = extend_to_support(&b, b.center(), &ctx, &[], true, &gp());
    assert!((e.min[2] - 0.6).abs() < 1e-9, "{e:?}");
    // Box bottom 5 cm inside the nightstand (depth noise): pulled back up onto its top.
    let b2 = Aabb::new([1.1, 1.1, 0.55], [1.3, 1.3, 1.1]);
    let (e2, moved) = extend_to_support(&b2, b2.center(), &ctx, &[], true, &gp());
    assert!((e2.min[2] - 0.6).abs() < 1e-9, "{e2:?}");
    assert_eq!((moved.len(), moved[0].side), (1, "min"));
}

#[test]
fn a_noisy_floor_is_found_at_its_middle_not_its_fringe() {
    // Floor points spread +-3 cm around z = 0 (deterministic pseudo-noise).
    let mut floor = plane(2, 0.0, (0, 0.8, 1.7), (1, 0.8, 1.7), 0.02);
    for (i, q) in floor.iter_mut().enumerate() {
        q.z = 0.03 * (((i * 7919) % 61) as f64 / 30.0 - 1.0);
    }
    let b = Aabb::new([1.0, 1.0, 0.45], [1.5, 1.5, 0.9]);
    let (e, _) = extend_to_support(&b, b.center(), &floor, &[], true, &gp());
    assert!(e.min[2].abs() < 0.005, "{e:?}");
}

#[test]
fn noisy_points_behind_the_wall_are_cut_at_the_wall() {
    // A 3 cm picture on the wall y = 3.0; noise spread its cloud from 2.93 to 3.05.
    let b = Aabb::new([1.0, 2.93, 1.2], [1.6, 3.05, 1.7]);
    let mut wall = plane(1, 3.0, (0, 0.8, 1.8), (2, 1.0, 1.9), 0.02);
    wall.retain(|q| !(q.x > 1.0 && q.x < 1.6 && q.z > 1.2 && q.z < 1.7));
    // The picture's own front surface, inside the footprint, must not pass as a support.
    wall.extend(plane(1, 2.97, (0, 1.04, 1.56), (2, 1.24, 1.66), 0.02));
    // Bulk: the picture's front at 2.97 (the noisy cloud's median, not the box centre).
    let bulk = [1.3, 2.97, 1.45];
    let (e, moved) = extend_to_support(&b, bulk, &wall, &[], true, &gp());
    assert!((e.max[1] - 3.0).abs() < 1e-9, "{e:?} {moved:?}");
    assert_eq!((e.min, moved.len()), (b.min, 1));
    assert_eq!(
        median_point(&[
            Point3::new(0.0, 5.0, 1.0),
            Point3::new(2.0, 1.0, 0.0),
            Point3::new(1.0, 3.0, 9.0)
        ]),
        Some([1.0, 3.0, 1.0])
    );
    assert_eq!(median_point(&[]), None);
}

#[test]
fn a_window_above_a_cabinet_does_not_move_down_onto_it() {
    // Window 0.97..2.17 m high on the wall y = 6.1; a cabinet top at z = 0.54 in front of
    // the wall below it, wider than the window.
    let b = Aabb::new([0.7, 6.05, 0.97], [1.9, 6.1, 2.17]);
    let top = plane(2, 0.54, (0, 0.5, 2.1), (1, 5.6, 6.1), 0.02);
    let p = gp();
    assert!(
        p.support.hangs("window")
            && p.support.hangs("Framed Pictures")
            && p.support.hangs("white board")
    );
    assert!(!p.support.hangs("chair") && !p.support.hangs("window seat"));
    assert!(
        p.support.is_flat("wooden doors")
            && p.support.is_flat("picture")
            && !p.support.hangs("door")
    );
    assert!(
        !p.support.is_flat("chair")
            && !p.support.is_flat("lamp")
            && !p.support.is_flat("door knob")
    );
    let (moved_box, _) = extend_to_support(&b, b.center(), &top, &[], true, &p);
    assert!(
        (moved_box.min[2] - 0.54).abs() < 0.02,
        "a resting object would move: {moved_box:?}"
    );
    let (e, moved) = extend_to_support(&b, b.center(), &top, &[], !p.support.hangs("window"), &p);
    assert_eq!((e, moved.len()), (b, 0));
}

/// [`context_points`] as it was before it read the grown box only: the box as a
/// whole-frame mask, the whole mask dilated, the whole frame back-projected.
fn context_points_whole_frame(
    mask: &Mask,
    bbox: [f32; 4],
    cam: &FrameCamera,
    depth: &DepthMap,
    p: &SupportParams,
) -> Result<Vec<Point3<f64>>, ProjectionError> {
    let (bw, bh) = (bbox[2] - bbox[0], bbox[3] - bbox[1]);
    let g = p.context_grow as f32;
    let grown = [
        bbox[0] - g * bw,
        bbox[1] - g * bh,
        bbox[2] + g * bw,
        bbox[3] + g * bh,
    ];
    let mut region = Mask::from_box(mask.width, mask.height, grown);
    let scale = f64::from(mask.width) / 1296.0;
    let clearance = (f64::from(p.mask_clearance) * scale).round() as u32;
    let blocked = crate::geometry::dilate_square(mask, 2 * clearance + 1);
    for (r, b) in region.data.iter_mut().zip(&blocked.data) {
        *r &= !*b;
    }
    let opts = BackprojectOptions {
        stride: 1,
        voxel: 0.0,
        one_per_depth_pixel: true,
    };
    let pts = crate::geometry::backproject_mask(&region, cam, depth, opts)?;
    Ok(crate::geometry::cloud::voxel_downsample(&pts, p.voxel))
}

#[test]
fn context_points_of_the_grown_box_equal_the_whole_frames_to_the_bit() {
    // A 259x193 colour / 128x96 depth camera (about ScanNet's 2:1, not exactly) over a
    // room corner with two boxes; masks of random blobs, boxes anywhere (odd corners for
    // the stride grid, beyond the frame, empty), clearances up to a 20-pixel radius.
    let color = Intrinsics {
        fx: 200.0,
        fy: 200.0,
        cx: 129.0,
        cy: 96.0,
        width: 259,
        height: 193,
    };
    let cam = FrameCamera {
        color,
        depth: None,
        depth_size: (128, 96),
        pose: look_at_pose(
            Point3::new(0.3, 0.2, 1.4),
            Point3::new(2.0, 2.5, 0.5),
            Vector3::z(),
        ),
        align: Matrix4::identity(),
    };
    let depth = crate::geometry::test_scene::render(
        &cam,
        &[
            ([-1.0, -1.0, -0.1], [4.0, 4.0, 0.0]),
            ([-1.0, 3.0, 0.0], [4.0, 3.1, 3.0]),
            ([1.2, 1.6, 0.0], [1.8, 2.1, 0.8]),
            ([0.4, 2.2, 0.3], [0.9, 2.6, 1.1]),
        ],
        6.0,
    );
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = |n: u32| {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed % u64::from(n.max(1))) as u32
    };
    let mut compared = 0;
    let mut nonempty = 0;
    for case in 0..60 {
        let mut mask = Mask::new(259, 193);
        for _ in 0..1 + rnd(4) {
            let (cx, cy, r) = (rnd(259), rnd(193), 2 + rnd(40));
            for y in cy.saturating_sub(r)..(cy + r).min(193) {
                for x in cx.saturating_sub(r)..(cx + r).min(259) {
                    if (x as i64 - cx as i64).pow(2) + (y as i64 - cy as i64).pow(2)
                        < i64::from(r * r) - i64::from(rnd(3 * r))
                    {
                        mask.set(x, y, true);
                    }
                }
            }
        }
        if case % 10 == 9 {
            mask = Mask::new(259, 193);
        }
        let x0 = rnd(300) as f32 - 30.5;
        let y0 = rnd(230) as f32 - 20.25;
        let bbox = match case % 7 {
            0 => [x0, y0, x0, y0],             // empty before growing
            1 => [300.0, 10.0, 400.0, 50.0],   // beyond the frame
            2 => [-80.0, -60.0, 400.0, 300.0], // all of it
            _ => [
                x0,
                y0,
                x0 + 1.0 + rnd(150) as f32,
                y0 + 1.0 + rnd(120) as f32,
            ],
        };
        let mut p = SupportParams {
            mask_clearance: [0, 9, 30, 100, 330][case % 5],
            ..SupportParams::default()
        };
        if case % 4 == 3 {
            p.context_grow = 0.0;
        }
        let want = context_points_whole_frame(&mask, bbox, &cam, &depth, &p);
        let got = context_points(&mask, bbox, &cam, &depth, &p);
        let bits = |v: &[Point3<f64>]| -> Vec<[u64; 3]> {
            v.iter()
                .map(|q| [q.x.to_bits(), q.y.to_bits(), q.z.to_bits()])
                .collect()
        };
        match (want, got) {
            (Ok(w), Ok(g)) => {
                assert_eq!(bits(&g), bits(&w), "case {case}: {bbox:?}");
                nonempty += usize::from(!w.is_empty());
            }
            (w, g) => panic!("case {case}: {w:?} against {g:?}"),
        }
        compared += 1;
    }
    assert_eq!(compared, 60);
    assert!(nonempty > 30, "only {nonempty} cases had context points");
    // Errors as before: a mask of the wrong size.
    let small = Mask::new(80, 60);
    let p = SupportParams::default();
    let box_ = [10.0, 10.0, 40.0, 40.0];
    assert_eq!(
        context_points(&small, box_, &cam, &depth, &p).map_err(|e| e.to_string()),
        context_points_whole_frame(&small, box_, &cam, &depth, &p).map_err(|e| e.to_string())
    );
}

#[test]
fn chair_seats_pushed_under_a_table_hold_it_up_unless_it_stands_on_the_floor() {
    // A 1 x 1 m table top measured at 0.72..0.75 m (its thin legs eroded away); the seats
    // of three chairs pushed in under its front and side edges at 0.45 m reach out into
    // the ring around its footprint; the floor is seen between them.
    let b = Aabb::new([1.5, 1.5, 0.72], [2.5, 2.5, 0.75]);
    let seats = [
        ([1.55, 1.15], [2.0, 1.6]),
        ([2.4, 1.6], [2.85, 2.05]),
        ([1.15, 1.9], [1.6, 2.35]),
    ];
    let under_a_seat = |q: &Point3<f64>| {
        seats
            .iter()
            .any(|(lo, hi)| q.x >= lo[0] && q.x <= hi[0] && q.y >= lo[1] && q.y <= hi[1])
    };
    let mut ctx: Vec<Point3<f64>> = plane(2, 0.0, (0, 1.0, 3.0), (1, 1.0, 3.0), 0.02)
        .into_iter()
        .filter(|q| !under_a_seat(q))
        .collect();
    for (lo, hi) in seats {
        ctx.extend(plane(2, 0.45, (0, lo[0], hi[0]), (1, lo[1], hi[1]), 0.02));
    }
    // Support completion sets the table on the seats, the nearest layer below.
    let (e, moved) = extend_to_support(&b, b.center(), &ctx, &[], true, &gp());
    assert!((e.min[2] - 0.45).abs() < 0.02 && moved.len() == 1, "{e:?}");
    // A class that stands on the floor goes there first; the floor's layer is then found.
    let (stood, rec) = crate::geometry::floor_reach::stand_on_floor(&b, 0.0, 2.0);
    let rec = rec.expect("moved");
    assert_eq!((rec.from, rec.to), (0.72, 0.0));
    let (e, _) = extend_to_support(&stood, b.center(), &ctx, &[], true, &gp());
    assert!(e.min[2].abs() < 0.02, "{e:?}");
    assert_eq!((e.max[2], e.min[0], e.max[1]), (0.75, 1.5, 2.5));
    // On or below the floor, or farther above it than the limit: left alone.
    for z in [0.0, -0.05, 2.5] {
        let c = Aabb::new([1.5, 1.5, z], [2.5, 2.5, z + 0.2]);
        assert_eq!(
            crate::geometry::floor_reach::stand_on_floor(&c, 0.0, 2.0),
            (c, None)
        );
    }
    let p = gp().support;
    assert!(p.stands("dining table") && p.stands("chairs") && p.stands("Sofa"));
    assert!(!p.stands("table lamp") && !p.stands("cup") && !p.stands("picture"));
}

#[test]
fn surfaces_running_along_the_axis_are_no_layer_for_a_pillows_sides() {
    // A pillow's measured front half (0.39 m wide) on a sofa's seat (z = 0.41) against
    // its back (y = 5.25), each measured 4 cm thick (depth noise); seat and back run the
    // sofa's whole width along x.
    let b = Aabb::new([1.66, 5.07, 0.46], [2.05, 5.21, 0.74]);
    let mut ctx = Vec::new();
    for d in [-0.02, 0.0, 0.02] {
        ctx.extend(plane(2, 0.41 + d, (0, 0.9, 2.6), (1, 4.6, 5.25), 0.02));
        ctx.extend(plane(1, 5.25 + d, (0, 0.9, 2.6), (2, 0.41, 0.9), 0.02));
    }
    let (e, moved) = extend_to_support(&b, b.center(), &ctx, &[], true, &gp());
    // Down onto the seat and back onto the sofa's back: real layers.
    assert!(
        (e.min[2] - 0.41).abs() < 0.03 && (e.max[1] - 5.25).abs() < 0.03,
        "{e:?}"
    );
    // The sides stay: every slab across x holds the same share of seat and back.
    assert_eq!((e.min[0], e.max[0]), (1.66, 2.05), "{moved:?}");
    // Without the peak test, a slab inside the box passes and pulls a side in.
    let mut off = gp();
    off.support.layer_peak = 0.0;
    let (e, _) = extend_to_support(&b, b.center(), &ctx, &[], true, &off);
    assert!(e.min[0] > 1.67 || e.max[0] < 2.04, "{e:?}");
}

#[test]
fn an_objects_own_rim_is_no_support_and_the_table_beyond_it_is() {
    // A vase seen from above: its points end at its belly (z = 0.90), the widest part,
    // and the belly's rim just outside the mask lies 0.5-1.8 cm around the footprint at
    // that height. The table top it stands on (z = 0.75) shows around it.
    let b = Aabb::new([0.405, 2.265, 0.90], [0.565, 2.425, 1.06]);
    let mut rim = Vec::new();
    for d in [0.005, 0.012, 0.018] {
        for k in 0..=20 {
            let t = f64::from(k) / 20.0;
            let (x, y) = (0.405 + 0.16 * t, 2.265 + 0.16 * t);
            rim.extend([
                Point3::new(x, 2.265 - d, 0.893),
                Point3::new(x, 2.425 + d, 0.893),
                Point3::new(0.405 - d, y, 0.893),
                Point3::new(0.565 + d, y, 0.893),
            ]);
        }
    }
    let table = plane(2, 0.75, (0, 0.30, 0.66), (1, 2.16, 2.52), 0.02);
    let ctx: Vec<_> = rim.iter().chain(&table).copied().collect();
    let (e, moved) = extend_to_support(&b, b.center(), &ctx, &[], true, &gp());
    assert!((e.min[2] - 0.75).abs() < 1e-9, "{e:?} {moved:?}");
    // Counted as support, the rim stops the bottom at the belly.
    let mut p = gp();
    p.support.rim = 0.0;
    let (e, _) = extend_to_support(&b, b.center(), &ctx, &[], true, &p);
    assert!((e.min[2] - 0.893).abs() < 1e-6, "{e:?}");
}

#[test]
fn a_surface_both_side_faces_fall_back_onto_is_the_objects_own() {
    // A monitor seen from behind: its back panel shows all around its mask, measured from
    // 2.499 to 2.545 (noise reaching back); its cloud runs 2.454-2.545 (stand and noise)
    // with the median on the panel. Each side face finds the panel within its reach inside
    // the box, at 2.517 and 2.522 (each sees a different part of the noise).
    let b = Aabb::new([2.454, 3.93, 0.93], [2.545, 4.47, 1.24]);
    let mut panel = plane(0, 2.511, (1, 3.76, 4.64), (2, 0.76, 1.42), 0.01);
    for (i, q) in panel.iter_mut().enumerate() {
        q.x += 0.046 * (((i * 7919) % 61) as f64 / 60.0) - 0.012;
    }
    let bulk = [2.519, 4.2, 1.08];
    let (e, moved) = extend_to_support(&b, bulk, &panel, &[], false, &gp());
    assert_eq!((e.min[0], e.max[0]), (2.454, 2.545), "{moved:?}");
    assert!(moved.iter().all(|m| m.axis != "x"), "{moved:?}");
    // Only the back face falls back when the median lies before the panel (the wall
    // behind a picture, noise beyond it).
    let bulk = [2.49, 4.2, 1.08];
    let (e, _) = extend_to_support(&b, bulk, &panel, &[], false, &gp());
    assert!(
        e.min[0] == 2.454 && (e.max[0] - 2.522).abs() < 0.002,
        "{e:?}"
    );
}
