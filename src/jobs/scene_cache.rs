//! Decoded scenes shared by the jobs, bounded in bytes.
//!
//! A scene decoded for a job (cameras and depth maps) is shared three ways:
//! - concurrent jobs on the same scene get the same copy: while any job holds it, a later
//!   job finds it through a weak reference, whatever the cache's bound;
//! - loads are single-flight: jobs that start together on a scene nobody holds wait for one
//!   load instead of decoding a copy each;
//! - finished scenes stay in a least-recently-used cache whose total size (the bytes of
//!   their frame records, and of depth maps decoded into memory, see [`scene_bytes`]) stays
//!   under `max_bytes`; a scene larger than the whole bound is not kept once its last job
//!   ends.

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, Mutex, Weak};

use crate::scene::SceneData;

/// Default bound of the scene cache (`scene_cache_mb`).
pub const DEFAULT_SCENE_CACHE_MB: u64 = 128;

/// The bytes a decoded scene holds of its own: each frame's record and paths, plus depth
/// maps decoded into memory. Depth read through the scene's mapped depth file (the usual
/// case, see `scene::depth_file`) is not counted: those are clean file pages, shared by
/// every job and process, which the kernel drops when memory is short.
pub fn scene_bytes(s: &SceneData) -> u64 {
    s.frames
        .iter()
        .map(|f| {
            let depth = if f.depth.data.is_shared() {
                0
            } else {
                f.depth.data.len() as u64 * 2
            };
            let paths = f.color_path.as_os_str().len()
                + f.instance_path.as_ref().map_or(0, |p| p.as_os_str().len())
                + f.name.len();
            depth + paths as u64 + std::mem::size_of_val(f) as u64
        })
        .sum()
}

#[derive(Default)]
struct Inner {
    /// Kept scenes, least recently used first: (id, scene, bytes).
    kept: Vec<(String, Arc<SceneData>, u64)>,
    /// Every scene some job may still hold.
    live: HashMap<String, Weak<SceneData>>,
    /// One lock per scene being loaded (single flight).
    loading: HashMap<String, Arc<tokio::sync::Mutex<()>>>,
    /// Scenes forgotten so far (see [`SceneCache::put_unless_forgotten`]).
    forgets: u64,
}

/// See the module documentation.
pub struct SceneCache {
    max_bytes: u64,
    inner: Mutex<Inner>,
}

impl Default for SceneCache {
    fn default() -> Self {
        Self::new(DEFAULT_SCENE_CACHE_MB << 20)
    }
}

