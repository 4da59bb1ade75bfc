//! ScanNet `.sens` (SensorData version 4), read as a stream.
//!
//! Conventions:
//! - Layout, all little-endian: `u32` version (4); `u64` length + bytes of the sensor name;
//!   four 4x4 `f32` row-major matrices (colour intrinsics, colour extrinsics, depth
//!   intrinsics, depth extrinsics; the extrinsics are ignored, ScanNet writes identity);
//!   `i32` colour compression (2 = JPEG, the only one accepted); `i32` depth compression
//!   (1 = zlib over `u16`, 0 = raw `u16`); `u32` colour width, height, depth width, height;
//!   `f32` depth shift (depth units per metre, ScanNet 1000); `u64` frame count. Then per
//!   frame: 4x4 `f32` camera-to-world pose (row-major, camera axes x right, y down,
//!   z forward), `u64` colour and depth timestamps, `u64` colour and depth byte counts, the
//!   colour bytes, the depth bytes (row-major `u16`). IMU data after the frames is ignored.
//! - Depth is stored in millimetres (value * 1000 / depth shift).
//! - Frames are named by their number in the file; `every = N` keeps 0, N, 2N, ...
//!   (skipped frames are seeked over, never read). A pose with NaN/inf marks its frame
//!   unusable, as real ScanNet has such frames (FORMATS §1).
//! - The file is read frame by frame; memory does not grow with its size.

use flate2::read::ZlibDecoder;
use nalgebra::Matrix4;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use super::{FormatOptions, SceneOut};
use crate::scene::SceneError;

/// The version this reader understands.
pub const VERSION: u32 = 4;
/// Largest image side accepted from a header.
const MAX_SIDE: u32 = 16384;

/// The single `.sens` file of a folder, if any (two are refused).
pub fn find_sens(dir: &Path) -> Result<Option<PathBuf>, SceneError> {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return Ok(None);
    };
    let found: Vec<PathBuf> = rd
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("sens"))
        })
        .collect();
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.into_iter().next()),
        n => Err(SceneError::Malformed(format!(
            "the archive holds {n} .sens files; upload one scene at a time"
        ))),
    }
}

/// Does `head` start like a `.sens` file (version 4, a sensible name length)?
pub fn looks_like_sens(head: &[u8]) -> bool {
    head.len() >= 12
        && u32::from_le_bytes([head[0], head[1], head[2], head[3]]) == VERSION
        && u64::from_le_bytes([
            head[4], head[5], head[6], head[7], head[8], head[9], head[10], head[11],
        ]) < 4096
}

struct Reader {
    r: BufReader<File>,
    pos: u64,
    len: u64,
    name: String,
}

impl Reader {
    fn truncated(&self, what: &str) -> SceneError {
        SceneError::Truncated(format!(
            "{}: truncated while reading {what} (at byte {} of {})",
            self.name, self.pos, self.len
        ))
    }

    fn bytes(&mut self, buf: &mut [u8], what: &str) -> Result<(), SceneError> {
        if self.pos + buf.len() as u64 > self.len {
            return Err(self.truncated(what));
        }
        self.r.read_exact(buf).map_err(|_| self.truncated(what))?;
        self.pos += buf.len() as u64;
        Ok(())
    }

    fn u32(&mut self, what: &str) -> Result<u32, SceneError> {
        let mut b = [0u8; 4];
        self.bytes(&mut b, what)?;
        Ok(u32::from_le_bytes(b))
    }

    fn i32(&mut self, what: &str) -> Result<i32, SceneError> {
        Ok(self.u32(what)? as i32)
    }

    fn f32(&mut self, what: &str) -> Result<f32, SceneError> {
        Ok(f32::from_bits(self.u32(what)?))
    }

    fn u64(&mut self, what: &str) -> Result<u64, SceneError> {
        let mut b = [0u8; 8];
        self.bytes(&mut b, what)?;
        Ok(u64::from_le_bytes(b))
    }

    fn mat(&mut self, what: &str) -> Result<Matrix4<f64>, SceneError> {
        let mut b = [0u8; 64];
        self.bytes(&mut b, what)?;
        let v: Vec<f64> = b
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64)
            .collect();
        Ok(Matrix4::from_row_slice(&v))
    }

    fn skip(&mut self, n: u64, what: &str) -> Result<(), SceneError> {
        if self.pos + n > self.len {
            return Err(self.truncated(what));
        }
        self.r
            .seek_relative(n as i64)
            .map_err(|e| SceneError::Io(format!("{}: cannot seek: {e}", self.name)))?;
        self.pos += n;
        Ok(())
    }

    /// `n` bytes (already checked against the file size, so a lying count cannot make us
    /// allocate more than the file holds).
    fn vec(&mut self, n: u64, what: &str) -> Result<Vec<u8>, SceneError> {
        if self.pos + n > self.len {
            return Err(self.truncated(what));
        }
        let mut v = vec![0u8; n as usize];
        self.bytes(&mut v, what)?;
        Ok(v)
    }
}

fn bad(name: &str, rule: &str) -> SceneError {
    SceneError::Malformed(format!("{name}: {rule}"))
}

