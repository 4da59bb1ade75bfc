//! The set-of-marks path of the default install (a class no detector knows): the marks
//! offered and chosen, "no region is the target" followed by the VLM's own box, and the
//! ensemble views' boxes from their own candidates.

use crate::agent_fixture::*;
use crate::agent_paths::{assert_jpeg, prompts, QUERY};
use crate::fake_vlm::{last_message, text_of, Reply};
use grounder::vlm::prompts::markers;

/// The default configuration: the closed-vocabulary detector cannot see a whiteboard, so
/// the chosen image's class-agnostic candidates (found from the scan at indexing) are drawn
/// as numbered marks and the VLM picks one; the job ends with a box from the marks path.
#[tokio::test]
async fn a_class_no_detector_knows_is_grounded_through_set_of_marks() {
    let f = Fixture::start_with_candidates(vec![], 5_000, "centernet").await;
    let job = f.run_whiteboard_mark_0().await;
    assert_eq!(job["result"]["box_source"], "marks", "{:#}", job["result"]);
    let cands = steps(&job, "candidates");
    assert_eq!(cands.len(), 1, "{job:#}");
    let out = &cands[0]["outputs"];
    assert_eq!(out["from"], "index", "cached at indexing: {out:#}");
    let listed = out["candidates"].as_array().cloned().unwrap_or_default();
    assert!(!listed.is_empty(), "{out:#}");
    let marks = steps(&job, "mark_selection");
    assert_eq!(marks.len(), 1, "{job:#}");
    let url = marks[0]["inputs"]["annotated"].as_str().unwrap_or_default();
    assert!(url.contains("marks_00000_0.jpg"), "{url}");
    assert_jpeg(&f, url).await;
    let chosen = &marks[0]["outputs"]["box"];
    assert_eq!(chosen, &listed[0]["box"], "the box of mark 0");
    // The VLM saw the marks prompt with the regions listed.
    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 3, "analysis, image, mark");
    let text = reqs[2]["messages"]
        .as_array()
        .and_then(|m| m.last())
        .map(|m| m.to_string())
        .unwrap_or_default();
    assert!(
        text.contains("Task: mark selection") && text.contains("ID 0: box"),
        "{text}"
    );
    assert!(steps(&job, "segmentation").len() == 1, "{job:#}");
    assert_trace_clean(&job);
}

