//! Capture formats people hold, turned into the internal scene directory (FORMATS §1a:
//! `color/ depth/ pose/ intrinsic/`) before the usual validation runs.
//!
//! One module per format; each states its conventions (camera axes, depth unit, pose
//! direction, frame names) in its module doc. Frames are named by their position in the
//! capture (`first_name`, `first_name + 1`, ...; a `.sens` keeps its frame numbers, so
//! `every = 10` gives 0, 10, 20, ...), so image ids follow capture order. An optional
//! `instance/` folder beside the capture (masks named by those frame names, plus
//! `labels.json`) is carried over for evaluation, as in §1a.

pub mod arkit;
pub mod nerfstudio;
pub mod sens;
pub mod tum;

use image::{ImageBuffer, Luma};
use nalgebra::{Matrix3, Matrix4, UnitQuaternion, Vector3};
use std::path::{Component, Path, PathBuf};

use super::SceneError;

/// The capture formats, as named by `?format=`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CaptureFormat {
    /// ScanNet's `.sens` binary.
    Sens,
    /// TUM RGB-D folder (`rgb.txt`, `depth.txt`, `groundtruth.txt`).
    Tum,
    /// nerfstudio `transforms.json` with depth.
    Nerfstudio,
    /// ARKitScenes raw (`lowres_wide`, `lowres_depth`, `lowres_wide.traj`).
    Arkitscenes,
}

impl CaptureFormat {
    pub fn as_str(&self) -> &'static str {
        match self {
            CaptureFormat::Sens => "sens",
            CaptureFormat::Tum => "tum",
            CaptureFormat::Nerfstudio => "nerfstudio",
            CaptureFormat::Arkitscenes => "arkitscenes",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "sens" => Some(CaptureFormat::Sens),
            "tum" => Some(CaptureFormat::Tum),
            "nerfstudio" => Some(CaptureFormat::Nerfstudio),
            "arkitscenes" => Some(CaptureFormat::Arkitscenes),
            _ => None,
        }
    }
}

/// What the uploader may set for a capture format (query parameters).
#[derive(Debug, Clone, Copy)]
pub struct FormatOptions {
    /// Keep every N-th frame (1 keeps all).
    pub every: u64,
    /// Longest time (s) between a frame and each of the two poses it is interpolated from.
    pub max_pose_gap: f64,
    /// `fx fy cx cy` for TUM when the folder has no `intrinsics.txt`.
    pub intrinsics: Option<[f64; 4]>,
    /// nerfstudio: metres per depth-image unit (nerfstudio's `depth_unit_scale_factor`).
    pub depth_unit: f64,
    /// Name (number) of the first converted frame; appends start after the last frame.
    pub first_name: u64,
    /// Cap on the bytes the conversion writes.
    pub max_bytes: u64,
    /// Cap on the pixels of one image (`max_image_pixels`).
    pub max_pixels: u64,
}

impl Default for FormatOptions {
    fn default() -> Self {
        Self {
            every: 1,
            max_pose_gap: 0.1,
            intrinsics: None,
            depth_unit: 0.001,
            first_name: 0,
            max_bytes: u64::MAX,
            max_pixels: 100_000_000,
        }
    }
}

/// Find a capture format in an unpacked archive: in the folder itself, its single
/// sub-folder, or (ARKitScenes' `<video>/<video>_frames/`) one level further.
pub fn detect(dir: &Path) -> Option<(CaptureFormat, PathBuf)> {
    let mut here = dir.to_path_buf();
    for _ in 0..3 {
        if let Some(f) = detect_in(&here) {
            return Some((f, here));
        }
        let subdirs: Vec<PathBuf> = std::fs::read_dir(&here)
            .ok()?
            .flatten()
            .map(|e| e.path())
            .filter(|p| {
                p.is_dir()
                    && !p
                        .file_name()
                        .is_some_and(|n| n.to_string_lossy().starts_with("__MACOSX"))
            })
            .collect();
        let files = std::fs::read_dir(&here)
            .ok()?
            .flatten()
            .filter(|e| e.path().is_file())
            .count();
        if subdirs.len() != 1 || files > 0 {
            return None;
        }
        here = subdirs[0].clone();
    }
    None
}

