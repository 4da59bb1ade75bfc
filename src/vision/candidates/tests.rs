//! Rendered rooms: candidates must exist for objects no detector knows, and must not be
//! the room itself.

use super::*;
use crate::geometry::camera::look_at_pose;
use crate::geometry::test_scene::{first_hit, pixel_ray};
use crate::geometry::Intrinsics;
use nalgebra::{Matrix4, Vector3};

/// A box with a colour and an instance id (0 = room structure).
struct Part {
    lo: [f64; 3],
    hi: [f64; 3],
    rgb: [u8; 3],
    id: u16,
}

fn part(lo: [f64; 3], hi: [f64; 3], rgb: [u8; 3], id: u16) -> Part {
    Part { lo, hi, rgb, id }
}

/// A 4 x 4 x 2.5 m room: grey walls, brown floor, white ceiling.
fn room() -> Vec<Part> {
    let wall = [150, 150, 150];
    vec![
        part([-0.1, -0.1, -0.1], [4.1, 4.1, 0.0], [120, 90, 60], 0),
        part([-0.1, -0.1, 2.5], [4.1, 4.1, 2.6], [240, 240, 240], 0),
        part([-0.1, -0.1, 0.0], [0.0, 4.1, 2.5], wall, 0),
        part([4.0, -0.1, 0.0], [4.1, 4.1, 2.5], wall, 0),
        part([-0.1, -0.1, 0.0], [4.1, 0.0, 2.5], wall, 0),
        part([-0.1, 4.0, 0.0], [4.1, 4.1, 2.5], wall, 0),
    ]
}

fn layout() -> RoomLayout {
    RoomLayout {
        angle_deg: 0.0,
        u: [Some(0.0), Some(4.0)],
        v: [Some(0.0), Some(4.0)],
        faced: [true; 4],
        floor: Some(0.0),
        ceiling: Some(2.5),
        range: 6.0,
        reach: [[0.0, 4.0], [0.0, 4.0], [0.0, 2.5]],
        points: 0,
    }
}

fn camera(eye: [f64; 3], target: [f64; 3]) -> FrameCamera {
    let color = Intrinsics {
        fx: 250.0,
        fy: 250.0,
        cx: 159.5,
        cy: 119.5,
        width: 320,
        height: 240,
    };
    FrameCamera {
        color,
        depth: None,
        depth_size: (320, 240),
        pose: look_at_pose(eye.into(), target.into(), Vector3::z()),
        align: Matrix4::identity(),
    }
}

/// Ray-cast depth (mm), colour and instance ids of `parts` (colour and depth share K).
fn render(cam: &FrameCamera, parts: &[Part]) -> (DepthMap, RgbImage, Vec<u16>) {
    let (w, h) = (cam.color.width, cam.color.height);
    let mut depth = vec![0u16; (w * h) as usize];
    let mut ids = vec![0u16; (w * h) as usize];
    let mut img = RgbImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let (o, d) = pixel_ray(cam, f64::from(x), f64::from(y));
            if let Some((n, t)) = first_hit(&o, &d, parts.iter().map(|p| (&p.lo, &p.hi))) {
                let (i, p) = ((y * w + x) as usize, &parts[n]);
                depth[i] = (t * 1000.0).round() as u16;
                ids[i] = p.id;
                img.put_pixel(x, y, image::Rgb(p.rgb));
            }
        }
    }
    (DepthMap::new(w, h, depth), img, ids)
}

/// The box of instance `id`'s pixels.
fn truth_box(ids: &[u16], w: u32, id: u16) -> [f32; 4] {
    let mut b = [f32::MAX, f32::MAX, 0.0f32, 0.0f32];
    for (i, &v) in ids.iter().enumerate() {
        if v == id {
            let (x, y) = ((i as u32 % w) as f32, (i as u32 / w) as f32);
            b = [
                b[0].min(x),
                b[1].min(y),
                b[2].max(x + 1.0),
                b[3].max(y + 1.0),
            ];
        }
    }
    b
}

fn best_iou(cands: &[Candidate], truth: &[f32; 4]) -> f64 {
    cands
        .iter()
        .map(|c| box_iou(&c.bbox, truth))
        .fold(0.0, f64::max)
}

/// The candidate whose box best overlaps `truth`.
fn best<'a>(cands: &'a [Candidate], truth: &[f32; 4]) -> Option<&'a Candidate> {
    cands
        .iter()
        .max_by(|a, b| box_iou(&a.bbox, truth).total_cmp(&box_iou(&b.bbox, truth)))
}

