//! Ours: the whole object's box in one ensemble view, from the VLM (`[agent.candidates]
//! view_box`). When the chosen view saw only a part of the object (`geometry::partial`)
//! and no other view has a detection of the class or a class-agnostic candidate that
//! holds the reprojected part, every view would segment the part alone and the box would
//! stop where the chosen frame's edge cut the object (a window seen from up close, whose
//! whole is seen only from across the room). The VLM is then shown the view most likely
//! to hold all of the object, with the part outlined, and asked for the whole object's
//! box there. The answer is used as a detection would be: only when it holds at least
//! half the reprojected pixels ([`super::ensemble_boxes::pick_detection`]). It never fails
//! the job: a refusal, an unusable box or a failed call keeps the view's footprint.

use image::RgbImage;
use serde_json::{json, Value};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

use super::conversation::Conversation;
use super::ensemble_boxes::{pick_detection, BoxFrom};
use super::vlm_log::VlmLog;
use super::{step, VlmGrounder};
use crate::geometry::ensemble::ViewCandidate;
use crate::jobs::{JobContext, JobFailure};
use crate::stitch::label::{stroke_rect, PixelRect};
use crate::stitch::render::encode_jpeg;
use crate::vlm::boxes::{parse_box, BoxAnswer};
use crate::vlm::{CallBudget, ImageData, Message, VlmStep};

/// The view to ask, as a position in `views` (`(footprint box, frame size)` each): the one
/// whose footprint lies farthest inside its frame for its size (the smallest distance to
/// an edge over the footprint's longer side), so that the rest of the object has the
/// most room around the part there. A footprint within `border_frac` of the width from
/// an edge is cut in that view too, and is not asked about.
pub fn pick_view(views: &[([f32; 4], (u32, u32))], border_frac: f64) -> Option<usize> {
    views
        .iter()
        .enumerate()
        .filter_map(|(k, (b, (w, h)))| {
            let (w, h) = (*w as f32, *h as f32);
            let margin = b[0].min(b[1]).min(w - b[2]).min(h - b[3]);
            let side = (b[2] - b[0]).max(b[3] - b[1]).max(1.0);
            (margin > border_frac as f32 * w).then_some((k, margin / side))
        })
        .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
        .map(|(k, _)| k)
}

