//! Stage 4b: instance selection. With several candidates in the chosen frame, the VLM sees
//! the frame with "ID:n" labels at the box centres and answers an object id; an invalid id
//! gets feedback within the same retry budget. The same exchange serves set-of-marks
//! selection over class-agnostic candidates ([`SelectKind::Marks`]: its own prompt, the
//! regions' outlines drawn, and "none of these" as a valid answer).

use image::RgbImage;
use serde_json::{json, Value};
use std::time::Instant;

use super::conversation::Conversation;
use super::{step, VlmGrounder};
use crate::jobs::{JobContext, JobFailure};
use crate::stitch::annotate::annotate_instances;
use crate::stitch::render::encode_jpeg;
use crate::vision::Detection;
use crate::vlm::json::{parse_instance, parse_no_object, QueryAnalysis};
use crate::vlm::prompts::{InstanceInput, ReplyKind};
use crate::vlm::{CallBudget, ImageData, Message};

/// What the candidates are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SelectKind {
    /// Detections of the target class.
    Detections,
    /// Class-agnostic regions (set-of-marks).
    Marks,
}

impl SelectKind {
    fn step(self) -> &'static str {
        match self {
            SelectKind::Detections => "instance_selection",
            SelectKind::Marks => "mark_selection",
        }
    }
    fn artifact(self) -> &'static str {
        match self {
            SelectKind::Detections => "instances",
            SelectKind::Marks => "marks",
        }
    }
}

/// The chosen candidate's index and box; `None` when, in set-of-marks selection, the VLM
/// says that no region is the target.
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
    kind: SelectKind,
) -> Result<Option<(usize, [f32; 4])>, JobFailure> {
    let t = Instant::now();
    let boxes: Vec<(String, [f32; 4])> = dets
        .iter()
        .enumerate()
        .map(|(i, d)| (i.to_string(), d.bbox))
        .collect();
    let mut opts = g.params.annotate.clone();
    opts.draw_boxes |= kind == SelectKind::Marks;
    let img = image.clone();
    let quality = g.params.stitch.jpeg_quality;
    let jpeg = tokio::task::spawn_blocking(move || {
        annotate_instances(&img, &boxes, &opts).and_then(|a| encode_jpeg(&a, quality))
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("annotation task failed: {e}")))?
    .map_err(|e| JobFailure::new("annotation_failed", format!("{e:#}")))?;
    let url = ctx
        .trace
        .artifact(
            &format!("{}_{idx:05}_{}.jpg", kind.artifact(), conv.rounds),
            jpeg.clone(),
        )
        .await?;
    let candidates: Vec<[f32; 4]> = dets.iter().map(|d| d.bbox).collect();
    let input = InstanceInput {
        query: &ctx.query,
        target_class: &analysis.target_class,
        image_id: idx as u32,
        width: image.width(),
        height: image.height(),
        candidates: &candidates,
    };
    let text = match kind {
        SelectKind::Detections => g.prompts.instance_selection(&input),
        SelectKind::Marks => g.prompts.mark_selection(&input),
    };
    conv.messages
        .push(Message::user_with_images(text, vec![ImageData::jpeg(jpeg)]));
    conv.image_urls.push(url.clone());
    let mut exchanges: Vec<Value> = Vec::new();
    loop {
        let (reply, mut rec) = conv
            .ask(g, budget, crate::vlm::VlmStep::ObjectSelection)
            .await?;
        if kind == SelectKind::Marks {
            if let Some(reasoning) = parse_no_object(&reply) {
                exchanges.push(rec);
                step(
                    ctx,
                    kind.step(),
                    json!({"candidates": dets.len(), "annotated": url}),
                    json!({"index": null, "box": null, "none": true, "asked_vlm": true, "reasoning": reasoning, "vlm": exchanges}),
                    t,
                )
                .await;
                return Ok(None);
            }
        }
        let (fb, why) = match parse_instance(&reply) {
            Ok(a) if (a.object_id as usize) < dets.len() => {
                exchanges.push(rec);
                let i = a.object_id as usize;
                step(
                    ctx,
                    kind.step(),
                    json!({"candidates": dets.len(), "annotated": url}),
                    json!({"index": i, "box": dets[i].bbox, "asked_vlm": true, "reasoning": a.reasoning, "vlm": exchanges}),
                    t,
                )
                .await;
                return Ok(Some((i, dets[i].bbox)));
            }
            Ok(a) => (
                g.prompts
                    .feedback_object_id_invalid(&a.object_id_text, dets.len()),
                format!("object id {:?} is not a candidate", a.object_id_text),
            ),
            Err(e) => (
                g.prompts.feedback_unparsable(ReplyKind::Instance),
                format!("unparsable reply: {e}"),
            ),
        };
        rec["invalid"] = json!(why);
        rec["feedback"] = json!(fb);
        exchanges.push(rec);
        if let Err(e) = conv.feedback(g, fb, &why) {
            step(
                ctx,
                kind.step(),
                json!({"candidates": dets.len(), "annotated": url}),
                json!({"failed": true, "vlm": exchanges}),
                t,
            )
            .await;
            return Err(e);
        }
    }
}