/// The candidate that best overlaps instance `id`, and the instance's box.
fn best_for(cam: &FrameCamera, parts: &[Part], id: u16) -> (Candidate, [f32; 4]) {
    let (cands, ids) = run(cam, parts);
    let truth = truth_box(&ids, cam.color.width, id);
    let c = best(&cands, &truth).cloned().expect("some candidate");
    (c, truth)
}

fn run(cam: &FrameCamera, parts: &[Part]) -> (Vec<Candidate>, Vec<u16>) {
    run_with(cam, parts, &CandidateParams::default())
}

/// [`run`] with settings `p`.
fn run_with(cam: &FrameCamera, parts: &[Part], p: &CandidateParams) -> (Vec<Candidate>, Vec<u16>) {
    let (depth, img, ids) = render(cam, parts);
    let c = frame_candidates(
        cam,
        &depth,
        &img,
        Some(&layout()),
        &LayoutParams::default(),
        p,
    );
    (c, ids)
}

/// A floor lamp 20 cm before the wall at y = 4 (thin pole, red shade), instance `id`, and
/// the camera both lamp tests look at it with.
fn floor_lamp(id: u16) -> ([Part; 2], FrameCamera) {
    let pole = part([1.97, 3.67, 0.0], [2.03, 3.73, 1.3], [40, 40, 40], id);
    let shade = part([1.8, 3.5, 1.3], [2.2, 3.9, 1.6], [200, 30, 30], id);
    ([pole, shade], camera([2.0, 0.8, 1.4], [2.0, 4.0, 1.0]))
}

#[test]
fn a_lamp_before_a_wall_is_a_candidate_and_the_wall_is_not() {
    let mut parts = room();
    let (lamp, cam) = floor_lamp(7);
    parts.extend(lamp);
    let (cands, ids) = run(&cam, &parts);
    let truth = truth_box(&ids, 320, 7);
    let iou = best_iou(&cands, &truth);
    assert!(
        iou > 0.7,
        "best IoU {iou:.2} with the lamp {truth:?}: {cands:?}"
    );
    // Nothing covers most of the image (the wall, the floor).
    for c in &cands {
        let area = f64::from((c.bbox[2] - c.bbox[0]) * (c.bbox[3] - c.bbox[1]));
        assert!(area < 0.5 * 320.0 * 240.0, "a candidate is the room: {c:?}");
    }
}

#[test]
fn a_lamp_with_its_flat_foot_in_the_floors_band_reaches_down_to_the_floor() {
    // A floor lamp seen from above and in front: its 3 cm foot, 36 cm wide, lies within the
    // floor's structure band, so its cells are cut with the floor; the pole and the shade
    // reach down to the band.
    let mut parts = room();
    let (dark, light) = ([60, 60, 60], [200, 200, 200]);
    parts.push(part([1.82, 2.32, 0.0], [2.18, 2.68, 0.03], light, 7));
    parts.push(part([1.98, 2.48, 0.03], [2.02, 2.52, 1.2], dark, 7));
    parts.push(part([1.78, 2.28, 1.2], [2.22, 2.72, 1.45], light, 7));
    let cam = camera([2.0, 0.6, 2.2], [2.0, 2.5, 0.7]);
    let (cands, ids) = run(&cam, &parts);
    let truth = truth_box(&ids, 320, 7);
    let c = best(&cands, &truth).expect("a candidate");
    // The lamp's box ends where its foot meets the floor, not where the band begins, and
    // no lower than the shade dropped onto the floor would reach (the shade is 4 cm wider
    // than the foot each way).
    assert!(
        c.bbox[3] >= truth[3] - 1.0 && c.bbox[3] <= truth[3] + 12.0,
        "the candidate {c:?} ends at {} and the lamp at {}",
        c.bbox[3],
        truth[3]
    );
    assert!(box_iou(&c.bbox, &truth) > 0.8, "{c:?} for {truth:?}");
}

