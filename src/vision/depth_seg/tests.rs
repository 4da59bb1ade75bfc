use super::*;
use crate::geometry::camera::look_at_pose;
use crate::geometry::test_scene::render_coloured;
use crate::geometry::{DepthMap, FrameCamera, Intrinsics};
use image::{Rgb, RgbImage};
use nalgebra::{Matrix4, Point3, Vector3};

pub(super) const S: u32 = 80;

/// An S x S camera with focal length `f` (pixels), centred principal point, depth aligned.
fn camera(f: f64, pose: Matrix4<f64>) -> FrameCamera {
    let k = Intrinsics {
        fx: f,
        fy: f,
        cx: 39.5,
        cy: 39.5,
        width: S,
        height: S,
    };
    FrameCamera {
        color: k,
        depth: None,
        depth_size: (S, S),
        pose,
        align: Matrix4::identity(),
    }
}

/// The S x S camera at 1 m height, looking level along +x, focal length 80 pixels.
pub(super) fn level_camera() -> FrameCamera {
    camera(
        80.0,
        look_at_pose(
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(3.0, 0.0, 1.0),
            Vector3::z(),
        ),
    )
}

/// A camera looking level along +x at a wall 3.1 m away (grey). Box [30, 30, 50, 50]:
/// a dark bin fills its right 60 % at 3.03 m (a depth step to the wall within the growth
/// limit) and leans into the wall at its top; a white bed at 2.0 m covers the box's left
/// 40 % and a little beyond.
fn scene() -> (RgbImage, DepthMap, FrameCamera, Mask) {
    let mut color = RgbImage::from_pixel(S, S, Rgb([150, 150, 150]));
    let mut depth = vec![3100u16; (S * S) as usize];
    let mut bin = Mask::new(S, S);
    for y in 30..50 {
        for x in 38..50 {
            bin.set(x, y, true);
            color.put_pixel(x, y, Rgb([30, 30, 30]));
            // top rows ramp into the wall behind
            depth[(y * S + x) as usize] = if y < 33 {
                3100 - (y as u16 - 29) * 20
            } else {
                3030
            };
        }
        for x in 26..38 {
            color.put_pixel(x, y, Rgb([235, 230, 225]));
            depth[(y * S + x) as usize] = 2000;
        }
    }
    let cam = level_camera();
    (color, DepthMap::new(S, S, depth), cam, bin)
}

#[test]
fn the_surface_that_fills_the_box_wins_over_a_nearer_occluder() {
    let (color, depth, cam, bin) = scene();
    let seg = DepthSegmenter::default();
    let m = seg
        .segment(
            &SegmentInput {
                color: &color,
                depth: &depth,
                camera: &cam,
            },
            [38.0, 30.0, 50.0, 50.0],
        )
        .unwrap();
    assert!(m.iou(&bin) > 0.9, "tight box: IoU {}", m.iou(&bin));
    // The box of the visible bin plus the bed's part: the bed is nearer and stays inside.
    let m = seg
        .segment(
            &SegmentInput {
                color: &color,
                depth: &depth,
                camera: &cam,
            },
            [30.0, 30.0, 50.0, 50.0],
        )
        .unwrap();
    assert!(m.iou(&bin) > 0.8, "bed in front: IoU {}", m.iou(&bin));
    // On depth alone the bin runs onto the wall and past the box, and the bed wins.
    let depth_only = DepthSegmenter {
        colour_tol: f64::INFINITY,
        colour_alternative: false,
        ..DepthSegmenter::default()
    };
    let m = depth_only
        .segment(
            &SegmentInput {
                color: &color,
                depth: &depth,
                camera: &cam,
            },
            [30.0, 30.0, 50.0, 50.0],
        )
        .unwrap();
    assert!(m.iou(&bin) < 0.2, "depth only: IoU {}", m.iou(&bin));
}

