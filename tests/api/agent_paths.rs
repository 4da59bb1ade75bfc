//! Each feedback path: the exact feedback text the agent sent, the final job state and the
//! trace steps.

use crate::agent_fixture::*;
use crate::fake_vlm::{images_in, last_message, text_of, Reply};
use grounder::vlm::prompts::{InstanceInput, Prompts, ReplyKind};
use serde_json::Value;
use std::time::{Duration, Instant};

pub(crate) const QUERY: &str = "the object the test is about";

pub(crate) fn prompts() -> Prompts {
    Prompts::embedded()
}

/// GET an artifact URL and check it is a JPEG.
pub(crate) async fn assert_jpeg(f: &Fixture, url: &str) {
    let r = f.app.client.get(f.app.url(url)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200, "{url}");
    assert_eq!(r.headers()["content-type"], "image/jpeg", "{url}");
    let b = r.bytes().await.unwrap();
    assert!(
        b.len() > 100 && b[..3] == [0xFF, 0xD8, 0xFF],
        "{url} is not a JPEG"
    );
    image::load_from_memory_with_format(&b, image::ImageFormat::Jpeg).expect("decodable JPEG");
}

/// The `vlm` exchanges recorded in a step's outputs.
fn exchanges(step: &Value) -> &Vec<Value> {
    step["outputs"]["vlm"].as_array().expect("vlm exchanges")
}

#[tokio::test]
async fn unparsable_then_invalid_image_then_success() {
    let f = Fixture::start(vec![], 5_000).await;
    let (class, frame) = class_with_single(&f);
    f.vlm.script_push(vec![
        analysis(&class),
        Reply::ok("I would say the third picture."),
        pick_image("00999"),
        pick_image(frame as u32),
    ]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "succeeded", "{job:#}");
    let offered = f.offered(&class);
    assert!(offered.contains(&(frame as u32)));

    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 4, "QA + 3 grounding turns");
    assert_eq!(f.vlm.remaining(), 0);
    // The first grounding turn: system + user text with the grids.
    let first = &reqs[1]["messages"];
    assert_eq!(first.as_array().unwrap().len(), 2);
    assert!(images_in(&first[1]) >= 1);
    let fb1 = prompts().feedback_unparsable(ReplyKind::Grounding);
    assert_eq!(text_of(last_message(&reqs[2])), fb1);
    let hist = reqs[2]["messages"].as_array().unwrap();
    assert_eq!(
        text_of(&hist[hist.len() - 2]),
        "I would say the third picture.",
        "the bad reply stays in the history"
    );
    let fb2 = prompts().feedback_image_invalid("00999", &offered);
    assert_eq!(text_of(last_message(&reqs[3])), fb2);
    // Earlier failed rounds are trimmed: system, grids, the last reply, its feedback.
    let hist = reqs[3]["messages"].as_array().unwrap();
    assert_eq!(hist.len(), 4, "{hist:#?}");
    assert!(
        hist.iter()
            .all(|m| text_of(m) != "I would say the third picture." && text_of(m) != fb1),
        "the first failed round is left out"
    );

    let names = step_names(&job);
    for s in [
        "query_analysis",
        "preselection",
        "stitching",
        "image_selection",
        "detection",
        "instance_selection",
        "segmentation",
        "projection",
        "summary",
    ] {
        assert!(names.iter().any(|n| n == s), "missing step {s}: {names:?}");
    }
    let sel = steps(&job, "image_selection");
    assert_eq!(sel.len(), 1);
    let ex = exchanges(sel[0]);
    assert_eq!(ex.len(), 3);
    assert_eq!(ex[0]["feedback"], fb1.as_str());
    assert_eq!(ex[1]["feedback"], fb2.as_str());
    assert!(ex[2].get("feedback").is_none());
    assert_eq!(sel[0]["outputs"]["image_id"], format!("{frame:05}"));
    let inst = steps(&job, "instance_selection");
    assert_eq!(inst[0]["outputs"]["asked_vlm"], false);
    // The synthetic scene's objects are boxes: their box gets no round back, and the
    // trace says why.
    let rb = &steps(&job, "projection")[0]["outputs"]["round_back"];
    assert_eq!(rb["applied"], false, "{rb}");
    assert!(rb["skipped"].is_string() && rb["width"].is_number(), "{rb}");
    let summary = &steps(&job, "summary")[0]["outputs"];
    assert_eq!(summary["feedback_rounds"], 2);
    assert_eq!(summary["vlm_calls"], 4);
    assert!(summary["non_vlm_ms"].as_f64().unwrap() > 0.0);
    assert_eq!(
        job["result"]["image_id"],
        format!("{frame:05}"),
        "{:#}",
        job["result"]
    );
    assert!(job["result"]["box"]["size"]
        .as_array()
        .unwrap()
        .iter()
        .all(|v| v.as_f64().unwrap() > 0.0));
    assert_trace_clean(&job);
    let grids = steps(&job, "stitching")[0]["outputs"]["grids"]
        .as_array()
        .unwrap()
        .clone();
    assert!(grids[0]["url"]
        .as_str()
        .unwrap()
        .ends_with("/artifacts/grid_0.jpg"));
    for g in &grids {
        assert_jpeg(&f, g["url"].as_str().unwrap()).await;
    }
    // 320x240 frames in 2048-pixel grids are drawn larger than their previews.
    assert_eq!(steps(&job, "stitching")[0]["outputs"]["from_previews"], 0);
}

