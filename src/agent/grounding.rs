//! Stage 4: grounding with feedback (paper Sec. 3.3). The VLM picks an image id from the
//! stitched grids; an invalid id, a frame without the target class, an unparsable reply or
//! an invalid object id gets a feedback turn, at most `max_retries` in all. The VLM may
//! also answer that none of the offered frames shows the target ([`Grounded::NoneOffered`]):
//! the caller then offers the frames the detector's pre-selection left out. A box from the
//! marks or the VLM with almost no depth reading under it gets one feedback turn asking
//! for a frame nearer the object, naming the offered frames that measured what the box
//! shows (ours: the detector's boxes are checked so at pre-selection already).

use image::RgbImage;
use serde_json::{json, Value};
use std::sync::Arc;
use std::time::Instant;

use super::conversation::Conversation;
use super::preselect::{depth_fraction, Preselection};
use super::proposal::{propose, BoxSource, Outcome};
use super::stitching::Grids;
use super::vlm_log::VlmLog;
use super::{step, VlmGrounder};
use crate::geometry::{sightings, CandidateFrame, RoomLayout, Sighting};
use crate::jobs::{JobContext, JobFailure};
use crate::vision::{DetectInput, Detection, InstanceMask};
use crate::vlm::json::{parse_grounding, parse_no_image, QueryAnalysis};
use crate::vlm::prompts::{GroundingInput, ReplyKind};
use crate::vlm::{CallBudget, ImageData, Message, VlmStep};

/// The chosen frame and 2D box.
#[derive(Debug, Clone)]
pub struct Choice {
    pub frame_idx: usize,
    pub bbox: [f32; 4],
    pub image: Arc<RgbImage>,
    pub feedback_rounds: usize,
    /// Which path gave the box.
    pub source: BoxSource,
}

/// What grounding ended with.
#[derive(Debug)]
pub enum Grounded {
    /// A frame and a box in it.
    Chosen(Choice),
    /// The VLM saw the target in none of the offered frames (its reasoning).
    NoneOffered(String),
}

/// Run the detector on one frame (with ground truth for the oracle detector).
pub async fn redetect(
    g: &VlmGrounder,
    ctx: &JobContext,
    frame_idx: usize,
    image: Arc<RgbImage>,
) -> Result<Vec<Detection>, JobFailure> {
    let frame = ctx.scene.frames[frame_idx].clone();
    let labels = ctx.scene.instance_labels.clone();
    let detector = g.detector.clone();
    tokio::task::spawn_blocking(move || {
        let instances = match (&frame.instance_path, detector.needs_instances()) {
            (Some(p), true) => Some(read_instance_mask(p)?),
            _ => None,
        };
        let labels: Option<std::collections::HashMap<u32, String>> =
            labels.map(|l| l.into_iter().collect());
        let input = DetectInput {
            color: &image,
            instances: instances.as_ref(),
            labels: labels.as_ref(),
            frame_key: frame_idx as u64,
        };
        detector.detect(&input)
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("detector task failed: {e}")))?
    .map_err(|e| JobFailure::new("detector_failed", format!("{e:#}")))
}

/// Read a 16-bit instance-id PNG.
pub fn read_instance_mask(path: &std::path::Path) -> anyhow::Result<InstanceMask> {
    let mut reader = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| anyhow::anyhow!("cannot read instance mask {}: {e}", path.display()))?;
    reader.limits(crate::scene::import::decode_limits(
        crate::scene::import::DEFAULT_MAX_IMAGE_PIXELS,
    ));
    let img = reader
        .decode()
        .map_err(|e| anyhow::anyhow!("cannot read instance mask {}: {e}", path.display()))?
        .into_luma16();
    Ok(InstanceMask {
        width: img.width(),
        height: img.height(),
        data: img.into_raw(),
    })
}

/// Record the exchanges of a failed grounding and return the failure.
async fn fail_with_trace(
    ctx: &JobContext,
    e: JobFailure,
    exchanges: Vec<Value>,
    t: Instant,
) -> Result<Grounded, JobFailure> {
    step(
        ctx,
        "image_selection",
        json!({}),
        json!({"failed": true, "reason": e.code, "vlm": exchanges}),
        t,
    )
    .await;
    Err(e)
}

