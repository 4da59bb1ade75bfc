//! Tests of [`super`], on rendered scenes.

use super::*;
use crate::geometry::test_scene::{
    camera, first_surface_mask, room_slabs, seen_box, segmented_view,
};
use crate::geometry::Mask;

type Block = ([f64; 3], [f64; 3]);

/// A cabinet 1.9 m tall against the back of a 4 x 4 x 3 m room.
const CABINET: Block = ([1.4, 2.5, 0.0], [2.6, 2.9, 1.9]);
/// A box standing on the cabinet, 20 cm behind its front edge.
const ON_TOP: Block = ([1.85, 2.7, 1.9], [2.15, 2.85, 2.25]);
const RANGE: f64 = 6.0;

fn gp() -> GeometryParams {
    GeometryParams::default()
}

fn world(with_cabinet: bool) -> Vec<Block> {
    let mut w = room_slabs(4.0, 4.0, 3.0);
    if with_cabinet {
        w.push(CABINET);
    }
    w.push(ON_TOP);
    w
}

#[test]
fn a_box_seen_from_below_over_a_tall_cabinets_edge_is_set_down_on_the_cabinet() {
    let world = world(true);
    let cam = camera([2.0, 1.3, 1.2], [2.0, 2.7, 2.0]);
    let (depth, mask) = first_surface_mask(&cam, &world, ON_TOP, RANGE);
    let b = seen_box(&cam, &depth, &mask);
    // The edge hides the box's lower part: what was measured starts well above the top.
    assert!(b.min[2] > CABINET.1[2] + 0.06, "{b:?}");
    let view = segmented_view(7, &cam, &depth, &mask);
    let (out, record) = extend_to_hidden_base(&b, &[&view], &gp());
    let record = record.expect("the view was read");
    assert_eq!(record.views.len(), 1);
    let v = &record.views[0];
    assert_eq!((v.index, v.reads), (7, BaseReading::EdgeAboveEye), "{v:?}");
    assert!(
        v.occluded * 2 > v.columns && v.columns >= MIN_COLUMNS,
        "{v:?}"
    );
    // The edge's points lie on the cabinet's front face, just under its top.
    let edge = v.edge_z.expect("edge height");
    assert!((edge - CABINET.1[2]).abs() < 0.05, "{edge}");
    assert!((out.min[2] - CABINET.1[2]).abs() < 0.05, "{out:?}");
    assert_eq!(record.to, out.min[2]);
    assert_eq!(record.from, b.min[2]);
    // Only the bottom moves.
    assert_eq!(
        (out.max, out.min[0], out.min[1]),
        (b.max, b.min[0], b.min[1])
    );
}

#[test]
fn an_edge_below_the_eye_is_not_read_as_a_hidden_base() {
    // A chair-sized block on the floor behind a table, seen from above the table's top:
    // the table's edge hides the block's lower part, but the edge is below the eye, so
    // what it hides may run on down (to the floor here).
    const TABLE: Block = ([1.4, 2.3, 0.0], [2.6, 2.6, 0.75]);
    const CHAIR: Block = ([1.85, 2.8, 0.0], [2.15, 2.95, 1.0]);
    let mut world = room_slabs(4.0, 4.0, 3.0);
    world.extend([TABLE, CHAIR]);
    let cam = camera([2.0, 1.0, 1.2], [2.0, 2.8, 0.6]);
    let (depth, mask) = first_surface_mask(&cam, &world, CHAIR, RANGE);
    let b = seen_box(&cam, &depth, &mask);
    assert!(
        b.min[2] > 0.3,
        "the table hides the block's lower part: {b:?}"
    );
    let view = segmented_view(1, &cam, &depth, &mask);
    let (out, record) = extend_to_hidden_base(&b, &[&view], &gp());
    let record = record.expect("the view was read");
    let v = &record.views[0];
    assert_eq!(v.reads, BaseReading::EdgeBelowEye, "{record:?}");
    assert!((v.edge_z.expect("edge") - TABLE.1[2]).abs() < 0.05, "{v:?}");
    assert_eq!(out, b);
    assert_eq!(record.to, record.from);
}

#[test]
fn an_object_seen_standing_on_its_support_reads_open() {
    // From above the cabinet, the box's bottom meets the cabinet's top in view.
    let world = world(true);
    let high = camera([2.0, 1.3, 2.6], [2.0, 2.7, 2.0]);
    let (depth, mask) = first_surface_mask(&high, &world, ON_TOP, RANGE);
    let mut b = seen_box(&high, &depth, &mask);
    b.min[2] += 0.1;
    let view = segmented_view(1, &high, &depth, &mask);
    let (out, record) = extend_to_hidden_base(&b, &[&view], &gp());
    let record = record.expect("the view was read");
    assert_eq!(record.views[0].reads, BaseReading::Open, "{record:?}");
    assert_eq!(out, b);
}

