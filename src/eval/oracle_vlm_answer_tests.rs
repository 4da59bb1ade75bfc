//! Tests of the oracle VLM's reading and answers (`super`).
use super::*;
use crate::eval::oracle_vlm_truth::{FrameTruth, InstanceStat};
use std::collections::HashMap;

fn frame(size: (u32, u32), target: Option<(u64, [f32; 4])>) -> FrameTruth {
    let mut instances = HashMap::new();
    if let Some((pixels, bbox)) = target {
        instances.insert(7, InstanceStat { pixels, bbox });
    }
    FrameTruth {
        name: String::new(),
        color: None,
        size,
        instances,
        mask_area: u64::from(size.0) * u64::from(size.1),
    }
}

#[test]
fn a_sliver_is_not_shown_unless_no_frame_shows_more() {
    let (w, h) = (640, 480);
    let sliver = Some((80, [431.0, 0.0, 441.0, 8.0]));
    let whole = Some((5000, [100.0, 100.0, 180.0, 170.0]));
    let scene = SceneTruth {
        frames: vec![frame((w, h), sliver), frame((w, h), whole)],
    };
    // 80 of 307 200 pixels is under 0.1 %: frame 0 does not show it, frame 1 does.
    assert!(!scene.shows(0, 7) && scene.shows(1, 7));
    assert!(not_offered(&scene, 7, &[0]));
    assert!(!not_offered(&scene, 7, &[0, 1]));
    assert_eq!(best_frame(&scene, 7, Some(&[0]), &[]), Some(1));
    // An object no frame shows by the rule: the frames holding a pixel of it show it.
    // One that was not offered is not named: "not offered" is said, and the other
    // frames are offered (naming it ended such jobs `retry_limit_reached`).
    let tiny = SceneTruth {
        frames: vec![frame((w, h), None), frame((w, h), sliver)],
    };
    assert!(not_offered(&tiny, 7, &[0]));
    assert!(!not_offered(&tiny, 7, &[0, 1]));
    assert_eq!(best_frame(&tiny, 7, None, &[]), Some(1));
    assert_eq!(best_frame(&tiny, 7, Some(&[0, 1]), &[]), Some(1));
    // Not in any frame at all: nothing to offer, so never "not offered".
    let absent = SceneTruth {
        frames: vec![frame((w, h), None)],
    };
    assert!(!not_offered(&absent, 7, &[0]));
}

#[test]
fn a_whole_view_beats_a_larger_close_up_cut_by_the_border() {
    let scene = SceneTruth {
        frames: vec![
            // 0: close-up running off the right and bottom edges, 60k pixels.
            frame((640, 480), Some((60_000, [300.0, 200.0, 640.0, 480.0]))),
            // 1: the whole object, 40k pixels.
            frame((640, 480), Some((40_000, [100.0, 100.0, 400.0, 300.0]))),
            // 2: whole but small.
            frame((640, 480), Some((5_000, [10.0, 10.0, 90.0, 90.0]))),
            // 3: not visible.
            frame((640, 480), None),
        ],
    };
    assert!(scene.cut_by_border(0, 7) && !scene.cut_by_border(1, 7) && !scene.cut_by_border(3, 7));
    assert_eq!(best_frame(&scene, 7, None, &[]), Some(1));
    // A cut view still wins over a much smaller whole one.
    assert_eq!(best_frame(&scene, 7, Some(&[0, 2]), &[]), Some(0));
    assert_eq!(best_frame(&scene, 7, Some(&[0, 2]), &[0]), Some(2));
    // Nothing offered shows it: the best overall.
    assert_eq!(best_frame(&scene, 7, Some(&[3]), &[]), Some(1));
}

#[test]
fn a_view_box_request_is_read_as_a_box_request_about_the_view() {
    use crate::vlm::prompts::Prompts;
    let text = Prompts::embedded().view_box_request(
        "the curtain by the bed",
        "curtain",
        21,
        4,
        (320, 240),
        [10.0, 20.0, 30.0, 40.0],
        BoxFormat::Yxyx1000,
    );
    let seen = SeenMessage {
        role: "user".into(),
        text,
        images: vec![],
    };
    let conv = read_conversation(&[seen]).expect("a task");
    assert_eq!(conv.mode, Mode::Box);
    // The view's id and size, not the chosen frame's (named later in the text).
    assert_eq!((conv.frame, conv.frame_size), (Some(21), Some((320, 240))));
    assert_eq!(conv.box_format, Some(BoxFormat::Yxyx1000));
    assert_eq!(conv.query.as_deref(), Some("the curtain by the bed"));
    assert!(conv.candidates.is_empty());
}

