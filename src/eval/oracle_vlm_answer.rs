//! What the oracle VLM answers: reads the conversation (text and images only), recognises
//! the prompt by the templates' marker lines, and answers from ground truth.
//!
//! Query lookup: the last `Query: ` line is matched (case/whitespace-insensitive) against
//! queries.jsonl. When the same text belongs to several (scene, target) pairs, the oracle
//! compares colour histograms of the received images with the candidate scenes' frames
//! (instance selection: the frame with the chosen image id; grounding: the offered frames)
//! and takes the closest scene. Query analysis carries no image: the most frequent label
//! among the matches is answered.

use super::oracle_vlm_truth::{
    color_histogram_bytes, color_histogram_file, hist_distance, QueryRec, SceneTruth, Truth,
};
use crate::vlm::boxes::BoxFormat;
use crate::vlm::prompts::markers;
use rand::Rng;
use serde_json::json;
use std::sync::Arc;

/// A message as the oracle sees it.
#[derive(Debug, Clone, Default)]
pub struct SeenMessage {
    /// "system", "user" or "assistant".
    pub role: String,
    /// Text parts joined.
    pub text: String,
    /// Decoded image bytes (from data URLs).
    pub images: Vec<Vec<u8>>,
}

/// Which question is being asked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Query analysis.
    Analysis,
    /// Image selection.
    Grounding,
    /// Object selection (detections or set-of-marks regions).
    Instance,
    /// The target's 2D box in a frame.
    Box,
}

/// The facts the oracle extracted from a conversation.
#[derive(Debug, Clone)]
pub struct Conversation {
    /// Question kind (from the latest task message).
    pub mode: Mode,
    /// The user's sentence.
    pub query: Option<String>,
    /// Image ids offered in the grounding message, if listed.
    pub offered: Option<Vec<u32>>,
    /// Image ids rejected by object-not-existing or not-measured feedback.
    pub rejected: Vec<u32>,
    /// Image ids the latest not-measured feedback names as having measured the place.
    pub measured_by: Vec<u32>,
    /// Instance selection: the frame's image id.
    pub frame: Option<u32>,
    /// Instance selection: the frame size the boxes refer to.
    pub frame_size: Option<(u32, u32)>,
    /// Instance selection: candidate boxes by object id.
    pub candidates: Vec<[f32; 4]>,
    /// Instance selection over set-of-marks regions, where "none" is a valid answer.
    pub marks: bool,
    /// Box request: the coordinate convention asked for.
    pub box_format: Option<BoxFormat>,
    /// Images of the latest task message.
    pub images: Vec<Vec<u8>>,
}

fn has_marker(text: &str, marker: &str) -> bool {
    text.lines().any(|l| l.trim() == marker)
}

/// Five-digit numbers standing alone in `s`.
fn five_digit_ids(s: &str) -> Vec<u32> {
    s.split(|c: char| !c.is_ascii_digit())
        .filter(|t| t.len() == 5)
        .filter_map(|t| t.parse().ok())
        .collect()
}

/// The ids on the latest line (latest message first, its lines in order) whose trimmed
/// text `list_of` accepts, read from what `list_of` returns of it.
fn latest_ids(users: &[&SeenMessage], list_of: impl Fn(&str) -> Option<&str>) -> Option<Vec<u32>> {
    users
        .iter()
        .rev()
        .flat_map(|m| m.text.lines())
        .find_map(|l| list_of(l.trim()).map(five_digit_ids))
}

/// Feedback rejecting the chosen image: the VLM is to choose another one.
fn sends_back(text: &str) -> bool {
    has_marker(text, markers::OBJECT_NOT_EXISTING) || has_marker(text, markers::NO_DEPTH)
}

