//! Scene indexing: after upload, the configured detector runs over every usable frame in
//! the background and its detections are cached, so a query's view pre-selection is a
//! lookup. Each frame's half-size preview is stored on the way, for stitching. The scene is
//! `indexing` until done, then `ready` (jobs on it wait queued).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use crate::geometry::{LayoutParams, RoomLayout};
use crate::jobs::JobSystem;
use crate::scene::FrameData;
use crate::store::Store;
use crate::vision::candidates::{frame_candidates, CandidateParams};
use crate::vision::{DetectInput, Detection, Detector};

/// The hook the upload handler calls with a new scene id.
/// The hook the upload handler calls with a new scene id and the first frame idx to index
/// (0: the whole scene, from scratch; more: only the frames appended from there on).
pub type IndexHook = Arc<dyn Fn(String, usize) + Send + Sync>;

/// Class-agnostic candidates at indexing: their settings and the room they are found in.
#[derive(Clone)]
pub struct CandidateSetup {
    pub params: CandidateParams,
    pub layout: LayoutParams,
}

/// One frame's index: the detector's boxes and, when asked for, the class-agnostic
/// candidates.
pub struct FrameIndex {
    pub detections: Vec<Detection>,
    pub candidates: Option<Vec<Detection>>,
}

/// Detect on one stored frame (decoding its JPEG; instance masks for the oracle), find its
/// class-agnostic candidates when `candidates` is given, and store its preview. A preview
/// that cannot be written is only logged: stitching then reads the full frame.
pub fn index_frame(
    detector: &dyn Detector,
    frame: &FrameData,
    labels: Option<&HashMap<u32, String>>,
    candidates: Option<(&CandidateSetup, Option<&RoomLayout>)>,
) -> anyhow::Result<FrameIndex> {
    let img = image::open(&frame.color_path)
        .map_err(|e| anyhow::anyhow!("frame {}: cannot decode colour: {e}", frame.name))?
        .into_rgb8();
    let candidates = candidates.map(|(setup, room)| {
        frame_candidates(
            &frame.camera,
            &frame.depth,
            &img,
            room,
            &setup.layout,
            &setup.params,
        )
        .into_iter()
        .map(|c| Detection {
            label: c.kind.label().to_string(),
            score: 1.0,
            bbox: c.bbox,
        })
        .collect()
    });
    if let Err(e) = store_preview(&img, &frame.preview_path()) {
        tracing::warn!(frame = %frame.name, "cannot store the frame's preview: {e:#}");
    }
    let instances = match (&frame.instance_path, detector.needs_instances()) {
        (Some(p), true) => Some(crate::agent::grounding::read_instance_mask(p)?),
        (None, true) => anyhow::bail!(
            "the {} detector needs instance masks and frame {} has none",
            detector.name(),
            frame.name
        ),
        _ => None,
    };
    let detections = detector.detect(&DetectInput {
        color: &img,
        instances: instances.as_ref(),
        labels,
        frame_key: frame.idx as u64,
    })?;
    Ok(FrameIndex {
        detections,
        candidates,
    })
}

/// Write the preview of `img` to `path` atomically (a crash never leaves half a file).
fn store_preview(img: &image::RgbImage, path: &Path) -> anyhow::Result<()> {
    let jpeg = crate::stitch::make_preview(img)?;
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, jpeg)?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

/// Build the hook; `detector` is None when it could not be loaded (readiness says why).
pub fn hook(
    detector_key: String,
    detector: Option<Arc<dyn Detector>>,
    candidates: Option<CandidateSetup>,
    store: Store,
    jobs: JobSystem,
) -> IndexHook {
    Arc::new(move |scene_id: String, from: usize| {
        let (store, jobs, detector, key, cands) = (
            store.clone(),
            jobs.clone(),
            detector.clone(),
            detector_key.clone(),
            candidates.clone(),
        );
        tokio::spawn(async move {
            // At most `max_concurrent_indexing` scenes at once; the others wait here.
            let _slot = jobs.indexing_slot().await;
            if let Err(e) = store.begin_index_attempt(&scene_id).await {
                tracing::error!(scene = %scene_id, "cannot count the indexing attempt: {e}");
            }
            let outcome = index_scene(&store, &jobs, &scene_id, &key, detector, cands, from).await;
            if outcome.is_ok() {
                jobs.warm_scene_points(&scene_id);
            }
            let (status, err) = match outcome {
                Ok(()) => ("ready", None),
                Err(e) => {
                    // The log keeps the full reason; the scene (and its jobs) name files only.
                    tracing::warn!(scene = %scene_id, "indexing failed: {e:#}");
                    let why = super::redact::without_paths(&format!("{e:#}"));
                    ("failed", Some(why))
                }
            };
            let ended = store.end_index_attempts(&scene_id).await;
            if let Err(e) = ended.and(
                store
                    .set_scene_status(&scene_id, status, err.as_deref())
                    .await,
            ) {
                tracing::error!(scene = %scene_id, "cannot record indexing outcome: {e}");
            }
            if status == "failed" {
                // Jobs already queued on it would wait forever: they fail with its reason.
                match store.fail_queued_jobs_of_failed_scenes().await {
                    Ok(n) if n > 0 => {
                        tracing::warn!(scene = %scene_id, jobs = n, "failed the jobs queued on a scene that failed indexing")
                    }
                    Ok(_) => {}
                    Err(e) => {
                        tracing::error!(scene = %scene_id, "cannot fail the queued jobs: {e}")
                    }
                }
            }
            jobs.wake();
        });
    })
}