#[test]
fn two_touching_objects_of_different_colours_are_separate_candidates() {
    let mut parts = room();
    // A bed with two pillows touching each other, blue and yellow.
    parts.push(part([1.0, 2.0, 0.0], [3.0, 4.0, 0.5], [230, 230, 230], 1));
    parts.push(part([1.2, 3.4, 0.5], [1.95, 3.9, 0.65], [40, 60, 200], 2));
    parts.push(part([1.95, 3.4, 0.5], [2.7, 3.9, 0.65], [220, 200, 30], 3));
    let cam = camera([2.0, 1.0, 1.6], [2.0, 3.5, 0.5]);
    let (cands, ids) = run(&cam, &parts);
    for id in [1, 2, 3] {
        let truth = truth_box(&ids, 320, id);
        let iou = best_iou(&cands, &truth);
        assert!(
            iou > 0.6,
            "object {id}: best IoU {iou:.2} with {truth:?}: {cands:?}"
        );
    }
}

#[test]
fn a_picture_on_a_wall_is_a_candidate() {
    let mut parts = room();
    // A 60 x 40 cm picture 2 cm proud of the wall at y = 4, green.
    parts.push(part([1.7, 3.98, 1.2], [2.3, 4.0, 1.6], [40, 160, 60], 9));
    let cam = camera([2.0, 1.5, 1.4], [2.0, 4.0, 1.4]);
    let (c, truth) = best_for(&cam, &parts, 9);
    assert!(
        box_iou(&c.bbox, &truth) > 0.7 && c.kind == CandidateKind::OnWall,
        "{c:?} against {truth:?}"
    );
}

#[test]
fn a_window_standing_out_past_the_structure_margin_is_one_candidate() {
    let mut parts = room();
    // A brown 1 x 1 m window in the wall at y = 4: its upper panel 5 cm proud of the wall
    // (within the structure margin at 3.5 m, 7.5 cm), its lower panel and sill 10 cm (past
    // it). The window is one object on the wall.
    let brown = [120, 80, 40];
    parts.push(part([1.5, 3.95, 1.5], [2.5, 4.0, 2.0], brown, 9));
    parts.push(part([1.5, 3.9, 1.0], [2.5, 4.0, 1.5], brown, 9));
    let cam = camera([2.0, 0.5, 1.4], [2.0, 4.0, 1.4]);
    let (c, truth) = best_for(&cam, &parts, 9);
    assert!(
        box_iou(&c.bbox, &truth) > 0.8 && c.kind == CandidateKind::OnWall,
        "{c:?} against {truth:?}"
    );
}

#[test]
fn a_board_on_the_wall_does_not_take_the_top_of_the_cabinet_below_it() {
    let mut parts = room();
    // A green cabinet 20 cm deep against the wall at y = 4, and a green board on the
    // wall just above it. The cabinet's top near the wall lies within twice the structure
    // margin of the wall, but the cabinet as a whole stands out from it.
    let green = [40, 160, 60];
    parts.push(part([1.6, 3.8, 0.0], [2.4, 4.0, 1.0], green, 8));
    parts.push(part([1.6, 3.98, 1.0], [2.4, 4.0, 1.4], green, 9));
    let cam = camera([2.0, 2.8, 2.4], [2.0, 4.0, 1.0]);
    let (cands, ids) = run(&cam, &parts);
    let truth = truth_box(&ids, 320, 9);
    let c = cands
        .iter()
        .filter(|c| c.kind == CandidateKind::OnWall)
        .max_by(|a, b| box_iou(&a.bbox, &truth).total_cmp(&box_iou(&b.bbox, &truth)))
        .expect("an on-wall candidate");
    assert!(box_iou(&c.bbox, &truth) > 0.7, "{c:?} against {truth:?}");
    assert!(c.min[1] > 3.9, "the board reaches onto the cabinet: {c:?}");
}

#[test]
fn a_dark_grey_board_on_a_grey_wall_is_a_candidate() {
    let mut parts = room();
    // Neutral like the wall (150 grey), a third as bright: the hue rule alone, which
    // allows a factor of 4 for shading, takes it for the wall.
    parts.push(part([1.6, 3.98, 1.1], [2.4, 4.0, 1.7], [45, 45, 45], 9));
    let cam = camera([2.0, 1.5, 1.4], [2.0, 4.0, 1.4]);
    let (c, truth) = best_for(&cam, &parts, 9);
    assert!(
        box_iou(&c.bbox, &truth) > 0.8 && c.kind == CandidateKind::OnWall,
        "{c:?} against {truth:?}"
    );
}

