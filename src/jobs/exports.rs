//! Scene exports for the viewer and for robots: the scene's points (coloured, voxel-
//! downsampled, in the frame of the jobs' boxes) and each frame's camera and detections.
//! The points are computed once per scene and voxel size, stored beside the scene
//! (written by tmp + rename) and kept in memory for the next request.

use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use super::JobSystem;
use crate::geometry::export::{encode_ply, frame_points, voxel_downsample_colored, ColoredPoint};
use crate::scene::{FrameData, SceneData};
use crate::vision::Detection;

/// Voxel sizes (m) the points export accepts.
pub const VOXEL_RANGE: std::ops::RangeInclusive<f64> = 0.01..=1.0;
/// Voxel size (m) when none is asked for.
pub const DEFAULT_VOXEL: f64 = 0.05;
/// Longest time in all the background points export waits for running jobs.
pub const WARM_PATIENCE: std::time::Duration = std::time::Duration::from_secs(60);
/// Depth samples taken per frame at most (the stride between sampled pixels follows).
const SAMPLES_PER_FRAME: u64 = 40_000;

/// Why an export could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("no scene with id {0:?}")]
    SceneNotFound(String),
    #[error("voxel must be between 0.01 and 1 metres, got {0}")]
    BadVoxel(f64),
    #[error("{0}")]
    Internal(String),
    /// The service began to stop while the export was being computed.
    #[error("the service is stopping")]
    Stopping,
}

/// Points exports kept in memory, newest last.
#[derive(Default)]
pub struct PointsCache {
    inner: Mutex<Vec<(String, Arc<Vec<u8>>)>>,
}

impl PointsCache {
    const CAPACITY: usize = 8;

    fn get(&self, key: &str) -> Option<Arc<Vec<u8>>> {
        let g = self.inner.lock().ok()?;
        g.iter().find(|(k, _)| k == key).map(|(_, v)| v.clone())
    }

    fn put(&self, key: String, v: Arc<Vec<u8>>) {
        if let Ok(mut g) = self.inner.lock() {
            g.retain(|(k, _)| *k != key);
            g.push((key, v));
            if g.len() > Self::CAPACITY {
                g.remove(0);
            }
        }
    }

    /// Forget every export of a scene (it was deleted).
    pub fn forget_scene(&self, scene_id: &str) {
        if let Ok(mut g) = self.inner.lock() {
            g.retain(|(k, _)| !k.starts_with(&format!("{scene_id}/")));
        }
    }
}

/// One frame as the scene viewer shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FrameInfo {
    /// Five-digit image id (as shown to the VLM and in traces).
    pub image_id: String,
    pub name: String,
    pub usable: bool,
    /// Camera position in the output frame (null for unusable frames).
    pub position: Option<[f64; 3]>,
    /// Unit viewing direction in the output frame (null for unusable frames).
    pub forward: Option<[f64; 3]>,
    /// Cached detections of the configured detector, boxes in colour-image pixels.
    #[schema(value_type = Vec<Object>)]
    pub detections: Vec<Detection>,
}

/// The voxel size asked for, checked, as whole millimetres (the cache key).
pub fn voxel_mm(voxel: Option<f64>) -> Result<u32, ExportError> {
    let v = voxel.unwrap_or(DEFAULT_VOXEL);
    if !v.is_finite() || !VOXEL_RANGE.contains(&v) {
        return Err(ExportError::BadVoxel(v));
    }
    Ok((v * 1000.0).round() as u32)
}

/// One frame's sampled, coloured points, downsampled to `voxel` m (blocking; decodes the
/// frame's preview, or its colour image when it has none).
fn frame_cloud(f: &FrameData, voxel: f64) -> Vec<ColoredPoint> {
    let (w, h) = (f.camera.color.width as u64, f.camera.color.height as u64);
    let stride = ((w * h) as f64 / SAMPLES_PER_FRAME as f64).sqrt().ceil() as u32;
    let preview = f.preview_path();
    let path = if preview.is_file() {
        preview
    } else {
        f.color_path.clone()
    };
    let color = image::open(&path).ok().map(|i| i.into_rgb8());
    let pts = frame_points(&f.camera, &f.depth, color.as_ref(), stride.max(1));
    voxel_downsample_colored(&pts, voxel)
}

/// The PLY of the frames' clouds (in frame order), downsampled once more as a whole.
fn points_ply(scene: &SceneData, per_frame: Vec<Vec<ColoredPoint>>, voxel: f64) -> Vec<u8> {
    let all: Vec<_> = per_frame.into_iter().flatten().collect();
    let pts = voxel_downsample_colored(&all, voxel);
    let frame = if scene.axis_align.is_some() {
        "the scene's axis-aligned frame (axis_align_matrix applied), as the jobs' boxes"
    } else {
        "the scene's frame, as the jobs' boxes"
    };
    encode_ply(
        &pts,
        &[
            format!("grounder: scene {} points, voxel {voxel} m", scene.id),
            format!("frame: {frame}"),
        ],
    )
}