/// The folder itself, or its single sub-folder when it holds nothing else.
pub fn single_folder(dir: &Path) -> PathBuf {
    let entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| rd.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    if entries.len() == 1 && entries[0].is_dir() {
        return entries[0].clone();
    }
    dir.to_path_buf()
}

fn detect_in(dir: &Path) -> Option<CaptureFormat> {
    if dir.join("lowres_wide.traj").is_file() && dir.join("lowres_wide").is_dir() {
        return Some(CaptureFormat::Arkitscenes);
    }
    if dir.join("transforms.json").is_file() {
        return Some(CaptureFormat::Nerfstudio);
    }
    if dir.join("rgb.txt").is_file() && dir.join("depth.txt").is_file() {
        return Some(CaptureFormat::Tum);
    }
    if sens::find_sens(dir).ok().flatten().is_some() {
        return Some(CaptureFormat::Sens);
    }
    None
}

/// Convert the capture at `input` (a folder, or for `.sens` also the file itself) into a
/// scene directory at `out`. Returns the number of frames written.
pub fn convert(
    format: CaptureFormat,
    input: &Path,
    out: &Path,
    opts: &FormatOptions,
) -> Result<usize, SceneError> {
    if opts.every == 0 {
        return Err(SceneError::Malformed("every must be at least 1".into()));
    }
    let mut w = SceneOut::create(out, opts.max_bytes)?;
    let n = match format {
        CaptureFormat::Sens => {
            let file = if input.is_file() {
                input.to_path_buf()
            } else {
                sens::find_sens(input)?.ok_or_else(|| {
                    SceneError::Malformed("format sens: the archive holds no .sens file".into())
                })?
            };
            sens::convert(&file, &mut w, opts)?
        }
        CaptureFormat::Tum => tum::convert(input, &mut w, opts)?,
        CaptureFormat::Nerfstudio => nerfstudio::convert(input, &mut w, opts)?,
        CaptureFormat::Arkitscenes => arkit::convert(input, &mut w, opts)?,
    };
    if n == 0 {
        return Err(SceneError::NoFrames);
    }
    if input.is_dir() {
        w.carry_instances(input)?;
    }
    Ok(n)
}

/// Writes the internal scene directory, counting bytes against a cap.
pub struct SceneOut {
    root: PathBuf,
    written: u64,
    max_bytes: u64,
}

fn io_err(what: &str, e: impl std::fmt::Display) -> SceneError {
    SceneError::Io(format!("{what}: {e}"))
}

impl SceneOut {
    pub fn create(root: &Path, max_bytes: u64) -> Result<Self, SceneError> {
        for d in ["color", "depth", "pose", "intrinsic"] {
            std::fs::create_dir_all(root.join(d))
                .map_err(|e| io_err("cannot create scene folder", e))?;
        }
        Ok(Self {
            root: root.to_path_buf(),
            written: 0,
            max_bytes,
        })
    }

    fn write(&mut self, rel: &str, bytes: &[u8]) -> Result<(), SceneError> {
        self.written += bytes.len() as u64;
        if self.written > self.max_bytes {
            return Err(SceneError::TooLarge(format!(
                "the capture converts to more than {} bytes",
                self.max_bytes
            )));
        }
        std::fs::write(self.root.join(rel), bytes).map_err(|e| io_err("cannot write frame", e))
    }

    /// A JPEG as it is (validation checks it later).
    pub fn color_jpeg(&mut self, name: &str, jpeg: &[u8]) -> Result<(), SceneError> {
        self.write(&format!("color/{name}.jpg"), jpeg)
    }

