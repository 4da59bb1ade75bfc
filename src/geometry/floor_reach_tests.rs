//! Tests of [`super`], on rendered scenes.

use super::*;
use crate::geometry::camera::transform_point;
use crate::geometry::test_scene::{
    camera, first_hit, first_surface_mask, pixel_ray, room_slabs, seen_box, segmented_view,
};
use crate::geometry::FrameCamera;

type Block = ([f64; 3], [f64; 3]);

/// A floor lamp in a 4 x 4 x 3 m room: a 4 cm pole under a 40 cm shade.
const POLE: Block = ([1.98, 2.48, 0.0], [2.02, 2.52, 1.3]);
const SHADE: Block = ([1.8, 2.3, 1.3], [2.2, 2.7, 1.6]);
const RANGE: f64 = 6.0;

fn world() -> Vec<Block> {
    let mut w = room_slabs(4.0, 4.0, 3.0);
    w.push(POLE);
    w.push(SHADE);
    w
}

/// The image box of `blocks`' corners (a detector's box of their silhouette).
fn image_box(cam: &FrameCamera, blocks: &[Block]) -> [f32; 4] {
    let to_cam = cam.out_to_cam().expect("pose");
    let mut r = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    for (lo, hi) in blocks {
        for i in 0..8 {
            let c = |k: usize| if i >> k & 1 == 0 { lo[k] } else { hi[k] };
            let p = transform_point(&to_cam, &Point3::new(c(0), c(1), c(2)));
            let (u, v, _) = cam.color.project(&p).expect("in front");
            r = [r[0].min(u), r[1].min(v), r[2].max(u), r[3].max(v)];
        }
    }
    let w = f64::from(cam.color.width - 1);
    let h = f64::from(cam.color.height - 1);
    [
        r[0].clamp(0.0, w) as f32,
        r[1].clamp(0.0, h) as f32,
        r[2].clamp(0.0, w) as f32,
        r[3].clamp(0.0, h) as f32,
    ]
}

fn front_camera() -> FrameCamera {
    camera([2.0, 0.3, 1.4], [2.0, 2.5, 0.8])
}

#[test]
fn a_lamp_whose_boxes_reach_the_floor_is_set_down_on_it() {
    let cam = front_camera();
    let (depth, mask) = first_surface_mask(&cam, &world(), SHADE, RANGE);
    let b = seen_box(&cam, &depth, &mask);
    assert!(b.min[2] > 1.2, "only the shade was measured: {b:?}");
    let lamp = image_box(&cam, &[POLE, SHADE]);
    let v = segmented_view(4, &cam, &depth, &mask);
    let (out, record) = extend_to_floor_reach(&b, &[(&v, lamp)], 0.0, &GeometryParams::default());
    let record = record.expect("a record");
    assert_eq!(record.views[0].reaches_floor, Some(true), "{record:?}");
    assert_eq!(out.min[2], 0.0, "{record:?}");
    assert_eq!(
        (out.max, out.min[0], out.min[1]),
        (b.max, b.min[0], b.min[1])
    );
    // The shade's own box says the object ends where it was measured.
    let shade = image_box(&cam, &[SHADE]);
    let (out, record) = extend_to_floor_reach(&b, &[(&v, shade)], 0.0, &GeometryParams::default());
    let record = record.expect("a record");
    assert_eq!(out, b, "{record:?}");
    assert_eq!(record.views[0].reaches_floor, Some(false), "{record:?}");
}

#[test]
fn one_view_whose_box_ends_at_the_shade_vetoes_the_move() {
    let cam = front_camera();
    let (depth, mask) = first_surface_mask(&cam, &world(), SHADE, RANGE);
    let b = seen_box(&cam, &depth, &mask);
    let side = camera([0.4, 1.0, 1.5], [2.0, 2.5, 1.0]);
    let (side_depth, side_mask) = first_surface_mask(&side, &world(), SHADE, RANGE);
    let (a, s) = (
        segmented_view(1, &cam, &depth, &mask),
        segmented_view(2, &side, &side_depth, &side_mask),
    );
    let gp = GeometryParams::default();
    let both = [
        (&a, image_box(&cam, &[POLE, SHADE])),
        (&s, image_box(&side, &[POLE, SHADE])),
    ];
    assert_eq!(extend_to_floor_reach(&b, &both, 0.0, &gp).0.min[2], 0.0);
    let veto = [
        (&a, image_box(&cam, &[POLE, SHADE])),
        (&s, image_box(&side, &[SHADE])),
    ];
    let (out, record) = extend_to_floor_reach(&b, &veto, 0.0, &gp);
    assert_eq!(out, b, "{record:?}");
}

