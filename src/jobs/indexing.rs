//! Scene indexing: after upload, the configured detector runs over every usable frame in
//! the background and its detections are cached, so a query's view pre-selection is a
//! lookup. Each frame's half-size preview is stored on the way, for stitching. The scene is
//! `indexing` until done, then `ready` (jobs on it wait queued).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use crate::jobs::JobSystem;
use crate::scene::FrameData;
use crate::store::Store;
use crate::vision::{DetectInput, Detection, Detector};

/// The hook the upload handler calls with a new scene id.
pub type IndexHook = Arc<dyn Fn(String) + Send + Sync>;

/// Detect on one stored frame (decoding its JPEG; instance masks for the oracle) and store
/// its preview. A preview that cannot be written is only logged: stitching then reads the
/// full frame.
pub fn detect_frame(
    detector: &dyn Detector,
    frame: &FrameData,
    labels: Option<&HashMap<u32, String>>,
) -> anyhow::Result<Vec<Detection>> {
    let img = image::open(&frame.color_path)
        .map_err(|e| anyhow::anyhow!("frame {}: cannot decode colour: {e}", frame.name))?
        .to_rgb8();
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
    detector.detect(&DetectInput {
        color: &img,
        instances: instances.as_ref(),
        labels,
        frame_key: frame.idx as u64,
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
    store: Store,
    jobs: JobSystem,
) -> IndexHook {
    Arc::new(move |scene_id: String| {
        let (store, jobs, detector, key) = (
            store.clone(),
            jobs.clone(),
            detector.clone(),
            detector_key.clone(),
        );
        tokio::spawn(async move {
            let outcome = index_scene(&store, &jobs, &scene_id, &key, detector).await;
            if outcome.is_ok() {
                jobs.warm_scene_points(&scene_id);
            }
            let (status, err) = match outcome {
                Ok(()) => ("ready", None),
                Err(e) => ("failed", Some(format!("{e:#}"))),
            };
            if let Err(e) = store
                .set_scene_status(&scene_id, status, err.as_deref())
                .await
            {
                tracing::error!(scene = %scene_id, "cannot record indexing outcome: {e}");
            }
            jobs.wake();
        });
    })
}

/// Restart indexing of scenes a previous process left half-indexed.
pub async fn resume(store: &Store, hook: &IndexHook) -> anyhow::Result<()> {
    for id in store.scenes_with_status("indexing").await? {
        hook(id);
    }
    Ok(())
}

async fn index_scene(
    store: &Store,
    jobs: &JobSystem,
    scene_id: &str,
    key: &str,
    detector: Option<Arc<dyn Detector>>,
) -> anyhow::Result<()> {
    let Some(detector) = detector else {
        anyhow::bail!("detector {key:?} could not be loaded (see /readyz)");
    };
    let scene = store
        .load_scene(scene_id, &jobs.scene_dir(scene_id))
        .await?
        .ok_or_else(|| anyhow::anyhow!("scene {scene_id} vanished"))?;
    let labels: Option<HashMap<u32, String>> = scene
        .instance_labels
        .clone()
        .map(|l| l.into_iter().collect());
    let usable: Vec<FrameData> = scene.frames.iter().filter(|f| f.usable).cloned().collect();
    store.reset_index(scene_id, key, usable.len()).await?;
    for frame in usable {
        let (d, l) = (detector.clone(), labels.clone());
        let (idx, dets) = tokio::task::spawn_blocking(move || {
            detect_frame(d.as_ref(), &frame, l.as_ref()).map(|x| (frame.idx, x))
        })
        .await??;
        store.put_detections(scene_id, key, idx, &dets).await?;
    }
    Ok(())
}
