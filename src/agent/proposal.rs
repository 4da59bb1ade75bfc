//! Stage 4a: the target's 2D box in the image the VLM chose, by one of three paths:
//! - **detector**: the local detector's boxes of the target class (the paper's path), one
//!   picked by the VLM when there are several;
//! - **marks** (ours): when the detector cannot see the class or finds no target in the
//!   image, the class-agnostic candidates of that image are drawn as numbered regions and
//!   the VLM picks one ([`super::marks`]);
//! - **VLM box** (`detector = "vlm"`): the VLM itself answers the box ([`super::vlm_box`]).
//!
//! The trace and the result say which path gave the box (`box_source`).

use image::RgbImage;
use serde::Serialize;
use serde_json::{json, Value};
use std::time::Instant;

use super::conversation::Conversation;
use super::grounding::redetect;
use super::instance::{self, SelectKind};
use super::preselect::{same_class, Preselection};
use super::{marks, step, vlm_box, VlmGrounder};
use crate::jobs::{JobContext, JobFailure};
use crate::vision::Detection;
use crate::vlm::json::QueryAnalysis;
use crate::vlm::CallBudget;

/// Which path gave the box.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BoxSource {
    Detector,
    Marks,
    VlmBox,
}

/// What the chosen image gave.
pub enum Outcome {
    /// A box for the target, and the path that gave it.
    Box([f32; 4], BoxSource),
    /// Nothing in this image: the feedback to send and why (the VLM picks another image).
    NotHere { feedback: String, why: String },
}

/// Feedback that the chosen image holds no target.
pub fn not_here(g: &VlmGrounder, idx: usize, class: &str, why: String) -> Outcome {
    Outcome::NotHere {
        feedback: g.prompts.feedback_object_not_existing(idx as u32, class),
        why,
    }
}

/// The target's box in image `idx` (decoded as `image`), by the first path that applies.
#[allow(clippy::too_many_arguments)]
pub async fn propose(
    g: &VlmGrounder,
    ctx: &JobContext,
    budget: &CallBudget,
    conv: &mut Conversation<'_>,
    analysis: &QueryAnalysis,
    pre: &Preselection,
    idx: usize,
    image: &RgbImage,
) -> Result<Outcome, JobFailure> {
    let class = analysis.target_class.as_str();
    if g.vlm_boxes {
        return vlm_box::ask(g, ctx, budget, conv, analysis, idx, image).await;
    }
    let Some(det_class) = &pre.detector_class else {
        if g.params.candidates.enabled {
            return marks::select(
                g,
                ctx,
                budget,
                conv,
                analysis,
                idx,
                image,
                &[],
                "the detector has no class for the target",
            )
            .await;
        }
        return Err(JobFailure::new(
            "detector_cannot_see_class",
            format!("the detector has no class for {class:?}, so no box can be proposed in the chosen image (class-agnostic candidates are off)"),
        ));
    };
    let td = Instant::now();
    let dets: Vec<Detection> = redetect(g, ctx, idx, std::sync::Arc::new(image.clone()))
        .await?
        .into_iter()
        .filter(|d| same_class(&d.label, det_class))
        .collect();
    let det_json: Vec<Value> = dets
        .iter()
        .map(|d| json!({"box": d.bbox, "score": d.score, "label": d.label}))
        .collect();
    step(
        ctx,
        "detection",
        json!({"image_id": format!("{idx:05}"), "class": det_class}),
        json!({"image_id": format!("{idx:05}"), "frame": ctx.scene.frames[idx].name, "detections": det_json}),
        td,
    )
    .await;
    let cands = &g.params.candidates;
    if cands.enabled && (dets.is_empty() || cands.beside_detections) {
        let why = if dets.is_empty() {
            "the detector found no target in the chosen image"
        } else {
            "candidates are offered beside the detections"
        };
        return marks::select(g, ctx, budget, conv, analysis, idx, image, &dets, why).await;
    }
    match dets.len() {
        0 => Ok(not_here(
            g,
            idx,
            class,
            format!("no {det_class} detected in image {idx:05}"),
        )),
        1 => {
            step(
                ctx,
                "instance_selection",
                json!({"candidates": 1}),
                json!({"index": 0, "box": dets[0].bbox, "asked_vlm": false}),
                td,
            )
            .await;
            Ok(Outcome::Box(dets[0].bbox, BoxSource::Detector))
        }
        _ => match instance::select(
            g,
            ctx,
            budget,
            conv,
            analysis,
            idx,
            image,
            &dets,
            SelectKind::Detections,
        )
        .await?
        {
            Some((_, bbox)) => Ok(Outcome::Box(bbox, BoxSource::Detector)),
            // Only set-of-marks selection takes "none" as an answer.
            None => Ok(not_here(
                g,
                idx,
                class,
                format!("no {det_class} chosen in image {idx:05}"),
            )),
        },
    }
}
