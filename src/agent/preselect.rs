//! Stage 2: view pre-selection from the scene's cached detections. A usable frame is
//! offered when it holds a detection of the target class above the score threshold; when
//! the detector cannot see the class or finds nothing, evenly sampled usable frames are
//! offered instead, and the trace says why.

use serde_json::json;
use std::time::Instant;

use super::{step, VlmGrounder};
use crate::jobs::{JobContext, JobFailure};
use crate::vlm::json::QueryAnalysis;

/// The frames offered to the VLM.
#[derive(Debug, Clone)]
pub struct Preselection {
    /// Frame indices (= image ids), ascending.
    pub frames: Vec<usize>,
    /// The detector's class for the target (None: it cannot see it).
    pub detector_class: Option<String>,
    /// Why the fallback was used, if it was.
    pub fallback: Option<String>,
}

/// Does a detection label name the detector class (compared in normalised form)?
pub fn same_class(label: &str, class: &str) -> bool {
    label == class || crate::vision::synonyms::normalize(label) == crate::vision::synonyms::normalize(class)
}

/// `n` indices spread evenly over `items` (all of them when there are fewer).
pub fn evenly_sampled(items: &[usize], n: usize) -> Vec<usize> {
    if items.len() <= n || n == 0 {
        return items.to_vec();
    }
    (0..n).map(|i| items[i * items.len() / n]).collect()
}

pub async fn run(g: &VlmGrounder, ctx: &JobContext, analysis: &QueryAnalysis) -> Result<Preselection, JobFailure> {
    let t = Instant::now();
    let usable: Vec<usize> = ctx.scene.usable_frames().map(|f| f.idx).collect();
    if usable.is_empty() {
        return Err(JobFailure::new("no_usable_frames", "every frame of the scene has an invalid pose"));
    }
    let class = g.detector.can_see(&analysis.target_class);
    let (frames, fallback) = match &class {
        None => (evenly_sampled(&usable, g.params.fallback_frames), Some(format!("detector cannot see this class: {:?}", analysis.target_class))),
        Some(c) => {
            let dets = ctx.store.detections(&ctx.scene.id, &g.detector_key).await.map_err(|e| JobFailure::new("storage_error", e.to_string()))?;
            let hits: Vec<usize> = usable
                .iter()
                .copied()
                .filter(|i| dets.get(i).is_some_and(|d| d.iter().any(|d| same_class(&d.label, c) && d.score > g.params.preselect_score)))
                .collect();
            if hits.is_empty() {
                (evenly_sampled(&usable, g.params.fallback_frames), Some(format!("no frame has a {c:?} detection above {}", g.params.preselect_score)))
            } else {
                (hits, None)
            }
        }
    };
    let names: Vec<&str> = frames.iter().map(|&i| ctx.scene.frames[i].name.as_str()).collect();
    let image_ids: Vec<String> = frames.iter().map(|i| format!("{i:05}")).collect();
    step(
        ctx,
        "preselection",
        json!({"target_class": analysis.target_class, "usable_frames": usable.len()}),
        json!({"detector_class": class, "image_ids": image_ids, "frames": names, "fallback": fallback}),
        t,
    )
    .await;
    Ok(Preselection { frames, detector_class: class, fallback })
}

#[cfg(test)]
mod tests {
    use super::evenly_sampled;

    #[test]
    fn samples_evenly_without_repeats() {
        let items: Vec<usize> = (0..10).collect();
        assert_eq!(evenly_sampled(&items, 5), vec![0, 2, 4, 6, 8]);
        assert_eq!(evenly_sampled(&items, 20), items);
        assert_eq!(evenly_sampled(&items[..3], 2), vec![0, 1]);
    }
}
