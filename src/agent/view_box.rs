//! Ours: the whole object's box in ensemble views, from the VLM (`[agent.candidates]
//! view_box`). When the chosen view saw only a part of the object (`geometry::partial`),
//! a view with no detection of the class or class-agnostic candidate holding the
//! reprojected part segments that part alone, and the box would stop where the chosen
//! frame's edge cut the object (a window seen from up close, whose whole is seen only from
//! across the room). Unless some view has a detection of the class (which holds the whole
//! object there), the VLM is shown up to `view_box_views` such views, those most likely to
//! hold all of the object first, one call each, with the part outlined, and asked for the
//! whole object's box there. An answer is used as a detection would be: only when it holds
//! at least half the reprojected pixels ([`super::ensemble_boxes::pick_detection`]). It
//! never fails the job: a refusal, an unusable box or a failed call keeps the view's
//! footprint. The views are asked at the same time, no more of them than the job's VLM
//! call budget has calls left.

use image::RgbImage;
use serde_json::{json, Value};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

use super::conversation::Conversation;
use super::ensemble_boxes::{pick_detection, BoxFrom};
use super::vlm_log::VlmLog;
use super::VlmGrounder;
use crate::geometry::ensemble::ViewCandidate;
use crate::jobs::{JobContext, JobFailure};
use crate::stitch::label::{stroke_rect, PixelRect};
use crate::stitch::render::encode_jpeg;
use crate::vlm::boxes::{parse_box, BoxAnswer};
use crate::vlm::{CallBudget, ImageData, Message, VlmStep};

/// The views to ask, as positions in `views` (`(footprint box, frame size)` each), best
/// first: the one whose footprint lies farthest inside its frame for its size (the
/// smallest distance to an edge over the footprint's longer side) has the most room
/// around the part for the rest of the object. A footprint within `border_frac` of the
/// width from an edge is cut in that view too, and is not asked about.
pub fn rank_views(views: &[([f32; 4], (u32, u32))], border_frac: f64) -> Vec<usize> {
    let mut ranked: Vec<(usize, f32)> = views
        .iter()
        .enumerate()
        .filter_map(|(k, (b, (w, h)))| {
            let (w, h) = (*w as f32, *h as f32);
            let margin = b[0].min(b[1]).min(w - b[2]).min(h - b[3]);
            let side = (b[2] - b[0]).max(b[3] - b[1]).max(1.0);
            (margin > border_frac as f32 * w).then_some((k, margin / side))
        })
        .collect();
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    ranked.into_iter().map(|(k, _)| k).collect()
}

/// The views that may be asked: those whose box is the footprint, unless some view has a
/// detection of the class (it holds the whole object there, so the fusion is not capped
/// by the part). `None` when none may be.
pub fn footprint_views(view_boxes: &[(usize, [f32; 4], BoxFrom)]) -> Option<Vec<usize>> {
    if view_boxes.iter().any(|v| v.2 == BoxFrom::Detection) {
        return None;
    }
    let views: Vec<usize> = view_boxes
        .iter()
        .filter(|v| v.2 == BoxFrom::Footprint)
        .map(|v| v.0)
        .collect();
    (!views.is_empty()).then_some(views)
}

/// What every `view_box` request of a job shares.
pub struct Asker<'a> {
    pub g: &'a VlmGrounder,
    pub ctx: &'a JobContext,
    pub budget: &'a CallBudget,
    pub log: &'a VlmLog,
    pub target_class: &'a str,
    /// The chosen frame, where the part was seen.
    pub anchor_idx: usize,
}

/// A view made ready to ask: the frame with the part outlined, stored as an artifact.
struct Prepared<'v> {
    view: &'v ViewCandidate,
    size: (u32, u32),
    jpeg: Vec<u8>,
    url: String,
}

/// Ask for the whole object's box in the views whose box is the part's footprint, when the
/// chosen view saw a part and no view has a detection of the class (see the module
/// documentation); a view's box and its source are replaced when its answer is used. The
/// views are asked at the same time, and the compute `slot` is let go meanwhile. Returns
/// what was done, for the projection's trace (null when nothing was asked).
pub async fn complete(
    a: &Asker<'_>,
    anchor_partial: bool,
    views: &[ViewCandidate],
    view_boxes: &mut [(usize, [f32; 4], BoxFrom)],
    decoded: &HashMap<usize, Arc<RgbImage>>,
    slot: &mut Option<tokio::sync::SemaphorePermit<'_>>,
) -> Result<Value, JobFailure> {
    let cp = &a.g.params.candidates;
    if !cp.enabled || !cp.view_box || cp.view_box_views == 0 || !anchor_partial {
        return Ok(Value::Null);
    }
    let Some(askable) = footprint_views(view_boxes) else {
        return Ok(Value::Null);
    };
    // Views (positions in `views`) whose box is the footprint, with a decoded image.
    let usable: Vec<(usize, &Arc<RgbImage>)> = views
        .iter()
        .enumerate()
        .filter(|(_, v)| askable.contains(&v.index))
        .filter_map(|(k, v)| decoded.get(&v.index).map(|img| (k, img)))
        .collect();
    if usable.is_empty() {
        return Ok(Value::Null);
    }
    let shapes: Vec<([f32; 4], (u32, u32))> = usable
        .iter()
        .map(|(k, img)| (views[*k].bbox, img.dimensions()))
        .collect();
    let ranked = rank_views(&shapes, cp.partial.border_frac);
    if ranked.is_empty() {
        return Ok(json!({"asked": false, "why": "every view's part touches its frame's edge"}));
    }
    let wanted = ranked.len().min(cp.view_box_views);
    // A call past the job's budget would only be refused: the views beyond it keep their
    // footprint.
    let n = wanted.min(usize::try_from(a.budget.calls_left()).unwrap_or(usize::MAX));
    let mut prepared = Vec::with_capacity(n);
    for &pos in &ranked[..n] {
        let (k, image) = usable[pos];
        prepared.push(prepare(a, &views[k], image.clone()).await?);
    }
    // Other jobs may compute while this one waits for the VLM (the caller takes a slot
    // again before it goes on).
    slot.take();
    let answers = futures::future::join_all(prepared.iter().map(|p| ask_view(a, p))).await;
    let mut asked = Vec::new();
    for (p, answer) in prepared.iter().zip(answers) {
        let (record, answer) = answer?;
        a.ctx.trace.step("view_box", record).await;
        if let Some(b) = answer {
            if let Some(vb) = view_boxes.iter_mut().find(|v| v.0 == p.view.index) {
                vb.1 = b;
                vb.2 = BoxFrom::VlmBox;
            }
        }
        asked.push(json!({"image_id": format!("{:05}", p.view.index), "used": answer.is_some()}));
    }
    let mut out = json!({"asked": !asked.is_empty(), "views": asked});
    if n < wanted {
        out["stopped"] = json!("the job's VLM call budget is spent");
    }
    Ok(out)
}