/// The ensemble views of a marks job take their boxes from their own cached candidates (the
/// region holding the reprojected object), not only from the reprojected points; with
/// `in_views` off they do not, and with `in_views_partial_only` (the default) only when
/// the chosen view's mask shows a part of the object (the trace's `anchor_partial`, or
/// `anchor_face_only` for a solid object).
#[tokio::test]
async fn ensemble_views_take_the_candidate_that_holds_the_object() {
    for (in_views, partial_only) in [(true, false), (false, false), (true, true)] {
        let f = Fixture::start_with_config(5_000, "centernet", |c| {
            c.agent.candidates.enabled = true;
            c.agent.candidates.in_views = in_views;
            c.agent.candidates.in_views_partial_only = partial_only;
        })
        .await;
        let job = f.run_whiteboard_mark_0().await;
        let proj = steps(&job, "projection");
        let views = proj[0]["outputs"]["views"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        assert!(!views.is_empty(), "{:#}", proj[0]);
        let mut from_candidates = 0;
        // The whole scene's candidates in one read equal the per-frame reads.
        let all = f
            .store
            .scene_candidates(&f.scene_id, &f.candidates_key)
            .await
            .unwrap();
        assert!(!all.is_empty());
        for (idx, list) in &all {
            let one = f
                .store
                .frame_candidates(&f.scene_id, &f.candidates_key, *idx)
                .await
                .unwrap();
            assert_eq!(one.as_ref(), Some(list), "frame {idx}");
        }
        for v in &views {
            let idx: usize = v["image_id"].as_str().unwrap().parse().unwrap();
            let cands = f.candidates(idx).await;
            if v["box_from"] == "candidate" {
                from_candidates += 1;
                let b: Vec<f32> = serde_json::from_value(v["box"].clone()).unwrap();
                assert!(
                    cands.iter().any(|c| c.bbox.to_vec() == b),
                    "view {idx}: {b:?} is not one of its candidates"
                );
            } else {
                assert_eq!(v["box_from"], "footprint", "{v:#}");
                assert_eq!(v["box"], v["footprint"], "{v:#}");
            }
        }
        let out = &proj[0]["outputs"];
        let partial = out["anchor_partial"]["partial"].as_bool();
        assert!(partial.is_some(), "{out:#}");
        // A solid object seen by one face counts as a part too (a whiteboard hangs: never).
        let face = out["anchor_face_only"].as_bool();
        assert_eq!(face, Some(false), "{out:#}");
        let take = in_views && (!partial_only || partial == Some(true) || face == Some(true));
        assert_eq!(out["views_take_candidates"], take, "{out:#}");
        if take {
            assert!(from_candidates > 0, "no view used a candidate: {views:#?}");
        } else {
            assert_eq!(from_candidates, 0, "{views:#?}");
        }
    }
}

/// No marked region outlines the target (an object of the wall's colour flush with it has
/// no region of its own): the VLM says so, is asked for the box itself in the same image,
/// and the job ends with a box from the VLM (`box_fallback`, on by default).
#[tokio::test]
async fn no_mark_outlines_the_target_so_the_vlm_draws_its_box() {
    let f = Fixture::start_with_candidates(vec![], 5_000, "centernet").await;
    f.vlm.script_push(vec![
        analysis("whiteboard"),
        pick_image("00000"),
        Reply::ok(
            serde_json::json!({"reasoning": "the board has no outline", "object_id": null})
                .to_string(),
        ),
        Reply::ok(
            serde_json::json!({"reasoning": "left of the door", "bbox_2d": [2, 2, 30, 30]})
                .to_string(),
        ),
    ]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "succeeded", "{job:#}");
    assert_eq!(
        job["result"]["box_source"], "vlm_box",
        "{:#}",
        job["result"]
    );
    let marks = steps(&job, "mark_selection");
    assert_eq!(marks.len(), 1, "{job:#}");
    assert_eq!(marks[0]["outputs"]["none"], true, "{:#}", marks[0]);
    let boxes = steps(&job, "vlm_box");
    assert_eq!(boxes.len(), 1, "{job:#}");
    assert_eq!(
        boxes[0]["outputs"]["box"],
        serde_json::json!([2.0, 2.0, 30.0, 30.0])
    );
    let seg = steps(&job, "segmentation");
    assert_eq!(seg.len(), 1, "{job:#}");
    assert_eq!(seg[0]["inputs"]["box"], boxes[0]["outputs"]["box"]);
    // The box request followed the marks in the same conversation.
    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 4, "analysis, image, marks, box");
    let text = text_of(last_message(&reqs[3]));
    assert!(text.contains("Task: object box"), "{text}");
    let history = reqs[3]["messages"].to_string();
    assert!(history.contains("Task: mark selection"), "{history}");
    assert_trace_clean(&job);
}

/// The chosen image has no candidate at all (here: every region is below `min_cells`, as a
/// white door flush with a white wall is): the VLM is asked for the box at once instead of
/// being sent to another image, and with `box_fallback` off it is sent on.
#[tokio::test]
async fn an_image_without_any_candidate_gets_its_box_from_the_vlm() {
    for fallback in [true, false] {
        let f = Fixture::start_with_config(5_000, "centernet", |c| {
            c.agent.candidates.enabled = true;
            c.agent.candidates.min_cells = 1_000_000;
            c.agent.candidates.box_fallback = fallback;
        })
        .await;
        assert!(f.candidates(0).await.is_empty(), "frame 0 has candidates");
        f.vlm.script_push(vec![
            analysis("whiteboard"),
            pick_image("00000"),
            Reply::ok(
                serde_json::json!({"reasoning": "left of the door", "bbox_2d": [2, 2, 30, 30]})
                    .to_string(),
            ),
        ]);
        let job = f.run_job(QUERY).await;
        let listed = steps(&job, "candidates");
        assert!(!listed.is_empty(), "{job:#}");
        assert_eq!(listed[0]["outputs"]["candidates"], serde_json::json!([]));
        assert!(steps(&job, "mark_selection").is_empty(), "{job:#}");
        let reqs = f.vlm.requests();
        assert!(reqs.len() >= 3, "{} requests", reqs.len());
        let asked = text_of(last_message(&reqs[2]));
        if fallback {
            assert_eq!(job["status"], "succeeded", "{job:#}");
            assert_eq!(
                job["result"]["box_source"], "vlm_box",
                "{:#}",
                job["result"]
            );
            assert!(asked.contains("Task: object box"), "{asked}");
            let boxes = steps(&job, "vlm_box");
            assert_eq!(boxes.len(), 1, "{job:#}");
            assert_eq!(
                boxes[0]["outputs"]["box"],
                serde_json::json!([2.0, 2.0, 30.0, 30.0])
            );
            assert_trace_clean(&job);
        } else {
            let fb = prompts().feedback_object_not_existing(0, "whiteboard");
            assert_eq!(asked, fb);
            assert!(steps(&job, "vlm_box").is_empty(), "{job:#}");
        }
    }
}

