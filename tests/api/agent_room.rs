//! The room layout (`geometry::estimate_room`, over every frame's depth) is estimated once
//! per loaded scene and shared by the jobs, not once per query (#18's timing target).

use crate::agent_fixture::*;
use grounder::geometry::GeometryParams;
use serde_json::Value;

/// A class flat against a wall (so its jobs use the room) with a frame showing exactly one
/// instance.
fn flat_class(f: &Fixture) -> (String, usize) {
    let support = GeometryParams::default().support;
    let mut labels: Vec<String> = f.dets.values().flatten().map(|d| d.label.clone()).collect();
    labels.sort();
    labels.dedup();
    labels
        .into_iter()
        .filter(|l| support.is_flat(l))
        .find_map(|l| f.frames_with(&l, 1).first().map(|&i| (l, i)))
        .unwrap_or_else(|| panic!("no flat class seen alone in a frame: {:?}", f.dets))
}

/// Run the same query twice; each job's room layout (pre-selection's trace), box and
/// count of room estimates so far.
async fn two_jobs(f: &Fixture, marks: bool) -> Vec<(Value, Value, Value)> {
    let (class, frame) = flat_class(f);
    let mut out = Vec::new();
    for _ in 0..2 {
        let mut replies = vec![analysis(&class), pick_image(format!("{frame:05}"))];
        if marks {
            // With candidates beside the detections, mark 0 is the detection.
            replies.push(pick_object(0));
        }
        f.vlm.script_push(replies);
        let job = f.run_job(&format!("the {class}")).await;
        assert_eq!(job["status"], "succeeded", "{job:#}");
        let pre = steps(&job, "preselection");
        let summary = steps(&job, "summary");
        assert_eq!((pre.len(), summary.len()), (1, 1), "{job:#}");
        out.push((
            pre[0]["outputs"]["room_layout"].clone(),
            job["result"]["box"].clone(),
            summary[0]["outputs"]["room_layout_estimates"].clone(),
        ));
    }
    out
}

#[tokio::test]
async fn the_first_job_estimates_the_room_and_the_next_reuse_it() {
    // Without candidates, indexing needs no room: the first job that does estimates it.
    let f = Fixture::start(vec![], 10_000).await;
    let jobs = two_jobs(&f, false).await;
    assert!(jobs[0].0.is_object(), "a room was estimated: {:?}", jobs[0]);
    assert_eq!(jobs[0].0, jobs[1].0, "the same room");
    assert_eq!(jobs[0].1, jobs[1].1, "the same box");
    assert_eq!(jobs[0].2, 1, "{jobs:?}");
    assert_eq!(
        jobs[1].2, 1,
        "not estimated again for the second query: {jobs:?}"
    );
}

#[tokio::test]
async fn the_room_estimated_at_indexing_serves_every_job() {
    // With candidates (the default), indexing estimates the room and hands its loaded
    // scene, room included, to the jobs.
    let f = Fixture::start_with_candidates(vec![], 10_000, "oracle").await;
    let jobs = two_jobs(&f, true).await;
    assert!(jobs[0].0.is_object(), "a room was estimated: {:?}", jobs[0]);
    assert_eq!(jobs[0].0, jobs[1].0);
    assert_eq!(jobs[0].1, jobs[1].1);
    assert_eq!(jobs[0].2, 1, "indexing's estimate, no job's: {jobs:?}");
    assert_eq!(jobs[1].2, 1, "{jobs:?}");
}