#[test]
fn a_lamp_grouped_with_a_cabinet_behind_it_is_a_candidate_of_its_own() {
    // The lamp of the first test (a shade before its pole), and a cabinet 25 cm behind
    // the shade that its right edge touches in the image: the three are one group, and
    // only the shade and the pole together outline the lamp.
    let mut parts = room();
    let (lamp, cam) = floor_lamp(7);
    parts.extend(lamp);
    parts.push(part([2.2, 3.75, 0.0], [2.9, 4.0, 1.8], [230, 220, 200], 8));
    let (cands, ids) = run(&cam, &parts);
    for (id, what) in [(7, "lamp"), (8, "cabinet")] {
        let truth = truth_box(&ids, 320, id);
        let iou = best_iou(&cands, &truth);
        assert!(
            iou > 0.7,
            "{what}: best IoU {iou:.2} with {truth:?}: {cands:?}"
        );
    }
}

#[test]
fn without_depth_or_room_nothing_is_proposed() {
    let cam = camera([2.0, 1.0, 1.4], [2.0, 4.0, 1.4]);
    let depth = DepthMap::new(320, 240, vec![0; 320 * 240]);
    let img = RgbImage::new(320, 240);
    let c = frame_candidates(
        &cam,
        &depth,
        &img,
        None,
        &LayoutParams::default(),
        &CandidateParams::default(),
    );
    assert!(c.is_empty(), "{c:?}");
}

/// A table with four legs, its top `top` and `colour`, as parts of instance `id`.
fn table(lo: [f64; 2], hi: [f64; 2], top: f64, colour: [u8; 3], id: u16) -> Vec<Part> {
    let leg = 0.05;
    let mut out = vec![part(
        [lo[0], lo[1], top - 0.04],
        [hi[0], hi[1], top],
        colour,
        id,
    )];
    for (x, y) in [
        (lo[0], lo[1]),
        (hi[0] - leg, lo[1]),
        (lo[0], hi[1] - leg),
        (hi[0] - leg, hi[1] - leg),
    ] {
        out.push(part(
            [x, y, 0.0],
            [x + leg, y + leg, top - 0.04],
            colour,
            id,
        ));
    }
    out
}

#[test]
fn a_box_on_a_table_of_its_colour_is_a_candidate_of_its_own() {
    let white = [210, 210, 205];
    let mut parts = room();
    parts.extend(table([1.2, 2.4], [2.8, 3.4], 0.75, white, 1));
    parts.push(part([1.8, 2.7, 0.75], [2.2, 3.0, 0.95], white, 2));
    let cam = camera([2.0, 0.8, 1.6], [2.0, 2.9, 0.8]);
    let (cands, ids) = run(&cam, &parts);
    let truth = truth_box(&ids, 320, 2);
    let c = best(&cands, &truth).expect("some candidate");
    assert!(
        box_iou(&c.bbox, &truth) > 0.7 && c.kind == CandidateKind::OnTop,
        "{c:?} against the box {truth:?}: {cands:?}"
    );
    // With `tops` off, depth and colour alone give box and table as one region.
    let (depth, img, _) = render(&cam, &parts);
    let p = CandidateParams {
        tops: false,
        ..CandidateParams::default()
    };
    let lp = LayoutParams::default();
    let off = frame_candidates(&cam, &depth, &img, Some(&layout()), &lp, &p);
    assert!(best_iou(&off, &truth) < 0.5, "{off:?}");
}

#[test]
fn a_chair_back_over_its_seat_is_not_an_object_on_it() {
    let brown = [120, 70, 30];
    let mut parts = room();
    let leg = 0.04;
    parts.push(part([1.7, 2.6, 0.42], [2.3, 3.1, 0.47], brown, 1));
    parts.push(part([1.7, 3.05, 0.47], [2.3, 3.1, 1.0], brown, 1));
    for (x, y) in [
        (1.7, 2.6),
        (2.3 - leg, 2.6),
        (1.7, 3.1 - leg),
        (2.3 - leg, 3.1 - leg),
    ] {
        parts.push(part([x, y, 0.0], [x + leg, y + leg, 0.42], brown, 1));
    }
    let cam = camera([2.0, 1.2, 1.5], [2.0, 2.8, 0.6]);
    let (cands, ids) = run(&cam, &parts);
    assert!(
        cands.iter().all(|c| c.kind != CandidateKind::OnTop),
        "{cands:?}"
    );
    // The chair itself is still a candidate.
    let truth = truth_box(&ids, 320, 1);
    assert!(best_iou(&cands, &truth) > 0.8, "{cands:?}");
}

