//! Where scene files and job artifacts live (`storage`): a folder (`file://DIR`, by default
//! the data dir; replicas may share it on one volume), or an S3-compatible bucket
//! (`s3://bucket/prefix`) with a bounded local cache. The local folder is always the
//! working copy: with a bucket, a scene's files are uploaded under
//! `<prefix>/scenes/<id>/` before its row turns visible or ready, artifacts under
//! `<prefix>/artifacts/<job>/`; a replica that lacks a scene downloads it into its cache,
//! which evicts whole scenes not in use, least recently used first. See docs/storage.md.

mod cache;
mod remote;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

pub use cache::CacheIndex;
pub use remote::{local_files, Remote, RemoteLimits};

/// Default bound of the local scene cache with a bucket, MB.
pub const DEFAULT_CACHE_MB: u64 = 10_240;

/// Marks a local scene folder as complete (uploaded or downloaded in full).
const COMPLETE: &str = ".complete";

#[derive(Debug, thiserror::Error)]
pub enum StorageError {
    #[error("storage setting: {0}")]
    Config(String),
    #[error("object store: {0}")]
    Remote(String),
    #[error("local files: {0}")]
    Local(String),
    #[error("object store: {0}")]
    Missing(String),
}

/// What `storage` names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StorageSpec {
    /// A folder (None: the data dir).
    File(Option<PathBuf>),
    /// A bucket and a key prefix (may be empty).
    S3 { bucket: String, prefix: String },
}

impl StorageSpec {
    /// Parse `""` (the data dir), `file://DIR` or `s3://bucket[/prefix]`.
    pub fn parse(text: &str) -> Result<Self, StorageError> {
        let text = text.trim();
        if text.is_empty() {
            return Ok(Self::File(None));
        }
        if let Some(dir) = text.strip_prefix("file://") {
            if dir.is_empty() {
                return Err(StorageError::Config(
                    "file:// needs a folder, as in file:///srv/grounder".into(),
                ));
            }
            return Ok(Self::File(Some(PathBuf::from(dir))));
        }
        if let Some(rest) = text.strip_prefix("s3://") {
            let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
            if bucket.is_empty() {
                return Err(StorageError::Config(format!(
                    "{text:?} names no bucket; use s3://bucket/prefix"
                )));
            }
            return Ok(Self::S3 {
                bucket: bucket.to_string(),
                prefix: prefix.trim_matches('/').to_string(),
            });
        }
        Err(StorageError::Config(format!(
            "{text:?} is neither file://DIR nor s3://bucket/prefix"
        )))
    }
}

/// Scene files and artifacts; shared by the API and the workers.
pub struct Storage {
    root: PathBuf,
    remote: Option<Remote>,
    index: Mutex<CacheIndex>,
    /// One download of a scene at a time.
    loading: Mutex<HashMap<String, Arc<tokio::sync::Mutex<()>>>>,
    downloads: AtomicU64,
}

/// A scene held in use: the cache does not evict it until this is dropped.
pub struct ScenePin {
    storage: Option<Arc<Storage>>,
    id: String,
}

impl std::fmt::Debug for Storage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Storage")
            .field("root", &self.root)
            .field("remote", &self.remote_url())
            .finish_non_exhaustive()
    }
}

impl Drop for ScenePin {
    fn drop(&mut self) {
        if let Some(s) = self.storage.take() {
            s.lock_index().unpin(&self.id);
            // The scene may now be evicted, should the cache be over its bound.
            if let Ok(rt) = tokio::runtime::Handle::try_current() {
                rt.spawn(async move { s.evict().await });
            }
        }
    }
}

fn local(what: &str, e: impl std::fmt::Display) -> StorageError {
    StorageError::Local(format!("{what}: {e}"))
}

impl Storage {
    /// Local folder storage rooted at `root` (`root/scenes`, `root/artifacts`).
    pub fn local(root: &Path) -> Arc<Self> {
        Arc::new(Self::new(root.to_path_buf(), None, 0))
    }

