//! Limits enforced on an archive's raw bytes before any reader allocates what the archive
//! claims.
//!
//! - [`TarGuard`] sits under the tar reader (below gzip's output for tar.gz) and follows the
//!   tar stream's own structure as the bytes pass: every 512-byte header is read, and a
//!   metadata entry (GNU long name or long link, PAX local or global header) larger than
//!   [`MAX_TAR_METADATA`] is refused before the tar crate reads it whole into memory. It
//!   also counts every byte, metadata included, against the unpacked-size budget, and the
//!   decompression ratio against [`MAX_RATIO`].
//! - [`check_zip_directory`] reads a zip's end-of-central-directory record (zip64 too) and
//!   refuses an entry count or a directory size over the limits before the directory is
//!   parsed.

use std::cell::RefCell;
use std::io::{Read, Seek, SeekFrom};
use std::rc::Rc;

use super::SceneError;

/// Largest tar metadata entry (long name, PAX header) accepted, bytes.
pub const MAX_TAR_METADATA: u64 = 1 << 20;

/// Largest ratio of unpacked to compressed bytes, once past [`RATIO_FLOOR`] unpacked bytes.
pub const MAX_RATIO: u64 = 1000;

/// Unpacked bytes before the ratio is checked (small archives of zeros are fine).
const RATIO_FLOOR: u64 = 64 << 20;

/// Largest zip central directory accepted, bytes (an entry's record is ~50 bytes plus its
/// name: 200 000 entries take ~20 MB).
pub const MAX_ZIP_DIRECTORY: u64 = 64 << 20;

/// Counts the bytes read through it (the compressed side of a tar.gz).
pub struct Counted<R> {
    pub inner: R,
    pub count: Rc<RefCell<u64>>,
}

impl<R: Read> Read for Counted<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        *self.count.borrow_mut() += n as u64;
        Ok(n)
    }
}

/// Follows a tar stream's headers as it is read; see the module docs. When it refuses, the
/// reason is left in `refused` (the tar reader's own error only says the read failed).
pub struct TarGuard<R> {
    inner: R,
    header: Vec<u8>,
    /// Data bytes (with padding) before the next header.
    skip: u64,
    total: u64,
    entries: u64,
    max_bytes: u64,
    /// Bytes read on the compressed side, when there is one.
    compressed: Option<Rc<RefCell<u64>>>,
    pub refused: Rc<RefCell<Option<SceneError>>>,
}

/// The size field of a tar header: octal digits, or base-256 when its first byte's high bit
/// is set (GNU, for sizes past 8 GiB).
fn header_size(h: &[u8]) -> Option<u64> {
    let field = &h[124..136];
    if field[0] & 0x80 != 0 {
        let mut v: u64 = u64::from(field[0] & 0x7f);
        for &b in &field[1..] {
            v = v.checked_mul(256)?.checked_add(u64::from(b))?;
        }
        return Some(v);
    }
    let text: String = field
        .iter()
        .take_while(|&&b| b != 0)
        .map(|&b| b as char)
        .collect();
    let t = text.trim();
    if t.is_empty() {
        return Some(0);
    }
    u64::from_str_radix(t, 8).ok()
}

impl<R: Read> TarGuard<R> {
    pub fn new(inner: R, max_bytes: u64, compressed: Option<Rc<RefCell<u64>>>) -> Self {
        Self {
            inner,
            header: Vec::with_capacity(512),
            skip: 0,
            total: 0,
            entries: 0,
            max_bytes,
            compressed,
            refused: Rc::new(RefCell::new(None)),
        }
    }

    fn refuse(&self, e: SceneError) -> std::io::Error {
        let msg = e.to_string();
        *self.refused.borrow_mut() = Some(e);
        std::io::Error::other(msg)
    }

    /// Walk the structure over bytes just read.
    fn follow(&mut self, mut bytes: &[u8]) -> std::io::Result<()> {
        while !bytes.is_empty() {
            if self.skip > 0 {
                let k = (self.skip.min(bytes.len() as u64)) as usize;
                self.skip -= k as u64;
                bytes = &bytes[k..];
                continue;
            }
            let k = (512 - self.header.len()).min(bytes.len());
            self.header.extend_from_slice(&bytes[..k]);
            bytes = &bytes[k..];
            if self.header.len() < 512 {
                continue;
            }
            let h = std::mem::take(&mut self.header);
            if h.iter().all(|&b| b == 0) {
                continue;
            }
            self.entries += 1;
            let size = header_size(&h).ok_or_else(|| {
                self.refuse(SceneError::Truncated(format!(
                    "tar entry {}: unreadable size field",
                    self.entries
                )))
            })?;
            let meta = match h[156] {
                b'L' => Some("a GNU long name"),
                b'K' => Some("a GNU long link name"),
                b'x' => Some("a PAX header"),
                b'g' => Some("a PAX global header"),
                _ => None,
            };
            if let Some(what) = meta {
                if size > MAX_TAR_METADATA {
                    return Err(self.refuse(SceneError::TooLarge(format!(
                        "tar entry {} is {what} of {size} bytes; metadata entries may hold at \
                         most {MAX_TAR_METADATA} bytes",
                        self.entries
                    ))));
                }
            }
            self.skip = size.div_ceil(512).saturating_mul(512);
        }
        Ok(())
    }
}