#[tokio::test]
async fn grids_drawn_at_half_size_or_less_read_the_previews_indexing_stored() {
    // A 256-pixel side limit draws every 320x240 frame at about a quarter of its size.
    let f = Fixture::start_with(vec![], 5_000, "oracle", |c| c.max_image_side = 256).await;
    let colour = f
        .app
        .data_dir
        .join("scenes")
        .join(&f.scene_id)
        .join("color");
    let (mut previews, mut frames) = (0, 0);
    for e in std::fs::read_dir(&colour).unwrap() {
        let p = e.unwrap().path();
        if p.to_string_lossy().ends_with(".preview.jpg") {
            let img = image::open(&p).unwrap();
            assert_eq!((img.width(), img.height()), (160, 120), "{}", p.display());
            previews += 1;
        } else {
            frames += 1;
        }
    }
    assert!(frames > 0);
    assert_eq!(
        previews, frames,
        "one preview per frame (the fixture scene has no unusable frame)"
    );

    let (class, frame) = class_with_single(&f);
    f.vlm
        .script_push(vec![analysis(&class), pick_image(frame as u32)]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "succeeded", "{job:#}");
    let st = &steps(&job, "stitching")[0]["outputs"];
    assert_eq!(st["from_previews"], f.offered(&class).len(), "{st:#}");
    for g in st["grids"].as_array().unwrap() {
        assert_eq!(
            g["height"]
                .as_u64()
                .unwrap()
                .max(g["width"].as_u64().unwrap()),
            256,
            "{g}"
        );
        assert_jpeg(&f, g["url"].as_str().unwrap()).await;
    }
    // Detection and projection still ran on the full frame: the box is in its pixels.
    let det = &steps(&job, "detection")[0]["outputs"]["detections"][0]["box"];
    let want = f.dets[&frame]
        .iter()
        .find(|d| d.label == class)
        .unwrap()
        .bbox;
    let got: Vec<f32> = det
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap() as f32)
        .collect();
    assert_eq!(got, want.to_vec());
}

#[tokio::test]
async fn image_without_the_target_gets_object_not_existing() {
    let f = Fixture::start(vec![], 5_000).await;
    let (class, good) = class_with_single(&f);
    // A frame without the class; its cached detections get a false positive of the class,
    // so pre-selection offers it while the fresh detection finds nothing.
    let empty = *f
        .frames_with(&class, 0)
        .first()
        .expect("a frame without the class");
    let mut dets = f.dets[&empty].clone();
    dets.push(grounder::vision::Detection {
        label: class.clone(),
        score: 0.9,
        bbox: [10.0, 10.0, 60.0, 60.0],
    });
    f.store
        .put_detections(&f.scene_id, "oracle", empty, &dets)
        .await
        .unwrap();
    f.vlm.script_push(vec![
        analysis(&class),
        pick_image(empty as u32),
        pick_image(good as u32),
    ]);

    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "succeeded", "{job:#}");
    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 3);
    let fb = prompts().feedback_object_not_existing(empty as u32, &class);
    assert_eq!(text_of(last_message(&reqs[2])), fb);
    let det = steps(&job, "detection");
    assert_eq!(det.len(), 2);
    assert_eq!(det[0]["outputs"]["image_id"], format!("{empty:05}"));
    assert_eq!(det[0]["outputs"]["detections"].as_array().unwrap().len(), 0);
    assert_eq!(det[1]["outputs"]["detections"].as_array().unwrap().len(), 1);
    let sel = steps(&job, "image_selection");
    assert_eq!(sel.len(), 2, "one per chosen image");
    let ex = exchanges(sel[1]);
    assert_eq!(
        ex[0]["feedback"],
        fb.as_str(),
        "the trace records the feedback: {:#}",
        sel[1]
    );
    assert_eq!(
        ex[1]["sent"][0]["text"],
        fb.as_str(),
        "and the message sent with it: {:#}",
        sel[1]
    );
    assert_eq!(job["result"]["image_id"], format!("{good:05}"));
    assert_eq!(steps(&job, "summary")[0]["outputs"]["feedback_rounds"], 1);
    assert_trace_clean(&job);
}

