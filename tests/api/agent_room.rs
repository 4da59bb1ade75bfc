//! The room layout (`geometry::estimate_room`, over every frame's depth) is estimated once
//! per loaded scene and shared by the jobs, not once per query (#18's timing target).

use crate::agent_fixture::*;
use grounder::geometry::{Aabb, GeometryParams};
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

/// Each class not flat against a wall seen alone in a frame, with its finished job (the
/// VLM picks that frame).
async fn jobs_by_class(f: &Fixture) -> Vec<(String, Value)> {
    let support = GeometryParams::default().support;
    let mut labels: Vec<String> = f.dets.values().flatten().map(|d| d.label.clone()).collect();
    labels.sort();
    labels.dedup();
    let mut out = Vec::new();
    for class in labels.into_iter().filter(|l| !support.is_flat(l)) {
        let Some(&frame) = f.frames_with(&class, 1).first() else {
            continue;
        };
        f.vlm
            .script_push(vec![analysis(&class), pick_image(format!("{frame:05}"))]);
        let job = f.run_job(&format!("the {class}")).await;
        assert_eq!(job["status"], "succeeded", "{job:#}");
        out.push((class, job));
    }
    out
}

/// Each class not flat against a wall seen alone in a frame: its job's room-wall cuts
/// (the segmentation step's `wall_cuts` on the room's own axes, "u" or "v") and its box.
async fn cuts_by_class(f: &Fixture) -> Vec<(String, Vec<Value>, Value)> {
    let mut out = Vec::new();
    for (class, job) in jobs_by_class(f).await {
        let seg = steps(&job, "segmentation");
        let cuts: Vec<Value> = seg[0]["outputs"]["wall_cuts"]
            .as_array()
            .expect("wall_cuts")
            .iter()
            .filter(|c| c["axis"] == "u" || c["axis"] == "v")
            .cloned()
            .collect();
        out.push((class, cuts, job["result"]["box"].clone()));
    }
    out
}

/// A job's box (`result.box`) as an `Aabb`.
fn aabb(b: &Value) -> Aabb {
    let p = |k: &str| {
        let v: Vec<f64> = b[k]
            .as_array()
            .expect("box corner")
            .iter()
            .map(|x| x.as_f64().expect("number"))
            .collect();
        [v[0], v[1], v[2]]
    };
    Aabb {
        min: p("min"),
        max: p("max"),
    }
}

#[tokio::test]
async fn points_on_a_wall_of_the_room_are_cut_from_an_object_that_is_not_flat() {
    let on = cuts_by_class(&Fixture::start(vec![], 10_000).await).await;
    let off = Fixture::start_with_config(10_000, "oracle", |c| {
        c.agent.geometry.support.room_wall_cut = false;
    })
    .await;
    let off = cuts_by_class(&off).await;
    let truth = &scene_tar().1.objects;
    let mut cut = 0;
    for ((class, cuts, b), (class_off, cuts_off, b_off)) in on.iter().zip(&off) {
        assert_eq!(class, class_off);
        assert!(cuts_off.is_empty(), "{class}: cut while off: {cuts_off:?}");
        if cuts.is_empty() {
            continue;
        }
        cut += 1;
        // Each cut says how wide its band was and what colour kept within it.
        for c in cuts {
            assert!(
                c["band"].as_f64().is_some_and(|b| b > 0.0) && c["kept_by_colour"].is_u64(),
                "{class}: {c}"
            );
        }
        // The object asked for: the instance of that class the box lies on.
        let (a, a_off) = (aabb(b), aabb(b_off));
        let gt = truth
            .iter()
            .filter(|o| o.label == *class)
            .max_by(|x, y| a.iou(&x.aabb).total_cmp(&a.iou(&y.aabb)))
            .expect("the class's object");
        let (iou, iou_off) = (a.iou(&gt.aabb), a_off.iou(&gt.aabb));
        eprintln!("{class}: {cuts:?} IoU {iou:.3} (off {iou_off:.3})");
        // What was cut was the wall, not the object.
        assert!(
            iou >= iou_off - 0.02 && iou > 0.5,
            "{class}: IoU {iou:.3} with the cut, {iou_off:.3} without; {cuts:?}"
        );
    }
    assert!(cut > 0, "no job cut a room wall: {on:?}");
}

#[tokio::test]
async fn an_object_of_a_class_that_stands_on_the_floor_gets_its_bottom_on_the_room_floor() {
    let f = Fixture::start(vec![], 10_000).await;
    let support = GeometryParams::default().support;
    let (mut standing, mut other) = (0, 0);
    for (class, job) in jobs_by_class(&f).await {
        let proj = &steps(&job, "projection")[0]["outputs"];
        let stood = &proj["floor_standing"];
        let fused_bottom = proj["fused_box"]["min"][2].as_f64().expect("fused box");
        let bottom = aabb(&job["result"]["box"]).min[2];
        eprintln!("{class}: fused bottom {fused_bottom:.3}, box bottom {bottom:.3}, {stood}");
        if support.stands(&class) {
            standing += 1;
            // Its bottom moved onto the floor unless the points already reached it, and
            // support completion then settled it on the measured floor.
            if fused_bottom > 0.05 {
                let to = stood["to"]
                    .as_f64()
                    .unwrap_or_else(|| panic!("{class}: {proj}"));
                assert!(to.abs() < 0.05, "{class}: {stood}");
            }
            assert!(bottom.abs() < 0.05, "{class}: bottom {bottom}, {stood}");
        } else {
            other += 1;
            assert!(stood.is_null(), "{class}: {stood}");
        }
    }
    assert!(
        standing > 0 && other > 0,
        "{standing} standing, {other} other"
    );
}