/// Why a box from the marks or the VLM cannot be measured in 3D: under
/// `unmeasured_fraction` of its depth pixels hold a reading (the room's box counting for
/// objects flat against a wall, as at pre-selection). None when it can, or when the check
/// is off (the caller makes it once per job).
fn unmeasured(
    g: &VlmGrounder,
    ctx: &JobContext,
    idx: usize,
    bbox: [f32; 4],
    source: BoxSource,
    layout: Option<&RoomLayout>,
) -> Option<String> {
    let cp = &g.params.candidates;
    if source == BoxSource::Detector || !cp.enabled || !cp.unmeasured_retry {
        return None;
    }
    let f = &ctx.scene.frames[idx];
    let frac = depth_fraction(f, bbox, layout, &g.params.geometry.layout);
    (frac < cp.unmeasured_fraction).then(|| {
        format!(
            "{:.0} % of the depth pixels under the box in image {idx:05} hold a reading (at least {:.0} % needed)",
            frac * 100.0,
            cp.unmeasured_fraction * 100.0
        )
    })
}

/// The offered frames (`pre`) other than `idx` that measured what `bbox` shows there
/// ([`sightings`]), best first; empty when the setting is off.
async fn nearer_frames(
    g: &VlmGrounder,
    ctx: &JobContext,
    idx: usize,
    bbox: [f32; 4],
    pre: &Preselection,
    layout: Option<&RoomLayout>,
) -> Result<Vec<Sighting>, JobFailure> {
    let cp = g.params.candidates.clone();
    if !cp.nearer_frames || cp.nearer_max == 0 {
        return Ok(Vec::new());
    }
    let (scene, room, params) = (
        ctx.scene.clone(),
        layout.cloned(),
        g.params.geometry.clone(),
    );
    let offered: Vec<usize> = pre.frames.iter().copied().filter(|&i| i != idx).collect();
    tokio::task::spawn_blocking(move || {
        let frames: Vec<CandidateFrame> = offered
            .iter()
            .filter_map(|&i| scene.frames.get(i).filter(|f| f.usable))
            .map(|f| CandidateFrame {
                index: f.idx,
                camera: &f.camera,
                depth: &f.depth,
            })
            .collect();
        let mut s = sightings(
            &scene.frames[idx].camera,
            bbox,
            room.as_ref(),
            &frames,
            cp.nearer_share,
            &params,
        );
        s.truncate(cp.nearer_max);
        s
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("nearer-frame search failed: {e}")))
}