/// The scene's points as binary PLY, voxel `mm` millimetres (blocking; decodes previews;
/// frames in parallel: what a viewer waiting for it gets).
pub fn compute_scene_points(scene: &SceneData, mm: u32) -> Vec<u8> {
    use rayon::prelude::*;
    let voxel = mm as f64 / 1000.0;
    let per_frame: Vec<_> = scene
        .usable_frames()
        .collect::<Vec<_>>()
        .par_iter()
        .map(|f| frame_cloud(f, voxel))
        .collect();
    points_ply(scene, per_frame, voxel)
}

/// Frames a background export computes between two looks at the jobs.
const PACED_CHUNK: usize = 4;

/// [`compute_scene_points`] for background work: the same bytes, computed on one thread
/// [`PACED_CHUNK`] frames at a time, awaiting `gate` before each chunk (it returns when
/// the export may go on, e.g. once no job is running), so a query never shares the cores
/// with more than one chunk of it.
pub async fn compute_scene_points_paced<G, F>(
    scene: Arc<SceneData>,
    mm: u32,
    mut gate: G,
) -> Result<Vec<u8>, ExportError>
where
    G: FnMut() -> F,
    F: std::future::Future<Output = bool>,
{
    let voxel = mm as f64 / 1000.0;
    let usable: Vec<usize> = scene.usable_frames().map(|f| f.idx).collect();
    let mut per_frame = Vec::with_capacity(usable.len());
    for chunk in usable.chunks(PACED_CHUNK) {
        if !gate().await {
            return Err(ExportError::Stopping);
        }
        let (sc, chunk) = (scene.clone(), chunk.to_vec());
        let clouds = tokio::task::spawn_blocking(move || {
            chunk
                .iter()
                .map(|&i| frame_cloud(&sc.frames[i], voxel))
                .collect::<Vec<_>>()
        })
        .await
        .map_err(|e| ExportError::Internal(format!("points task failed: {e}")))?;
        per_frame.extend(clouds);
    }
    if !gate().await {
        return Err(ExportError::Stopping);
    }
    tokio::task::spawn_blocking(move || points_ply(&scene, per_frame, voxel))
        .await
        .map_err(|e| ExportError::Internal(format!("points task failed: {e}")))
}

fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = path.with_extension(format!("{}.tmp", uuid::Uuid::now_v7()));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

impl JobSystem {
    fn points_file(&self, scene_id: &str, mm: u32) -> PathBuf {
        self.scene_dir(scene_id).join(format!("points_{mm}mm.ply"))
    }

    /// The scene's points at voxel `mm` (see [`voxel_mm`]): from memory, else from the file
    /// stored beside the scene, else computed and stored.
    pub async fn scene_points(&self, scene_id: &str, mm: u32) -> Result<Arc<Vec<u8>>, ExportError> {
        let key = format!("{scene_id}/{mm}");
        if let Some(b) = self.points_cache().get(&key) {
            return Ok(b);
        }
        let file = self.points_file(scene_id, mm);
        if let Ok(b) = tokio::fs::read(&file).await {
            let b = Arc::new(b);
            self.points_cache().put(key, b.clone());
            return Ok(b);
        }
        // The previews it reads stay local while it is computed.
        let pin = self
            .acquire_scene(scene_id)
            .await
            .map_err(|f| ExportError::Internal(f.detail))?;
        let scene = self.scene_data(scene_id).await?;
        let bytes = tokio::task::spawn_blocking(move || {
            let b = compute_scene_points(&scene, mm);
            if let Err(e) = write_atomic(&file, &b) {
                tracing::warn!("cannot store {}: {e}", file.display());
            }
            b
        })
        .await
        .map_err(|e| ExportError::Internal(format!("points task failed: {e}")))?;
        // Kept in the bucket too, for the replicas that fetch the scene later.
        if let Err(e) = self.storage().sync_scene(scene_id).await {
            tracing::warn!(scene = %scene_id, "cannot upload the scene's points: {e}");
        }
        drop(pin);
        let b = Arc::new(bytes);
        self.points_cache().put(key, b.clone());
        Ok(b)
    }

    /// Every frame's camera and cached detections (of `detector`).
    pub async fn scene_frames(
        &self,
        scene_id: &str,
        detector: &str,
    ) -> Result<Vec<FrameInfo>, ExportError> {
        let scene = self.scene_data(scene_id).await?;
        let mut dets = self
            .store
            .detections(scene_id, detector)
            .await
            .map_err(|e| ExportError::Internal(e.to_string()))?;
        Ok(scene
            .frames
            .iter()
            .map(|f| {
                let m = f.camera.cam_to_out();
                let ok = f.usable && crate::geometry::camera::is_finite_matrix(&m);
                let forward = nalgebra::Vector3::new(m[(0, 2)], m[(1, 2)], m[(2, 2)]);
                let n = forward.norm();
                FrameInfo {
                    image_id: f.image_id(),
                    name: f.name.clone(),
                    usable: f.usable,
                    position: ok.then(|| [m[(0, 3)], m[(1, 3)], m[(2, 3)]]),
                    forward: (ok && n > 0.0).then(|| [forward.x / n, forward.y / n, forward.z / n]),
                    detections: dets.remove(&f.idx).unwrap_or_default(),
                }
            })
            .collect())
    }

