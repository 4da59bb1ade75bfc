//! `detector = "vlm"`: the VLM itself gives the target's 2D box in the image it chose, in
//! the coordinate convention of `[agent] box_format` (`vlm::boxes`). A box outside the
//! image, without area or unreadable gets feedback within the job's retry budget; "not in
//! this image" (`bbox_2d: null`) sends the VLM back to choose another image.

use image::RgbImage;
use serde_json::{json, Value};
use std::time::Instant;

use super::conversation::Conversation;
use super::proposal::{not_here, BoxSource, Outcome};
use super::{step, VlmGrounder};
use crate::jobs::{JobContext, JobFailure};
use crate::stitch::render::encode_jpeg;
use crate::vlm::boxes::{parse_box, BoxAnswer, BoxError};
use crate::vlm::json::QueryAnalysis;
use crate::vlm::prompts::ReplyKind;
use crate::vlm::{CallBudget, ImageData, Message};

/// Ask for the target's box in image `idx`.
pub async fn ask(
    g: &VlmGrounder,
    ctx: &JobContext,
    budget: &CallBudget,
    conv: &mut Conversation<'_>,
    analysis: &QueryAnalysis,
    idx: usize,
    image: &RgbImage,
) -> Result<Outcome, JobFailure> {
    let t = Instant::now();
    let format = g.params.box_format;
    let size = image.dimensions();
    let img = image.clone();
    let quality = g.params.stitch.jpeg_quality;
    let jpeg = tokio::task::spawn_blocking(move || encode_jpeg(&img, quality))
        .await
        .map_err(|e| JobFailure::new("internal", format!("encoding task failed: {e}")))?
        .map_err(|e| JobFailure::new("annotation_failed", format!("{e:#}")))?;
    let url = ctx
        .trace
        .artifact(
            &format!("box_request_{idx:05}_{}.jpg", conv.rounds),
            jpeg.clone(),
        )
        .await?;
    let text = g
        .prompts
        .box_request(&ctx.query, &analysis.target_class, idx as u32, size, format);
    conv.messages
        .push(Message::user_with_images(text, vec![ImageData::jpeg(jpeg)]));
    conv.image_urls.push(url.clone());
    let mut exchanges: Vec<Value> = Vec::new();
    let inputs =
        json!({"image_id": format!("{idx:05}"), "box_format": format.name(), "image": url});
    loop {
        let (reply, mut rec) = conv.ask(g, budget, crate::vlm::VlmStep::Box).await?;
        let (fb, why) = match parse_box(&reply, format, size) {
            Ok(BoxAnswer {
                bbox: Some(b),
                raw,
                reasoning,
            }) => {
                exchanges.push(rec);
                step(
                    ctx,
                    "vlm_box",
                    inputs,
                    json!({"box": b, "answered": raw, "reasoning": reasoning, "vlm": exchanges}),
                    t,
                )
                .await;
                return Ok(Outcome::Box(b, BoxSource::VlmBox));
            }
            Ok(BoxAnswer {
                bbox: None,
                reasoning,
                ..
            }) => {
                exchanges.push(rec);
                step(
                    ctx,
                    "vlm_box",
                    inputs,
                    json!({"box": null, "reasoning": reasoning, "vlm": exchanges}),
                    t,
                )
                .await;
                return Ok(not_here(
                    g,
                    idx,
                    &analysis.target_class,
                    format!("the VLM found no target in image {idx:05}"),
                ));
            }
            Err(BoxError::Unparsable) => (
                g.prompts.feedback_unparsable(ReplyKind::Box),
                "unparsable reply".to_string(),
            ),
            Err(e) => (
                g.prompts.feedback_box_invalid(&e.to_string(), format),
                e.to_string(),
            ),
        };
        rec["invalid"] = json!(why);
        rec["feedback"] = json!(fb);
        exchanges.push(rec);
        if let Err(e) = conv.feedback(g, fb, &why) {
            step(
                ctx,
                "vlm_box",
                inputs,
                json!({"failed": true, "vlm": exchanges}),
                t,
            )
            .await;
            return Err(e);
        }
    }
}
