//! Set-of-marks selection (ours): the class-agnostic candidates of the chosen image, found
//! at indexing from the scan itself (`vision::candidates`), are drawn as numbered regions
//! and the VLM picks the one the query describes, with the same feedback rules as instance
//! selection. When the VLM says no region is the target, or the image has no region at
//! all, it is asked for the box itself (`box_fallback`). A frame without current cached
//! candidates gets them computed here (`candidate_cache`).

use image::RgbImage;
use serde_json::json;
use std::time::Instant;

use super::candidate_cache;
use super::conversation::Conversation;
use super::instance::{self, SelectKind};
use super::proposal::{not_here, BoxSource, Outcome};
use super::{step, vlm_box, VlmGrounder};
use crate::jobs::{JobContext, JobFailure};
use crate::vision::candidates::box_iou;
use crate::vision::Detection;
use crate::vlm::json::QueryAnalysis;
use crate::vlm::CallBudget;

/// The candidates of frame `idx`: from the index, else computed now (and cached).
async fn candidates_of(
    g: &VlmGrounder,
    ctx: &JobContext,
    idx: usize,
    image: &RgbImage,
) -> Result<(Vec<Detection>, &'static str), JobFailure> {
    let mut found = candidate_cache::of_frames(g, ctx, &[idx], Some((idx, image))).await?;
    let source = if found.computed.is_empty() {
        "index"
    } else {
        "computed"
    };
    Ok((found.by_frame.remove(&idx).unwrap_or_default(), source))
}

/// Offer the candidates of image `idx` as marks, after the detector's boxes `dets` (of the
/// target class, possibly none); `why` says why marks are used.
#[allow(clippy::too_many_arguments)]
pub async fn select(
    g: &VlmGrounder,
    ctx: &JobContext,
    budget: &CallBudget,
    conv: &mut Conversation<'_>,
    analysis: &QueryAnalysis,
    idx: usize,
    image: &RgbImage,
    dets: &[Detection],
    why: &str,
) -> Result<Outcome, JobFailure> {
    let t = Instant::now();
    let (found, source) = candidates_of(g, ctx, idx, image).await?;
    let dedupe = g.params.candidates.dedupe_iou;
    let mut cands: Vec<Detection> = dets.to_vec();
    cands.extend(
        found
            .into_iter()
            .filter(|c| dets.iter().all(|d| box_iou(&d.bbox, &c.bbox) <= dedupe)),
    );
    let listed: Vec<_> = cands
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let kind = if i < dets.len() {
                "detection"
            } else {
                c.label.as_str()
            };
            json!({"id": i, "box": c.bbox, "kind": kind, "label": c.label})
        })
        .collect();
    step(
        ctx,
        "candidates",
        json!({"image_id": format!("{idx:05}"), "why": why}),
        json!({"image_id": format!("{idx:05}"), "frame": ctx.scene.frames[idx].name, "from": source, "candidates": listed}),
        t,
    )
    .await;
    // With no region at all (the scan separated nothing here that could be the target),
    // the VLM is not asked to pick one: that is the "no region outlines it" answer below.
    let chosen = if cands.is_empty() {
        None
    } else {
        instance::select(
            g,
            ctx,
            budget,
            conv,
            analysis,
            idx,
            image,
            &cands,
            SelectKind::Marks,
        )
        .await?
    };
    match chosen {
        Some((i, bbox)) => {
            let source = if i < dets.len() {
                BoxSource::Detector
            } else {
                BoxSource::Marks
            };
            Ok(Outcome::Box(bbox, source))
        }
        // No region outlines the target. Marks come from what the scan separates; an
        // object of the wall's colour flush with it, or one merged with its neighbour, has
        // no mark of its own, while the VLM may still see it: it draws the box itself.
        None if g.params.candidates.box_fallback => {
            vlm_box::ask(g, ctx, budget, conv, analysis, idx, image).await
        }
        None => {
            let why = if cands.is_empty() {
                format!("no candidate region in image {idx:05}")
            } else {
                format!("the VLM found no marked region that is the target in image {idx:05}")
            };
            Ok(not_here(g, idx, &analysis.target_class, why))
        }
    }
}
