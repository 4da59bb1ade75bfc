//! Which scenes the local cache holds, how large each is, which are in use, and which to
//! evict: whole scenes, least recently used first, never one in use. Pure bookkeeping; the
//! caller removes the folders.

use std::collections::HashMap;

#[derive(Debug, Clone, Copy)]
struct Entry {
    bytes: u64,
    last_use: u64,
    pins: usize,
    /// The scene revision the local copy holds every file of.
    revision: i64,
}

/// The local cache's index.
#[derive(Debug, Default)]
pub struct CacheIndex {
    max_bytes: u64,
    clock: u64,
    entries: HashMap<String, Entry>,
}

impl CacheIndex {
    pub fn new(max_bytes: u64) -> Self {
        Self {
            max_bytes,
            ..Self::default()
        }
    }

    fn tick(&mut self) -> u64 {
        self.clock += 1;
        self.clock
    }

    /// Is the scene held locally?
    pub fn holds(&self, id: &str) -> bool {
        self.entries.contains_key(id)
    }

    /// Record a scene now held locally, complete up to `revision` (replacing any earlier
    /// record of it; its pins stay).
    pub fn insert(&mut self, id: &str, bytes: u64, revision: i64) {
        let t = self.tick();
        let pins = self.entries.get(id).map_or(0, |e| e.pins);
        self.entries.insert(
            id.to_string(),
            Entry {
                bytes,
                last_use: t,
                pins,
                revision,
            },
        );
    }

    /// The revision the local copy of a held scene is complete up to.
    pub fn revision(&self, id: &str) -> Option<i64> {
        self.entries.get(id).map(|e| e.revision)
    }

    /// The scene's size changed (frames appended, previews written).
    pub fn resize(&mut self, id: &str, bytes: u64) {
        if let Some(e) = self.entries.get_mut(id) {
            e.bytes = bytes;
        }
    }

    /// Mark a held scene in use (and recently used). False when it is not held.
    pub fn pin(&mut self, id: &str) -> bool {
        let t = self.tick();
        match self.entries.get_mut(id) {
            Some(e) => {
                e.pins += 1;
                e.last_use = t;
                true
            }
            None => false,
        }
    }

    /// One use of the scene ended.
    pub fn unpin(&mut self, id: &str) {
        if let Some(e) = self.entries.get_mut(id) {
            e.pins = e.pins.saturating_sub(1);
        }
    }

    /// Forget a scene (deleted, or its folder removed).
    pub fn remove(&mut self, id: &str) {
        self.entries.remove(id);
    }

    /// Bytes of every held scene.
    pub fn total_bytes(&self) -> u64 {
        self.entries.values().map(|e| e.bytes).sum()
    }

    /// Scenes to evict so that the total fits the bound: least recently used first,
    /// none in use. They are forgotten here; the caller removes their folders. When the
    /// scenes in use alone exceed the bound, they stay (and the total with them).
    pub fn evict(&mut self) -> Vec<String> {
        let mut total = self.total_bytes();
        let mut idle: Vec<(u64, String)> = self
            .entries
            .iter()
            .filter(|(_, e)| e.pins == 0)
            .map(|(id, e)| (e.last_use, id.clone()))
            .collect();
        idle.sort();
        let mut out = Vec::new();
        for (_, id) in idle {
            if total <= self.max_bytes {
                break;
            }
            if let Some(e) = self.entries.remove(&id) {
                total = total.saturating_sub(e.bytes);
                out.push(id);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::CacheIndex;

    #[test]
    fn eviction_removes_the_least_recently_used_idle_scenes_until_the_bound_holds() {
        let mut c = CacheIndex::new(250);
        c.insert("a", 100, 0);
        c.insert("b", 100, 0);
        c.insert("c", 100, 0);
        // "a" is used again, so "b" is now the least recently used.
        assert!(c.pin("a"));
        c.unpin("a");
        assert_eq!(c.evict(), vec!["b".to_string()]);
        assert_eq!(c.total_bytes(), 200);
        assert!(c.holds("a") && c.holds("c") && !c.holds("b"));
        assert!(c.evict().is_empty());
    }

    #[test]
    fn a_scene_in_use_is_never_evicted_even_over_the_bound() {
        let mut c = CacheIndex::new(50);
        c.insert("a", 100, 0);
        c.insert("b", 100, 0);
        assert!(c.pin("a"));
        assert_eq!(c.evict(), vec!["b".to_string()]);
        assert!(c.holds("a"));
        assert_eq!(c.total_bytes(), 100);
        c.unpin("a");
        assert_eq!(c.evict(), vec!["a".to_string()]);
        assert_eq!(c.total_bytes(), 0);
        assert!(!c.pin("a"), "an evicted scene cannot be pinned");
    }
}