#[test]
fn a_box_on_the_lower_border_a_bottom_near_the_floor_or_no_view_say_nothing() {
    let cam = front_camera();
    let (depth, mask) = first_surface_mask(&cam, &world(), SHADE, RANGE);
    let b = seen_box(&cam, &depth, &mask);
    let v = segmented_view(3, &cam, &depth, &mask);
    let gp = GeometryParams::default();
    // The box cut by the image's lower border: the view is not read.
    let mut cut = image_box(&cam, &[POLE, SHADE]);
    cut[3] = (cam.color.height - 1) as f32;
    let (out, record) = extend_to_floor_reach(&b, &[(&v, cut)], 0.0, &gp);
    assert_eq!(out, b);
    assert_eq!(record.expect("a record").views[0].reaches_floor, None);
    // A box already standing within reach of the floor, or no view: no record.
    let mut low = b;
    low.min[2] = 0.03;
    let lamp = image_box(&cam, &[POLE, SHADE]);
    assert_eq!(
        extend_to_floor_reach(&low, &[(&v, lamp)], 0.0, &gp),
        (low, None)
    );
    assert_eq!(extend_to_floor_reach(&b, &[], 0.0, &gp), (b, None));
}

#[test]
fn a_cup_on_a_table_with_a_loose_box_stays_on_the_table() {
    const TABLE: Block = ([1.5, 2.0, 0.0], [2.5, 3.0, 0.75]);
    const CUP: Block = ([1.95, 2.3, 0.75], [2.05, 2.4, 0.87]);
    let mut w = room_slabs(4.0, 4.0, 3.0);
    w.extend([TABLE, CUP]);
    let cam = front_camera();
    let (depth, mask) = first_surface_mask(&cam, &w, CUP, RANGE);
    let b = seen_box(&cam, &depth, &mask);
    let v = segmented_view(5, &cam, &depth, &mask);
    // Two pixels below the cup's silhouette.
    let mut loose = image_box(&cam, &[CUP]);
    loose[3] += 2.0;
    let (out, record) = extend_to_floor_reach(&b, &[(&v, loose)], 0.0, &GeometryParams::default());
    let record = record.expect("a record");
    assert_eq!(record.views[0].reaches_floor, Some(false), "{record:?}");
    assert_eq!(
        record.views[0].below_edge,
        Some(BelowEdge::Support),
        "{record:?}"
    );
    assert_eq!(out, b);
    // The table top before the cup's foot is what it stands on: the box's edge, two
    // pixels into it, does not lower the bottom (at this resolution that is 40 % of the
    // cup's image).
    let (out, edge) = lower(&b, &v, loose, &GeometryParams::default());
    assert_eq!(out, b, "{edge:?}");
}

/// A desk between the front camera and the lamp: its top hides the pole's lower half.
const DESK: Block = ([1.5, 1.6, 0.0], [2.5, 2.0, 0.75]);

/// The lowest row where the line of sight through the pole's middle column meets the pole
/// first (a detector's box of what shows of the lamp ends there).
fn pole_bottom_row(cam: &FrameCamera, world: &[Block], pole: usize) -> f64 {
    let to_cam = cam.out_to_cam().expect("pose");
    let mid = transform_point(&to_cam, &Point3::new(2.0, 2.5, 1.0));
    let (u, _, _) = cam.color.project(&mid).expect("in front");
    let rows = f64::from(cam.color.height) * 4.0;
    (0..rows as u32)
        .map(|k| f64::from(k) / 4.0)
        .filter(|&v| {
            let (o, d) = pixel_ray(cam, u, v);
            first_hit(&o, &d, world.iter().map(|(lo, hi)| (lo, hi))).is_some_and(|(i, _)| i == pole)
        })
        .fold(f64::NAN, f64::max)
}