    /// The JPEG to show for frame `idx`: its preview when indexing stored one, else the
    /// colour image. `None` when the scene has no such frame.
    pub fn frame_image(&self, scene_id: &str, idx: usize) -> Option<PathBuf> {
        let color = self
            .scene_dir(scene_id)
            .join("color")
            .join(format!("{idx}.jpg"));
        let preview = color.with_extension("preview.jpg");
        if preview.is_file() {
            Some(preview)
        } else {
            color.is_file().then_some(color)
        }
    }

    /// The bytes of [`Self::frame_image`], fetching the scene from the bucket first when
    /// this replica does not hold it. `Ok(None)` when the scene has no such frame.
    pub async fn frame_jpeg(
        &self,
        scene_id: &str,
        idx: usize,
    ) -> Result<Option<Vec<u8>>, ExportError> {
        let _pin = self.acquire_scene(scene_id).await.map_err(|f| {
            if f.code == "scene_not_found" {
                ExportError::SceneNotFound(scene_id.to_string())
            } else {
                ExportError::Internal(f.detail)
            }
        })?;
        let Some(path) = self.frame_image(scene_id, idx) else {
            return Ok(None);
        };
        Ok(tokio::fs::read(path).await.ok())
    }

    /// Compute the default points export in the background (after indexing), so the first
    /// viewer of the scene does not wait for it. It yields to the queries: it runs on one
    /// thread, a few frames at a time, and goes on only while no job is running in this
    /// process nor queued on a ready scene ([`Self::jobs_idle`]); after
    /// [`WARM_PATIENCE`] of waiting in all it stops waiting (still one thread, one chunk at
    /// a time), so a busy service still gets the export.
    ///
    /// The task is one of the job system's background tasks: shutdown waits for it, and it
    /// stops between chunks once the service is stopping, writing nothing.
    pub fn warm_scene_points(&self, scene_id: &str) {
        let (me, id) = (self.clone(), scene_id.to_string());
        self.spawn_background(async move {
            match me.warm_points(&id).await {
                Ok(()) | Err(ExportError::Stopping) => {}
                Err(e) => tracing::warn!(scene = %id, "cannot prepare the scene's points: {e}"),
            }
        });
    }

    async fn warm_points(&self, scene_id: &str) -> Result<(), ExportError> {
        let mm = voxel_mm(None)?;
        let key = format!("{scene_id}/{mm}");
        let file = self.points_file(scene_id, mm);
        if self.points_cache().get(&key).is_some() || file.is_file() {
            return Ok(());
        }
        let pin = self
            .acquire_scene(scene_id)
            .await
            .map_err(|f| ExportError::Internal(f.detail))?;
        if self.stopping().is_cancelled() {
            return Err(ExportError::Stopping);
        }
        let scene = self.scene_data(scene_id).await?;
        let waited = Arc::new(Mutex::new(std::time::Duration::ZERO));
        let me = self.clone();
        let bytes = compute_scene_points_paced(scene, mm, || {
            let (me, waited) = (me.clone(), waited.clone());
            async move {
                me.wait_for_idle_jobs(&waited).await;
                !me.stopping().is_cancelled()
            }
        })
        .await?;
        let b = Arc::new(bytes);
        let (f, w) = (file.clone(), b.clone());
        let stored = tokio::task::spawn_blocking(move || write_atomic(&f, &w)).await;
        if !matches!(stored, Ok(Ok(()))) {
            tracing::warn!("cannot store {}", file.display());
        }
        if let Err(e) = self.storage().sync_scene(scene_id).await {
            tracing::warn!(scene = %scene_id, "cannot upload the scene's points: {e}");
        }
        drop(pin);
        self.points_cache().put(key, b);
        Ok(())
    }

    /// No job is running in this process and none is queued on a ready scene (it would
    /// start at once). A store error counts as busy.
    pub async fn jobs_idle(&self) -> bool {
        if !self.running().is_empty() {
            return false;
        }
        !self.store.has_runnable_jobs().await.unwrap_or(true)
    }

    /// Wait while jobs run (see [`Self::jobs_idle`]), adding the wait to `waited`; return
    /// at once once `waited` reached [`WARM_PATIENCE`] or the service is stopping.
    async fn wait_for_idle_jobs(&self, waited: &Mutex<std::time::Duration>) {
        let step = std::time::Duration::from_millis(50);
        loop {
            let total = waited.lock().map(|w| *w).unwrap_or(WARM_PATIENCE);
            if total >= WARM_PATIENCE || self.stopping().is_cancelled() || self.jobs_idle().await {
                return;
            }
            tokio::time::sleep(step).await;
            if let Ok(mut w) = waited.lock() {
                *w += step;
            }
        }
    }

    async fn scene_data(&self, scene_id: &str) -> Result<Arc<SceneData>, ExportError> {
        self.load_scene(scene_id).await.map_err(|f| {
            if f.code == "scene_not_found" {
                ExportError::SceneNotFound(scene_id.to_string())
            } else {
                ExportError::Internal(f.detail)
            }
        })
    }
}