/// Read a conversation. None when no task marker is present.
pub fn read_conversation(messages: &[SeenMessage]) -> Option<Conversation> {
    let users: Vec<&SeenMessage> = messages.iter().filter(|m| m.role == "user").collect();
    let (pos, mode) = users.iter().enumerate().rev().find_map(|(i, m)| {
        if has_marker(&m.text, markers::INSTANCE) || has_marker(&m.text, markers::MARKS) {
            Some((i, Mode::Instance))
        } else if has_marker(&m.text, markers::BOX) {
            Some((i, Mode::Box))
        } else if has_marker(&m.text, markers::GROUNDING) || sends_back(&m.text) {
            Some((i, Mode::Grounding))
        } else if has_marker(&m.text, markers::QUERY_ANALYSIS) {
            Some((i, Mode::Analysis))
        } else {
            None
        }
    })?;
    // Feedback that sends the VLM back to choosing an image, after an object, mark or box
    // task in that image: the image-selection task before it is the one answered again.
    let pos = if sends_back(&users[pos].text) {
        (0..pos)
            .rev()
            .find(|&i| has_marker(&users[i].text, markers::GROUNDING))
            .unwrap_or(pos)
    } else {
        pos
    };
    let task = users[pos];
    let query = users
        .iter()
        .rev()
        .flat_map(|m| m.text.lines().rev())
        .find_map(|l| {
            l.trim()
                .strip_prefix("Query:")
                .map(|q| q.trim().to_string())
        });
    let offered = latest_ids(&users, |l| {
        let rest = l.strip_prefix("Offered image ids")?;
        Some(rest.split_once(':')?.1)
    });
    let measured_line = |l: &str| l.trim().starts_with(markers::MEASURED_BY);
    let rejected = users
        .iter()
        .filter(|m| sends_back(&m.text))
        .flat_map(|m| m.text.lines().filter(|l| !measured_line(l)))
        .flat_map(five_digit_ids)
        .collect();
    let measured_by =
        latest_ids(&users, |l| l.strip_prefix(markers::MEASURED_BY)).unwrap_or_default();
    let mut conv = Conversation {
        mode,
        query,
        offered,
        rejected,
        measured_by,
        frame: None,
        frame_size: None,
        candidates: Vec::new(),
        marks: has_marker(&task.text, markers::MARKS),
        box_format: None,
        // Images of the task message; if the agent sent them in separate messages, all
        // images from the task message on.
        images: if task.images.is_empty() {
            users[pos..]
                .iter()
                .flat_map(|m| m.images.iter().cloned())
                .collect()
        } else {
            task.images.clone()
        },
    };
    if mode == Mode::Instance || mode == Mode::Box {
        let t = &task.text;
        conv.box_format = t
            .lines()
            .find_map(|l| BoxFormat::parse(l.trim().strip_prefix("Box format:")?));
        conv.frame = t.find("frame ").and_then(|i| {
            let head: String = t[i + 6..].chars().take(5).collect();
            five_digit_ids(&head).first().copied()
        });
        conv.frame_size = t.find(" pixels").and_then(|end| {
            let head = &t[..end];
            let open = head.rfind('(')?;
            let (w, h) = head[open + 1..].split_once(" x ")?;
            Some((w.trim().parse().ok()?, h.trim().parse().ok()?))
        });
        for l in t.lines() {
            let Some(rest) = l.trim().strip_prefix("ID ") else {
                continue;
            };
            let Some((_, b)) = rest.split_once('[') else {
                continue;
            };
            let nums: Vec<f32> = b
                .trim_end_matches(']')
                .split(',')
                .filter_map(|x| x.trim().parse().ok())
                .collect();
            if nums.len() == 4 {
                conv.candidates.push([nums[0], nums[1], nums[2], nums[3]]);
            }
        }
    }
    Some(conv)
}