    fn new(root: PathBuf, remote: Option<Remote>, cache_bytes: u64) -> Self {
        Self {
            root,
            remote,
            index: Mutex::new(CacheIndex::new(cache_bytes)),
            loading: Mutex::new(HashMap::new()),
            downloads: AtomicU64::new(0),
        }
    }

    /// Open the storage `spec` names; a bucket's cache lives under `data_dir` and is
    /// bounded to `cache_bytes`. `env` supplies the `AWS_*` settings. A bucket's requests
    /// are bounded by the default [`RemoteLimits`].
    pub async fn open(
        spec: &str,
        data_dir: &Path,
        cache_bytes: u64,
        env: &[(String, String)],
    ) -> Result<Arc<Self>, StorageError> {
        Self::open_with(spec, data_dir, cache_bytes, env, &RemoteLimits::default()).await
    }

    /// [`Self::open`] with a bucket's requests bounded by `limits`.
    pub async fn open_with(
        spec: &str,
        data_dir: &Path,
        cache_bytes: u64,
        env: &[(String, String)],
        limits: &RemoteLimits,
    ) -> Result<Arc<Self>, StorageError> {
        match StorageSpec::parse(spec)? {
            StorageSpec::File(dir) => Ok(Self::local(dir.as_deref().unwrap_or(data_dir))),
            StorageSpec::S3 { bucket, prefix } => {
                let remote = Remote::connect(&bucket, &prefix, env, limits)?;
                let me = Arc::new(Self::new(data_dir.to_path_buf(), Some(remote), cache_bytes));
                me.load_index()?;
                me.evict().await;
                Ok(me)
            }
        }
    }

    /// Index the complete scene folders already in the cache, oldest use first.
    fn load_index(&self) -> Result<(), StorageError> {
        let root = self.scenes_root();
        let rd = match std::fs::read_dir(&root) {
            Ok(rd) => rd,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
            Err(e) => return Err(local("cannot read the scene cache", e)),
        };
        let mut held = Vec::new();
        for entry in rd.flatten() {
            let marker = entry.path().join(COMPLETE);
            if let Ok(meta) = std::fs::metadata(&marker) {
                let used = meta.modified().ok();
                let id = entry.file_name().to_string_lossy().into_owned();
                let revision = std::fs::read_to_string(&marker)
                    .ok()
                    .and_then(|t| t.trim().parse().ok())
                    .unwrap_or(0);
                held.push((used, id, entry.path(), revision));
            }
        }
        held.sort();
        let mut index = self.lock_index();
        for (_, id, dir, revision) in held {
            index.insert(&id, dir_bytes(&dir), revision);
        }
        Ok(())
    }

    fn lock_index(&self) -> std::sync::MutexGuard<'_, CacheIndex> {
        self.index.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// `s3://bucket/prefix` when scenes live in a bucket.
    pub fn remote_url(&self) -> Option<&str> {
        self.remote.as_ref().map(|r| r.url.as_str())
    }

    pub fn scenes_root(&self) -> PathBuf {
        self.root.join("scenes")
    }

    pub fn artifacts_root(&self) -> PathBuf {
        self.root.join("artifacts")
    }

    /// The scene's local folder (with a bucket: its place in the cache).
    pub fn scene_dir(&self, id: &str) -> PathBuf {
        self.scenes_root().join(id)
    }

    /// The job's local artifact folder.
    pub fn artifact_dir(&self, job: &str) -> PathBuf {
        self.artifacts_root().join(job)
    }

    /// Scenes downloaded from the bucket by this process.
    pub fn downloads(&self) -> u64 {
        self.downloads.load(Ordering::Relaxed)
    }

    /// Bytes of the scenes held in the local cache (with a bucket).
    pub fn cached_bytes(&self) -> u64 {
        self.lock_index().total_bytes()
    }