#[tokio::test]
async fn several_candidates_go_through_instance_selection_with_feedback() {
    let f = Fixture::start(vec![], 5_000).await;
    let (class, frame) = class_with_several(&f);
    f.vlm.script_push(vec![
        analysis(&class),
        pick_image(frame as u32),
        pick_object(9),
        Reply::ok("{\"object_id\": "),
        pick_object(1),
    ]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "succeeded", "{job:#}");
    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 5);
    let det = steps(&job, "detection");
    let cands: Vec<[f32; 4]> = det[0]["outputs"]["detections"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| serde_json::from_value(d["box"].clone()).unwrap())
        .collect();
    assert!(cands.len() >= 2);
    let ask = last_message(&reqs[2]);
    assert_eq!(images_in(ask), 1, "the annotated frame is sent");
    let expected = prompts().instance_selection(&InstanceInput {
        query: QUERY,
        target_class: &class,
        image_id: frame as u32,
        width: 320,
        height: 240,
        candidates: &cands,
    });
    assert_eq!(text_of(ask), expected);
    let fb1 = prompts().feedback_object_id_invalid("9", cands.len());
    assert_eq!(text_of(last_message(&reqs[3])), fb1);
    let fb2 = prompts().feedback_unparsable(ReplyKind::Instance);
    assert_eq!(text_of(last_message(&reqs[4])), fb2);

    let inst = steps(&job, "instance_selection");
    assert_eq!(inst.len(), 1);
    let out = &inst[0]["outputs"];
    assert_eq!(
        (out["index"].as_u64(), &out["asked_vlm"]),
        (Some(1), &Value::Bool(true))
    );
    let chosen: [f32; 4] = serde_json::from_value(out["box"].clone()).unwrap();
    assert_eq!(chosen, cands[1]);
    let ex = exchanges(inst[0]);
    assert_eq!(
        (ex[0]["feedback"].as_str(), ex[1]["feedback"].as_str()),
        (Some(fb1.as_str()), Some(fb2.as_str()))
    );
    let url = inst[0]["inputs"]["annotated"].as_str().unwrap();
    assert!(url.contains(&format!("instances_{frame:05}_")));
    assert_eq!(
        ex[0]["sent"][0]["images"][0], url,
        "trace names the image by URL"
    );
    assert_jpeg(&f, url).await;
    assert_eq!(steps(&job, "summary")[0]["outputs"]["feedback_rounds"], 2);
    let dbox: [f32; 4] = serde_json::from_value(job["result"]["detection_box"].clone()).unwrap();
    assert_eq!(dbox, cands[1]);
    assert_trace_clean(&job);
}

#[tokio::test]
async fn rate_limit_and_timeout_are_retried_transparently() {
    let f = Fixture::start(vec![], 400).await;
    let (class, frame) = class_with_single(&f);
    f.vlm.script_push(vec![
        Reply::status(429, Some("0")),
        analysis(&class),
        pick_image(frame as u32).delayed(1_500),
        pick_image(frame as u32),
    ]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "succeeded", "{job:#}");
    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 4);
    assert_eq!(reqs[0], reqs[1], "429: the same request is sent again");
    assert_eq!(reqs[2], reqs[3], "timeout: the same request is sent again");
    assert_eq!(
        reqs[3]["messages"].as_array().unwrap().len(),
        2,
        "no feedback turn for transport errors"
    );
    let qa = steps(&job, "query_analysis");
    assert_eq!(exchanges(qa[0])[0]["reply"]["attempts"], 2);
    let sel = steps(&job, "image_selection");
    assert_eq!(exchanges(sel[0])[0]["reply"]["attempts"], 2);
    let summary = &steps(&job, "summary")[0]["outputs"];
    assert_eq!(
        (
            summary["vlm_calls"].as_u64(),
            summary["feedback_rounds"].as_u64()
        ),
        (Some(4), Some(0))
    );
    assert_trace_clean(&job);
}