impl<R: Read> Read for TarGuard<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.refused.borrow().is_some() {
            return Err(std::io::Error::other("the archive was refused"));
        }
        let n = self.inner.read(buf)?;
        self.total += n as u64;
        // Headers and padding count too: 512 bytes per entry on top of the file bytes.
        if self.total
            > self
                .max_bytes
                .saturating_add(self.entries.saturating_mul(1024))
        {
            return Err(self.refuse(SceneError::TooLarge(format!(
                "the archive unpacks to more than {} bytes (max_unpacked_bytes)",
                self.max_bytes
            ))));
        }
        if let Some(c) = &self.compressed {
            let packed = (*c.borrow()).max(1);
            if self.total > RATIO_FLOOR && self.total / packed > MAX_RATIO {
                return Err(self.refuse(SceneError::TooLarge(format!(
                    "the archive expands more than {MAX_RATIO}-fold ({} bytes from {packed}); \
                     refused as a decompression bomb",
                    self.total
                ))));
            }
        }
        self.follow(&buf[..n])?;
        Ok(n)
    }
}

fn u16_at(b: &[u8], i: usize) -> u64 {
    u64::from(u16::from_le_bytes([b[i], b[i + 1]]))
}

fn u32_at(b: &[u8], i: usize) -> u64 {
    u64::from(u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]))
}

fn u64_at(b: &[u8], i: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[i..i + 8]);
    u64::from_le_bytes(a)
}

/// Refuse a zip whose end record declares more than `max_files` entries or a central
/// directory over [`MAX_ZIP_DIRECTORY`] bytes, before the directory is parsed.
pub fn check_zip_directory<F: Read + Seek>(f: &mut F, max_files: u64) -> Result<(), SceneError> {
    let io = |e: std::io::Error| SceneError::Io(format!("cannot read upload: {e}"));
    let len = f.seek(SeekFrom::End(0)).map_err(io)?;
    // The end record is 22 bytes plus a comment of up to 65535.
    let tail_len = len.min(22 + 65_535 + 20);
    f.seek(SeekFrom::Start(len - tail_len)).map_err(io)?;
    let mut tail = vec![0u8; tail_len as usize];
    f.read_exact(&mut tail).map_err(io)?;
    let Some(eocd) = (0..tail.len().saturating_sub(21))
        .rev()
        .find(|&i| tail[i..i + 4] == [0x50, 0x4b, 0x05, 0x06])
    else {
        return Err(SceneError::Truncated(
            "zip archive is truncated or corrupt: no end of central directory record".into(),
        ));
    };
    let mut entries = u16_at(&tail, eocd + 10);
    let mut dir_size = u32_at(&tail, eocd + 12);
    // Zip64: a locator just before the end record points at the zip64 end record.
    if eocd >= 20 && tail[eocd - 20..eocd - 16] == [0x50, 0x4b, 0x06, 0x07] {
        let at = u64_at(&tail, eocd - 20 + 8);
        let mut rec = [0u8; 56];
        if at + 56 <= len {
            f.seek(SeekFrom::Start(at)).map_err(io)?;
            f.read_exact(&mut rec).map_err(io)?;
            if rec[..4] == [0x50, 0x4b, 0x06, 0x06] {
                entries = entries.max(u64_at(&rec, 32));
                dir_size = dir_size.max(u64_at(&rec, 40));
            }
        }
    }
    if entries > max_files {
        return Err(SceneError::TooLarge(format!(
            "the zip archive declares {entries} entries, more than {max_files} \
             (max_archive_files)"
        )));
    }
    if dir_size > MAX_ZIP_DIRECTORY {
        return Err(SceneError::TooLarge(format!(
            "the zip archive's central directory is {dir_size} bytes, more than \
             {MAX_ZIP_DIRECTORY}"
        )));
    }
    f.seek(SeekFrom::Start(0)).map_err(io)?;
    Ok(())
}
