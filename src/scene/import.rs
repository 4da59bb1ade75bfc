//! Validating a scene directory and decoding what the store keeps (poses, depth).

use image::ImageDecoder;
use nalgebra::Matrix4;
use rayon::prelude::*;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use super::format::{self, Layout, SceneFiles};
use super::model::compress_depth;
use super::SceneError;
use crate::geometry::camera::is_finite_matrix;
use crate::geometry::{DepthMap, FrameCamera, Intrinsics};

/// One validated frame, ready to be stored.
#[derive(Debug)]
pub struct ImportedFrame {
    pub idx: usize,
    pub name: String,
    pub pose: Matrix4<f64>,
    pub usable: bool,
    pub depth_blob: Vec<u8>,
    pub color_path: PathBuf,
    pub instance_path: Option<PathBuf>,
}

/// A validated scene, ready to be stored.
#[derive(Debug)]
pub struct ImportedScene {
    pub name: String,
    pub layout: Layout,
    /// The capture format the upload was converted from (None: a FORMATS §1 layout).
    pub format: Option<super::formats::CaptureFormat>,
    pub color: Intrinsics,
    pub depth: Option<Intrinsics>,
    pub depth_size: (u32, u32),
    pub axis_align: Option<Matrix4<f64>>,
    pub frames: Vec<ImportedFrame>,
    pub instance_labels: Option<PathBuf>,
}

impl ImportedScene {
    pub fn unusable_names(&self) -> Vec<String> {
        self.frames
            .iter()
            .filter(|f| !f.usable)
            .map(|f| f.name.clone())
            .collect()
    }

    /// The camera of one of this scene's frames (identity alignment when the scene has none).
    pub fn camera(&self, frame: &ImportedFrame) -> FrameCamera {
        FrameCamera {
            color: self.color,
            depth: self.depth,
            depth_size: self.depth_size,
            pose: frame.pose,
            align: self.axis_align.unwrap_or_else(Matrix4::identity),
        }
    }
}

/// Find, scan and import a scene directory in place (either layout of FORMATS.md §1), with
/// the default per-image pixel limit: what the command-line tools read a scene with.
pub fn import_dir(dir: &Path) -> Result<ImportedScene, SceneError> {
    let root = format::find_scene_root(dir)?;
    let files = format::scan(&root)?;
    import(&files, dir, DEFAULT_MAX_IMAGE_PIXELS)
}

fn image_size(path: &Path, what: &str) -> Result<(u32, u32), SceneError> {
    image::image_dimensions(path)
        .map_err(|e| SceneError::BadImage(format!("{what}: unreadable image: {e}")))
}

/// Most pixels a whole scene may hold (frames x (colour + depth pixels)) when the caller
/// names no limit: 10 Gpx is about 6,400 frames of ScanNet (1296x968 colour, 640x480 depth).
pub const DEFAULT_MAX_SCENE_PIXELS: u64 = 10_000_000_000;

/// The refusal of a scene of `frames` frames of `color` + `depth` pixels each when that is
/// over `max` pixels (setting `max_scene_pixels`).
pub fn scene_pixels_error(
    frames: u64,
    color: (u32, u32),
    depth: (u32, u32),
    max: u64,
) -> Option<SceneError> {
    let per_frame =
        u64::from(color.0) * u64::from(color.1) + u64::from(depth.0) * u64::from(depth.1);
    let total = frames.saturating_mul(per_frame);
    (total > max).then(|| {
        SceneError::SceneTooLarge(format!(
            "the scene has {frames} frames of {}x{} colour + {}x{} depth = {total} pixels, \
             over the limit of {max} pixels (max_scene_pixels); send fewer frames",
            color.0, color.1, depth.0, depth.1
        ))
    })
}