/// Ask for the whole object's box in one view when every view's box is its footprint and
/// the chosen view saw a part (see the module documentation); the view's box and its
/// source are replaced when the answer is used. The compute `slot` is let go while the VLM
/// is asked. Returns what was done, for the
/// projection's trace (null when nothing was asked).
#[allow(clippy::too_many_arguments)]
pub async fn complete(
    g: &VlmGrounder,
    ctx: &JobContext,
    budget: &CallBudget,
    log: &mut VlmLog,
    target_class: &str,
    anchor_idx: usize,
    anchor_partial: bool,
    views: &[ViewCandidate],
    view_boxes: &mut [(usize, [f32; 4], BoxFrom)],
    decoded: &HashMap<usize, Arc<RgbImage>>,
    slot: &mut Option<tokio::sync::SemaphorePermit<'_>>,
) -> Result<Value, JobFailure> {
    let cp = &g.params.candidates;
    if !cp.enabled
        || !cp.view_box
        || !anchor_partial
        || view_boxes.iter().any(|v| v.2 != BoxFrom::Footprint)
    {
        return Ok(Value::Null);
    }
    // Views (positions in `views`) with a decoded image.
    let usable: Vec<(usize, &Arc<RgbImage>)> = views
        .iter()
        .enumerate()
        .filter_map(|(k, v)| decoded.get(&v.index).map(|img| (k, img)))
        .collect();
    let shapes: Vec<([f32; 4], (u32, u32))> = usable
        .iter()
        .map(|(k, img)| (views[*k].bbox, img.dimensions()))
        .collect();
    let Some(pos) = pick_view(&shapes, cp.partial.border_frac) else {
        return Ok(json!({"asked": false, "why": "every view's part touches its frame's edge"}));
    };
    let (k, image) = (usable[pos].0, usable[pos].1.clone());
    let view = &views[k];
    let t = Instant::now();
    let format = g.params.box_format;
    let size = image.dimensions();
    let part = view.bbox;
    let quality = g.params.stitch.jpeg_quality;
    let jpeg = tokio::task::spawn_blocking(move || {
        let mut img = (*image).clone();
        let thickness = ((img.height() as f32 * 0.004).round() as u32).max(2);
        let rect = PixelRect {
            x: part[0].round() as i32,
            y: part[1].round() as i32,
            w: ((part[2] - part[0]).round() as u32).max(1),
            h: ((part[3] - part[1]).round() as u32).max(1),
        };
        stroke_rect(&mut img, rect, thickness, [255, 0, 0]);
        encode_jpeg(&img, quality)
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("encoding task failed: {e}")))?
    .map_err(|e| JobFailure::new("annotation_failed", format!("{e:#}")))?;
    let url = ctx
        .trace
        .artifact(&format!("view_box_{:05}.jpg", view.index), jpeg.clone())
        .await?;
    let text = g.prompts.view_box_request(
        &ctx.query,
        target_class,
        view.index as u32,
        anchor_idx as u32,
        size,
        part,
        format,
    );
    let inputs = json!({"image_id": format!("{:05}", view.index), "anchor_image_id": format!("{anchor_idx:05}"), "part_box": part, "box_format": format.name(), "image": url});
    let mut conv = Conversation {
        messages: vec![Message::user_with_images(text, vec![ImageData::jpeg(jpeg)])],
        image_urls: vec![url],
        logged: 0,
        log,
        rounds: 0,
        feedback_at: Vec::new(),
    };
    // Other jobs may compute while this one waits for the VLM (the caller takes a slot
    // again before it goes on).
    slot.take();
    let (outputs, answer) = match conv.ask(g, budget, VlmStep::Box).await {
        Err(e) if e.code == "canceled" => return Err(e),
        Err(e) => (
            json!({"box": null, "used": false, "why": format!("the call failed: {}", e.detail)}),
            None,
        ),
        Ok((reply, rec)) => match parse_box(&reply, format, size) {
            Ok(BoxAnswer {
                bbox: Some(b),
                raw,
                reasoning,
            }) => {
                let holds = pick_detection(&[b], &view.pixels).is_some();
                let why = if holds {
                    "the box holds the reprojected part"
                } else {
                    "the box holds less than half of the reprojected part"
                };
                (
                    json!({"box": b, "answered": raw, "used": holds, "why": why, "reasoning": reasoning, "vlm": [rec]}),
                    holds.then_some(b),
                )
            }
            Ok(BoxAnswer {
                bbox: None,
                reasoning,
                ..
            }) => (
                json!({"box": null, "used": false, "why": "the VLM did not see the object in this view", "reasoning": reasoning, "vlm": [rec]}),
                None,
            ),
            Err(e) => (
                json!({"box": null, "used": false, "why": e.to_string(), "vlm": [rec]}),
                None,
            ),
        },
    };
    step(ctx, "view_box", inputs, outputs.clone(), t).await;
    if let Some(b) = answer {
        if let Some(vb) = view_boxes.iter_mut().find(|v| v.0 == view.index) {
            vb.1 = b;
            vb.2 = BoxFrom::VlmBox;
        }
    }
    Ok(json!({"asked": true, "image_id": format!("{:05}", view.index), "used": answer.is_some()}))
}

#[cfg(test)]
mod tests {
    use super::pick_view;

    #[test]
    fn the_view_with_the_most_room_around_the_part_is_asked() {
        let size = (640, 480);
        let views = [
            // Touches the top edge: cut there too.
            ([234.0, 0.0, 275.0, 50.0], size),
            // 26 px from the top for a 73 px part.
            ([415.0, 26.0, 450.0, 99.0], size),
            // 59 px from the top for a 72 px part: the most room.
            ([157.0, 59.0, 193.0, 131.0], size),
            // Central but large: 40 px of room for a 400 px part.
            ([120.0, 40.0, 520.0, 440.0], size),
        ];
        assert_eq!(pick_view(&views, 0.01), Some(2));
        assert_eq!(pick_view(&views[..2], 0.01), Some(1));
        // Only parts at the edge: nobody is asked.
        assert_eq!(pick_view(&views[..1], 0.01), None);
        assert_eq!(pick_view(&[], 0.01), None);
        // A part 5 px from the edge of a 640 px frame is within 1 % of it.
        assert_eq!(pick_view(&[([5.0, 100.0, 50.0, 150.0], size)], 0.01), None);
    }
}