/// Pick the (scene, target) for the query; see the module doc for ties.
fn resolve<'a>(
    truth: &'a Truth,
    conv: &Conversation,
) -> Option<(&'a QueryRec, Option<Arc<SceneTruth>>)> {
    let matches = truth.find(conv.query.as_deref()?);
    if matches.len() <= 1 || conv.mode == Mode::Analysis {
        let q = if conv.mode == Mode::Analysis {
            majority_label(&matches)?
        } else {
            *matches.first()?
        };
        let scene = truth
            .scene(&q.scene_id)
            .map_err(|e| tracing::warn!("oracle: {e:#}"))
            .ok();
        return Some((q, scene));
    }
    let received: Vec<[f32; 64]> = conv
        .images
        .iter()
        .filter_map(|b| color_histogram_bytes(b))
        .collect();
    let mut best: Option<(f32, &QueryRec, Arc<SceneTruth>)> = None;
    for q in matches {
        let Ok(scene) = truth.scene(&q.scene_id) else {
            continue;
        };
        let ids: Vec<u32> = match (conv.mode, conv.frame, &conv.offered) {
            (Mode::Instance | Mode::Box, Some(f), _) => vec![f],
            (_, _, Some(o)) => o.clone(),
            _ => (0..scene.frames.len() as u32).take(12).collect(),
        };
        let hists: Vec<[f32; 64]> = ids
            .iter()
            .filter_map(|&i| {
                scene
                    .frames
                    .get(i as usize)?
                    .color
                    .as_deref()
                    .and_then(color_histogram_file)
            })
            .collect();
        let d = match (mean_hist(&received), mean_hist(&hists)) {
            (Some(a), Some(b)) => hist_distance(&a, &b),
            _ => f32::INFINITY,
        };
        if best.as_ref().is_none_or(|(bd, _, _)| d < *bd) {
            best = Some((d, q, scene));
        }
    }
    best.map(|(_, q, s)| (q, Some(s)))
}

fn majority_label<'a>(m: &[&'a QueryRec]) -> Option<&'a QueryRec> {
    m.iter().copied().max_by_key(|q| {
        m.iter()
            .filter(|o| o.target_label == q.target_label)
            .count()
    })
}

fn mean_hist(h: &[[f32; 64]]) -> Option<[f32; 64]> {
    if h.is_empty() {
        return None;
    }
    let mut out = [0f32; 64];
    for x in h {
        for (o, v) in out.iter_mut().zip(x) {
            *o += v / h.len() as f32;
        }
    }
    Some(out)
}

fn iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let area = |r: &[f32; 4]| (r[2] - r[0]).max(0.0) * (r[3] - r[1]).max(0.0);
    let union = area(a) + area(b) - inter;
    if union > 0.0 {
        inter / union
    } else {
        0.0
    }
}

/// Which frames show `target`: those that do by the scorer's rule ([`SceneTruth::shows`]);
/// when none does (an object too small for every view), those holding a pixel of it.
fn showing(scene: &SceneTruth, target: u32) -> impl Fn(u32) -> bool + '_ {
    let by_rule = (0..scene.frames.len() as u32).any(|i| scene.shows(i, target));
    move |i| {
        if by_rule {
            scene.shows(i, target)
        } else {
            scene.pixels(i, target) > 0
        }
    }
}

/// No offered frame shows `target`, while some frame of the scene does (so the VLM can
/// be shown it once the other frames are offered). "Shows" is [`best_frame`]'s rule, so the
/// oracle never names a frame that was not offered where it could have said so.
pub fn not_offered(scene: &SceneTruth, target: u32, offered: &[u32]) -> bool {
    let shows = showing(scene, target);
    offered.iter().all(|&i| !shows(i)) && (0..scene.frames.len() as u32).any(shows)
}

/// The best image id: among the offered (else all) frames, not rejected, the one that
/// shows the target best ([`SceneTruth::visibility`]: most pixels, halved when cut by the
/// image border).
pub fn best_frame(
    scene: &SceneTruth,
    target: u32,
    offered: Option<&[u32]>,
    rejected: &[u32],
) -> Option<u32> {
    let all: Vec<u32> = (0..scene.frames.len() as u32).collect();
    let pool: Vec<u32> = offered
        .unwrap_or(&all)
        .iter()
        .copied()
        .filter(|i| !rejected.contains(i))
        .collect();
    let shows = showing(scene, target);
    let pick = |ids: &[u32]| {
        ids.iter()
            .copied()
            .filter(|&i| shows(i))
            .max_by_key(|&i| (scene.visibility(i, target), std::cmp::Reverse(i)))
    };
    // Not visible in any offered frame: answer the best frame overall and let feedback work.
    pick(&pool)
        .or_else(|| {
            pick(
                &all.iter()
                    .copied()
                    .filter(|i| !rejected.contains(i))
                    .collect::<Vec<_>>(),
            )
        })
        .or(pool.first().copied())
}

