//! The VLM may answer that none of the offered frames shows the target. When the
//! detector chose those frames (its false detections elsewhere, its misses of the target),
//! the service offers the frames it left out, once; otherwise the job ends
//! `target_not_found`.

use crate::agent_fixture::*;
use crate::agent_paths::QUERY;
use crate::fake_vlm::{text_of, Reply};
use serde_json::{json, Value};

/// A grounding reply saying no offered frame shows the target.
fn none_here() -> Reply {
    Reply::ok(
        json!({"reasoning": "no frame shows one", "target_image_id": null, "reference_image_ids": []})
            .to_string(),
    )
}

/// The cached detections say the class is only in `fake` (a false detection), nowhere else.
async fn detections_only_in(f: &Fixture, class: &str, fake: usize) {
    for (&i, d) in &f.dets {
        let mut kept: Vec<_> = d.iter().filter(|d| d.label != class).cloned().collect();
        if i == fake {
            kept.push(grounder::vision::Detection {
                label: class.to_string(),
                score: 0.9,
                bbox: [10.0, 10.0, 60.0, 60.0],
            });
        }
        f.store
            .put_detections(&f.scene_id, "oracle", i, &kept)
            .await
            .unwrap();
    }
}

fn image_ids(step: &Value) -> Vec<String> {
    step["outputs"]["image_ids"]
        .as_array()
        .unwrap_or_else(|| panic!("{step:#}"))
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect()
}

/// A fixture whose cached detections put `class` only in `fake`, a frame without it;
/// `good` shows exactly one instance of it: (fixture, class, good, fake).
async fn detector_misleads() -> (Fixture, String, usize, usize) {
    let f = Fixture::start(vec![], 5_000).await;
    let (class, good) = class_with_single(&f);
    let fake = *f
        .frames_with(&class, 0)
        .first()
        .expect("a frame without the class");
    detections_only_in(&f, &class, fake).await;
    (f, class, good, fake)
}

#[tokio::test]
async fn no_offered_frame_shows_the_target_so_the_frames_the_detector_left_out_are_offered() {
    let (f, class, good, fake) = detector_misleads().await;
    f.vlm
        .script_push(vec![analysis(&class), none_here(), pick_image(good as u32)]);

    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "succeeded", "{job:#}");
    assert_eq!(job["result"]["image_id"], format!("{good:05}"));

    let pre = steps(&job, "preselection");
    assert_eq!(pre.len(), 2, "the first offer and the widened one");
    assert_eq!(image_ids(pre[0]), vec![format!("{fake:05}")]);
    let wider = image_ids(pre[1]);
    assert!(wider.contains(&format!("{good:05}")), "{wider:?}");
    assert!(!wider.contains(&format!("{fake:05}")), "{wider:?}");
    let why = pre[1]["outputs"]["fallback"].as_str().unwrap_or_default();
    assert!(why.contains("none of the 1 frames"), "{why}");

    let sel = steps(&job, "image_selection");
    assert_eq!(sel.len(), 2);
    assert_eq!(sel[0]["outputs"]["none"], true, "{:#}", sel[0]);
    assert_eq!(sel[1]["outputs"]["image_id"], format!("{good:05}"));

    // Both offers' grids stay readable: the widened one does not overwrite the first.
    let grids: Vec<String> = steps(&job, "stitching")
        .iter()
        .flat_map(|s| s["outputs"]["grids"].as_array().unwrap().clone())
        .map(|g| g["url"].as_str().unwrap().to_string())
        .collect();
    let mut unique = grids.clone();
    unique.sort();
    unique.dedup();
    assert!(grids.len() >= 2 && unique.len() == grids.len(), "{grids:?}");

    // The second grounding request offers the new ids, in a new conversation.
    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 3);
    let text = text_of(&reqs[2]["messages"][1]);
    assert!(text.contains(&format!("{good:05}")), "{text}");
    assert!(!text.contains(&format!("{fake:05}")), "{text}");
    assert_trace_clean(&job);
}

#[tokio::test]
async fn none_after_widening_ends_target_not_found() {
    let (f, class, _, _) = detector_misleads().await;
    f.vlm
        .script_push(vec![analysis(&class), none_here(), none_here()]);

    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "failed", "{job:#}");
    assert_eq!(job["error"]["code"], "target_not_found", "{job:#}");
    assert_eq!(f.vlm.requests().len(), 3, "widened once, then stopped");
    let sel = steps(&job, "image_selection");
    assert_eq!(sel.len(), 2);
    assert!(sel.iter().all(|s| s["outputs"]["none"] == true), "{sel:#?}");
}

/// The cached detections keep `class` only in frame `kept` (the detector missed it
/// everywhere else).
async fn detections_kept_only_in(f: &Fixture, class: &str, kept: usize) {
    for (&i, d) in &f.dets {
        let d: Vec<_> = d
            .iter()
            .filter(|d| d.label != class || i == kept)
            .cloned()
            .collect();
        f.store
            .put_detections(&f.scene_id, "oracle", i, &d)
            .await
            .unwrap();
    }
}

#[tokio::test]
async fn frames_that_see_what_a_detection_shows_are_offered_though_the_detector_missed_it_there() {
    for reseen in [true, false] {
        let f = Fixture::start_with_config(5_000, "oracle", |c| {
            c.agent.preselect_reseen = reseen;
        })
        .await;
        let (class, good) = class_with_single(&f);
        // The frames that show an object of the class (the oracle detector's cache).
        let showing: Vec<String> = f
            .offered(&class)
            .iter()
            .map(|i| format!("{i:05}"))
            .collect();
        detections_kept_only_in(&f, &class, good).await;
        f.vlm
            .script_push(vec![analysis(&class), pick_image(good as u32)]);
        let job = f.run_job(QUERY).await;
        let pre = steps(&job, "preselection");
        let offered = image_ids(pre[0]);
        let again: Vec<String> = pre[0]["outputs"]["reseen"]
            .as_array()
            .unwrap_or_else(|| panic!("{:#}", pre[0]))
            .iter()
            .map(|v| v.as_str().unwrap_or_default().to_string())
            .collect();
        assert!(offered.contains(&format!("{good:05}")), "{offered:?}");
        if reseen {
            assert!(!again.is_empty(), "{:#}", pre[0]);
            assert!(
                again
                    .iter()
                    .all(|i| offered.contains(i) && showing.contains(i)),
                "offered again {again:?}, frames showing the class {showing:?}"
            );
        } else {
            assert_eq!(offered, vec![format!("{good:05}")]);
            assert!(again.is_empty(), "{:#}", pre[0]);
        }
    }
}