#[allow(clippy::too_many_arguments)]
pub async fn run(
    g: &VlmGrounder,
    ctx: &JobContext,
    budget: &CallBudget,
    log: &VlmLog,
    analysis: &QueryAnalysis,
    pre: &Preselection,
    grids: &Grids,
    layout: Option<&RoomLayout>,
) -> Result<Grounded, JobFailure> {
    let t = Instant::now();
    let offered: Vec<u32> = pre.frames.iter().map(|&i| i as u32).collect();
    let text = g.prompts.grounding_input(&GroundingInput {
        query: &ctx.query,
        target_class: &analysis.target_class,
        attributes: &analysis.attributes,
        conditions: &analysis.conditions,
        image_ids: &offered,
        num_grids: grids.images.len(),
    });
    let images = grids
        .images
        .iter()
        .map(|s| ImageData::jpeg(s.jpeg.clone()))
        .collect();
    let mut conv = Conversation {
        messages: vec![
            Message::system(g.prompts.grounding_system()),
            Message::user_with_images(text, images),
        ],
        image_urls: grids.urls.clone(),
        logged: 0,
        log,
        rounds: 0,
        feedback_at: Vec::new(),
    };
    let mut exchanges: Vec<Value> = Vec::new();
    let mut depth_checked = false;
    loop {
        let (reply, mut rec) = match conv.ask(g, budget, VlmStep::ImageSelection).await {
            Ok(r) => r,
            Err(e) => return fail_with_trace(ctx, e, exchanges, t).await,
        };
        if let Some(reasoning) = parse_no_image(&reply) {
            exchanges.push(rec);
            step(
                ctx,
                "image_selection",
                json!({"offered": offered.len()}),
                json!({"none": true, "reasoning": reasoning, "vlm": exchanges}),
                t,
            )
            .await;
            return Ok(Grounded::NoneOffered(reasoning));
        }
        let answer = match parse_grounding(&reply) {
            Ok(a) => a,
            Err(e) => {
                let fb = g.prompts.feedback_unparsable(ReplyKind::Grounding);
                rec["invalid"] = json!(format!("unparsable reply: {e}"));
                rec["feedback"] = json!(fb);
                exchanges.push(rec);
                if let Err(e) = conv.feedback(g, fb, "unparsable reply") {
                    return fail_with_trace(ctx, e, exchanges, t).await;
                }
                continue;
            }
        };
        if !offered.contains(&answer.target_image_id) {
            let fb = g
                .prompts
                .feedback_image_invalid(&answer.target_image_id_text, &offered);
            rec["invalid"] = json!(format!(
                "image id {:?} was not offered",
                answer.target_image_id_text
            ));
            rec["feedback"] = json!(fb);
            exchanges.push(rec);
            if let Err(e) = conv.feedback(g, fb, "invalid image id") {
                return fail_with_trace(ctx, e, exchanges, t).await;
            }
            continue;
        }
        let idx = answer.target_image_id as usize;
        exchanges.push(rec);
        step(
            ctx,
            "image_selection",
            json!({"offered": offered.len()}),
            json!({"image_id": format!("{idx:05}"), "frame": ctx.scene.frames[idx].name, "reasoning": answer.reasoning, "reference_image_ids": answer.reference_image_ids, "vlm": exchanges}),
            t,
        )
        .await;
        exchanges = Vec::new();

        let image = super::stitching::decode(&ctx.scene, &[idx])
            .await?
            .remove(&idx)
            .ok_or_else(|| JobFailure::new("internal", "frame decode lost"))?;
        match propose(g, ctx, budget, &mut conv, analysis, pre, idx, &image).await? {
            Outcome::Box(bbox, source) => {
                let why = (!depth_checked)
                    .then(|| unmeasured(g, ctx, idx, bbox, source, layout))
                    .flatten();
                if let Some(why) = why {
                    // Once per job: the next frame's box is taken as it is.
                    depth_checked = true;
                    let nearer = nearer_frames(g, ctx, idx, bbox, pre, layout).await?;
                    let ids: Vec<u32> = nearer.iter().map(|s| s.index as u32).collect();
                    let class = &analysis.target_class;
                    let fb = if ids.is_empty() {
                        g.prompts.feedback_no_depth(idx as u32, class)
                    } else {
                        g.prompts.feedback_no_depth_nearer(idx as u32, class, &ids)
                    };
                    let nearer: Vec<Value> = nearer
                        .iter()
                        .map(|s| json!({"image_id": format!("{:05}", s.index), "share": s.share, "rays": s.rays}))
                        .collect();
                    exchanges.push(json!({"feedback": fb, "invalid": why, "box": bbox, "nearer_frames": nearer}));
                    if let Err(e) = conv.feedback(g, fb, "no depth under the box") {
                        return fail_with_trace(ctx, e, exchanges, t).await;
                    }
                    continue;
                }
                return Ok(Grounded::Chosen(Choice {
                    frame_idx: idx,
                    bbox,
                    image,
                    feedback_rounds: conv.rounds,
                    source,
                }));
            }
            Outcome::NotHere { feedback, why } => {
                exchanges.push(json!({"feedback": feedback, "invalid": why}));
                if let Err(e) = conv.feedback(g, feedback, "no target in the chosen image") {
                    return fail_with_trace(ctx, e, exchanges, t).await;
                }
            }
        }
    }
}