/// The image the oracle names: among the frames the latest not-measured feedback named
/// (`measured_by`), the one that shows the target best, as a careful reader would take
/// them; when none of them shows it, [`best_frame`] over the offered frames.
pub fn image_choice(scene: &SceneTruth, target: u32, conv: &Conversation) -> Option<u32> {
    let named = &conv.measured_by;
    let shows = showing(scene, target);
    (!named.is_empty())
        .then(|| best_frame(scene, target, Some(named), &conv.rejected))
        .flatten()
        .filter(|i| named.contains(i) && shows(*i))
        .or_else(|| best_frame(scene, target, conv.offered.as_deref(), &conv.rejected))
}

/// A set-of-marks region outlines the target when its box overlaps the target's extent in
/// the frame by at least this IoU: the usual criterion for a box matching an object. Below
/// it (a piece of the object, or the object with its neighbour) the oracle answers that no
/// region is the target, as a careful reader of the marked image would.
pub const MARK_MATCH_IOU: f32 = 0.5;

/// The candidate best overlapping the target's extent in the frame (boxes rescaled from
/// the size stated in the prompt to the colour image size).
pub fn best_candidate(scene: &SceneTruth, target: u32, conv: &Conversation) -> Option<u32> {
    best_candidate_iou(scene, target, conv).map(|(i, _)| i)
}

/// [`best_candidate`] with its IoU.
pub fn best_candidate_iou(
    scene: &SceneTruth,
    target: u32,
    conv: &Conversation,
) -> Option<(u32, f32)> {
    let frame = scene.frames.get(conv.frame? as usize)?;
    let gt = frame.instances.get(&target)?.bbox;
    let (sx, sy) = match conv.frame_size {
        Some((w, h)) if w > 0 && h > 0 => (
            frame.size.0 as f32 / w as f32,
            frame.size.1 as f32 / h as f32,
        ),
        _ => (1.0, 1.0),
    };
    conv.candidates
        .iter()
        .enumerate()
        .map(|(i, b)| {
            (
                i as u32,
                iou(&[b[0] * sx, b[1] * sy, b[2] * sx, b[3] * sy], &gt),
            )
        })
        .filter(|(_, v)| *v > 0.0)
        .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
}

