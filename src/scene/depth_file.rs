//! A scene's depth maps as one file of raw little-endian u16 values (frame after frame, each
//! `width * height` values), mapped into memory so that the pipeline reads any frame's depth
//! without decoding the stored blobs: a loaded scene holds no decoded depth of its own, the
//! pages a job touches are shared by every job on the scene (and every process), and the
//! kernel drops them again when memory is short, since they are clean file pages.
//!
//! The file is a cache derived from the store's compressed blobs: written once (tmp +
//! rename, one frame decoded at a time) by whoever loads the scene first, found again by
//! its name, which carries the frame count, the depth size and a tag of the blobs' sizes,
//! so that a scene that grew or changed gets a new file.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use memmap2::Mmap;

use super::model::decompress_depth;
use crate::geometry::DepthMap;

/// Depth frames decoded from stored blobs by this process (to write depth files, or when a
/// file cannot be used), for tests and diagnostics.
static FRAMES_DECODED: AtomicU64 = AtomicU64::new(0);

/// How many depth frames this process decoded from their stored blobs so far.
pub fn frames_decoded() -> u64 {
    FRAMES_DECODED.load(Ordering::Relaxed)
}

/// Decode one stored depth blob (counted in [`frames_decoded`]).
pub fn decode(blob: &[u8], width: u32, height: u32) -> Option<DepthMap> {
    FRAMES_DECODED.fetch_add(1, Ordering::Relaxed);
    decompress_depth(blob, width, height)
}

/// What identifies a scene's depth: frame count, depth size, and the stored blobs' sizes in
/// frame order (a replaced frame almost always changes its compressed size).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DepthKey {
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub blob_sizes: Vec<u64>,
}

impl DepthKey {
    fn values_per_frame(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The file's name in the scene's folder.
    pub fn file_name(&self) -> String {
        // FNV-1a over the sizes: a tag, not a security check.
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for s in &self.blob_sizes {
            for b in s.to_le_bytes() {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        }
        format!(
            "depth-{}f-{}x{}-{h:016x}.u16",
            self.frames, self.width, self.height
        )
    }

    /// The file's path under `scene_dir`.
    pub fn path(&self, scene_dir: &Path) -> PathBuf {
        scene_dir.join(self.file_name())
    }
}

/// Why a depth file was not written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// A stored blob does not decode, or frames are missing: the scene's data is at fault.
    #[error("{0}")]
    Corrupt(String),
    /// The file could not be written (the stored data may be fine).
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// A mapped depth file.
pub struct DepthFile {
    map: Mmap,
}

impl AsRef<[u16]> for DepthFile {
    fn as_ref(&self) -> &[u16] {
        // `open` checked that the mapping (page-aligned) holds a whole number of u16.
        bytemuck::cast_slice(&self.map)
    }
}

/// The scene's depth maps from its file under `scene_dir`, each a window onto the mapping;
/// `Ok(None)` when there is no such file (or it has the wrong size, or this host is not
/// little-endian), so the caller writes it.
pub fn open(scene_dir: &Path, key: &DepthKey) -> std::io::Result<Option<Vec<DepthMap>>> {
    let n = key.values_per_frame();
    let want = key.frames as u64 * n as u64 * 2;
    if cfg!(target_endian = "big") || want == 0 {
        return Ok(None);
    }
    let file = match std::fs::File::open(key.path(scene_dir)) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e),
    };
    if file.metadata()?.len() != want {
        return Ok(None);
    }
    // SAFETY: the file is private to this service and never modified in place: it is
    // written under a temporary name and renamed, and replaced or deleted only by renaming
    // or unlinking, which leaves an existing mapping's pages intact. So the mapped bytes do
    // not change while mapped (the condition memmap2 asks the caller to uphold).
    let map = unsafe { Mmap::map(&file)? };
    if bytemuck::try_cast_slice::<u8, u16>(&map).is_err() {
        return Ok(None);
    }
    let buf: Arc<dyn AsRef<[u16]> + Send + Sync> = Arc::new(DepthFile { map });
    let maps = (0..key.frames)
        .map(|i| DepthMap::shared(key.width, key.height, buf.clone(), i * n))
        .collect::<Option<Vec<_>>>();
    Ok(maps)
}