#[test]
fn flying_pixels_do_not_bridge_an_object_to_the_wall_behind() {
    // Seen from above: a grey block's top 2.0 m away, the grey floor 2.1 m (a step
    // larger than one growth step, so only the sensor's mixed pixels around its outline
    // join the two). A narrow lens (fx 800: 2.5 mm per pixel at 2 m) so the step is not
    // mistaken for a slanted surface.
    let color = RgbImage::from_pixel(S, S, Rgb([140, 140, 140]));
    let mut depth = vec![2100u16; (S * S) as usize];
    let mut block = Mask::new(S, S);
    for y in 29..=50u32 {
        for x in 29..=50u32 {
            let ring = x == 29 || x == 50 || y == 29 || y == 50;
            depth[(y * S + x) as usize] = if ring { 2050 } else { 2000 };
            if !ring {
                block.set(x, y, true);
            }
        }
    }
    let depth = DepthMap::new(S, S, depth);
    let cam = camera(
        800.0,
        look_at_pose(
            Point3::new(0.0, 0.0, 3.0),
            Point3::new(0.0, 0.0, 0.0),
            Vector3::x(),
        ),
    );
    let input = SegmentInput {
        color: &color,
        depth: &depth,
        camera: &cam,
    };
    // A loose box: the wall shows in its border.
    let bbox = [26.0, 26.0, 54.0, 54.0];
    let m = DepthSegmenter {
        block_edges: true,
        ..DepthSegmenter::default()
    }
    .segment(&input, bbox)
    .unwrap();
    assert!(m.iou(&block) > 0.9, "IoU {}", m.iou(&block));
    let bridged = DepthSegmenter {
        block_edges: false,
        ..DepthSegmenter::default()
    }
    .segment(&input, bbox)
    .unwrap();
    assert!(
        bridged.iou(&block) < m.iou(&block),
        "without edge blocking: IoU {}",
        bridged.iou(&block)
    );
}

#[test]
fn a_slanted_surface_is_not_taken_for_an_edge() {
    // A plate tilted about 63 degrees away from the camera in a coarse image (fx 80, so
    // 2.5 cm per pixel at 2 m): each row 5 cm deeper than the one above, within one
    // growth step, but two rows differ by more than one. Wall at 3.5 m.
    let color = RgbImage::from_pixel(S, S, Rgb([140, 140, 140]));
    let mut depth = vec![3500u16; (S * S) as usize];
    let mut plate = Mask::new(S, S);
    for y in 30..50u32 {
        for x in 30..50u32 {
            depth[(y * S + x) as usize] = 1500 + (y as u16 - 30) * 50;
            plate.set(x, y, true);
        }
    }
    let depth = DepthMap::new(S, S, depth);
    let cam = level_camera();
    let input = SegmentInput {
        color: &color,
        depth: &depth,
        camera: &cam,
    };
    let seg = DepthSegmenter::from_spec("edges=on").unwrap();
    assert!(seg.block_edges);
    let m = seg.segment(&input, [29.0, 29.0, 51.0, 51.0]).unwrap();
    // The plate's one-cell outline against the wall is given up (18x18 of 20x20 cells);
    // taken for an edge, every row of the ramp would be cut out instead.
    assert!(m.iou(&plate) > 0.75, "IoU {}", m.iou(&plate));
    assert!(DepthSegmenter::from_spec("edges=maybe").is_err());
    assert!(!DepthSegmenter::from_spec("").unwrap().block_edges);
}