    /// Any other colour image (PNG, ...): decoded and stored as a JPEG of quality 95.
    pub fn color_image(&mut self, name: &str, path: &Path, what: &str) -> Result<(), SceneError> {
        let bytes = std::fs::read(path)
            .map_err(|e| SceneError::Malformed(format!("{what}: cannot read: {e}")))?;
        if bytes.starts_with(&[0xFF, 0xD8]) {
            return self.color_jpeg(name, &bytes);
        }
        let img = image::load_from_memory(&bytes)
            .map_err(|e| SceneError::BadImage(format!("{what}: unreadable image: {e}")))?
            .to_rgb8();
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95)
            .encode_image(&img)
            .map_err(|e| SceneError::BadImage(format!("{what}: cannot re-encode: {e}")))?;
        self.color_jpeg(name, &out)
    }

    /// Depth in millimetres as a 16-bit PNG.
    pub fn depth_mm(&mut self, name: &str, w: u32, h: u32, mm: Vec<u16>) -> Result<(), SceneError> {
        let img: ImageBuffer<Luma<u16>, Vec<u16>> = ImageBuffer::from_raw(w, h, mm)
            .ok_or_else(|| SceneError::Malformed(format!("frame {name}: depth size mismatch")))?;
        let mut png = Vec::with_capacity((w * h) as usize);
        let enc = image::codecs::png::PngEncoder::new_with_quality(
            &mut png,
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Sub,
        );
        img.write_with_encoder(enc)
            .map_err(|e| io_err("cannot encode depth", e))?;
        self.write(&format!("depth/{name}.png"), &png)
    }

    /// Camera-to-world pose (non-finite values mark the frame unusable).
    pub fn pose(&mut self, name: &str, m: &Matrix4<f64>) -> Result<(), SceneError> {
        self.write(&format!("pose/{name}.txt"), matrix_text(m).as_bytes())
    }

    pub fn intrinsics(
        &mut self,
        color: &Matrix4<f64>,
        depth: Option<&Matrix4<f64>>,
    ) -> Result<(), SceneError> {
        self.write(
            "intrinsic/intrinsic_color.txt",
            matrix_text(color).as_bytes(),
        )?;
        if let Some(d) = depth {
            self.write("intrinsic/intrinsic_depth.txt", matrix_text(d).as_bytes())?;
        }
        Ok(())
    }

    /// Move an `instance/` folder beside the capture into the scene (evaluation only).
    fn carry_instances(&mut self, input: &Path) -> Result<(), SceneError> {
        let src = input.join("instance");
        if src.is_dir() {
            std::fs::rename(&src, self.root.join("instance"))
                .map_err(|e| io_err("cannot move instance masks", e))?;
        }
        Ok(())
    }
}

/// A 4x4 as text, full precision (round-trips through `parse_matrix`).
pub fn matrix_text(m: &Matrix4<f64>) -> String {
    let mut s = String::new();
    for r in 0..4 {
        let row: Vec<String> = (0..4).map(|c| format!("{}", m[(r, c)])).collect();
        s.push_str(&row.join(" "));
        s.push('\n');
    }
    s
}

/// K as a 4x4.
pub fn k_matrix(fx: f64, fy: f64, cx: f64, cy: f64) -> Matrix4<f64> {
    let mut k = Matrix4::identity();
    k[(0, 0)] = fx;
    k[(1, 1)] = fy;
    k[(0, 2)] = cx;
    k[(1, 2)] = cy;
    k
}

/// A pose that marks its frame unusable.
pub fn nan_pose() -> Matrix4<f64> {
    Matrix4::from_element(f64::NAN)
}

/// `rel` (a path written inside a capture file) joined to `base`, refused when it is
/// absolute or climbs out with `..`.
pub fn safe_join(base: &Path, rel: &str, what: &str) -> Result<PathBuf, SceneError> {
    let p = Path::new(rel);
    let mut depth: i64 = 0;
    for c in p.components() {
        match c {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir => {
                depth -= 1;
                if depth < 0 {
                    return Err(SceneError::Malformed(format!(
                        "{what}: path {rel:?} points outside the archive"
                    )));
                }
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err(SceneError::Malformed(format!(
                    "{what}: path {rel:?} is absolute; paths must be relative and stay inside the archive"
                )))
            }
        }
    }
    Ok(base.join(p))
}

/// A rigid camera-to-world pose at time `t`.
#[derive(Debug, Clone, Copy)]
pub struct TimedPose {
    pub t: f64,
    pub rot: UnitQuaternion<f64>,
    pub pos: Vector3<f64>,
}

impl TimedPose {
    pub fn matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        let r: Matrix3<f64> = *self.rot.to_rotation_matrix().matrix();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.pos);
        m
    }
}