/// Produce the reply text. `error_rate` with the given RNG injects fallible answers.
pub fn answer(truth: &Truth, conv: &Conversation, error_rate: f64, rng: &mut impl Rng) -> String {
    let resolved = resolve(truth, conv);
    let fail = error_rate > 0.0 && rng.gen_bool(error_rate.clamp(0.0, 1.0));
    let kind = if fail { rng.gen_range(0..3u8) } else { u8::MAX };
    // Query analysis has no id to get wrong: its fallible answer is malformed JSON.
    if kind == 2 || (fail && conv.mode == Mode::Analysis) {
        return "{\"reasoning\": \"I believe the object is in".to_string();
    }
    match conv.mode {
        Mode::Analysis => {
            let (class, cond) = match &resolved {
                Some((q, _)) => (q.target_label.clone(), vec![q.text.clone()]),
                None => ("unknown".to_string(), vec![]),
            };
            json!({"target_class": class, "attributes": [], "conditions": cond}).to_string()
        }
        Mode::Grounding if resolved.is_none() => {
            // A sentence the ground truth does not hold: no frame shows it, so the oracle
            // names none (the job ends `target_not_found` instead of boxing something).
            json!({"reasoning": "oracle: this sentence is not in the ground truth",
                   "target_image_id": "none", "reference_image_ids": []})
            .to_string()
        }
        Mode::Grounding
            if kind == u8::MAX
                && conv.offered.as_deref().is_some_and(|o| {
                    resolved.as_ref().is_some_and(|(q, s)| {
                        s.as_deref().is_some_and(|s| not_offered(s, q.target_id, o))
                    })
                }) =>
        {
            // No offered frame shows the target (the detector's pre-selection left it out):
            // say so, as the prompt allows, and the service offers the other frames.
            json!({"reasoning": "oracle: no offered frame shows the target",
                   "target_image_id": null, "reference_image_ids": []})
            .to_string()
        }
        Mode::Grounding => {
            let offered = conv.offered.as_deref();
            let best = resolved
                .as_ref()
                .and_then(|(q, s)| image_choice(s.as_deref()?, q.target_id, conv));
            let mut id = best
                .or_else(|| offered.and_then(|o| o.first().copied()))
                .unwrap_or(0);
            let mut why = "the target is shown best in this frame".to_string();
            if kind == 0 {
                if let Some(other) = offered.and_then(|o| o.iter().copied().find(|&i| i != id)) {
                    id = other;
                    why = "injected error: a wrong frame".into();
                }
            }
            if kind == 1 {
                id = offered
                    .and_then(|o| o.iter().max().copied())
                    .unwrap_or(id)
                    .saturating_add(1000)
                    % 100_000;
                why = "injected error: an id that was not offered".into();
            }
            json!({"reasoning": format!("oracle: {why}"), "target_image_id": format!("{id:05}"),
                   "reference_image_ids": [format!("{id:05}")]})
            .to_string()
        }
        Mode::Instance => {
            let best = resolved
                .as_ref()
                .and_then(|(q, s)| best_candidate_iou(s.as_deref()?, q.target_id, conv));
            // No region outlines the target, none even touches it, or the target is not in
            // this frame: a careful reader answers that none is the target rather than
            // picking an unrelated region.
            let none_fits = resolved.is_some() && best.is_none_or(|(_, v)| v < MARK_MATCH_IOU);
            if conv.marks && kind == u8::MAX && none_fits {
                return json!({"reasoning": "oracle: no region outlines the target", "object_id": null})
                    .to_string();
            }
            let best = best.map(|(i, _)| i);
            let n = conv.candidates.len() as u32;
            let mut id = best.unwrap_or(0);
            let mut why = "this box overlaps the target most".to_string();
            if kind == 0 && n > 1 {
                id = (id + 1) % n;
                why = "injected error: a wrong object".into();
            }
            if kind == 1 || (kind == 0 && n <= 1) {
                id = n;
                why = "injected error: an id that does not exist".into();
            }
            json!({"reasoning": format!("oracle: {why}"), "object_id": id}).to_string()
        }
        Mode::Box => {
            let format = conv.box_format.unwrap_or_default();
            let size = conv.frame_size.unwrap_or((1, 1));
            let truth_box = resolved
                .as_ref()
                .and_then(|(q, s)| target_box(s.as_deref()?, q.target_id, conv));
            let Some(mut b) = truth_box else {
                return json!({"reasoning": "oracle: the target is not in this frame", "bbox_2d": null})
                    .to_string();
            };
            let mut why = "the target's extent in this frame";
            if kind == 0 {
                // Beside the target: the box of whatever stands next to it.
                let w = b[2] - b[0];
                let shift = if b[2] + w <= size.0 as f32 {
                    w
                } else {
                    -w.min(b[0])
                };
                b = [b[0] + shift, b[1], b[2] + shift, b[3]];
                why = "injected error: a box beside the target";
            }
            if kind == 1 {
                b = [b[0], b[1], size.0 as f32 * 1.5 + 10.0, b[3]];
                why = "injected error: a box outside the frame";
            }
            let e = format.encode(b, size);
            json!({"reasoning": format!("oracle: {why}"), "bbox_2d": [e[0].round(), e[1].round(), e[2].round(), e[3].round()]})
                .to_string()
        }
    }
}

/// The target's box in the frame of a box request, in the pixels the prompt states.
pub fn target_box(scene: &SceneTruth, target: u32, conv: &Conversation) -> Option<[f32; 4]> {
    let frame = scene.frames.get(conv.frame? as usize)?;
    let gt = frame.instances.get(&target)?.bbox;
    let (w, h) = conv.frame_size.filter(|s| s.0 > 0 && s.1 > 0)?;
    let (sx, sy) = (
        w as f32 / frame.size.0.max(1) as f32,
        h as f32 / frame.size.1.max(1) as f32,
    );
    Some([gt[0] * sx, gt[1] * sy, gt[2] * sx, gt[3] * sy])
}

#[cfg(test)]
#[path = "oracle_vlm_answer_tests.rs"]
mod tests;