#[test]
fn touching_objects_at_one_depth_are_told_apart_by_colour() {
    // Two pillows at 2.0 m in front of a wall at 3.1 m: the green one spans
    // [20, 40) x [30, 50); the pink one, beside it at the same depth, covers the green one's
    // top-right corner [30, 40) x [30, 40) in the image and runs on to x = 50. The green
    // one's tight box is [20, 40) x [30, 50), a quarter of it pink.
    let mut color = RgbImage::from_pixel(S, S, Rgb([150, 150, 150]));
    let mut depth = vec![3100u16; (S * S) as usize];
    let mut green = Mask::new(S, S);
    for y in 30..50 {
        for x in 20..50 {
            let pink = x >= 30 && y < 40;
            if !pink && x >= 40 {
                continue;
            }
            depth[(y * S + x) as usize] = 2000;
            if pink {
                color.put_pixel(x, y, Rgb([230, 120, 150]));
            } else {
                green.set(x, y, true);
                color.put_pixel(x, y, Rgb([40, 150, 50]));
            }
        }
    }
    let cam = level_camera();
    let depth = DepthMap::new(S, S, depth);
    let input = SegmentInput {
        color: &color,
        depth: &depth,
        camera: &cam,
    };
    let bbox = [20.0, 30.0, 40.0, 50.0];
    let m = DepthSegmenter::default().segment(&input, bbox).unwrap();
    assert!(m.iou(&green) > 0.9, "with colour: IoU {}", m.iou(&green));
    // On depth alone both pillows are one surface (running past the box by less than
    // `max_outside`, so no regrowth is forced) and the pink corner stays in.
    let m = DepthSegmenter::from_spec("colour=off")
        .unwrap()
        .segment(&input, bbox)
        .unwrap();
    assert!(m.iou(&green) < 0.8, "depth alone: IoU {}", m.iou(&green));
    assert!(DepthSegmenter::from_spec("colour=maybe").is_err());
}

#[test]
fn hue_survives_shading_but_not_another_colour() {
    let white = [200.0, 198.0, 192.0];
    // The same white face turned from the light, and a pink pillow.
    assert!(same_hue(&white, &[90, 89, 86], 60.0));
    assert!(!same_hue(&white, &[230, 120, 150], 60.0));
    // Green against pink; white against black (a factor over 4 in brightness).
    assert!(!same_hue(&[40.0, 150.0, 50.0], &[230, 120, 150], 60.0));
    assert!(!same_hue(&white, &[20, 20, 20], 60.0));
    // Near-black colours match each other only.
    assert!(same_hue(&[8.0, 8.0, 9.0], &[12, 10, 9], 60.0));
    assert!(!same_hue(&[8.0, 8.0, 9.0], &[120, 10, 9], 60.0));
}

/// The tight box of a mask.
pub(super) fn mask_box(m: &Mask) -> [f32; 4] {
    let (w, h) = (m.width, m.height);
    let px: Vec<(u32, u32)> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .filter(|&(x, y)| m.get(x, y))
        .collect();
    let (x0, y0) = px.iter().fold((w, h), |a, p| (a.0.min(p.0), a.1.min(p.1)));
    let (x1, y1) = px.iter().fold((0, 0), |a, p| (a.0.max(p.0), a.1.max(p.1)));
    [x0 as f32, y0 as f32, x1 as f32 + 1.0, y1 as f32 + 1.0]
}

#[test]
fn a_cups_own_lower_side_is_not_cut_as_its_support() {
    // A 10 cm blue cup on a shelf whose top (1.20 m) is above the camera (1.15 m), seen
    // level from 0.95 m: no shelf top is in sight, and the cup's lowest 3 cm fill 30 % of
    // its box's rows. The board's front edge, 7 cm nearer than the cup, hides its lowest
    // few millimetres: a step the growth does not take. A grey wall 3 m away.
    let cup = ([0.95, -0.05, 1.2], [1.05, 0.05, 1.3], [40, 70, 190]);
    let board = ([0.88, -0.6, 1.17], [1.3, 0.6, 1.2], [200, 180, 150]);
    let wall = ([3.0, -5.0, 0.0], [3.1, 5.0, 3.0], [150, 150, 150]);
    let cam = camera(
        160.0,
        look_at_pose(
            Point3::new(0.0, 0.0, 1.15),
            Point3::new(1.0, 0.0, 1.15),
            Vector3::z(),
        ),
    );
    let (color, depth, truth) = render_coloured(&cam, &[cup, board, wall], 0);
    let input = SegmentInput {
        color: &color,
        depth: &depth,
        camera: &cam,
    };
    let bbox = mask_box(&truth);
    let m = DepthSegmenter::default().segment(&input, bbox).unwrap();
    assert!(m.iou(&truth) > 0.9, "IoU {} (box {bbox:?})", m.iou(&truth));
}