/// The pose at `t`, interpolated (slerp / lerp) between the two samples around it when
/// both lie within `max_gap` seconds; None otherwise. `poses` are sorted by time.
pub fn interpolate(poses: &[TimedPose], t: f64, max_gap: f64) -> Option<Matrix4<f64>> {
    let i = poses.partition_point(|p| p.t <= t);
    // poses[i-1].t <= t < poses[i].t
    if i > 0 && (poses[i - 1].t - t).abs() < 1e-9 {
        return Some(poses[i - 1].matrix());
    }
    if i == 0 || i == poses.len() {
        return None;
    }
    let (a, b) = (&poses[i - 1], &poses[i]);
    if t - a.t > max_gap || b.t - t > max_gap {
        return None;
    }
    let s = (t - a.t) / (b.t - a.t);
    let rot = a.rot.try_slerp(&b.rot, s, 1e-9).unwrap_or(a.rot);
    let pos = a.pos + (b.pos - a.pos) * s;
    Some(TimedPose { t, rot, pos }.matrix())
}

/// Is the top-left 3x3 a rotation (orthonormal, determinant +1) within `tol`?
pub fn is_rotation(m: &Matrix4<f64>, tol: f64) -> bool {
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let e = r.transpose() * r - Matrix3::identity();
    e.iter().all(|x| x.abs() <= tol) && (r.determinant() - 1.0).abs() <= tol
}

/// Lines of a whitespace-separated text file: (1-based line number, tokens), skipping
/// blank lines and `#` comments.
pub fn data_lines(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.trim();
        (!l.is_empty() && !l.starts_with('#')).then(|| (i + 1, l.split_whitespace().collect()))
    })
}

/// Read a capture's text file, naming it in the error.
pub fn read_text(path: &Path, what: &str) -> Result<String, SceneError> {
    std::fs::read_to_string(path)
        .map_err(|e| SceneError::Malformed(format!("{what}: cannot read: {e}")))
}

/// Parse a finite number, naming the file, line and rule.
pub fn finite(tok: &str, what: &str) -> Result<f64, SceneError> {
    match tok.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(SceneError::Malformed(format!(
            "{what}: {tok:?} is not finite; every number must be finite"
        ))),
        Err(_) => Err(SceneError::Malformed(format!(
            "{what}: {tok:?} is not a number"
        ))),
    }
}

/// Decode a 16-bit depth PNG into raw values.
pub fn read_depth_u16(
    path: &Path,
    what: &str,
    max_pixels: u64,
) -> Result<(u32, u32, Vec<u16>), SceneError> {
    if !path.is_file() {
        return Err(SceneError::Malformed(format!(
            "{what}: the depth image is missing; every frame needs one"
        )));
    }
    let d = super::import::read_depth_png(path, what, max_pixels)?;
    Ok((d.width, d.height, d.data.into_vec()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn safe_join_refuses_escapes() {
        let b = Path::new("/x");
        assert!(safe_join(b, "a/../../etc", "t").is_err());
        assert!(safe_join(b, "/etc/passwd", "t").is_err());
        assert_eq!(
            safe_join(b, "./a/b.png", "t").unwrap(),
            Path::new("/x/a/b.png")
        );
        assert!(safe_join(b, "a/../b.png", "t").is_ok());
    }

    #[test]
    fn interpolates_between_close_samples_only() {
        let p = |t: f64, x: f64, yaw: f64| TimedPose {
            t,
            rot: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            pos: Vector3::new(x, 0.0, 0.0),
        };
        let poses = [p(0.0, 0.0, 0.0), p(0.1, 1.0, 0.2), p(1.0, 2.0, 0.2)];
        let m = interpolate(&poses, 0.05, 0.1).unwrap();
        assert!((m[(0, 3)] - 0.5).abs() < 1e-9);
        let yaw = m[(1, 0)].atan2(m[(0, 0)]);
        assert!((yaw - 0.1).abs() < 1e-9, "{yaw}");
        assert!(interpolate(&poses, 0.5, 0.1).is_none(), "gap too long");
        assert!(
            interpolate(&poses, -0.01, 0.1).is_none(),
            "before the first"
        );
        assert!(interpolate(&poses, 1.0, 0.1).is_some(), "exactly the last");
    }
}
