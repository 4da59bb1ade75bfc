//! Scene indexing: after upload, the configured detector runs over every usable frame in
//! the background and its detections are cached, so a query's view pre-selection is a
//! lookup. Each frame's half-size preview is stored on the way, for stitching. The scene is
//! `indexing` until done, then `ready` (jobs on it wait queued).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

use crate::geometry::{LayoutParams, RoomLayout};
use crate::jobs::JobSystem;
use crate::scene::FrameData;
use crate::store::{Claim, Store, StoreError};
use crate::vision::candidates::{frame_candidates, CandidateParams};
use crate::vision::{DetectInput, Detection, Detector};

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
        .map(Detection::from)
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

/// Starts and resumes the indexing of scenes. One indexer per scene at a time, across
/// replicas: it holds a lease on the scene row (`store::replicas`), renewed every third of
/// the lease; once the lease runs out (its replica died) any replica takes the scene over.
pub struct Indexer {
    detector_key: String,
    /// None when the detector could not be loaded (readiness says why).
    detector: Option<Arc<dyn Detector>>,
    candidates: Option<CandidateSetup>,
    store: Store,
    jobs: JobSystem,
}

/// How often an indexing lease is renewed, and a waiting indexer looks again.
fn period(store: &Store) -> Duration {
    Duration::from_millis((store.lease_ms() / 3).max(100) as u64)
}

impl Indexer {
    pub fn new(
        detector_key: String,
        detector: Option<Arc<dyn Detector>>,
        candidates: Option<CandidateSetup>,
        store: Store,
        jobs: JobSystem,
    ) -> Arc<Self> {
        Arc::new(Self {
            detector_key,
            detector,
            candidates,
            store,
            jobs,
        })
    }

    /// The hook the upload handler calls: index now, or once the scene's current indexer
    /// (on this or another replica) is done.
    pub fn hook(self: &Arc<Self>) -> IndexHook {
        let me = self.clone();
        Arc::new(move |scene_id: String, from: usize| me.start(scene_id, from, Claim::Start))
    }

    /// Index `scene_id` from frame `from` in the background, claiming it as `how` allows.
    /// The job system's shutdown waits for it: a stopping service ends it between frames
    /// and frees the lease, leaving the scene `indexing` for a restart (or another
    /// replica) to resume at once.
    pub fn start(self: &Arc<Self>, scene_id: String, from: usize, how: Claim) {
        let me = self.clone();
        self.jobs
            .spawn_background(async move { me.run(scene_id, from, how).await });
    }

    /// Take the scene's indexing lease as `owner`. [`Claim::Start`] waits while another
    /// indexer holds it (until the service stops); the others give up at once. False when
    /// not taken.
    async fn claim(&self, id: &str, owner: &str, how: Claim) -> Result<bool, StoreError> {
        let stopping = self.jobs.stopping();
        loop {
            if stopping.is_cancelled() {
                return Ok(false);
            }
            if self.store.claim_indexing(id, owner, how).await? {
                return Ok(true);
            }
            if how != Claim::Start {
                return Ok(false);
            }
            if !self.store.indexing_held(id).await? {
                // Freed meanwhile, or the scene is gone or hidden.
                return self.store.claim_indexing(id, owner, how).await;
            }
            tokio::select! {
                _ = tokio::time::sleep(period(&self.store)) => {}
                _ = stopping.cancelled() => return Ok(false),
            }
        }
    }