#[test]
fn a_table_top_the_growth_ran_onto_is_cut() {
    // Seen from above (camera 1.6 m high): a 20 cm block standing on a table top of the
    // same colour, so depth runs on from the block's foot onto the table and colour
    // cannot tell them apart. The band just above the table is cut and the block regrown.
    let block = ([1.1, -0.1, 0.75], [1.3, 0.1, 0.95], [120, 100, 80]);
    let table = ([0.5, -1.0, 0.72], [2.2, 1.0, 0.75], [120, 100, 80]);
    let floor = ([-5.0, -5.0, -0.1], [5.0, 5.0, 0.0], [90, 90, 90]);
    let cam = camera(
        160.0,
        look_at_pose(
            Point3::new(0.0, 0.0, 1.6),
            Point3::new(1.2, 0.0, 0.8),
            Vector3::z(),
        ),
    );
    let (color, depth, truth) = render_coloured(&cam, &[block, table, floor], 0);
    let input = SegmentInput {
        color: &color,
        depth: &depth,
        camera: &cam,
    };
    // A detector's loose box: table top in its border.
    let t = mask_box(&truth);
    let bbox = [t[0] - 4.0, t[1] - 4.0, t[2] + 4.0, t[3] + 4.0];
    let m = DepthSegmenter::default().segment(&input, bbox).unwrap();
    let uncut = DepthSegmenter {
        support_band: 0.0,
        ..DepthSegmenter::default()
    }
    .segment(&input, bbox)
    .unwrap();
    eprintln!(
        "cut {} uncut {} box {bbox:?}",
        m.iou(&truth),
        uncut.iou(&truth)
    );
    assert!(m.iou(&truth) > 0.8, "IoU {} (box {bbox:?})", m.iou(&truth));
    assert!(
        uncut.iou(&truth) < m.iou(&truth),
        "without the cut: IoU {}",
        uncut.iou(&truth)
    );
}

/// A grey wall at 3.1 m; a brown window frame [20, 60) x [20, 60) at 3.03 m, 4 pixels
/// wide, with a mullion at x in [36, 40); glass panes 1 cm before the wall either side of
/// it, the left one pale blue, the right one `right`. Returns the frame and each pane's mask.
fn window(right: [u8; 3]) -> (RgbImage, DepthMap, FrameCamera, [Mask; 2]) {
    let mut color = RgbImage::from_pixel(S, S, Rgb([150, 150, 150]));
    let mut depth = vec![3100u16; (S * S) as usize];
    let mut panes = [Mask::new(S, S), Mask::new(S, S)];
    for y in 20..60u32 {
        for x in 20..60u32 {
            let frame = !(24..56).contains(&y) || !(24..56).contains(&x) || (36..40).contains(&x);
            let i = (y * S + x) as usize;
            if frame {
                depth[i] = 3030;
                color.put_pixel(x, y, Rgb([120, 80, 40]));
            } else {
                depth[i] = 3090;
                let k = usize::from(x >= 38);
                color.put_pixel(x, y, Rgb(if k == 0 { [175, 195, 215] } else { right }));
                panes[k].set(x, y, true);
            }
        }
    }
    let cam = level_camera();
    (color, DepthMap::new(S, S, depth), cam, panes)
}

fn share_in(pane: &Mask, m: &Mask) -> f64 {
    let held = (0..S)
        .flat_map(|y| (0..S).map(move |x| (x, y)))
        .filter(|&(x, y)| pane.get(x, y) && m.get(x, y))
        .count();
    held as f64 / pane.count() as f64
}

