//! Keeping the data dir (and the bucket of an `s3://` storage) and the store in step. A scene's files exist only while its row
//! does: deletes remove the files between marking the row `deleting` and removing it, and
//! at start-up [`reconcile`] finishes what a crash interrupted (rows left `importing` or
//! `deleting`, folders without a row, artifacts without a job, spooled uploads).
//!
//! Alone on its database (SQLite), a process owns every leftover. Beside other replicas
//! (PostgreSQL, [`Mode::Shared`]) it finishes only the imports and deletes of dead replicas
//! (`store::replicas`), and removes a file or folder no row names only when nothing in it
//! changed for a grace period: another replica may be writing it right now (an upload's
//! spool, an append's frame files, which are written before their rows).

use std::path::Path;
use std::time::{Duration, SystemTime};

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

/// Whose leftovers a sweep may remove.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// The only process on its database: everything left over is a dead process's.
    Alone,
    /// Beside live replicas: only dead replicas' rows, only files untouched for `grace`.
    Shared { grace: Duration },
}

impl Mode {
    /// May the leftover at `path` go: always when alone; beside other replicas, when
    /// nothing in it (the newest modification in its tree) changed for the grace period.
    fn settled(self, path: &Path) -> bool {
        match self {
            Mode::Alone => true,
            Mode::Shared { grace } => newest_change(path)
                .and_then(|t| SystemTime::now().duration_since(t).ok())
                .is_some_and(|age| age >= grace),
        }
    }
}

/// The newest modification time of `path` and everything under it (None when unreadable).
fn newest_change(path: &Path) -> Option<SystemTime> {
    let meta = std::fs::symlink_metadata(path).ok()?;
    let mut newest = meta.modified().ok()?;
    if meta.is_dir() {
        for entry in std::fs::read_dir(path).ok()?.flatten() {
            newest = newest.max(newest_change(&entry.path())?);
        }
    }
    Some(newest)
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

/// Finish the imports and deletes that dead processes left (all of them when `mode` is
/// [`Mode::Alone`], only those of dead replicas beside others). Returns (imports undone,
/// deletes finished).
pub async fn finish_hidden(
    store: &Store,
    storage: &Storage,
    mode: Mode,
) -> anyhow::Result<(usize, usize)> {
    let hidden = match mode {
        Mode::Alone => store.hidden_scenes().await?,
        Mode::Shared { .. } => store.hidden_scenes_of_dead().await?,
    };
    let mut out = (0, 0);
    for (id, status) in hidden {
        finish_removal(store, storage, &id).await?;
        if status == "importing" {
            out.0 += 1;
        } else {
            out.1 += 1;
        }
    }
    Ok(out)
}

/// Reconcile the data dir (and the bucket) with the store (run at start-up, before
/// anything serves); `mode` says whose leftovers these may be.
pub async fn reconcile(
    store: &Store,
    data_dir: &Path,
    storage: &Storage,
    mode: Mode,
) -> anyhow::Result<Swept> {
    let mut out = Swept::default();
    // Spooled uploads and unpack folders of requests that never finished.
    let tmp = data_dir.join("tmp");
    if mode == Mode::Alone {
        remove_dir(&tmp).await?;
    } else {
        for name in entries(&tmp)? {
            let path = tmp.join(name);
            if mode.settled(&path) {
                if path.is_dir() {
                    remove_dir(&path).await?;
                } else {
                    let _ = std::fs::remove_file(&path);
                }
            }
        }
    }
    (out.imports_undone, out.deletes_finished) = finish_hidden(store, storage, mode).await?;
    // Rows are read after the folders are listed (below, per folder, beside others): a
    // scene's row is written before its folder, so a folder listed without a row then is
    // a leftover, not an import that began after the rows were read.
    let known = store.scene_ids().await?;
    // Local folders: scene folders (with a bucket, the cache) and, from the cache,
    // downloads and evictions cut short (`.<id>.part-*`, `.<id>.evicted-*`).
    let scenes_root = storage.scenes_root();
    for name in entries(&scenes_root)? {
        let dir = scenes_root.join(&name);
        let orphan =
            !known.contains(&name) && (mode == Mode::Alone || !store.scene_exists(&name).await?);
        if orphan {
            if mode.settled(&dir) {
                remove_dir(&dir).await?;
                out.orphan_folders += 1;
            }
            continue;
        }
        // Half-written files (previews are written as `<name>.tmp`, then renamed), and
        // frame files no row names: frames are appended files first, rows second, and
        // removed rows first, files second.
        let stems = store.frame_files(&name).await?;
        for sub in ["color", "instance"] {
            for f in entries(&dir.join(sub))? {
                let path = dir.join(sub).join(&f);
                if !mode.settled(&path) {
                    continue;
                }
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
        if !store.job_exists(&name).await? && mode.settled(&storage.artifact_dir(&name)) {
            remove_dir(&storage.artifact_dir(&name)).await?;
            out.orphan_artifacts += 1;
        }
    }
    // The bucket: objects are written after their row exists and removed before it goes,
    // so objects without a row are left by a crash (or by a database that does not own
    // this bucket prefix: one prefix belongs to one database).
    // Beside other replicas a scene created since `known` was read is asked for again
    // (its row exists before its objects).
    let (scenes, jobs) = storage.remote_ids().await?;
    for id in scenes {
        if !known.contains(&id) && (mode == Mode::Alone || !store.scene_exists(&id).await?) {
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