    async fn run(&self, scene_id: String, from: usize, how: Claim) {
        let (store, jobs) = (&self.store, &self.jobs);
        let owner = format!("{}/{}", store.replica, uuid::Uuid::now_v7());
        match self.claim(&scene_id, &owner, how).await {
            Ok(true) => {}
            Ok(false) => {
                tracing::debug!(scene = %scene_id, "another indexer has the scene");
                return;
            }
            Err(e) => {
                tracing::error!(scene = %scene_id, "cannot claim the scene's indexing: {e}");
                return;
            }
        }
        let lost = CancellationToken::new();
        let keeper = AbortOnDrop(tokio::spawn(keep_lease(
            store.clone(),
            scene_id.clone(),
            owner.clone(),
            lost.clone(),
        )));
        // At most `max_concurrent_indexing` scenes at once; the others wait here.
        let stopping = jobs.stopping();
        let _slot = tokio::select! {
            s = jobs.indexing_slot() => s,
            _ = stopping.cancelled() => {
                drop(keeper);
                self.release(&scene_id, &owner, false).await;
                return;
            }
        };
        if let Err(e) = store.begin_index_attempt(&scene_id).await {
            tracing::error!(scene = %scene_id, "cannot count the indexing attempt: {e}");
        }
        let (key, det, cands) = (
            &self.detector_key,
            self.detector.clone(),
            self.candidates.clone(),
        );
        let outcome = tokio::select! {
            r = index_scene(store, jobs, &scene_id, key, det, cands, from) => r,
            _ = lost.cancelled() => {
                tracing::warn!(scene = %scene_id, "the indexing lease was lost (another replica took the scene over, or the scene is being deleted); stopped");
                return;
            }
        };
        drop(keeper);
        if let Ok(Indexed::Stopped) = &outcome {
            self.release(&scene_id, &owner, true).await;
            return;
        }
        if outcome.is_ok() {
            jobs.warm_scene_points(&scene_id);
        }
        let (status, err) = match outcome {
            // Done: Stopped returned above.
            Ok(_) => ("ready", None),
            Err(e) => {
                // The log keeps the full reason; the scene (and its jobs) name files only.
                tracing::warn!(scene = %scene_id, "indexing failed: {e:#}");
                let why = super::redact::without_paths(&format!("{e:#}"));
                ("failed", Some(why))
            }
        };
        match store
            .end_indexing(&scene_id, &owner, status, err.as_deref())
            .await
        {
            Ok(true) => {}
            Ok(false) => {
                tracing::warn!(scene = %scene_id, "the indexing lease was lost before the outcome was recorded");
                return;
            }
            Err(e) => tracing::error!(scene = %scene_id, "cannot record indexing outcome: {e}"),
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
    }

    /// The service is stopping: free `owner`'s lease on the scene, which stays `indexing`
    /// for a restart or another replica to resume at once. `uncount`: the attempt was
    /// counted, and a stop is not the crash `max_index_attempts` counts.
    async fn release(&self, scene_id: &str, owner: &str, uncount: bool) {
        match self.store.release_indexing(scene_id, owner, uncount).await {
            Ok(true) => {
                tracing::info!(scene = %scene_id, "indexing stopped with the service; it resumes at the next start")
            }
            Ok(false) => {}
            Err(e) => tracing::warn!(scene = %scene_id, "cannot free the indexing lease: {e}"),
        }
    }
}

/// How [`index_scene`] ended when it did not fail.
enum Indexed {
    Done,
    /// The service began stopping: the frames indexed so far are stored, the rest not.
    Stopped,
}

/// Aborts a task when dropped.
struct AbortOnDrop(tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Renew `owner`'s indexing lease every third of the lease until it is lost (`lost` is
/// then cancelled) or this task is aborted.
async fn keep_lease(store: Store, id: String, owner: String, lost: CancellationToken) {
    loop {
        tokio::time::sleep(period(&store)).await;
        match store.renew_indexing(&id, &owner).await {
            Ok(true) => {}
            Ok(false) => {
                lost.cancel();
                return;
            }
            Err(e) => tracing::warn!(scene = %id, "cannot renew the indexing lease: {e}"),
        }
    }
}

/// Restart the indexing that dead processes left: with [`Claim::Force`] (the only
/// process, at start-up) every scene left `indexing`; with [`Claim::TakeOver`] (replicas)
/// those whose lease ran out. A scene whose indexing was interrupted `max_attempts` times
/// (each time the process died: out of memory, a crashing model) ends `failed` with the
/// reason instead of being tried again.
pub async fn resume(indexer: &Arc<Indexer>, max_attempts: i64, how: Claim) -> anyhow::Result<()> {
    let store = &indexer.store;
    let left = match how {
        Claim::TakeOver => store.unclaimed_indexing().await?,
        _ => store.interrupted_indexing().await?,
    };
    for (id, attempts) in left {
        if attempts >= max_attempts.max(1) {
            let owner = format!("{}/give-up", store.replica);
            if !store.claim_indexing(&id, &owner, how).await? {
                continue;
            }
            let why = format!(
                "indexing was interrupted {attempts} times (the process stopped during it each \
                 time, for example out of memory); given up after max_index_attempts = {max_attempts}"
            );
            tracing::error!(scene = %id, "{why}");
            store
                .end_indexing(&id, &owner, "failed", Some(&why))
                .await?;
        } else {
            tracing::info!(scene = %id, "resuming indexing left by a stopped process");
            indexer.start(id, 0, how);
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
) -> anyhow::Result<Indexed> {
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
    let cache_key = candidates
        .as_ref()
        .map(|c| c.params.cache_key(&c.layout))
        .unwrap_or_default();
    let stopping = jobs.stopping();
    for frame in usable.into_iter().filter(|f| f.idx >= from) {
        if stopping.is_cancelled() {
            return Ok(Indexed::Stopped);
        }
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
            store.put_candidates(scene_id, &cache_key, idx, c).await?;
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
    Ok(Indexed::Done)
}