#[tokio::test]
async fn retry_limit_reached_fails_with_the_reason() {
    let f = Fixture::start(vec![], 5_000).await;
    let (class, _) = class_with_single(&f);
    let offered = f.offered(&class);
    f.vlm.script_push(vec![
        analysis(&class),
        pick_image("00999"),
        pick_image("00998"),
        pick_image("00997"),
        pick_image("00996"),
        pick_image(offered[0]),
    ]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "failed", "{job:#}");
    assert_eq!(job["error"]["code"], "retry_limit_reached");
    let msg = job["error"]["detail"]
        .as_str()
        .unwrap_or_else(|| panic!("{:#}", job["error"]));
    assert!(
        msg.contains("3 feedback rounds") && msg.contains("invalid image id"),
        "{msg}"
    );
    let reqs = f.vlm.requests();
    assert_eq!(
        reqs.len(),
        5,
        "QA + the first answer + 3 feedback rounds, then stop"
    );
    assert_eq!(f.vlm.remaining(), 1);
    for (k, bad) in ["00999", "00998", "00997"].iter().enumerate() {
        assert_eq!(
            text_of(last_message(&reqs[k + 2])),
            prompts().feedback_image_invalid(bad, &offered)
        );
    }
    let sel = steps(&job, "image_selection");
    assert_eq!(sel.len(), 1);
    assert_eq!(sel[0]["outputs"]["failed"], true);
    assert_eq!(sel[0]["outputs"]["reason"], "retry_limit_reached");
    assert_eq!(exchanges(sel[0]).len(), 4);
    let names = step_names(&job);
    assert!(
        !names.iter().any(|n| n == "segmentation" || n == "summary"),
        "{names:?}"
    );
    assert_trace_clean(&job);
}