/// The frame with the part outlined in red, encoded and stored as the request's artifact.
async fn prepare<'v>(
    a: &Asker<'_>,
    view: &'v ViewCandidate,
    image: Arc<RgbImage>,
) -> Result<Prepared<'v>, JobFailure> {
    let size = image.dimensions();
    let part = view.bbox;
    let quality = a.g.params.stitch.jpeg_quality;
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
    let url = a
        .ctx
        .trace
        .artifact(&format!("view_box_{:05}.jpg", view.index), jpeg.clone())
        .await?;
    Ok(Prepared {
        view,
        size,
        jpeg,
        url,
    })
}

/// One view's request: the VLM's box of the whole object there. Returns the `view_box`
/// step's record and the box when it holds the part; fails only when the job is canceled.
async fn ask_view(
    a: &Asker<'_>,
    p: &Prepared<'_>,
) -> Result<(Value, Option<[f32; 4]>), JobFailure> {
    let t = Instant::now();
    let (g, view, part) = (a.g, p.view, p.view.bbox);
    let format = g.params.box_format;
    let text = g.prompts.view_box_request(
        &a.ctx.query,
        a.target_class,
        view.index as u32,
        a.anchor_idx as u32,
        p.size,
        part,
        format,
    );
    let inputs = json!({"image_id": format!("{:05}", view.index), "anchor_image_id": format!("{:05}", a.anchor_idx), "part_box": part, "box_format": format.name(), "image": p.url});
    let mut conv = Conversation {
        messages: vec![Message::user_with_images(
            text,
            vec![ImageData::jpeg(p.jpeg.clone())],
        )],
        image_urls: vec![p.url.clone()],
        logged: 0,
        log: a.log,
        rounds: 0,
        feedback_at: Vec::new(),
    };
    let (outputs, answer) = match conv.ask(g, a.budget, VlmStep::Box).await {
        Err(e) if e.code == "canceled" => return Err(e),
        Err(e) => (
            json!({"box": null, "used": false, "why": format!("the call failed: {}", e.detail)}),
            None,
        ),
        Ok((reply, rec)) => match parse_box(&reply, format, p.size) {
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
    Ok((
        json!({"inputs": inputs, "outputs": outputs, "ms": super::ms(t)}),
        answer,
    ))
}

#[cfg(test)]
mod tests {
    use super::{footprint_views, rank_views};
    use crate::agent::ensemble_boxes::BoxFrom;

    #[test]
    fn footprint_views_are_asked_unless_a_view_has_a_detection() {
        let b = [0.0, 0.0, 10.0, 10.0];
        let mixed = [
            (3, b, BoxFrom::Footprint),
            (5, b, BoxFrom::Candidate),
            (7, b, BoxFrom::Footprint),
        ];
        // A candidate may be partial or merged: the footprints beside it are still asked.
        assert_eq!(footprint_views(&mixed), Some(vec![3, 7]));
        let mut detected = mixed;
        detected[1].2 = BoxFrom::Detection;
        assert_eq!(footprint_views(&detected), None);
        assert_eq!(footprint_views(&[(5, b, BoxFrom::Candidate)]), None);
        assert_eq!(footprint_views(&[]), None);
    }

    #[test]
    fn views_with_the_most_room_around_the_part_are_asked_first() {
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
        assert_eq!(rank_views(&views, 0.01), vec![2, 1, 3]);
        assert_eq!(rank_views(&views[..2], 0.01), vec![1]);
        // Only parts at the edge: nobody is asked.
        assert!(rank_views(&views[..1], 0.01).is_empty());
        assert!(rank_views(&[], 0.01).is_empty());
        // A part 5 px from the edge of a 640 px frame is within 1 % of it.
        assert!(rank_views(&[([5.0, 100.0, 50.0, 150.0], size)], 0.01).is_empty());
        // Equal room: the earlier view first.
        let twins = [([100.0, 100.0, 140.0, 140.0], size); 2];
        assert_eq!(rank_views(&twins, 0.01), vec![0, 1]);
    }
}