impl SceneCache {
    pub fn new(max_bytes: u64) -> Self {
        Self {
            max_bytes,
            inner: Mutex::new(Inner::default()),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // A panic while holding this lock cannot leave the maps inconsistent (every
        // update is a single insert or removal), so a poisoned lock is used as is.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The scene if a job holds it or the cache kept it (it becomes the most recent).
    pub fn get(&self, id: &str) -> Option<Arc<SceneData>> {
        let mut g = self.lock();
        if let Some(pos) = g.kept.iter().position(|(k, _, _)| k == id) {
            let e = g.kept.remove(pos);
            let s = e.1.clone();
            g.kept.push(e);
            return Some(s);
        }
        let live = g.live.get(id).and_then(Weak::upgrade);
        if live.is_none() {
            g.live.remove(id);
        }
        live
    }

    /// Record a freshly loaded scene: shared while held, kept within the byte bound.
    pub fn put(&self, id: &str, scene: Arc<SceneData>) {
        let mut g = self.lock();
        self.put_locked(&mut g, id, scene);
    }

    fn put_locked(&self, g: &mut Inner, id: &str, scene: Arc<SceneData>) {
        let bytes = scene_bytes(&scene);
        g.live.retain(|_, w| w.strong_count() > 0);
        g.live.insert(id.to_string(), Arc::downgrade(&scene));
        g.kept.retain(|(k, _, _)| k != id);
        if bytes > self.max_bytes {
            return;
        }
        g.kept.push((id.to_string(), scene, bytes));
        let mut total: u64 = g.kept.iter().map(|e| e.2).sum();
        while total > self.max_bytes && !g.kept.is_empty() {
            let (_, _, b) = g.kept.remove(0);
            total -= b;
        }
    }

    /// Forget a scene (deleted, or its frames changed): neither kept nor handed to later
    /// jobs.
    pub fn remove(&self, id: &str) {
        let mut g = self.lock();
        g.kept.retain(|(k, _, _)| k != id);
        g.live.remove(id);
        g.forgets += 1;
    }

    /// A mark to take before loading a scene outside the cache (see
    /// [`SceneCache::put_unless_forgotten`]).
    pub fn mark(&self) -> u64 {
        self.lock().forgets
    }

    /// Offer a scene loaded outside the cache (indexing's copy, with its room layout) to
    /// later jobs, unless the cache already has one or any scene was forgotten since
    /// `mark` was taken (its frames may have changed after this copy was loaded). Whether
    /// it was put.
    pub fn put_unless_forgotten(&self, id: &str, scene: Arc<SceneData>, mark: u64) -> bool {
        let mut g = self.lock();
        let held = g.kept.iter().any(|(k, _, _)| k == id)
            || g.live.get(id).is_some_and(|w| w.strong_count() > 0);
        if g.forgets != mark || held {
            return false;
        }
        self.put_locked(&mut g, id, scene);
        true
    }

    /// Bytes of the scenes kept (not counting those only jobs hold).
    pub fn kept_bytes(&self) -> u64 {
        self.lock().kept.iter().map(|e| e.2).sum()
    }

    /// The scene from memory, else from `load` run once however many callers ask at once.
    pub async fn get_or_load<E, F, Fut>(&self, id: &str, load: F) -> Result<Arc<SceneData>, E>
    where
        F: FnOnce() -> Fut,
        Fut: Future<Output = Result<SceneData, E>>,
    {
        if let Some(s) = self.get(id) {
            return Ok(s);
        }
        let flight = self
            .lock()
            .loading
            .entry(id.to_string())
            .or_default()
            .clone();
        let result = {
            let _turn = flight.lock().await;
            match self.get(id) {
                Some(s) => Ok(s),
                None => load().await.map(|s| {
                    let s = Arc::new(s);
                    self.put(id, s.clone());
                    s
                }),
            }
        };
        let mut g = self.lock();
        // The last one through removes the scene's lock (the map holds one reference).
        if Arc::strong_count(&flight) <= 2 {
            g.loading.remove(id);
        }
        result
    }
}

/// The scene as the job was claimed: frames appended since (between the claim and the
/// load) are left out, so a caller who saw the job running never changes what it grounds
/// in. Frames are only appended while a job runs (removal waits), so they come last.
pub(crate) fn frames_at_claim(scene: Arc<SceneData>, claimed: Option<i64>) -> Arc<SceneData> {
    match claimed {
        Some(n) if (n.max(0) as usize) < scene.frames.len() => {
            let n = n.max(0) as usize;
            let mut only = (*scene).clone();
            only.frames.retain(|f| f.idx < n);
            Arc::new(only)
        }
        _ => scene,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{DepthMap, FrameCamera, Intrinsics};
    use crate::scene::FrameData;
    use nalgebra::Matrix4;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A scene of `frames` frames with 100x100 depth maps (20 000 bytes each).
    fn scene(id: &str, frames: usize) -> SceneData {
        let k = Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: 50.0,
            cy: 50.0,
            width: 100,
            height: 100,
        };
        let frames = (0..frames)
            .map(|i| FrameData {
                idx: i,
                name: i.to_string(),
                usable: true,
                camera: FrameCamera {
                    color: k,
                    depth: None,
                    depth_size: (100, 100),
                    pose: Matrix4::identity(),
                    align: Matrix4::identity(),
                },
                depth: Arc::new(DepthMap::new(100, 100, vec![1000; 100 * 100])),
                color_path: format!("/s/color/{i}.jpg").into(),
                instance_path: None,
            })
            .collect();
        SceneData {
            id: id.into(),
            color: k,
            depth: None,
            axis_align: None,
            frames,
            instance_labels: None,
            room: Default::default(),
        }
    }

    #[test]
    fn a_job_keeps_the_frames_its_scene_had_when_claimed() {
        let all = Arc::new(scene("a", 6));
        let kept = frames_at_claim(all.clone(), Some(4));
        let idx: Vec<usize> = kept.frames.iter().map(|f| f.idx).collect();
        assert_eq!(idx, [0, 1, 2, 3]);
        assert_eq!(all.frames.len(), 6, "the shared scene is untouched");
        for same in [None, Some(6), Some(9)] {
            assert!(Arc::ptr_eq(&frames_at_claim(all.clone(), same), &all));
        }
    }

    #[test]
    fn the_cache_keeps_what_fits_its_byte_bound_and_drops_the_oldest() {
        let one = scene_bytes(&scene("a", 10));
        assert!(one > 200_000, "ten 100x100 depth maps are counted: {one}");
        // Room for two such scenes, not three.
        let c = SceneCache::new(one * 2 + one / 2);
        for id in ["a", "b", "c"] {
            c.put(id, Arc::new(scene(id, 10)));
        }
        assert!(c.kept_bytes() <= one * 2 + one / 2, "{}", c.kept_bytes());
        assert_eq!(c.kept_bytes(), one * 2);
        assert!(
            c.get("a").is_none(),
            "the oldest was dropped (nobody holds it)"
        );
        assert!(c.get("b").is_some() && c.get("c").is_some());
        // Using b makes c the oldest.
        let _ = c.get("b");
        c.put("d", Arc::new(scene("d", 10)));
        assert!(c.get("c").is_none());
        assert!(c.get("b").is_some() && c.get("d").is_some());
    }

    #[test]
    fn a_scene_over_the_bound_is_shared_while_held_and_not_kept() {
        let c = SceneCache::new(1000);
        let held = Arc::new(scene("big", 5));
        c.put("big", held.clone());
        assert_eq!(c.kept_bytes(), 0);
        let again = c.get("big").map(|s| Arc::ptr_eq(&s, &held));
        assert_eq!(again, Some(true), "a job holding it shares it");
        drop(held);
        assert!(c.get("big").is_none(), "gone once no job holds it");
    }

    #[test]
    fn mapped_depth_is_not_counted_against_the_bound() {
        let owned = scene("a", 10);
        let buf: Arc<dyn AsRef<[u16]> + Send + Sync> = Arc::new(vec![1000u16; 10 * 100 * 100]);
        let mut mapped = owned.clone();
        for (i, f) in mapped.frames.iter_mut().enumerate() {
            f.depth = Arc::new(DepthMap::shared(100, 100, buf.clone(), i * 10_000).unwrap());
        }
        assert_eq!(mapped.frames[9].depth, owned.frames[9].depth);
        let (a, b) = (scene_bytes(&owned), scene_bytes(&mapped));
        assert_eq!(a - b, 10 * 100 * 100 * 2, "{a} vs {b}");
        assert!(b < 10_000, "records only: {b}");
    }

    #[test]
    fn a_scene_loaded_outside_is_kept_unless_forgotten_since() {
        let c = SceneCache::new(1 << 30);
        let mark = c.mark();
        let s = Arc::new(scene("a", 2));
        assert!(c.put_unless_forgotten("a", s.clone(), mark));
        assert!(c.get("a").is_some_and(|g| Arc::ptr_eq(&g, &s)));
        // Already there: the cached copy stays.
        assert!(!c.put_unless_forgotten("a", Arc::new(scene("a", 2)), c.mark()));
        assert!(c.get("a").is_some_and(|g| Arc::ptr_eq(&g, &s)));
        // Loaded, then the scene's frames changed (it was forgotten): not kept.
        let mark = c.mark();
        c.remove("a");
        assert!(!c.put_unless_forgotten("a", Arc::new(scene("a", 2)), mark));
        assert!(c.get("a").is_none());
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
    async fn concurrent_jobs_on_one_scene_load_it_once() {
        let c = Arc::new(SceneCache::new(1 << 30));
        let loads = Arc::new(AtomicUsize::new(0));
        let tasks: Vec<_> = (0..8)
            .map(|_| {
                let (c, loads) = (c.clone(), loads.clone());
                tokio::spawn(async move {
                    c.get_or_load("s", || async {
                        loads.fetch_add(1, Ordering::SeqCst);
                        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                        Ok::<_, ()>(scene("s", 2))
                    })
                    .await
                })
            })
            .collect();
        let mut got = Vec::new();
        for t in tasks {
            got.push(t.await.unwrap().unwrap());
        }
        assert_eq!(loads.load(Ordering::SeqCst), 1);
        assert!(got.iter().all(|s| Arc::ptr_eq(s, &got[0])));
        assert!(c.lock().loading.is_empty(), "the flight lock is cleaned up");
    }
}