    /// A scene's files were placed in its local folder (an upload): with a bucket, upload
    /// them and enter the folder in the cache. The returned pin keeps it there until the
    /// caller has published the scene.
    pub async fn store_scene(self: &Arc<Self>, id: &str) -> Result<ScenePin, StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(self.no_pin(id));
        };
        let dir = self.scene_dir(id);
        remote.push_dir(&dir, &scene_key(id)).await?;
        // Revision 0: a later use at the scene's real revision checks that nothing is
        // missing (a listing, no download).
        tokio::fs::write(dir.join(COMPLETE), b"0")
            .await
            .map_err(|e| local("cannot mark the scene complete", e))?;
        let bytes = dir_bytes(&dir);
        let pinned = {
            let mut index = self.lock_index();
            index.insert(id, bytes, 0);
            index.pin(id)
        };
        self.evict().await;
        Ok(ScenePin {
            storage: pinned.then(|| self.clone()),
            id: id.to_string(),
        })
    }

    /// Upload what the scene's local folder holds and the bucket lacks (frames appended,
    /// previews and points written). Nothing to do without a bucket.
    pub async fn sync_scene(&self, id: &str) -> Result<(), StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(());
        };
        let dir = self.scene_dir(id);
        remote.push_dir(&dir, &scene_key(id)).await?;
        self.lock_index().resize(id, dir_bytes(&dir));
        Ok(())
    }

    fn no_pin(&self, id: &str) -> ScenePin {
        ScenePin {
            storage: None,
            id: id.to_string(),
        }
    }

    /// Pin the scene when its local copy is complete up to `revision`.
    fn pin_fresh(&self, id: &str, revision: i64) -> bool {
        let mut index = self.lock_index();
        index.revision(id).is_some_and(|r| r >= revision) && index.pin(id)
    }

    /// Make sure the scene's files at `revision` (its row's) are in its local folder
    /// (downloading them from the bucket into the cache when not; for an older local copy
    /// of a scene that grew, the files it lacks) and keep them there while the pin lives.
    pub async fn acquire_scene(
        self: &Arc<Self>,
        id: &str,
        revision: i64,
    ) -> Result<ScenePin, StorageError> {
        let Some(remote) = &self.remote else {
            return Ok(self.no_pin(id));
        };
        let pin = |me: &Arc<Self>| ScenePin {
            storage: Some(me.clone()),
            id: id.to_string(),
        };
        if self.pin_fresh(id, revision) {
            self.evict().await;
            return Ok(pin(self));
        }
        let lock = {
            let mut loading = self.loading.lock().unwrap_or_else(|p| p.into_inner());
            loading.entry(id.to_string()).or_default().clone()
        };
        let _one_at_a_time = lock.lock().await;
        if self.pin_fresh(id, revision) {
            return Ok(pin(self));
        }
        if self.lock_index().pin(id) {
            // Held, but older: fetch what it lacks beside what jobs may be reading.
            let held = pin(self);
            let dir = self.scene_dir(id);
            remote.pull_dir(&scene_key(id), &dir).await?;
            tokio::fs::write(dir.join(COMPLETE), revision.to_string())
                .await
                .map_err(|e| local("cannot mark the scene complete", e))?;
            let mut index = self.lock_index();
            index.insert(id, dir_bytes(&dir), revision);
            return Ok(held);
        }
        // Downloaded beside its place (a name no scene has, so an interrupted download is
        // an orphan folder for the start-up sweep) and renamed into place when complete.
        let part = self
            .scenes_root()
            .join(format!(".{id}.part-{}", uuid::Uuid::now_v7()));
        let pulled = remote.pull_dir(&scene_key(id), &part).await;
        let placed = match pulled {
            Ok(bytes) => self.place_download(id, &part, bytes, revision).await,
            Err(e) => Err(e),
        };
        if placed.is_err() {
            let _ = tokio::fs::remove_dir_all(&part).await;
        }
        placed?;
        self.downloads.fetch_add(1, Ordering::Relaxed);
        tracing::info!(scene = %id, "scene downloaded from {}", remote.url);
        self.evict().await;
        Ok(pin(self))
    }

    async fn place_download(
        &self,
        id: &str,
        part: &Path,
        bytes: u64,
        revision: i64,
    ) -> Result<(), StorageError> {
        tokio::fs::write(part.join(COMPLETE), revision.to_string())
            .await
            .map_err(|e| local("cannot mark the scene complete", e))?;
        let dir = self.scene_dir(id);
        // A folder that is not in the index is incomplete (an upload cut short): replaced.
        if tokio::fs::metadata(&dir).await.is_ok() {
            crate::jobs::sweep::remove_dir(&dir)
                .await
                .map_err(|e| local("cannot replace an incomplete scene folder", e))?;
        }
        tokio::fs::rename(part, &dir)
            .await
            .map_err(|e| local("cannot place the downloaded scene", e))?;
        let mut index = self.lock_index();
        index.insert(id, bytes, revision);
        index.pin(id);
        Ok(())
    }

    /// Remove scenes from the cache until it fits its bound (never one in use).
    async fn evict(&self) {
        let gone: Vec<PathBuf> = {
            let mut index = self.lock_index();
            index
                .evict()
                .into_iter()
                .filter_map(|id| {
                    // Renamed away while the index is locked: a download of the same scene
                    // never finds half a folder.
                    let dir = self.scene_dir(&id);
                    let away = self
                        .scenes_root()
                        .join(format!(".{id}.evicted-{}", uuid::Uuid::now_v7()));
                    tracing::debug!(scene = %id, "evicted from the local cache");
                    std::fs::rename(&dir, &away).ok().map(|_| away)
                })
                .collect()
        };
        for dir in gone {
            if let Err(e) = crate::jobs::sweep::remove_dir(&dir).await {
                tracing::warn!("cannot remove an evicted scene folder (the next start will): {e}");
            }
        }
    }

    /// Remove a scene's files (local and in the bucket) and the artifacts of `jobs`.
    pub async fn remove_scene(&self, id: &str, jobs: &[String]) -> Result<(), StorageError> {
        self.lock_index().remove(id);
        for job in jobs {
            if let Some(r) = &self.remote {
                r.delete_dir(&artifact_key(job)).await?;
            }
            crate::jobs::sweep::remove_dir(&self.artifact_dir(job))
                .await
                .map_err(|e| local("cannot remove artifacts", e))?;
        }
        if let Some(r) = &self.remote {
            r.delete_dir(&scene_key(id)).await?;
        }
        crate::jobs::sweep::remove_dir(&self.scene_dir(id))
            .await
            .map_err(|e| local("cannot remove the scene folder", e))?;
        Ok(())
    }

    /// Remove some of a scene's files (`rels` relative to its folder), local and remote.
    pub async fn remove_scene_files(&self, id: &str, rels: &[String]) -> Result<(), StorageError> {
        let dir = self.scene_dir(id);
        for rel in rels {
            let _ = tokio::fs::remove_file(dir.join(rel)).await;
        }
        if let Some(r) = &self.remote {
            let keys: Vec<String> = rels
                .iter()
                .map(|rel| format!("{}/{rel}", scene_key(id)))
                .collect();
            r.delete(&keys).await?;
        }
        Ok(())
    }

    /// Copy an artifact just written locally to the bucket.
    pub async fn put_artifact(
        &self,
        job: &str,
        name: &str,
        bytes: Vec<u8>,
    ) -> Result<(), StorageError> {
        match &self.remote {
            Some(r) => r.put(&format!("{}/{name}", artifact_key(job)), bytes).await,
            None => Ok(()),
        }
    }

    /// An artifact: the local copy, else the bucket's. None when neither has it.
    pub async fn read_artifact(
        &self,
        job: &str,
        name: &str,
    ) -> Result<Option<Vec<u8>>, StorageError> {
        match tokio::fs::read(self.artifact_dir(job).join(name)).await {
            Ok(b) => return Ok(Some(b)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(local("cannot read an artifact", e)),
        }
        match &self.remote {
            Some(r) => r.get(&format!("{}/{name}", artifact_key(job))).await,
            None => Ok(None),
        }
    }

    /// Scene ids and job ids that have objects in the bucket (empty without one).
    pub async fn remote_ids(&self) -> Result<(Vec<String>, Vec<String>), StorageError> {
        match &self.remote {
            Some(r) => Ok((r.children("scenes").await?, r.children("artifacts").await?)),
            None => Ok((Vec::new(), Vec::new())),
        }
    }

    /// Remove the bucket's objects of a scene (`scene`) or of a job's artifacts.
    pub async fn remove_remote(
        &self,
        scene: Option<&str>,
        job: Option<&str>,
    ) -> Result<(), StorageError> {
        if let Some(r) = &self.remote {
            if let Some(id) = scene {
                r.delete_dir(&scene_key(id)).await?;
            }
            if let Some(j) = job {
                r.delete_dir(&artifact_key(j)).await?;
            }
        }
        Ok(())
    }

    /// Direct access to the bucket (tests, tools).
    pub fn remote(&self) -> Option<&Remote> {
        self.remote.as_ref()
    }
}