/// Refuse a scene over `max` pixels in all (see [`scene_pixels_error`]) from the headers of
/// its first frame, before any frame is decoded.
/// An image over `max_pixels` on its own is named as such first.
pub fn check_scene_pixels(files: &SceneFiles, max_pixels: u64, max: u64) -> Result<(), SceneError> {
    let Some(first) = files.frames.first() else {
        return Ok(());
    };
    let what = format!("frame {} colour", first.name);
    let color = image_size(&first.color, &what)?;
    check_pixels(color.0, color.1, max_pixels, &what)?;
    let depth = match &first.depth {
        Some(d) => {
            let what = format!("frame {} depth", first.name);
            let size = image_size(d, &what)?;
            check_pixels(size.0, size.1, max_pixels, &what)?;
            size
        }
        None => (0, 0),
    };
    match scene_pixels_error(files.frames.len() as u64, color, depth, max) {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// Most pixels one uploaded image may declare (colour, depth or instance mask) when the
/// caller names no limit: 50 Mpx holds an 8K frame. Anything larger is refused from its
/// header, before a byte of pixels is allocated.
pub const DEFAULT_MAX_IMAGE_PIXELS: u64 = 50_000_000;

/// Decoder limits for an image of at most `max_pixels` pixels (at most 8 bytes each).
pub fn decode_limits(max_pixels: u64) -> image::Limits {
    let mut limits = image::Limits::default();
    let side = u32::try_from(max_pixels).unwrap_or(u32::MAX);
    limits.max_image_width = Some(side);
    limits.max_image_height = Some(side);
    limits.max_alloc = Some(max_pixels.saturating_mul(8));
    limits
}

/// Refuse an image whose header declares more than `max_pixels` pixels.
pub fn check_pixels(w: u32, h: u32, max_pixels: u64, what: &str) -> Result<(), SceneError> {
    let n = u64::from(w) * u64::from(h);
    if n > max_pixels {
        return Err(SceneError::ImageTooLarge(format!(
            "{what}: the image declares {w}x{h} = {n} pixels, over the limit of {max_pixels} \
             (max_image_pixels)"
        )));
    }
    Ok(())
}

/// Decode a 16-bit depth PNG of at most `max_pixels` pixels. The size comes from the
/// header and is checked before anything is allocated.
pub fn read_depth_png(path: &Path, what: &str, max_pixels: u64) -> Result<DepthMap, SceneError> {
    let file = std::fs::File::open(path)
        .map_err(|e| SceneError::BadImage(format!("{what}: cannot open: {e}")))?;
    let dec = image::codecs::png::PngDecoder::with_limits(
        BufReader::new(file),
        decode_limits(max_pixels),
    )
    .map_err(|e| match e {
        image::ImageError::Limits(_) => SceneError::ImageTooLarge(format!(
            "{what}: the PNG is over the limit of {max_pixels} pixels (max_image_pixels): {e}"
        )),
        e => SceneError::BadImage(format!("{what}: not a readable PNG: {e}")),
    })?;
    if dec.color_type() != image::ColorType::L16 {
        return Err(SceneError::BadImage(format!(
            "{what}: depth must be a 16-bit single-channel PNG in millimetres, found {:?}",
            dec.color_type()
        )));
    }
    let (w, h) = dec.dimensions();
    check_pixels(w, h, max_pixels, what)?;
    let len = usize::try_from(dec.total_bytes())
        .map_err(|_| SceneError::ImageTooLarge(format!("{what}: the image is too large")))?;
    let mut buf = vec![0u8; len];
    dec.read_image(&mut buf)
        .map_err(|e| SceneError::BadImage(format!("{what}: truncated or corrupt PNG: {e}")))?;
    // The decoder yields native-endian u16 samples.
    let data = buf
        .chunks_exact(2)
        .map(|c| u16::from_ne_bytes([c[0], c[1]]))
        .collect();
    Ok(DepthMap::new(w, h, data))
}

fn check_jpeg(path: &Path, what: &str, max_pixels: u64) -> Result<(u32, u32), SceneError> {
    let bytes = std::fs::read(path)
        .map_err(|e| SceneError::BadImage(format!("{what}: cannot read: {e}")))?;
    // Decoders conceal truncation by filling grey; a complete JPEG ends with EOI (FF D9).
    let trimmed = bytes
        .iter()
        .rposition(|&b| b != 0)
        .map(|i| &bytes[..=i])
        .unwrap_or(&[]);
    if !bytes.starts_with(&[0xFF, 0xD8]) || !trimmed.ends_with(&[0xFF, 0xD9]) {
        return Err(SceneError::BadImage(format!(
            "{what}: not a complete JPEG (missing start or end marker; truncated?)"
        )));
    }
    let mut reader =
        image::ImageReader::with_format(std::io::Cursor::new(&bytes[..]), image::ImageFormat::Jpeg);
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| SceneError::BadImage(format!("{what}: unreadable JPEG header: {e}")))?;
    check_pixels(w, h, max_pixels, what)?;
    reader =
        image::ImageReader::with_format(std::io::Cursor::new(&bytes[..]), image::ImageFormat::Jpeg);
    reader.limits(decode_limits(max_pixels));
    let img = reader
        .decode()
        .map_err(|e| SceneError::BadImage(format!("{what}: unreadable or truncated JPEG: {e}")))?;
    Ok((img.width(), img.height()))
}

/// Does a depth image of size (w, h) fit the colour size or the depth intrinsics?
fn depth_size_ok(w: u32, h: u32, color: &Intrinsics, depth_k: Option<&Intrinsics>) -> bool {
    if (w, h) == (color.width, color.height) {
        return true;
    }
    if let Some(k) = depth_k {
        // The principal point of real depth intrinsics sits near the image centre.
        let near = |c: f64, n: u32| (2.0 * c - n as f64).abs() <= 0.2 * n as f64;
        return near(k.cx, w) && near(k.cy, h);
    }
    let a = w as f64 / h as f64;
    let b = color.width as f64 / color.height as f64;
    (a / b - 1.0).abs() <= 0.05
}

/// Validate every file of a scene directory and decode poses and depth (in parallel).
/// `work_root` is the unpack folder (its own name is not the scene's name).
/// Every image is refused from its header when it declares more than `max_pixels` pixels.
pub fn import(
    files: &SceneFiles,
    work_root: &Path,
    max_pixels: u64,
) -> Result<ImportedScene, SceneError> {
    let k = format::read_matrix(&files.intrinsic_color, "colour intrinsics")?;
    let first = &files.frames[0];
    let what = format!("frame {} colour", first.name);
    let (cw, ch) = image_size(&first.color, &what)?;
    check_pixels(cw, ch, max_pixels, &what)?;
    let color = Intrinsics::from_matrix(&k, cw, ch);
    if !(color.fx.is_finite() && color.fy.is_finite() && color.fx > 0.0 && color.fy > 0.0) {
        return Err(SceneError::Malformed(
            "colour intrinsics: focal lengths must be positive numbers".into(),
        ));
    }
    let depth_k_m = match &files.intrinsic_depth {
        Some(p) => Some(format::read_matrix(p, "depth intrinsics")?),
        None => None,
    };
    let axis_align = match &files.axis_align {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .map_err(|e| SceneError::Malformed(format!("axis alignment: cannot read: {e}")))?;
            let m = format::parse_axis_align(&text, "axis_align_matrix.txt")?;
            if !is_finite_matrix(&m) {
                return Err(SceneError::Malformed(
                    "axis_align_matrix.txt holds non-finite numbers".into(),
                ));
            }
            Some(m)
        }
        None => None,
    };

    let results: Vec<Result<_, SceneError>> = files
        .frames
        .par_iter()
        .enumerate()
        .map(|(idx, f)| {
            let size = check_jpeg(&f.color, &format!("frame {} colour", f.name), max_pixels)?;
            if size != (cw, ch) {
                return Err(SceneError::BadImage(format!(
                    "frame {} colour is {}x{} but frame {} is {cw}x{ch}; all colour frames must share one size",
                    f.name, size.0, size.1, first.name
                )));
            }
            let depth_path = f.depth.as_ref().ok_or_else(|| SceneError::Malformed(format!("frame {}: no depth", f.name)))?;
            let depth =
                read_depth_png(depth_path, &format!("frame {} depth", f.name), max_pixels)?;
            let pose_path = f.pose.as_ref().ok_or_else(|| SceneError::Malformed(format!("frame {}: no pose", f.name)))?;
            let pose = format::read_matrix(pose_path, &format!("frame {} pose", f.name))?;
            let usable = is_finite_matrix(&pose);
            let frame = ImportedFrame {
                idx,
                name: f.name.clone(),
                pose,
                usable,
                depth_blob: compress_depth(&depth),
                color_path: f.color.clone(),
                instance_path: f.instance.clone(),
            };
            Ok((frame, (depth.width, depth.height)))
        })
        .collect();

    let mut frames = Vec::with_capacity(results.len());
    let mut depth_size = None;
    for r in results {
        let (frame, size) = r?;
        match depth_size {
            None => depth_size = Some(size),
            Some(s) if s != size => {
                return Err(SceneError::DepthSize(format!(
                    "frame {} depth is {}x{} but earlier depth frames are {}x{}",
                    frame.name, size.0, size.1, s.0, s.1
                )))
            }
            _ => {}
        }
        frames.push(frame);
    }
    let (dw, dh) = depth_size.ok_or(SceneError::NoFrames)?;
    let depth_k = depth_k_m.map(|m| Intrinsics::from_matrix(&m, dw, dh));
    if !depth_size_ok(dw, dh, &color, depth_k.as_ref()) {
        return Err(SceneError::DepthSize(format!(
            "depth images are {dw}x{dh}, which matches neither the colour size {cw}x{ch} nor the depth intrinsics"
        )));
    }
    let name = files
        .root
        .file_name()
        .filter(|_| files.root != work_root)
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    Ok(ImportedScene {
        name,
        layout: files.layout,
        format: None,
        color,
        depth: depth_k,
        depth_size: (dw, dh),
        axis_align,
        frames,
        instance_labels: files.instance_labels.clone(),
    })
}