#[test]
fn a_window_split_by_its_mullion_keeps_both_panes() {
    // The wall and the glass are one surface to depth, so colour keeps the glass, which the
    // mullion cuts in two.
    let segment = |right| {
        let (color, depth, cam, panes) = window(right);
        let input = SegmentInput {
            color: &color,
            depth: &depth,
            camera: &cam,
        };
        let m = DepthSegmenter::default()
            .segment(&input, [20.0, 20.0, 60.0, 60.0])
            .unwrap();
        (share_in(&panes[0], &m), share_in(&panes[1], &m))
    };
    let (left, right) = segment([175, 195, 215]);
    assert!(left > 0.8 && right > 0.8, "panes: {left:.2} {right:.2}");
    // Of another colour, the smaller piece is another surface: only the larger stays.
    let (left, right) = segment([60, 140, 70]);
    assert!(left < 0.05 && right > 0.8, "panes: {left:.2} {right:.2}");
}

#[test]
fn what_the_larger_step_reaches_past_the_box_is_not_a_part() {
    // A brown cabinet 20 cm in front of a grey wall, seen level: across the step between
    // an object's parts the growth runs from the cabinet onto the wall, past the box.
    let floor = ([-1.0, -3.0, -0.1], [6.0, 3.0, 0.0], [150, 110, 70]);
    let cabinet = ([2.8, -0.3, 0.0], [3.2, 0.3, 0.8], [120, 80, 40]);
    let wall = ([3.4, -3.0, 0.0], [3.5, 3.0, 3.0], [150, 150, 150]);
    let cam = level_camera();
    let (color, depth, truth) = render_coloured(&cam, &[floor, cabinet, wall], 1);
    let input = SegmentInput {
        color: &color,
        depth: &depth,
        camera: &cam,
    };
    let bbox = mask_box(&truth);
    let seg = DepthSegmenter::default();
    let g = seg.grid(&input, bbox).expect("a grid");
    let (grouped, past) = seg.surface_with(&g, 2.85, 1.0, Colour::Off, Reach::Group);
    assert!(past > 0.3, "the growth reaches the wall: {past}");
    let (region, _) = seg.surface(&g, 2.85, 1.0);
    assert!(grouped.iter().zip(&region).any(|(&a, &b)| a && !b));
    assert!(DepthSegmenter::with_parts(&g, &region, &grouped, (S, S)).is_none());
    let m = seg.segment(&input, bbox).unwrap();
    assert!(m.iou(&truth) > 0.8, "IoU {}", m.iou(&truth));
}

#[test]
fn a_surface_that_explains_its_box_is_not_joined_to_what_stands_beside_it() {
    // Box [20, 20, 60, 60] at 2 m: the object fills its left 80 %; in the right 20 %, a
    // neighbour 20 cm behind it (a table's end beside a chair), within the box, with a
    // wall at 4 m around both.
    let mut color = RgbImage::from_pixel(S, S, Rgb([150, 150, 150]));
    let mut depth = vec![4000u16; (S * S) as usize];
    let mut object = Mask::new(S, S);
    for y in 20..60 {
        for x in 20..60 {
            let (d, c) = if x < 52 {
                (2000, [120, 60, 30])
            } else {
                (2200, [40, 40, 40])
            };
            depth[(y * S + x) as usize] = d;
            color.put_pixel(x, y, Rgb(c));
            object.set(x, y, x < 52);
        }
    }
    let (depth, cam) = (DepthMap::new(S, S, depth), level_camera());
    let input = SegmentInput {
        color: &color,
        depth: &depth,
        camera: &cam,
    };
    let bbox = [20.0, 20.0, 60.0, 60.0];
    let seg = DepthSegmenter::default();
    let m = seg.segment(&input, bbox).unwrap();
    assert!(m.iou(&object) > 0.9, "IoU {}", m.iou(&object));
    // Were parts joined whatever the best surface explains, the neighbour would join.
    let always = DepthSegmenter {
        group_below: f64::INFINITY,
        ..DepthSegmenter::default()
    };
    let joined = always.segment(&input, bbox).unwrap();
    assert!(joined.get(56, 40) && joined.iou(&object) < 0.9);
}