/// Write the scene's depth file from its stored blobs (in frame order), one frame decoded
/// at a time, then rename it into place and remove the scene's older depth files. An error
/// names the frame whose blob does not decode. The scene's folder must exist: a missing one
/// means the scene is being deleted (a load racing the delete must not bring it back), and
/// gives an [`WriteError::Io`] of kind `NotFound`.
pub fn write(
    scene_dir: &Path,
    key: &DepthKey,
    blobs: impl Iterator<Item = Vec<u8>>,
) -> Result<(), WriteError> {
    let name = key.file_name();
    let path = scene_dir.join(&name);
    let tmp = scene_dir.join(format!(".{name}.{}.tmp", uuid::Uuid::now_v7()));
    let result = (|| {
        if !scene_dir.is_dir() {
            return Err(WriteError::Io(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("the scene's folder {} is gone", scene_dir.display()),
            )));
        }
        let mut out = std::io::BufWriter::with_capacity(1 << 16, std::fs::File::create(&tmp)?);
        let mut count = 0usize;
        for blob in blobs {
            let d = decode(&blob, key.width, key.height).ok_or_else(|| {
                WriteError::Corrupt(format!("frame {count}: the stored depth is corrupt"))
            })?;
            if cfg!(target_endian = "little") {
                out.write_all(bytemuck::cast_slice(&d.data))?;
            } else {
                for v in d.data.iter() {
                    out.write_all(&v.to_le_bytes())?;
                }
            }
            count += 1;
        }
        if count != key.frames {
            return Err(WriteError::Corrupt(format!(
                "expected the depth of {} frames, read {count}",
                key.frames
            )));
        }
        out.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        std::fs::rename(&tmp, &path)?;
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
        return result;
    }
    // Older files of this scene (before it grew or changed): jobs that mapped them keep
    // their pages until they end.
    if let Ok(rd) = std::fs::read_dir(scene_dir) {
        for e in rd.flatten() {
            let n = e.file_name();
            let n = n.to_string_lossy();
            if is_depth_file(&n) && n != name {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
    Ok(())
}

/// True for the name of a scene's mapped depth file: a cache each process builds from the
/// stored depth, never copied between replicas.
pub fn is_depth_file(name: &str) -> bool {
    name.starts_with("depth-") && name.ends_with(".u16") && !name.contains('/')
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::model::compress_depth;

    fn key(frames: &[DepthMap]) -> DepthKey {
        DepthKey {
            frames: frames.len(),
            width: frames[0].width,
            height: frames[0].height,
            blob_sizes: frames
                .iter()
                .map(|f| compress_depth(f).len() as u64)
                .collect(),
        }
    }

    fn frames() -> Vec<DepthMap> {
        (0..3u16)
            .map(|i| DepthMap::new(4, 3, (0..12).map(|v| v * 100 + i).collect()))
            .collect()
    }

    #[test]
    fn a_written_file_maps_back_to_the_same_depth_without_copies() {
        let dir = tempfile::tempdir().unwrap();
        let fr = frames();
        let k = key(&fr);
        assert!(
            open(dir.path(), &k).unwrap().is_none(),
            "nothing written yet"
        );
        write(dir.path(), &k, fr.iter().map(compress_depth)).unwrap();
        let back = open(dir.path(), &k).unwrap().unwrap();
        assert_eq!(back, fr);
        assert!(back.iter().all(|d| d.data.is_shared()));
        assert_eq!(back[2].get(3, 2), 1102);
        // Writing into a mapped frame copies it; the file is untouched.
        let mut d = back[1].clone();
        d.data[0] = 7;
        assert!(!d.data.is_shared());
        assert_eq!(open(dir.path(), &k).unwrap().unwrap()[1], fr[1]);
        // No temporary file is left behind.
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, vec![k.file_name()]);
    }

    #[test]
    fn a_grown_scene_gets_a_new_file_and_the_old_one_goes() {
        let dir = tempfile::tempdir().unwrap();
        let mut fr = frames();
        let k1 = key(&fr);
        write(dir.path(), &k1, fr.iter().map(compress_depth)).unwrap();
        fr.push(DepthMap::new(4, 3, vec![9; 12]));
        let k2 = key(&fr);
        assert_ne!(k1.file_name(), k2.file_name());
        assert!(open(dir.path(), &k2).unwrap().is_none());
        write(dir.path(), &k2, fr.iter().map(compress_depth)).unwrap();
        assert_eq!(open(dir.path(), &k2).unwrap().unwrap(), fr);
        assert!(open(dir.path(), &k1).unwrap().is_none(), "old file removed");
    }

    #[test]
    fn a_missing_scene_folder_is_not_created_again() {
        let dir = tempfile::tempdir().unwrap();
        let gone = dir.path().join("deleted-scene");
        let fr = frames();
        let k = key(&fr);
        let e = write(&gone, &k, fr.iter().map(compress_depth)).unwrap_err();
        assert!(
            matches!(&e, WriteError::Io(io) if io.kind() == std::io::ErrorKind::NotFound),
            "{e}"
        );
        assert!(!gone.exists(), "the folder came back");
    }

    #[test]
    fn a_corrupt_blob_or_a_missing_frame_writes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let fr = frames();
        let k = key(&fr);
        let mut blobs: Vec<Vec<u8>> = fr.iter().map(compress_depth).collect();
        blobs[1] = vec![1, 2, 3];
        let e = write(dir.path(), &k, blobs.into_iter()).unwrap_err();
        assert!(e.to_string().contains("frame 1"), "{e}");
        let e = write(dir.path(), &k, fr.iter().take(2).map(compress_depth)).unwrap_err();
        assert!(e.to_string().contains("3 frames, read 2"), "{e}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