#[tokio::test]
async fn cancel_during_a_vlm_call_stops_the_job() {
    let f = Fixture::start(vec![], 20_000).await;
    let (class, frame) = class_with_single(&f);
    // The grounding call hangs for 4 s; the job is cancelled while it is in flight.
    f.vlm.script_push(vec![
        analysis(&class),
        pick_image(frame as u32).delayed(4_000),
        pick_image(frame as u32),
        pick_image(frame as u32),
    ]);
    let id = f.submit(QUERY).await;
    let t = Instant::now();
    while f.vlm.requests().len() < 2 {
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "grounding call never arrived"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let r = f
        .app
        .client
        .post(f.app.url(&format!("/v1/jobs/{id}/cancel")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let cancelled_at = Instant::now();
    let job = f.app.wait_job(&id, Duration::from_secs(10)).await;
    assert_eq!(job["status"], "canceled", "{job:#}");
    // The single worker is free again long before the hanging call would have returned:
    // the next job (query analysis cached) runs its grounding call at once.
    let next = f.run_job(QUERY).await;
    assert_eq!(next["status"], "succeeded", "{next:#}");
    assert!(
        cancelled_at.elapsed() < Duration::from_millis(3_500),
        "the worker waited for the cancelled call: {:?}",
        cancelled_at.elapsed()
    );
    tokio::time::sleep(Duration::from_millis(300)).await;
    let reqs = f.vlm.requests();
    assert_eq!(
        reqs.len(),
        3,
        "no VLM call of the cancelled job after the one in flight"
    );
    assert_eq!(f.vlm.remaining(), 1);
    let (_, job) = f.app.get_json(&format!("/v1/jobs/{id}")).await;
    let names = step_names(&job);
    assert!(!names.iter().any(|n| n == "summary"), "{names:?}");
    // The step the cancellation interrupted is recorded as failed with the reason.
    for s in steps(&job, "image_selection") {
        assert_eq!(s["outputs"]["failed"], true, "{s:#}");
        assert_eq!(s["outputs"]["reason"], "canceled", "{s:#}");
    }
    assert_eq!(steps(&next, "query_analysis")[0]["outputs"]["cached"], true);
}

#[tokio::test]
async fn a_class_no_frame_shows_falls_back_to_evenly_sampled_frames() {
    let f = Fixture::start(vec![], 5_000).await;
    // The oracle detector is open-vocabulary, but no cached detection is a "unicorn".
    // (A closed-vocabulary detector takes the sibling branch, "detector cannot see this
    // class", with the same sampling; CenterNet's mapping is tested in vision_centernet.)
    f.vlm.script_push(vec![
        analysis("unicorn"),
        pick_image("00000"),
        pick_image("00000"),
        pick_image("00000"),
        pick_image("00000"),
    ]);
    let job = f.run_job(QUERY).await;
    assert!(
        job["status"] == "failed" || job["status"] == "succeeded",
        "{job:#}"
    );
    let pre = steps(&job, "preselection");
    assert_eq!(pre.len(), 1, "{job:#}");
    let out = &pre[0]["outputs"];
    assert_eq!(out["detector_class"], "unicorn", "{out:#}");
    let why = out["fallback"].as_str().unwrap_or_default();
    assert!(
        why.starts_with("no frame has a \"unicorn\" detection"),
        "{why}"
    );
    // Evenly sampled usable frames: distinct, in order, at most `fallback_frames` of them.
    let usable = pre[0]["inputs"]["usable_frames"].as_u64().unwrap_or(0) as usize;
    let ids: Vec<u32> = out["image_ids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().parse().unwrap())
        .collect();
    let want = usable.min(grounder::agent::AgentParams::default().fallback_frames);
    assert_eq!(ids.len(), want, "{out:#}");
    assert!(want > 0 && ids.windows(2).all(|w| w[0] < w[1]), "{ids:?}");
    // Those frames reached the VLM as grids.
    let reqs = f.vlm.requests();
    assert!(
        reqs.len() >= 2,
        "query analysis and at least one grounding turn"
    );
    assert!(images_in(&reqs[1]["messages"][1]) >= 1);
}

#[tokio::test]
async fn a_class_the_closed_vocabulary_detector_cannot_see_falls_back_and_fails_by_name() {
    // The real CenterNet (COCO-80) indexes the scene; a whiteboard has no COCO class.
    let f = Fixture::start_with_detector(vec![], 5_000, "centernet").await;
    let coco: Vec<String> =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/models/coco80.txt"))
            .unwrap()
            .lines()
            .map(str::to_string)
            .collect();
    assert_eq!(coco.len(), 80);
    assert!(grounder::vision::synonyms::map_to_vocabulary("whiteboard", &coco).is_none());
    let (_, scene) = f.app.get_json(&format!("/v1/scenes/{}", f.scene_id)).await;
    assert_eq!(scene["index"]["detector"], "centernet", "{scene:#}");
    assert!(
        scene["index"]["total"].as_i64().unwrap_or(0) > 0
            && scene["index"]["done"] == scene["index"]["total"],
        "{scene:#}"
    );
    f.vlm
        .script_push(vec![analysis("whiteboard"), pick_image("00000")]);
    let job = f.run_job(QUERY).await;
    // Pre-selection: no detector class, evenly sampled usable frames, said in the trace.
    let pre = steps(&job, "preselection");
    assert_eq!(pre.len(), 1, "{job:#}");
    let out = &pre[0]["outputs"];
    assert!(out["detector_class"].is_null(), "{out:#}");
    let why = out["fallback"].as_str().unwrap_or_default();
    assert_eq!(why, "detector cannot see this class: \"whiteboard\"");
    let usable = pre[0]["inputs"]["usable_frames"].as_u64().unwrap_or(0) as usize;
    let ids: Vec<u32> = out["image_ids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().parse().unwrap())
        .collect();
    let want = usable.min(grounder::agent::AgentParams::default().fallback_frames);
    assert!(want > 0 && ids.len() == want, "{ids:?} of {usable} usable");
    assert!(ids.windows(2).all(|w| w[0] < w[1]), "{ids:?}");
    // The frames reached the VLM; after the VLM picks an image no box can be proposed
    // there, so the job ends with a named reason instead of guessing.
    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 2, "query analysis and one grounding turn");
    assert!(images_in(&reqs[1]["messages"][1]) >= 1);
    assert_eq!(job["status"], "failed", "{job:#}");
    assert_eq!(
        job["error"]["code"], "detector_cannot_see_class",
        "{:#}",
        job["error"]
    );
    assert!(job["error"]["detail"]
        .as_str()
        .unwrap_or_default()
        .contains("whiteboard"));
    assert!(!step_names(&job)
        .iter()
        .any(|n| n == "detection" || n == "segmentation"));
    assert_trace_clean(&job);
}
