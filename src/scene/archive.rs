//! Safe unpacking of uploaded archives (tar, tar.gz, zip) into a private directory.
//!
//! Refuses absolute paths, `..`, links and device entries, and caps the total unpacked size
//! and the entry count (zip bombs). Sizes are counted from the bytes actually written, not
//! from what the archive's headers claim.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Component, Path, PathBuf};

use super::archive_guard::{check_zip_directory, Counted, TarGuard};
use super::SceneError;

/// The archive kinds we accept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArchiveKind {
    Tar,
    TarGz,
    Zip,
}

/// Limits for unpacking.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    pub max_bytes: u64,
    pub max_files: u64,
    /// Most pixels one image of the scene may declare (checked from its header).
    pub max_image_pixels: u64,
    /// Most pixels the whole scene may hold: frames x (colour + depth pixels), checked
    /// from the first frame's headers before any frame is decoded.
    pub max_scene_pixels: u64,
}

/// Decide the kind from the leading bytes (authoritative) with the content type as a hint.
pub fn sniff(head: &[u8], content_type: Option<&str>) -> Result<ArchiveKind, SceneError> {
    if head.len() >= 4 && head[..4] == [0x50, 0x4b, 0x03, 0x04] {
        return Ok(ArchiveKind::Zip);
    }
    if head.len() >= 4 && head[..4] == [0x50, 0x4b, 0x05, 0x06] {
        return Err(SceneError::NoFrames); // an empty zip
    }
    if head.len() >= 2 && head[..2] == [0x1f, 0x8b] {
        return Ok(ArchiveKind::TarGz);
    }
    if head.len() >= 262 && &head[257..262] == b"ustar" {
        return Ok(ArchiveKind::Tar);
    }
    let ct = content_type.unwrap_or("unknown");
    Err(SceneError::NotArchive(format!(
        "the body (content type {ct}) is not a tar, tar.gz or zip archive"
    )))
}

/// Check an entry's path and return it relative to the destination.
fn safe_relative(path: &Path) -> Result<PathBuf, SceneError> {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::Normal(p) => out.push(p),
            Component::CurDir => {}
            Component::ParentDir => {
                return Err(SceneError::UnsafeArchive(format!(
                    "entry {:?} climbs out with '..'",
                    path.display().to_string()
                )))
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err(SceneError::UnsafeArchive(format!(
                    "entry {:?} has an absolute path",
                    path.display().to_string()
                )))
            }
        }
    }
    Ok(out)
}

struct Budget {
    limits: Limits,
    bytes: u64,
    files: u64,
}

impl Budget {
    fn entry(&mut self) -> Result<(), SceneError> {
        self.files += 1;
        if self.files > self.limits.max_files {
            return Err(SceneError::TooLarge(format!(
                "the archive holds more than {} entries",
                self.limits.max_files
            )));
        }
        Ok(())
    }

    /// Copy `r` into a new file at `dest`, counting against the byte cap.
    fn write_file(&mut self, r: &mut dyn Read, dest: &Path) -> Result<(), SceneError> {
        if let Some(parent) = dest.parent() {
            std::fs::create_dir_all(parent)
                .map_err(|e| SceneError::Io(format!("cannot create folder: {e}")))?;
        }
        let mut f =
            File::create(dest).map_err(|e| SceneError::Io(format!("cannot write file: {e}")))?;
        let mut buf = vec![0u8; 1 << 16];
        loop {
            let n = r.read(&mut buf).map_err(|e| {
                SceneError::Truncated(format!("archive cannot be read to the end: {e}"))
            })?;
            if n == 0 {
                break;
            }
            self.bytes += n as u64;
            if self.bytes > self.limits.max_bytes {
                return Err(SceneError::TooLarge(format!(
                    "the archive unpacks to more than {} bytes",
                    self.limits.max_bytes
                )));
            }
            f.write_all(&buf[..n])
                .map_err(|e| SceneError::Io(format!("cannot write file: {e}")))?;
        }
        Ok(())
    }
}

/// Unpack `archive` (a file) into `dest` (an existing empty directory).
pub fn unpack(
    archive: &Path,
    kind: ArchiveKind,
    dest: &Path,
    limits: Limits,
) -> Result<(), SceneError> {
    let file =
        File::open(archive).map_err(|e| SceneError::Io(format!("cannot open upload: {e}")))?;
    let mut budget = Budget {
        limits,
        bytes: 0,
        files: 0,
    };
    match kind {
        ArchiveKind::Tar => {
            let guard = TarGuard::new(std::io::BufReader::new(file), limits.max_bytes, None);
            unpack_tar(guard, dest, &mut budget)
        }
        ArchiveKind::TarGz => {
            let packed = std::rc::Rc::new(std::cell::RefCell::new(0u64));
            let counted = Counted {
                inner: std::io::BufReader::new(file),
                count: packed.clone(),
            };
            let guard = TarGuard::new(
                flate2::read::GzDecoder::new(counted),
                limits.max_bytes,
                Some(packed),
            );
            unpack_tar(guard, dest, &mut budget)
        }
        ArchiveKind::Zip => {
            let mut file = file;
            check_zip_directory(&mut file, limits.max_files)?;
            unpack_zip(file, dest, &mut budget)
        }
    }
}