/// With `box_fallback` off, "no region" sends the VLM to another image.
#[tokio::test]
async fn without_the_box_fallback_no_mark_means_not_in_this_image() {
    let f = Fixture::start_with_config(5_000, "centernet", |c| {
        c.agent.candidates.enabled = true;
        c.agent.candidates.box_fallback = false;
    })
    .await;
    f.vlm.script_push(vec![
        analysis("whiteboard"),
        pick_image("00000"),
        Reply::ok(serde_json::json!({"reasoning": "not outlined", "object_id": null}).to_string()),
    ]);
    let job = f.run_job(QUERY).await;
    let reqs = f.vlm.requests();
    assert!(reqs.len() >= 4, "{} requests", reqs.len());
    let fb = prompts().feedback_object_not_existing(0, "whiteboard");
    assert_eq!(text_of(last_message(&reqs[3])), fb);
    assert!(steps(&job, "vlm_box").is_empty(), "{job:#}");
}

/// The first mark of frame 0 that runs off the frame's left or right edge.
async fn edge_mark(f: &Fixture) -> usize {
    let w = grounder::synth::SynthParams::small(SEED).color_size.0 as f32;
    f.candidates(0)
        .await
        .iter()
        .position(|c| c.bbox[0] <= 0.0 || c.bbox[2] >= w)
        .expect("frame 0 has a mark at its edge")
}

/// The chosen view saw a part of the object (its mark runs off the frame's edge) and no
/// ensemble view has a box of its own for it (`in_views` off: every view's box is its
/// footprint): the VLM is asked for the whole object's box in one view (`view_box_views =
/// 1`), with the part outlined (`view_box`). A box holding the part replaces that view's footprint; one that
/// misses the part, or "not in this view", leaves it; with `view_box` off nobody is asked.
#[tokio::test]
async fn a_view_of_the_whole_object_gets_its_box_from_the_vlm_when_the_anchor_saw_a_part() {
    let (w, h) = grounder::synth::SynthParams::small(SEED).color_size;
    let whole = Some([0.0f32, 0.0, w as f32, h as f32]);
    for (answer, on, used) in [
        (whole, true, true),
        (Some([0.0, 0.0, 4.0, 4.0]), true, false),
        (None, true, false),
        (whole, false, false),
    ] {
        let f = Fixture::start_with_config(5_000, "centernet", |c| {
            c.agent.candidates.enabled = true;
            c.agent.candidates.in_views = false;
            c.agent.candidates.view_box = on;
            c.agent.candidates.view_box_views = 1;
        })
        .await;
        let cut = edge_mark(&f).await;
        let reply = serde_json::json!({"reasoning": "the whole board", "bbox_2d": answer});
        f.vlm.script_push(vec![
            analysis("whiteboard"),
            pick_image("00000"),
            pick_object(cut as u32),
            Reply::ok(reply.to_string()),
        ]);
        let job = f.run_job(QUERY).await;
        assert_eq!(job["status"], "succeeded", "{job:#}");
        let proj = &steps(&job, "projection")[0]["outputs"];
        assert_eq!(proj["anchor_partial"]["partial"], true, "{proj:#}");
        let asked = steps(&job, "view_box");
        if !on {
            assert!(asked.is_empty(), "{job:#}");
            assert!(proj["view_box"].is_null(), "{proj:#}");
            assert_eq!(f.vlm.requests().len(), 3, "analysis, image, mark");
            continue;
        }
        assert_eq!(asked.len(), 1, "{job:#}");
        let out = &asked[0]["outputs"];
        assert_eq!(out["used"], used, "{out:#}");
        let view = asked[0]["inputs"]["image_id"].as_str().unwrap_or_default();
        assert_jpeg(&f, asked[0]["inputs"]["image"].as_str().unwrap_or_default()).await;
        // The request names the view, the chosen frame and the part's box.
        let reqs = f.vlm.requests();
        assert_eq!(reqs.len(), 4, "analysis, image, mark, view box");
        let text = text_of(last_message(&reqs[3]));
        assert!(
            text.contains("Task: object box")
                && text.contains(&format!("This is frame {view}"))
                && text.contains("frame 00000"),
            "{text}"
        );
        let views = proj["views"].as_array().cloned().unwrap_or_default();
        let v = views
            .iter()
            .find(|v| v["image_id"] == view)
            .expect("the view asked about is an ensemble view");
        let others_footprint = views
            .iter()
            .filter(|o| o["image_id"] != view)
            .all(|o| o["box_from"] == "footprint" && o["box"] == o["footprint"]);
        assert!(others_footprint, "{views:#?}");
        if used {
            assert_eq!(v["box_from"], "vlm_box", "{v:#}");
            assert_eq!(v["box"], serde_json::json!(answer), "{v:#}");
        } else {
            assert_eq!(v["box_from"], "footprint", "{v:#}");
            assert_eq!(v["box"], v["footprint"], "{v:#}");
        }
        assert_trace_clean(&job);
    }
}

