//! How VLM endpoint errors end a job: each kind by its own code, not retried when a retry
//! cannot help, and a failed job's trace holding every step it reached with every
//! exchange (the failed call included).

use crate::agent_fixture::*;
use crate::fake_vlm::{text_of, Reply};
use serde_json::Value;

const QUERY: &str = "the object the test is about";

/// A scripted error with the server's own message.
fn error(status: u16, message: &str) -> Reply {
    Reply {
        content: message.to_string(),
        ..Reply::status(status, None)
    }
}

/// The `failure` step of a failed job.
fn failure(job: &Value) -> &Value {
    let s = steps(job, "failure");
    assert_eq!(s.len(), 1, "one failure step: {:#}", job["trace"]);
    &s[0]["outputs"]
}

#[tokio::test]
async fn context_overflow_is_rejected_not_retried_and_traced() {
    let f = Fixture::start(vec![], 5_000).await;
    let msg =
        "request (3026 tokens) exceeds the available context size (2048 tokens), try increasing it";
    f.vlm
        .script_push(vec![error(400, msg), Reply::ok("never sent")]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "failed", "{job:#}");
    assert_eq!(job["error"]["code"], "vlm_request_rejected");
    let detail = job["error"]["detail"].as_str().unwrap();
    assert!(
        detail.contains("exceeds the available context size"),
        "{detail}"
    );
    assert_eq!(
        f.vlm.requests().len(),
        1,
        "a rejected request is not retried"
    );
    // The step that was running holds the exchange and its error.
    let qa = steps(&job, "query_analysis");
    assert_eq!(qa.len(), 1, "{:#}", job["trace"]);
    let ex = qa[0]["outputs"]["vlm"].as_array().unwrap();
    assert_eq!(ex.len(), 1);
    assert_eq!(ex[0]["error"]["code"], "vlm_request_rejected");
    assert!(ex[0]["sent"][0]["text"].as_str().unwrap().contains(QUERY));
    let fail = failure(&job);
    assert_eq!(fail["reason"], "vlm_request_rejected");
    assert_eq!(fail["vlm_calls"], 1);
    assert_trace_clean(&job);
}

#[tokio::test]
async fn a_text_only_model_fails_at_the_first_image_and_readyz_says_so() {
    let f = Fixture::start(vec![], 5_000).await;
    let (class, _) = class_with_single(&f);
    let (code, _) = f.app.get_json("/readyz").await;
    assert_eq!(code, 200, "ready before any image was refused");
    f.vlm.script_push(vec![
        analysis(&class),
        error(
            500,
            "image input is not supported - hint: if this is unexpected, you may need to provide the mmproj",
        ),
        Reply::ok("never sent"),
    ]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "failed", "{job:#}");
    assert_eq!(job["error"]["code"], "vlm_cannot_see_images");
    assert_eq!(
        f.vlm.requests().len(),
        2,
        "query analysis, then one image request: a permanent answer is not retried"
    );
    // Every step reached is in the trace, with the model's reply of query analysis.
    let names = step_names(&job);
    for s in [
        "query_analysis",
        "preselection",
        "stitching",
        "image_selection",
        "failure",
    ] {
        assert!(names.iter().any(|n| n == s), "missing {s}: {names:?}");
    }
    let qa = steps(&job, "query_analysis")[0];
    assert!(qa["outputs"]["vlm"][0]["reply"]["text"]
        .as_str()
        .unwrap()
        .contains(&class));
    let fail = failure(&job);
    let ex = fail["vlm"].as_array().unwrap();
    assert_eq!(ex.len(), 1, "the failed image request: {ex:#?}");
    assert_eq!(ex[0]["step"], "image_selection");
    assert_eq!(ex[0]["error"]["code"], "vlm_cannot_see_images");
    assert!(
        !ex[0]["sent"][1]["images"].as_array().unwrap().is_empty(),
        "the images sent are named: {ex:#?}"
    );
    let (code, body) = f.app.get_json("/readyz").await;
    assert_eq!(code, 503, "{body}");
    assert!(
        body["detail"]
            .as_str()
            .unwrap()
            .contains("cannot take images"),
        "{body}"
    );
    assert_trace_clean(&job);
}