fn scene_key(id: &str) -> String {
    format!("scenes/{id}")
}

fn artifact_key(job: &str) -> String {
    format!("artifacts/{job}")
}

/// Total size of the files under `dir` (0 when unreadable).
fn dir_bytes(dir: &Path) -> u64 {
    local_files(dir)
        .map(|f| f.iter().map(|(_, n)| n).sum())
        .unwrap_or(0)
}

/// Move a file or folder: a rename, or a copy and a removal when the two paths are on
/// different volumes (a `file://` folder beside the data dir's spool).
pub fn move_path(src: &Path, dst: &Path) -> std::io::Result<()> {
    match std::fs::rename(src, dst) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::CrossesDevices => {
            copy_tree(src, dst)?;
            if src.is_dir() {
                std::fs::remove_dir_all(src)
            } else {
                std::fs::remove_file(src)
            }
        }
        Err(e) => Err(e),
    }
}

fn copy_tree(src: &Path, dst: &Path) -> std::io::Result<()> {
    if !src.is_dir() {
        return std::fs::copy(src, dst).map(|_| ());
    }
    std::fs::create_dir_all(dst)?;
    for entry in std::fs::read_dir(src)? {
        let entry = entry?;
        copy_tree(&entry.path(), &dst.join(entry.file_name()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::StorageSpec;
    use std::path::PathBuf;

    #[test]
    fn storage_settings_parse_or_say_what_is_accepted() {
        assert_eq!(StorageSpec::parse("").ok(), Some(StorageSpec::File(None)));
        assert_eq!(
            StorageSpec::parse("file:///srv/g").ok(),
            Some(StorageSpec::File(Some(PathBuf::from("/srv/g"))))
        );
        assert_eq!(
            StorageSpec::parse("s3://b/a/b/").ok(),
            Some(StorageSpec::S3 {
                bucket: "b".into(),
                prefix: "a/b".into()
            })
        );
        assert_eq!(
            StorageSpec::parse("s3://b").ok(),
            Some(StorageSpec::S3 {
                bucket: "b".into(),
                prefix: String::new()
            })
        );
        for bad in ["s3://", "s3:///x", "file://", "gs://b", "/srv/g"] {
            let e = StorageSpec::parse(bad).err().map(|e| e.to_string());
            assert!(e.is_some(), "accepted {bad:?}");
        }
    }
}