#[test]
fn two_pillows_side_by_side_on_a_bed_of_ones_colour_are_candidates_each() {
    // A blue bed; on its top a blue pillow and a yellow one touching it. Above the top both
    // pillows are one region; the blue one is told from the yellow by colour, and from the
    // bed only by standing on its top.
    let (blue, yellow) = ([40, 60, 170], [220, 200, 40]);
    let mut parts = room();
    parts.push(part([1.0, 2.2, 0.0], [3.0, 3.9, 0.5], blue, 1));
    parts.push(part([1.3, 3.3, 0.5], [1.95, 3.75, 0.63], blue, 2));
    parts.push(part([1.95, 3.3, 0.5], [2.6, 3.75, 0.63], yellow, 3));
    let cam = camera([2.0, 0.9, 1.5], [2.0, 3.3, 0.5]);
    let (cands, ids) = run(&cam, &parts);
    for id in [2, 3] {
        let truth = truth_box(&ids, 320, id);
        let iou = best_iou(&cands, &truth);
        assert!(iou > 0.7, "pillow {id}: {iou} against {truth:?}: {cands:?}");
    }
}

#[test]
fn two_pillows_of_one_colour_one_behind_the_other_are_candidates_each() {
    // A white bed; on its top two blue pillows, the farther one partly hidden behind the
    // nearer, 20 cm apart. Colour tells them from the bed as one part; their own level
    // tops, whose footprints do not overlap, tell them from each other.
    let (white, blue) = ([225, 225, 220], [40, 60, 170]);
    let mut parts = room();
    parts.push(part([1.0, 2.2, 0.0], [3.0, 3.9, 0.5], white, 1));
    parts.push(part([1.5, 2.7, 0.5], [2.3, 3.1, 0.65], blue, 2));
    parts.push(part([1.7, 3.3, 0.5], [2.5, 3.7, 0.66], blue, 3));
    let cam = camera([2.0, 0.9, 1.5], [2.0, 3.3, 0.5]);
    let ious = |p: &CandidateParams| {
        let (cands, ids) = run_with(&cam, &parts, p);
        [2, 3].map(|id| best_iou(&cands, &truth_box(&ids, 320, id)))
    };
    let on = ious(&CandidateParams::default());
    assert!(on.iter().all(|&v| v > 0.7), "{on:?}");
    // Without the split, one of them is only offered together with the other.
    let off = ious(&CandidateParams {
        side_by_side: false,
        ..CandidateParams::default()
    });
    assert!(off.iter().any(|&v| v < 0.7), "{off:?}");
}

#[test]
fn the_cache_key_changes_with_what_is_found_and_only_with_that() {
    let (p, lp) = (CandidateParams::default(), LayoutParams::default());
    let key = p.cache_key(&lp);
    assert!(
        key.starts_with(&format!("{CACHE_PREFIX}/v{ALGORITHM_VERSION}/")),
        "{key}"
    );
    assert_eq!(key, p.clone().cache_key(&lp.clone()), "the same settings");
    // Settings that change which candidates are found change the key...
    let finer = CandidateParams {
        cells_across: p.cells_across * 2,
        ..p.clone()
    };
    let no_tops = CandidateParams {
        tops: !p.tops,
        ..p.clone()
    };
    let coarse_room = LayoutParams {
        bin: lp.bin * 2.0,
        ..lp.clone()
    };
    for (what, other) in [
        ("cells_across", finer.cache_key(&lp)),
        ("tops", no_tops.cache_key(&lp)),
        ("layout bin", p.cache_key(&coarse_room)),
    ] {
        assert_ne!(key, other, "{what}");
    }
    // ...settings of their use do not: toggling them keeps the cache.
    let used_otherwise = CandidateParams {
        enabled: !p.enabled,
        in_views: !p.in_views,
        in_views_check: !p.in_views_check,
        box_fallback: !p.box_fallback,
        view_box_views: p.view_box_views + 1,
        nearer_share: p.nearer_share / 2.0,
        ..p.clone()
    };
    assert_eq!(key, used_otherwise.cache_key(&lp));
    // Every name left out of the digest is a setting (a misspelt one would leave it in).
    let fields = serde_json::to_value(&p).unwrap();
    for k in USE_ONLY {
        assert!(fields.get(k).is_some(), "{k} is not a setting");
    }
}