/// Unpack through the guard; a refusal of the guard's is the error, not the tar reader's
/// report of the failed read.
fn unpack_tar<R: Read>(r: TarGuard<R>, dest: &Path, budget: &mut Budget) -> Result<(), SceneError> {
    let refused = r.refused.clone();
    let result = unpack_tar_entries(r, dest, budget);
    let refusal = refused.borrow_mut().take();
    match refusal {
        Some(e) => Err(e),
        None => result,
    }
}

fn unpack_tar_entries<R: Read>(r: R, dest: &Path, budget: &mut Budget) -> Result<(), SceneError> {
    let mut ar = tar::Archive::new(r);
    let entries = ar
        .entries()
        .map_err(|e| SceneError::Truncated(format!("not a readable tar archive: {e}")))?;
    let mut any = false;
    for entry in entries {
        let mut entry = entry.map_err(|e| {
            SceneError::Truncated(format!("tar archive is truncated or corrupt: {e}"))
        })?;
        any = true;
        budget.entry()?;
        let path = entry
            .path()
            .map_err(|e| SceneError::UnsafeArchive(format!("entry with an unreadable path: {e}")))?
            .into_owned();
        let rel = safe_relative(&path)?;
        let kind = entry.header().entry_type();
        if kind.is_dir() {
            std::fs::create_dir_all(dest.join(&rel))
                .map_err(|e| SceneError::Io(format!("cannot create folder: {e}")))?;
        } else if kind.is_file() {
            if rel.as_os_str().is_empty() {
                continue;
            }
            budget.write_file(&mut entry, &dest.join(&rel))?;
        } else if kind.is_symlink() || kind.is_hard_link() {
            return Err(SceneError::UnsafeArchive(format!(
                "entry {:?} is a link; links are not accepted",
                path.display().to_string()
            )));
        } else if kind.is_pax_global_extensions()
            || kind.is_pax_local_extensions()
            || kind.is_gnu_longname()
        {
            continue;
        } else {
            return Err(SceneError::UnsafeArchive(format!(
                "entry {:?} is not a regular file or folder",
                path.display().to_string()
            )));
        }
    }
    if !any {
        return Err(SceneError::Truncated(
            "the tar archive holds no entries".into(),
        ));
    }
    Ok(())
}

fn unpack_zip(file: File, dest: &Path, budget: &mut Budget) -> Result<(), SceneError> {
    let mut zip = zip::ZipArchive::new(file)
        .map_err(|e| SceneError::Truncated(format!("zip archive is truncated or corrupt: {e}")))?;
    for i in 0..zip.len() {
        budget.entry()?;
        let mut entry = zip
            .by_index(i)
            .map_err(|e| SceneError::Truncated(format!("zip entry {i} cannot be read: {e}")))?;
        let raw = PathBuf::from(entry.name());
        let rel = safe_relative(&raw)?;
        if entry.enclosed_name().is_none() {
            return Err(SceneError::UnsafeArchive(format!(
                "entry {:?} escapes the archive",
                entry.name()
            )));
        }
        if entry.is_symlink() {
            return Err(SceneError::UnsafeArchive(format!(
                "entry {:?} is a link; links are not accepted",
                entry.name()
            )));
        }
        if entry.is_dir() {
            std::fs::create_dir_all(dest.join(&rel))
                .map_err(|e| SceneError::Io(format!("cannot create folder: {e}")))?;
        } else {
            budget.write_file(&mut entry, &dest.join(&rel))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_parent_and_absolute_paths() {
        assert!(safe_relative(Path::new("a/../../etc/passwd")).is_err());
        assert!(safe_relative(Path::new("/etc/passwd")).is_err());
        assert_eq!(
            safe_relative(Path::new("./scene/color/0.jpg")).unwrap(),
            PathBuf::from("scene/color/0.jpg")
        );
    }

    #[test]
    fn sniffs_kinds() {
        assert_eq!(
            sniff(&[0x1f, 0x8b, 8, 0], None).unwrap(),
            ArchiveKind::TarGz
        );
        assert_eq!(sniff(b"PK\x03\x04rest", None).unwrap(), ArchiveKind::Zip);
        let mut tar = vec![0u8; 512];
        tar[257..262].copy_from_slice(b"ustar");
        assert_eq!(sniff(&tar, None).unwrap(), ArchiveKind::Tar);
        assert!(matches!(
            sniff(b"hello world", Some("text/plain")),
            Err(SceneError::NotArchive(_))
        ));
    }
}