/// With `view_box_views` above 1, the views left with the footprint are asked at the same
/// time (at most that many and no more than the job's VLM budget has left, no view twice,
/// only views whose part does not come within 1 % of the frame's edge), and every answer
/// that holds the part replaces that view's footprint.
/// The shared scene's chosen frame is the first whose mark at the edge leaves two views to
/// ask.
#[tokio::test]
async fn several_views_of_a_partly_seen_object_get_their_boxes_from_the_vlm() {
    let (w, h) = grounder::synth::SynthParams::small(SEED).color_size;
    let whole = serde_json::json!({"reasoning": "the whole board", "bbox_2d": [0.0, 0.0, w as f32, h as f32]});
    // A footprint that may be asked: farther than 1 % of the width from every edge.
    let room = (0.01 * f64::from(w)).ceil();
    let askable = |v: &serde_json::Value| {
        let b: Vec<f64> = v["footprint"]
            .as_array()
            .map(|a| a.iter().filter_map(serde_json::Value::as_f64).collect())
            .unwrap_or_default();
        b.len() == 4
            && b[0]
                .min(b[1])
                .min(f64::from(w) - b[2])
                .min(f64::from(h) - b[3])
                > room
    };
    // (views that may be asked, the job's VLM call budget): the third run's budget covers
    // the three calls before the projection and one view, so asking stops after one.
    for (most, calls) in [(1usize, 16u32), (2, 16), (2, 4)] {
        let asks = most.min(calls as usize - 3);
        let f = Fixture::start_with_config(5_000, "centernet", |c| {
            c.agent.candidates.enabled = true;
            c.agent.candidates.in_views = false;
            c.agent.candidates.view_box_views = most;
            c.agent.max_vlm_calls = calls;
        })
        .await;
        let mut found = false;
        'frames: for frame in 0..8usize {
            let cands = f.candidates(frame).await;
            for (cut, _) in cands
                .iter()
                .enumerate()
                .filter(|(_, c)| c.bbox[0] <= 0.0 || c.bbox[2] >= w as f32)
            {
                let before = f.vlm.requests().len();
                let mut script = vec![
                    analysis("whiteboard"),
                    pick_image(format!("{frame:05}")),
                    pick_object(cut as u32),
                ];
                // Slow enough answers that views asked one after another never overlap.
                script.extend((0..asks).map(|_| Reply::ok(whole.to_string()).delayed(400)));
                f.vlm.script_push(script);
                f.vlm.take_max_in_flight();
                let job = f.run_job(QUERY).await;
                let at_once = f.vlm.take_max_in_flight();
                while f.vlm.remaining() > 0 {
                    f.vlm.script_pop();
                }
                if job["status"] != "succeeded" {
                    continue;
                }
                let proj = &steps(&job, "projection")[0]["outputs"];
                let views = proj["views"].as_array().cloned().unwrap_or_default();
                let n_askable = views.iter().filter(|v| askable(v)).count();
                if proj["anchor_partial"]["partial"] != true || n_askable < 2 {
                    continue;
                }
                let asked = steps(&job, "view_box");
                let ids: Vec<String> = asked
                    .iter()
                    .map(|s| {
                        s["inputs"]["image_id"]
                            .as_str()
                            .unwrap_or_default()
                            .to_string()
                    })
                    .collect();
                assert_eq!(ids.len(), asks, "{ids:?} {proj:#}");
                let unique: std::collections::BTreeSet<&String> = ids.iter().collect();
                assert_eq!(unique.len(), ids.len(), "no view asked twice: {ids:?}");
                assert_eq!(f.vlm.requests().len() - before, 3 + asks);
                assert_eq!(at_once, asks.max(1), "the views are asked at the same time");
                // Calls that overlap count once in the job's VLM time.
                let mut latencies = std::collections::BTreeMap::new();
                call_latencies(&job["trace"], &mut latencies);
                let summed: f64 = latencies.values().sum();
                let vlm_ms = steps(&job, "summary")[0]["outputs"]["vlm_ms"]
                    .as_f64()
                    .unwrap_or_default();
                if asks >= 2 {
                    assert!(vlm_ms < summed - 200.0, "{vlm_ms} of {latencies:?}");
                }
                let stopped = proj["view_box"]["stopped"].as_str().unwrap_or_default();
                assert_eq!(stopped.contains("budget"), asks < most, "{proj:#}");
                let listed: Vec<&str> = proj["view_box"]["views"]
                    .as_array()
                    .map(|a| a.iter().filter_map(|v| v["image_id"].as_str()).collect())
                    .unwrap_or_default();
                assert_eq!(listed, ids, "{proj:#}");
                for v in &views {
                    let was_asked = ids.iter().any(|id| v["image_id"] == id.as_str());
                    let want = if was_asked { "vlm_box" } else { "footprint" };
                    assert_eq!(v["box_from"], want, "{v:#}");
                    if was_asked {
                        assert!(askable(v), "a view at the edge was asked: {v:#}");
                    }
                }
                assert_trace_clean(&job);
                found = true;
                break 'frames;
            }
        }
        assert!(found, "no frame's mark at the edge left two views to ask");
    }
}

