//! Scene indexing: after upload, the configured detector runs over every usable frame in
//! the background and its detections are cached, so a query's view pre-selection is a
//! lookup. The scene is `indexing` until done, then `ready` (jobs on it wait queued).

use std::sync::Arc;

use crate::api::Readiness;
use crate::config::Config;
use crate::jobs::JobSystem;
use crate::scene::FrameData;
use crate::store::Store;
use crate::vision::Detection;

/// Runs the detector on one frame.
pub type DetectFn = Arc<dyn Fn(&FrameData) -> anyhow::Result<Vec<Detection>> + Send + Sync>;

/// Build the detector used for indexing; problems are reported through readiness.
pub fn build_detect_fn(cfg: &Config, readiness: &mut Readiness) -> Option<DetectFn> {
    match crate::vision::index::detect_fn(&cfg.detector) {
        Ok(f) => Some(f),
        Err(e) => {
            readiness.problems.push(format!("detector {:?} is not available: {e:#}", cfg.detector));
            None
        }
    }
}

/// The hook the upload handler calls with a new scene id.
pub fn hook(cfg: &Config, store: Store, jobs: JobSystem, readiness: &mut Readiness) -> Arc<dyn Fn(String) + Send + Sync> {
    let detector_name = cfg.detector.clone();
    let detect = if cfg.detector == "none" { None } else { build_detect_fn(cfg, readiness) };
    Arc::new(move |scene_id: String| {
        let (store, jobs, detect, name) = (store.clone(), jobs.clone(), detect.clone(), detector_name.clone());
        tokio::spawn(async move {
            let outcome = index_scene(&store, &jobs, &scene_id, &name, detect).await;
            let (status, err) = match outcome {
                Ok(()) => ("ready", None),
                Err(e) => ("failed", Some(format!("{e:#}"))),
            };
            if let Err(e) = store.set_scene_status(&scene_id, status, err.as_deref()).await {
                tracing::error!(scene = %scene_id, "cannot record indexing outcome: {e}");
            }
            jobs.wake();
        });
    })
}

/// Restart indexing of scenes a previous process left half-indexed.
pub async fn resume(store: &Store, hook: &Arc<dyn Fn(String) + Send + Sync>) -> anyhow::Result<()> {
    for id in store.scenes_with_status("indexing").await? {
        hook(id);
    }
    Ok(())
}

async fn index_scene(store: &Store, jobs: &JobSystem, scene_id: &str, detector: &str, detect: Option<DetectFn>) -> anyhow::Result<()> {
    let Some(detect) = detect else {
        anyhow::bail!("detector {detector:?} could not be loaded (see /readyz)");
    };
    let scene = store
        .load_scene(scene_id, &jobs.scene_dir(scene_id))
        .await?
        .ok_or_else(|| anyhow::anyhow!("scene {scene_id} vanished"))?;
    let usable: Vec<FrameData> = scene.frames.iter().filter(|f| f.usable).cloned().collect();
    store.reset_index(scene_id, detector, usable.len()).await?;
    for frame in usable {
        let d = detect.clone();
        let dets = tokio::task::spawn_blocking(move || d(&frame).map(|x| (frame.idx, x))).await??;
        store.put_detections(scene_id, detector, dets.0, &dets.1).await?;
    }
    Ok(())
}