/// The detector's box of what `cam` shows of the lamp in `world` (its pole second to
/// last): the shade's box down to the pole's lowest row in view.
fn shown_box(cam: &FrameCamera, world: &[Block]) -> [f32; 4] {
    let mut shown = image_box(cam, &[SHADE]);
    shown[3] = pole_bottom_row(cam, world, world.len() - 2) as f32;
    shown
}

/// [`lower_to_box_edge`] on `v`'s reading of `bbox`.
fn lower(
    b: &Aabb,
    v: &SegmentedView<'_>,
    bbox: [f32; 4],
    gp: &GeometryParams,
) -> (Aabb, Option<EdgeReach>) {
    lower_to_box_edge(b, read_view(v, bbox, b, Some(0.0), gp), Some(0.0), gp)
}

fn lamp_behind_desk() -> Vec<Block> {
    let mut w = room_slabs(4.0, 4.0, 3.0);
    w.extend([DESK, POLE, SHADE]);
    w
}

#[test]
fn a_lamp_whose_pole_is_hidden_behind_a_desk_reaches_down_to_where_its_box_ends() {
    let world = lamp_behind_desk();
    let cam = front_camera();
    let (depth, mask) = first_surface_mask(&cam, &world, SHADE, RANGE);
    let b = seen_box(&cam, &depth, &mask);
    assert!(b.min[2] > 1.2, "only the shade was measured: {b:?}");
    // What shows of the lamp: the shade and the pole down to the desk's far edge.
    let shown = shown_box(&cam, &world);
    let v = segmented_view(6, &cam, &depth, &mask);
    let gp = GeometryParams::default();
    let (out, edge) = lower(&b, &v, shown, &gp);
    let edge = edge.expect("the view is read");
    assert_eq!(edge.view.below_edge, Some(BelowEdge::Occluder), "{edge:?}");
    // The line of sight over the desk's far edge meets the pole 0.57 m up; at the shade's
    // front, nearer, it is a little higher: the bottom goes down to about there, never
    // below what shows.
    assert!(out.min[2] > 0.5 && out.min[2] < 0.8, "{edge:?}");
    assert_eq!(
        (out.max, out.min[0], out.min[1]),
        (b.max, b.min[0], b.min[1])
    );
    // The box of the shade alone holds nothing depth missed.
    let (out, edge) = lower(&b, &v, image_box(&cam, &[SHADE]), &gp);
    assert_eq!(out, b, "{edge:?}");
    // Turned off by the share of the box that must be unmeasured.
    let mut strict = gp.clone();
    strict.support.box_edge_unmeasured = 1.01;
    assert_eq!(lower(&b, &v, shown, &strict).0, b);
}

#[test]
fn a_box_that_ends_on_a_nearer_desk_does_not_veto_a_view_that_sees_the_foot() {
    let world = lamp_behind_desk();
    let front = front_camera();
    let (depth, mask) = first_surface_mask(&front, &world, SHADE, RANGE);
    // The shade's box, as the views fused would give it.
    let b = Aabb {
        min: SHADE.0,
        max: SHADE.1,
    };
    let shown = shown_box(&front, &world);
    let back = camera([2.0, 3.8, 1.4], [2.0, 2.5, 0.8]);
    let (back_depth, back_mask) = first_surface_mask(&back, &world, SHADE, RANGE);
    let (a, s) = (
        segmented_view(1, &front, &depth, &mask),
        segmented_view(2, &back, &back_depth, &back_mask),
    );
    let views = [(&a, shown), (&s, image_box(&back, &[POLE, SHADE]))];
    let (out, record) = extend_to_floor_reach(&b, &views, 0.0, &GeometryParams::default());
    let record = record.expect("a record");
    assert_eq!(record.views[0].reaches_floor, None, "{record:?}");
    assert_eq!(
        record.views[0].below_edge,
        Some(BelowEdge::Occluder),
        "{record:?}"
    );
    assert_eq!(record.views[1].reaches_floor, Some(true), "{record:?}");
    assert_eq!(out.min[2], 0.0, "{record:?}");
}