/// Each VLM reply's `latency_ms` anywhere in `v`, by its `vlm_call` number.
fn call_latencies(v: &serde_json::Value, out: &mut std::collections::BTreeMap<u64, f64>) {
    match v {
        serde_json::Value::Object(m) => {
            if let (Some(n), Some(ms)) = (
                m.get("vlm_call").and_then(serde_json::Value::as_u64),
                m.get("latency_ms").and_then(serde_json::Value::as_f64),
            ) {
                out.insert(n, ms);
            }
            m.values().for_each(|x| call_latencies(x, out));
        }
        serde_json::Value::Array(a) => a.iter().for_each(|x| call_latencies(x, out)),
        _ => {}
    }
}

/// The VLM's box lies where the sensor read no depth (`unmeasured_retry`, on by default):
/// it is told so once, with the frames that measured what its box shows
/// (`nearer_frames`, on by default; without it the plain feedback), and chooses another
/// frame, whose box is used. With the check off the box is taken as it is and nobody is
/// told. (A lamp stands in the room: for an object flat against a wall, pixels whose ray
/// leaves the room beyond the sensor's range would count as read.)
#[tokio::test]
async fn a_box_without_depth_sends_the_vlm_to_a_nearer_frame_once() {
    let (w, h) = grounder::synth::SynthParams::small(SEED).color_size;
    let left = [2.0, 2.0, (w / 2 - 40) as f32, (h - 2) as f32];
    for (on, nearer) in [(true, true), (true, false), (false, true)] {
        let f = Fixture::start_with_tar(
            crate::agent_fixture::tar_without_depth_on_the_left_of_frame_0(),
            5_000,
            "centernet",
            |c| {
                c.agent.candidates.enabled = true;
                c.agent.candidates.unmeasured_retry = on;
                c.agent.candidates.nearer_frames = nearer;
            },
        )
        .await;
        let job = run_left_box_then_frame_1(&f, left).await;
        let reqs = f.vlm.requests();
        let sent: Vec<String> = reqs.iter().map(|r| text_of(last_message(r))).collect();
        let plain = prompts().feedback_no_depth(0, "lamp");
        if !on {
            // No second image selection (the box, with no depth, may still ask for a view's
            // box before the job ends).
            assert!(
                !sent.iter().any(|t| t.starts_with(markers::NO_DEPTH)),
                "{sent:#?}"
            );
            let selections = sent
                .iter()
                .filter(|t| t.starts_with("Task: image selection"));
            assert_eq!(selections.count(), 1, "{sent:#?}");
            assert!(!steps(&job, "candidates").is_empty(), "{job:#}");
            continue;
        }
        assert_eq!(job["status"], "succeeded", "{job:#}");
        assert_eq!(reqs.len(), 6, "{sent:#?}");
        assert_eq!(job["result"]["image_id"], "00001", "{:#}", job["result"]);
        // The image selection that followed records the feedback, why, and the frames
        // named in it.
        let sel = steps(&job, "image_selection");
        let rec = sel
            .iter()
            .flat_map(|s| s["outputs"]["vlm"].as_array().into_iter().flatten())
            .find(|x| x["feedback"] == sent[4].as_str())
            .unwrap_or_else(|| panic!("no feedback record: {sel:#?}"));
        assert!(
            rec["invalid"]
                .as_str()
                .is_some_and(|w| w.contains("depth pixels")),
            "{rec:#}"
        );
        let named: Vec<u32> = rec["nearer_frames"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|s| s["image_id"].as_str()?.parse().ok())
            .collect();
        if nearer {
            // The other frames of the walk see the left of frame 0 within range.
            assert!(!named.is_empty() && !named.contains(&0), "{rec:#}");
            assert_eq!(
                sent[4],
                prompts().feedback_no_depth_nearer(0, "lamp", &named)
            );
        } else {
            assert!(named.is_empty(), "{rec:#}");
            assert_eq!(sent[4], plain);
        }
        assert_trace_clean(&job);
    }
}