/// Restart indexing of scenes a previous process left half-indexed. A scene whose indexing
/// was interrupted `max_attempts` times (each time the process died: out of memory, a
/// crashing model) ends `failed` with the reason instead of being tried again.
pub async fn resume(store: &Store, hook: &IndexHook, max_attempts: i64) -> anyhow::Result<()> {
    for (id, attempts) in store.interrupted_indexing().await? {
        if attempts >= max_attempts.max(1) {
            let why = format!(
                "indexing was interrupted {attempts} times (the process stopped during it each \
                 time, for example out of memory); given up after max_index_attempts = {max_attempts}"
            );
            tracing::error!(scene = %id, "{why}");
            store.set_scene_status(&id, "failed", Some(&why)).await?;
            store.end_index_attempts(&id).await?;
        } else {
            hook(id, 0);
        }
    }
    store.fail_queued_jobs_of_failed_scenes().await?;
    Ok(())
}

async fn index_scene(
    store: &Store,
    jobs: &JobSystem,
    scene_id: &str,
    key: &str,
    detector: Option<Arc<dyn Detector>>,
    candidates: Option<CandidateSetup>,
    from: usize,
) -> anyhow::Result<()> {
    let Some(detector) = detector else {
        anyhow::bail!("detector {key:?} could not be loaded (see /readyz)");
    };
    // The scene's files stay local while it is indexed (fetched when this replica lacks
    // them); what indexing writes beside them is uploaded before the scene turns ready.
    let _pin = jobs
        .acquire_scene(scene_id)
        .await
        .map_err(|e| anyhow::anyhow!("{}", e.detail))?;
    // Taken before loading: a scene forgotten meanwhile (frames changed) is not handed on.
    let mark = jobs.scene_cache().mark();
    let scene = Arc::new(
        store
            .load_scene(scene_id, &jobs.scene_dir(scene_id))
            .await?
            .ok_or_else(|| anyhow::anyhow!("scene {scene_id} vanished"))?,
    );
    let labels: Option<HashMap<u32, String>> = scene
        .instance_labels
        .clone()
        .map(|l| l.into_iter().collect());
    let usable: Vec<FrameData> = scene.frames.iter().filter(|f| f.usable).cloned().collect();
    if from == 0 {
        store.reset_index(scene_id, key, usable.len()).await?;
    }
    // The room's box, from every frame's depth, tells structure from objects. It is kept
    // with the scene, which later jobs get (below), so they need not estimate it again.
    let room: Option<Arc<RoomLayout>> = match &candidates {
        Some(setup) if setup.layout.enabled => {
            let (sc, lp) = (scene.clone(), setup.layout.clone());
            tokio::task::spawn_blocking(move || sc.room_layout(&lp)).await?
        }
        _ => None,
    };
    for frame in usable.into_iter().filter(|f| f.idx >= from) {
        let (d, l, c, r) = (
            detector.clone(),
            labels.clone(),
            candidates.clone(),
            room.clone(),
        );
        let (idx, index) = tokio::task::spawn_blocking(move || {
            let c = c.as_ref().map(|c| (c, r.as_deref()));
            index_frame(d.as_ref(), &frame, l.as_ref(), c).map(|x| (frame.idx, x))
        })
        .await??;
        if let Some(c) = &index.candidates {
            store.put_candidates(scene_id, idx, c).await?;
        }
        store
            .put_detections(scene_id, key, idx, &index.detections)
            .await?;
    }
    jobs.storage()
        .sync_scene(scene_id)
        .await
        .map_err(|e| anyhow::anyhow!("the previews cannot be stored: {e}"))?;
    jobs.scene_cache()
        .put_unless_forgotten(scene_id, scene, mark);
    Ok(())
}
