//! Keeping the data dir (and the bucket of an `s3://` storage) and the store in step. A scene's files exist only while its row
//! does: deletes remove the files between marking the row `deleting` and removing it, and
//! at start-up [`reconcile`] finishes what a crash interrupted (rows left `importing` or
//! `deleting`, folders without a row, artifacts without a job, spooled uploads).

use std::path::Path;

use crate::storage::Storage;
use crate::store::Store;

/// What a sweep removed.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Swept {
    /// Rows left `importing` by an interrupted upload (removed with their files).
    pub imports_undone: usize,
    /// Rows left `deleting` by an interrupted delete (their delete finished).
    pub deletes_finished: usize,
    /// Scene folders no row knows.
    pub orphan_folders: usize,
    /// Half-written files inside kept scene folders.
    pub partial_files: usize,
    /// Frame files of kept scenes that no frame row names (an append or a frame removal
    /// interrupted between its files and its rows).
    pub orphan_frame_files: usize,
    /// Artifact folders of jobs that no longer exist.
    pub orphan_artifacts: usize,
    /// Scene and artifact folders in the bucket that no row knows.
    pub orphan_objects: usize,
    /// Queued jobs whose scene is gone, canceled.
    pub jobs_canceled: u64,
}

impl Swept {
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }
}

/// Remove a folder and everything in it; a missing folder is fine. A background writer
/// (a preview, the cached points) may add a file while it is emptied, which fails the
/// removal with "directory not empty": it is tried again a few times.
pub async fn remove_dir(dir: &Path) -> std::io::Result<()> {
    let mut last = Ok(());
    for _ in 0..5 {
        match tokio::fs::remove_dir_all(dir).await {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound && dir.exists() => {
                tracing::debug!(dir = %dir.display(), "removing the folder again: {e}");
                last = Err(e);
                tokio::time::sleep(std::time::Duration::from_millis(50)).await;
            }
            _ => return Ok(()),
        }
    }
    last
}

/// Remove a scene's files and the artifacts of every job run on it (local copies and, with
/// a bucket, their objects).
pub async fn remove_scene_files(store: &Store, storage: &Storage, id: &str) -> anyhow::Result<()> {
    let jobs = store.job_ids_of_scene(id).await?;
    storage.remove_scene(id, &jobs).await?;
    Ok(())
}

/// Finish deleting a scene whose row is `deleting` (or undo an import left `importing`):
/// files (and objects) first, then the row. A crash at any point leaves the row hidden
/// until the next sweep finishes the job.
pub async fn finish_removal(store: &Store, storage: &Storage, id: &str) -> anyhow::Result<()> {
    remove_scene_files(store, storage, id).await?;
    store.remove_hidden_scene(id).await?;
    Ok(())
}

/// The stem a frame's files share: `12.jpg`, `12.preview.jpg`, `12.png` -> `12`.
fn frame_stem(file: &str) -> &str {
    file.split('.').next().unwrap_or(file)
}

/// A frame's image, preview or mask (not `labels.json` or other scene-wide files).
fn is_frame_file(file: &str) -> bool {
    file.ends_with(".jpg") || (file.ends_with(".png") && !file.starts_with("labels"))
}

/// Names of the entries of a folder (none when it does not exist).
fn entries(dir: &Path) -> std::io::Result<Vec<String>> {
    match std::fs::read_dir(dir) {
        Ok(rd) => rd
            .map(|e| e.map(|e| e.file_name().to_string_lossy().into_owned()))
            .collect(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(e) => Err(e),
    }
}

/// Reconcile the data dir (and the bucket) with the store (run at start-up, before
/// anything serves).
pub async fn reconcile(store: &Store, data_dir: &Path, storage: &Storage) -> anyhow::Result<Swept> {
    let mut out = Swept::default();
    // Spooled uploads and unpack folders of requests that never finished.
    remove_dir(&data_dir.join("tmp")).await?;
    for (id, status) in store.hidden_scenes().await? {
        finish_removal(store, storage, &id).await?;
        if status == "importing" {
            out.imports_undone += 1;
        } else {
            out.deletes_finished += 1;
        }
    }
    let known = store.scene_ids().await?;
    // Local folders: scene folders (with a bucket, the cache) and, from the cache,
    // downloads and evictions cut short (`.<id>.part-*`, `.<id>.evicted-*`).
    let scenes_root = storage.scenes_root();
    for name in entries(&scenes_root)? {
        let dir = scenes_root.join(&name);
        if !known.contains(&name) {
            remove_dir(&dir).await?;
            out.orphan_folders += 1;
            continue;
        }
        // Half-written files (previews are written as `<name>.tmp`, then renamed), and
        // frame files no row names: frames are appended files first, rows second, and
        // removed rows first, files second.
        let stems = store.frame_files(&name).await?;
        for sub in ["color", "instance"] {
            for f in entries(&dir.join(sub))? {
                let path = dir.join(sub).join(&f);
                if f.ends_with(".tmp") {
                    let _ = std::fs::remove_file(path);
                    out.partial_files += 1;
                } else if is_frame_file(&f) && !stems.contains(frame_stem(&f)) {
                    let _ = std::fs::remove_file(path);
                    out.orphan_frame_files += 1;
                }
            }
        }
    }
    for name in entries(&storage.artifacts_root())? {
        if !store.job_exists(&name).await? {
            remove_dir(&storage.artifact_dir(&name)).await?;
            out.orphan_artifacts += 1;
        }
    }
    // The bucket: objects are written after their row exists and removed before it goes,
    // so objects without a row are left by a crash (or by a database that does not own
    // this bucket prefix: one prefix belongs to one database).
    let (scenes, jobs) = storage.remote_ids().await?;
    for id in scenes {
        if !known.contains(&id) {
            storage.remove_remote(Some(&id), None).await?;
            out.orphan_objects += 1;
        }
    }
    for job in jobs {
        if !store.job_exists(&job).await? {
            storage.remove_remote(None, Some(&job)).await?;
            out.orphan_objects += 1;
        }
    }
    out.jobs_canceled = store.cancel_jobs_without_scene().await?;
    Ok(out)
}
