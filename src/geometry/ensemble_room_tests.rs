//! [`find_views_with_room`] for an anchor the chosen view measured: a frame that saw the
//! object only beyond its sensor's range joins through the room's box.

use super::*;
use crate::geometry::test_scene::{camera, render, room_slabs};
use crate::geometry::RoomLayout;

type Slab = ([f64; 3], [f64; 3]);

/// A room [0, 10] x [0, 4] x [0, 2.7] as 10 cm slabs, with a window 1 cm proud of the wall
/// x = 10 (y 1.4–2.6, z 0.9–1.9).
fn scene() -> Vec<Slab> {
    let mut slabs = room_slabs(10.0, 4.0, 2.7);
    slabs.push(([9.99, 1.4, 0.9], [10.0, 2.6, 1.9]));
    slabs
}

fn layout() -> RoomLayout {
    crate::geometry::test_scene::room_box(0.0, 10.0, 4.0, 2.7)
}

#[test]
fn a_frame_that_saw_a_measured_window_beyond_its_range_joins_through_the_room() {
    let params = GeometryParams::default();
    let range = 5.0;
    // The chosen view, 1.2 m from the window, measures the middle of it (its frame cuts
    // the rest).
    let near = camera([8.8, 2.0, 1.4], [10.0, 2.0, 1.4]);
    let near_depth = render(&near, &scene(), range);
    let mut mask = Mask::new(near.color.width, near.color.height);
    for y in 10..50 {
        for x in 10..70 {
            mask.set(x, y, true);
        }
    }
    let anchor = mask_points(&mask, &near, &near_depth, &params).expect("points");
    assert!(
        anchor.len() > 50 && anchor.iter().all(|p| p.x > 9.9),
        "the window was measured: {} points",
        anchor.len()
    );
    // A frame across the room sees the window 8 m away, beyond its range: no reading.
    let far = camera([2.0, 2.0, 1.4], [10.0, 2.0, 1.4]);
    let far_depth = render(&far, &scene(), range);
    let beside = camera([6.5, 0.8, 1.4], [10.0, 2.0, 1.4]);
    let beside_depth = render(&beside, &scene(), range);
    let frames = [
        CandidateFrame {
            index: 1,
            camera: &far,
            depth: &far_depth,
        },
        CandidateFrame {
            index: 2,
            camera: &beside,
            depth: &beside_depth,
        },
    ];
    // Without the room only the frame within range sees it.
    let alone: Vec<usize> = find_views(&anchor, &frames, &params)
        .iter()
        .map(|v| v.index)
        .collect();
    assert_eq!(alone, vec![2]);
    // With the room, the far frame joins: its ray leaves the room where the window is,
    // beyond its range.
    let room = layout();
    let views = find_views_with_room(&anchor, &frames, Some(&room), &params);
    let found: Vec<usize> = views.iter().map(|v| v.index).collect();
    assert!(found.contains(&1) && found.contains(&2), "{found:?}");
    let v = views.iter().find(|v| v.index == 1).expect("the far frame");
    assert!(v.visible_fraction > 0.9, "{v:?}");
    // A room whose range reaches the window: a missing reading there is no sign of
    // distance, so the far frame does not join.
    let long = RoomLayout {
        range: 9.0,
        ..layout()
    };
    let found: Vec<usize> = find_views_with_room(&anchor, &frames, Some(&long), &params)
        .iter()
        .map(|v| v.index)
        .collect();
    assert_eq!(found, vec![2]);
}