#[tokio::test]
async fn a_failed_job_keeps_the_replies_of_the_step_that_was_running() {
    let f = Fixture::start(vec![], 5_000).await;
    let (class, _) = class_with_single(&f);
    f.vlm.script_push(vec![
        analysis(&class),
        Reply::ok("the second one, I think"),
        error(422, "invalid request: messages too long"),
    ]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "failed", "{job:#}");
    assert_eq!(job["error"]["code"], "vlm_request_rejected");
    let sel = steps(&job, "image_selection");
    assert_eq!(sel.len(), 1, "{:#}", job["trace"]);
    assert_eq!(sel[0]["outputs"]["failed"], true);
    let ex = sel[0]["outputs"]["vlm"].as_array().unwrap();
    assert_eq!(ex.len(), 1);
    assert_eq!(ex[0]["reply"]["text"], "the second one, I think");
    let fail = failure(&job);
    let ex = fail["vlm"].as_array().unwrap();
    assert_eq!(ex.len(), 1, "only the call no step holds: {ex:#?}");
    assert!(ex[0]["error"]["message"]
        .as_str()
        .unwrap()
        .contains("messages too long"));
    assert_eq!(fail["vlm_calls"], 3);
}

#[tokio::test]
async fn query_analysis_feedback_sends_only_the_last_round_with_its_cap() {
    let f = Fixture::start(vec![], 5_000).await;
    let (class, frame) = class_with_single(&f);
    f.vlm.script_push(vec![
        Reply::ok("first ramble"),
        Reply::ok("second ramble"),
        analysis(&class),
        pick_image(frame as u32),
    ]);
    let job = f.run_job(QUERY).await;
    assert_eq!(job["status"], "succeeded", "{job:#}");
    let reqs = f.vlm.requests();
    let third = reqs[2]["messages"].as_array().unwrap();
    assert_eq!(third.len(), 3, "prompt, last reply, feedback: {third:#?}");
    assert_eq!(text_of(&third[1]), "second ramble");
    assert_eq!(reqs[0]["max_tokens"], 512, "query analysis cap");
    assert_eq!(reqs[3]["max_tokens"], 1024, "image selection cap");
}

/// The VLM client refuses a request with more images than `max_images_per_request`. A
/// conversation that showed the marks and then asks for a box holds the grids and two more
/// images; at a limit of the grids and one, the marks image is left out of the box request
/// (a line says so) and the job goes on.
#[tokio::test]
async fn a_conversation_over_the_image_limit_leaves_out_its_oldest_images_and_goes_on() {
    let f = Fixture::start_with_config(5_000, "centernet", |c| {
        c.agent.candidates.enabled = true;
        c.agent.image_limit = 1;
        if let Some(v) = c.vlm.as_mut() {
            v.max_images_per_request = 2;
        }
    })
    .await;
    f.vlm.script_push(vec![
        analysis("whiteboard"),
        pick_image("00000"),
        Reply::ok(serde_json::json!({"reasoning": "no outline", "object_id": null}).to_string()),
        Reply::ok(
            serde_json::json!({"reasoning": "left of the door", "bbox_2d": [2, 2, 30, 30]})
                .to_string(),
        ),
    ]);
    let job = f.run_job(QUERY).await;
    let grids = steps(&job, "stitching")
        .first()
        .and_then(|s| s["outputs"]["grids"].as_array().map(Vec::len));
    assert_eq!(grids, Some(1), "one grid at image_limit 1: {job:#}");
    assert_eq!(job["status"], "succeeded", "{job:#}");
    assert_eq!(
        job["result"]["box_source"], "vlm_box",
        "{:#}",
        job["result"]
    );
    let reqs = f.vlm.requests();
    assert_eq!(reqs.len(), 4, "analysis, image, marks, box");
    let msgs = reqs[3]["messages"].as_array().cloned().unwrap_or_default();
    let images: usize = msgs.iter().map(crate::fake_vlm::images_in).sum();
    assert_eq!(images, 2, "the grid and the box request's image");
    let history = reqs[3]["messages"].to_string();
    assert!(history.contains("Task: mark selection"), "{history}");
    assert!(history.contains("is left out here"), "{history}");
}