/// A view's candidate is checked against the chosen view before it is used
/// (`in_views_check`): segmented, then held to the fusion's chamfer filter. With a
/// threshold no cloud meets, every candidate view gives way to its footprint, and the trace
/// lists each check; with a threshold every cloud meets, the candidates stay; with the check
/// off, the candidates are used as found (and the fusion drops those views).
#[tokio::test]
async fn a_views_candidate_that_disagrees_with_the_chosen_view_gives_way_to_its_footprint() {
    for (threshold, check) in [(1e-12, true), (1e3, true), (1e-12, false)] {
        let f = Fixture::start_with_config(5_000, "centernet", |c| {
            c.agent.candidates.enabled = true;
            c.agent.candidates.view_box = false;
            c.agent.candidates.in_views_check = check;
            c.agent.geometry.chamfer_threshold = threshold;
            // The chosen view saw a part: its one-sided test takes the same threshold, so
            // the filter passes every view or none; and no dropped view is kept again for
            // agreeing with the chosen frame (`consensus.complement_agree`).
            c.agent.geometry.chamfer_cover_threshold = threshold;
            c.agent.geometry.consensus.complement_agree = 0.0;
        })
        .await;
        // A mark at the frame's edge: the chosen view saw a part, so the views take
        // candidates.
        let cut = edge_mark(&f).await;
        f.vlm.script_push(vec![
            analysis("whiteboard"),
            pick_image("00000"),
            pick_object(cut as u32),
        ]);
        let job = f.run_job(QUERY).await;
        assert_eq!(job["status"], "succeeded", "{job:#}");
        let proj = &steps(&job, "projection")[0]["outputs"];
        assert_eq!(proj["views_take_candidates"], true, "{proj:#}");
        let views = proj["views"].as_array().cloned().unwrap_or_default();
        let view = |id: &serde_json::Value| {
            views
                .iter()
                .find(|v| &v["image_id"] == id)
                .cloned()
                .expect("a checked view is an ensemble view")
        };
        if !check {
            assert!(proj["candidate_check"].is_null(), "{proj:#}");
            let taken: Vec<_> = views
                .iter()
                .filter(|v| v["box_from"] == "candidate")
                .collect();
            assert!(!taken.is_empty(), "the views take candidates: {views:#?}");
            assert!(taken.iter().all(|v| v["kept"] == false), "{views:#?}");
            continue;
        }
        let checked = proj["candidate_check"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        assert!(!checked.is_empty(), "{proj:#}");
        let passes = threshold > 1.0;
        for c in &checked {
            assert_eq!(c["kept"], passes, "{c:#}");
            let v = view(&c["image_id"]);
            if passes {
                // The candidate stays, and the fusion keeps the view.
                assert_eq!(v["box_from"], "candidate", "{c:#} {v:#}");
                assert_eq!(v["box"], c["box"], "{c:#} {v:#}");
                assert_eq!(v["kept"], true, "{c:#} {v:#}");
            } else {
                assert_eq!(v["box_from"], "footprint", "{c:#} {v:#}");
                assert_eq!(v["box"], v["footprint"], "{c:#} {v:#}");
            }
        }
        assert_trace_clean(&job);
    }
}