/// Convert a `.sens` file; returns the number of frames written.
pub fn convert(path: &Path, out: &mut SceneOut, opts: &FormatOptions) -> Result<usize, SceneError> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene.sens".into());
    let name = if name.ends_with(".upload") {
        "the .sens body".to_string()
    } else {
        name
    };
    let file = File::open(path).map_err(|e| SceneError::Io(format!("cannot open {name}: {e}")))?;
    let len = file
        .metadata()
        .map_err(|e| SceneError::Io(format!("cannot stat {name}: {e}")))?
        .len();
    let mut r = Reader {
        r: BufReader::with_capacity(1 << 20, file),
        pos: 0,
        len,
        name: name.clone(),
    };
    let version = r.u32("the version")?;
    if version != VERSION {
        return Err(bad(
            &name,
            &format!("version {version}; only SensorData version {VERSION} is read"),
        ));
    }
    let sensor_len = r.u64("the sensor name length")?;
    if sensor_len > 4096 {
        return Err(bad(
            &name,
            "sensor name longer than 4096 bytes; not a .sens file?",
        ));
    }
    r.skip(sensor_len, "the sensor name")?;
    let k_color = r.mat("the colour intrinsics")?;
    let _ext_color = r.mat("the colour extrinsics")?;
    let k_depth = r.mat("the depth intrinsics")?;
    let _ext_depth = r.mat("the depth extrinsics")?;
    let color_comp = r.i32("the colour compression")?;
    let depth_comp = r.i32("the depth compression")?;
    if color_comp != 2 {
        return Err(bad(
            &name,
            &format!("colour compression {color_comp}; colour must be JPEG (2)"),
        ));
    }
    if depth_comp != 0 && depth_comp != 1 {
        return Err(bad(
            &name,
            &format!("depth compression {depth_comp}; depth must be zlib (1) or raw (0) u16"),
        ));
    }
    let (cw, ch) = (r.u32("the colour width")?, r.u32("the colour height")?);
    let (dw, dh) = (r.u32("the depth width")?, r.u32("the depth height")?);
    for (what, v) in [
        ("colour width", cw),
        ("colour height", ch),
        ("depth width", dw),
        ("depth height", dh),
    ] {
        if v == 0 || v > MAX_SIDE {
            return Err(bad(&name, &format!("{what} {v} is outside 1..={MAX_SIDE}")));
        }
    }
    let shift = r.f32("the depth shift")? as f64;
    if !(shift.is_finite() && shift > 0.0) {
        return Err(bad(
            &name,
            "the depth shift must be a positive number (units per metre)",
        ));
    }
    let frames = r.u64("the frame count")?;
    // A frame takes at least 96 bytes (pose, timestamps, sizes).
    if frames.saturating_mul(96) > len {
        return Err(SceneError::Truncated(format!(
            "{name}: the header announces {frames} frames, more than the {len}-byte file can hold"
        )));
    }
    out.intrinsics(&k_color, Some(&k_depth))?;
    let depth_bytes = dw as u64 * dh as u64 * 2;
    let mut written = 0;
    for i in 0..frames {
        let what = |s: &str| format!("frame {i} {s}");
        let pose = r.mat(&what("pose"))?;
        let _ts_color = r.u64(&what("colour timestamp"))?;
        let _ts_depth = r.u64(&what("depth timestamp"))?;
        let color_size = r.u64(&what("colour size"))?;
        let depth_size = r.u64(&what("depth size"))?;
        if !i.is_multiple_of(opts.every) {
            r.skip(color_size, &what("colour"))?;
            r.skip(depth_size, &what("depth"))?;
            continue;
        }
        let frame_name = (opts.first_name + i).to_string();
        let jpeg = r.vec(color_size, &what("colour"))?;
        let raw = r.vec(depth_size, &what("depth"))?;
        let depth = if depth_comp == 1 {
            let mut d = Vec::with_capacity(depth_bytes as usize);
            ZlibDecoder::new(raw.as_slice())
                .take(depth_bytes + 1)
                .read_to_end(&mut d)
                .map_err(|e| {
                    bad(
                        &name,
                        &format!("frame {i} depth is not valid zlib data: {e}"),
                    )
                })?;
            d
        } else {
            raw
        };
        if depth.len() as u64 != depth_bytes {
            return Err(bad(
                &name,
                &format!(
                    "frame {i} depth holds {} bytes; a {dw}x{dh} u16 image needs {depth_bytes}",
                    depth.len()
                ),
            ));
        }
        let mm: Vec<u16> = depth
            .chunks_exact(2)
            .map(|c| {
                let v = u16::from_le_bytes([c[0], c[1]]);
                if shift == 1000.0 {
                    v
                } else {
                    (v as f64 * 1000.0 / shift).round().min(65535.0) as u16
                }
            })
            .collect();
        out.color_jpeg(&frame_name, &jpeg)?;
        out.depth_mm(&frame_name, dw, dh, mm)?;
        out.pose(&frame_name, &pose)?;
        written += 1;
    }
    Ok(written)
}