#[test]
fn a_view_that_sees_the_bottom_in_the_open_vetoes_the_move() {
    // The box floating with nothing under it: below its mask lies the far wall.
    let open_world = world(false);
    let cam = camera([2.0, 1.3, 1.2], [2.0, 2.7, 2.0]);
    let (d_open, m_open) = first_surface_mask(&cam, &open_world, ON_TOP, RANGE);
    let open = segmented_view(2, &cam, &d_open, &m_open);
    // The box as the cabinet's edge cuts it, and the view that shows that edge.
    let shelf_world = world(true);
    let (d_shelf, m_shelf) = first_surface_mask(&cam, &shelf_world, ON_TOP, RANGE);
    let b = seen_box(&cam, &d_shelf, &m_shelf);
    let shelf = segmented_view(3, &cam, &d_shelf, &m_shelf);
    let (alone, _) = extend_to_hidden_base(&b, &[&shelf], &gp());
    assert!(alone.min[2] < b.min[2] - 0.05, "{alone:?}");
    let (out, record) = extend_to_hidden_base(&b, &[&shelf, &open], &gp());
    let record = record.expect("the views were read");
    assert_eq!(record.views[1].reads, BaseReading::Open, "{record:?}");
    assert_eq!(out, b);
}

#[test]
fn a_view_looking_sideways_or_a_mask_on_the_lower_border_says_nothing() {
    let world = world(true);
    let cam = camera([2.0, 1.3, 1.2], [2.0, 2.7, 2.0]);
    let (depth, mask) = first_surface_mask(&cam, &world, ON_TOP, RANGE);
    let b = seen_box(&cam, &depth, &mask);
    // A mask on the image's two lower rows, under every column the object covers.
    let mut low = Mask::new(mask.width, mask.height);
    for x in 0..mask.width {
        if (0..mask.height).any(|y| mask.get(x, y)) {
            low.set(x, mask.height - 1, true);
            low.set(x, mask.height - 2, true);
        }
    }
    let bordered = segmented_view(4, &cam, &depth, &low);
    // A camera rolled by 90 degrees: "down" runs across its image.
    let mut rolled = cam;
    let roll = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 90f64.to_radians());
    rolled.pose *= roll.to_homogeneous();
    let sideways = segmented_view(5, &rolled, &depth, &mask);
    let (out, record) = extend_to_hidden_base(&b, &[&bordered, &sideways], &gp());
    let record = record.expect("the views were looked at");
    assert!(
        record.views.iter().all(|v| v.reads == BaseReading::Unread),
        "{record:?}"
    );
    assert_eq!(out, b);
}

#[test]
fn a_loose_mask_over_the_wall_behind_still_finds_the_edge() {
    // A box-shaped mask around the object, reaching onto the wall above and beside it and
    // down onto the cabinet's front: only pixels whose points lie in the box are the
    // object's.
    let world = world(true);
    let cam = camera([2.0, 1.3, 1.2], [2.0, 2.7, 2.0]);
    let (depth, tight) = first_surface_mask(&cam, &world, ON_TOP, RANGE);
    let b = seen_box(&cam, &depth, &tight);
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for y in 0..tight.height {
        for x in 0..tight.width {
            if tight.get(x, y) {
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
            }
        }
    }
    let loose = Mask::from_box(
        tight.width,
        tight.height,
        [
            x0.saturating_sub(4) as f32,
            y0.saturating_sub(6) as f32,
            (x1 + 5) as f32,
            (y1 + 2) as f32,
        ],
    );
    assert!(loose.count() > 2 * tight.count());
    let view = segmented_view(0, &cam, &depth, &loose);
    let (out, record) = extend_to_hidden_base(&b, &[&view], &gp());
    let record = record.expect("the view was read");
    assert_eq!(
        record.views[0].reads,
        BaseReading::EdgeAboveEye,
        "{record:?}"
    );
    assert!((out.min[2] - CABINET.1[2]).abs() < 0.05, "{out:?}");
}

#[test]
fn a_mask_that_stops_well_short_of_the_objects_bottom_still_finds_the_edge() {
    // Only the object's top rows are in the mask (a segmenter's mask in a close-up can
    // stop far above the silhouette); the walk down goes on over the object's own surface
    // to the edge.
    let world = world(true);
    let cam = camera([2.0, 1.3, 1.2], [2.0, 2.7, 2.0]);
    let (depth, full) = first_surface_mask(&cam, &world, ON_TOP, RANGE);
    let b = seen_box(&cam, &depth, &full);
    let rows: Vec<u32> = (0..full.height)
        .filter(|&y| (0..full.width).any(|x| full.get(x, y)))
        .collect();
    assert!(rows.len() >= 5, "{rows:?}");
    let mut top = Mask::new(full.width, full.height);
    for &y in &rows[..2] {
        for x in 0..full.width {
            top.set(x, y, full.get(x, y));
        }
    }
    let view = segmented_view(0, &cam, &depth, &top);
    let (out, record) = extend_to_hidden_base(&b, &[&view], &gp());
    let record = record.expect("the view was read");
    assert_eq!(
        record.views[0].reads,
        BaseReading::EdgeAboveEye,
        "{record:?}"
    );
    assert!((out.min[2] - CABINET.1[2]).abs() < 0.05, "{out:?}");
}