/// A user message of `text` without images.
fn user(text: String) -> SeenMessage {
    SeenMessage {
        role: "user".into(),
        text,
        images: vec![],
    }
}

#[test]
fn feedback_rejecting_the_image_after_a_mark_task_is_answered_as_image_selection() {
    use crate::vlm::prompts::Prompts;
    let p = Prompts::embedded();
    let grounding = format!(
        "{}\nQuery: the lamp\nOffered image ids (2): 00003, 00026",
        markers::GROUNDING
    );
    let marks = format!(
        "{}\nThis is frame 00026 at full resolution (640 x 480 pixels).\nQuery: the lamp",
        markers::MARKS
    );
    for fb in [
        p.feedback_no_depth(26, "lamp"),
        p.feedback_object_not_existing(26, "lamp"),
    ] {
        let conv = read_conversation(&[user(grounding.clone()), user(marks.clone()), user(fb)])
            .expect("a task");
        assert_eq!(conv.mode, Mode::Grounding);
        assert_eq!(conv.rejected, vec![26]);
        assert_eq!(conv.offered, Some(vec![3, 26]));
    }
    // Without the feedback the mark task is answered.
    let conv = read_conversation(&[user(grounding), user(marks)]).expect("a task");
    assert_eq!(conv.mode, Mode::Instance);
}

#[test]
fn frames_named_as_having_measured_the_place_are_read_apart_from_the_rejected_one() {
    use crate::vlm::prompts::Prompts;
    let p = Prompts::embedded();
    let grounding = format!(
        "{}\nQuery: the lamp\nOffered image ids (4): 00003, 00012, 00026, 00031",
        markers::GROUNDING
    );
    let fb = p.feedback_no_depth_nearer(26, "lamp", &[31, 12]);
    let conv = read_conversation(&[user(grounding.clone()), user(fb)]).expect("a task");
    assert_eq!(conv.mode, Mode::Grounding);
    assert_eq!(conv.rejected, vec![26]);
    assert_eq!(conv.measured_by, vec![31, 12]);
    assert_eq!(conv.offered, Some(vec![3, 12, 26, 31]));
    // The plain feedback names none.
    let conv = read_conversation(&[user(grounding), user(p.feedback_no_depth(26, "lamp"))])
        .expect("a task");
    assert!(conv.measured_by.is_empty());
}

#[test]
fn the_oracle_takes_the_best_of_the_frames_named_as_having_measured_the_place() {
    let (w, h) = (640, 480);
    let big = Some((9000, [100.0, 100.0, 200.0, 190.0]));
    let small = Some((2000, [300.0, 300.0, 350.0, 340.0]));
    let scene = SceneTruth {
        frames: vec![
            frame((w, h), big),
            frame((w, h), small),
            frame((w, h), None),
            frame((w, h), big),
        ],
    };
    let grounding = format!(
        "{}\nQuery: the lamp\nOffered image ids (4): 00000, 00001, 00002, 00003",
        markers::GROUNDING
    );
    let p = crate::vlm::prompts::Prompts::embedded();
    let read = |named: &[u32]| {
        let fb = p.feedback_no_depth_nearer(0, "lamp", named);
        read_conversation(&[user(grounding.clone()), user(fb)]).expect("a task")
    };
    // Frame 3 shows it best, but only frames 1 and 2 are named: 1 shows it.
    assert_eq!(image_choice(&scene, 7, &read(&[2, 1])), Some(1));
    // Named frames that do not show it are passed over for the best offered one.
    assert_eq!(image_choice(&scene, 7, &read(&[2])), Some(3));
    // The plain feedback: the best offered frame other than the rejected one.
    let plain = p.feedback_no_depth(0, "lamp");
    let conv = read_conversation(&[user(grounding), user(plain)]).expect("a task");
    assert_eq!(image_choice(&scene, 7, &conv), Some(3));
}
