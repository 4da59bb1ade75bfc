//! TUM RGB-D folders (the layout robot teams get from ROS bags).
//!
//! Conventions:
//! - `rgb.txt` and `depth.txt`: lines `timestamp path` (seconds; path relative to the
//!   folder), `#` comments. `groundtruth.txt`: lines `timestamp tx ty tz qx qy qz qw`, the
//!   camera-to-world pose of the optical centre (camera axes x right, y down, z forward),
//!   unit quaternion. Timestamps in each file must increase strictly.
//! - Each colour frame is paired with the depth image nearest in time when within
//!   0.02 s (colour frames without one are left out, as TUM's association tool does). Its
//!   pose is interpolated between the two ground-truth poses around its timestamp when
//!   both lie within `max_pose_gap` (default 0.1 s); otherwise the frame is kept but
//!   unusable.
//! - Depth PNGs are 16-bit, 5000 units per metre; colour and depth are registered at one
//!   size.
//! - Intrinsics: `intrinsics.txt` beside the lists (one line `fx fy cx cy`), else the
//!   query parameters `fx`, `fy`, `cx`, `cy`.
//! - Frames are named by their position among the paired frames.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use std::path::Path;

use super::{
    data_lines, finite, interpolate, k_matrix, nan_pose, read_depth_u16, read_text, safe_join,
    FormatOptions, SceneOut, TimedPose,
};
use crate::scene::SceneError;

/// Largest colour-depth time difference for a pair (s).
pub const PAIR_TOLERANCE: f64 = 0.02;
/// Depth units per metre.
pub const DEPTH_SCALE: f64 = 5000.0;

fn timestamps_increase(
    file: &str,
    line: usize,
    prev: Option<f64>,
    t: f64,
) -> Result<(), SceneError> {
    if let Some(p) = prev {
        if t <= p {
            return Err(SceneError::Malformed(format!(
                "{file} line {line}: timestamp {t} does not come after {p}; timestamps must increase"
            )));
        }
    }
    Ok(())
}

/// (timestamp, path) lines of `rgb.txt` / `depth.txt`.
fn read_list(dir: &Path, file: &str) -> Result<Vec<(f64, String)>, SceneError> {
    let text = read_text(&dir.join(file), file)?;
    let mut out: Vec<(f64, String)> = Vec::new();
    for (line, toks) in data_lines(&text) {
        if toks.len() < 2 {
            return Err(SceneError::Malformed(format!(
                "{file} line {line}: expected `timestamp path`"
            )));
        }
        let t = finite(toks[0], &format!("{file} line {line}"))?;
        timestamps_increase(file, line, out.last().map(|x| x.0), t)?;
        out.push((t, toks[1].to_string()));
    }
    Ok(out)
}

fn read_groundtruth(dir: &Path) -> Result<Vec<TimedPose>, SceneError> {
    let file = "groundtruth.txt";
    let text = read_text(&dir.join(file), file)?;
    let mut out: Vec<TimedPose> = Vec::new();
    for (line, toks) in data_lines(&text) {
        let what = format!("{file} line {line}");
        if toks.len() != 8 {
            return Err(SceneError::Malformed(format!(
                "{what}: expected `timestamp tx ty tz qx qy qz qw` (8 numbers), found {}",
                toks.len()
            )));
        }
        let v: Vec<f64> = toks
            .iter()
            .map(|t| finite(t, &what))
            .collect::<Result<_, _>>()?;
        timestamps_increase(file, line, out.last().map(|p| p.t), v[0])?;
        let q = Quaternion::new(v[7], v[4], v[5], v[6]);
        if (q.norm() - 1.0).abs() > 0.01 {
            return Err(SceneError::Malformed(format!(
                "{what}: the quaternion has norm {:.4}; it must be a unit quaternion",
                q.norm()
            )));
        }
        out.push(TimedPose {
            t: v[0],
            rot: UnitQuaternion::from_quaternion(q),
            pos: Vector3::new(v[1], v[2], v[3]),
        });
    }
    Ok(out)
}

fn intrinsics(dir: &Path, opts: &FormatOptions) -> Result<[f64; 4], SceneError> {
    let p = dir.join("intrinsics.txt");
    if p.is_file() {
        let text = read_text(&p, "intrinsics.txt")?;
        let toks: Vec<&str> = data_lines(&text).flat_map(|(_, t)| t).collect();
        if toks.len() != 4 {
            return Err(SceneError::Malformed(
                "intrinsics.txt: expected one line `fx fy cx cy`".into(),
            ));
        }
        let mut k = [0.0; 4];
        for (i, t) in toks.iter().enumerate() {
            k[i] = finite(t, "intrinsics.txt")?;
        }
        return Ok(k);
    }
    opts.intrinsics.ok_or_else(|| {
        SceneError::Malformed(
            "TUM folder without intrinsics: add intrinsics.txt (one line `fx fy cx cy`) beside rgb.txt, or pass ?fx=&fy=&cx=&cy="
                .into(),
        )
    })
}

/// Convert a TUM folder; returns the number of frames written.
pub fn convert(dir: &Path, out: &mut SceneOut, opts: &FormatOptions) -> Result<usize, SceneError> {
    let rgb = read_list(dir, "rgb.txt")?;
    let depth = read_list(dir, "depth.txt")?;
    let gt = read_groundtruth(dir)?;
    let [fx, fy, cx, cy] = intrinsics(dir, opts)?;
    if fx <= 0.0 || fy <= 0.0 {
        return Err(SceneError::Malformed(
            "TUM intrinsics: fx and fy must be positive".into(),
        ));
    }
    out.intrinsics(&k_matrix(fx, fy, cx, cy), None)?;
    let mut pos = 0u64;
    let mut written = 0;
    let mut size: Option<(u32, u32)> = None;
    for (t, rgb_path) in &rgb {
        let i = depth.partition_point(|d| d.0 < *t);
        let best = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter_map(|j| depth.get(j))
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()));
        let Some((_, depth_path)) = best.filter(|d| (d.0 - t).abs() <= PAIR_TOLERANCE) else {
            continue;
        };
        let keep = pos.is_multiple_of(opts.every);
        pos += 1;
        if !keep {
            continue;
        }
        let name = (opts.first_name + pos - 1).to_string();
        let color_file = safe_join(dir, rgb_path, "rgb.txt")?;
        if !color_file.is_file() {
            return Err(SceneError::Malformed(format!(
                "rgb.txt: {rgb_path} is missing"
            )));
        }
        let depth_file = safe_join(dir, depth_path, "depth.txt")?;
        let (dw, dh, raw) = read_depth_u16(
            &depth_file,
            &format!("depth.txt: {depth_path}"),
            opts.max_pixels,
        )?;
        let (cw, chh) = image::image_dimensions(&color_file).map_err(|e| {
            SceneError::BadImage(format!("rgb.txt: {rgb_path}: unreadable image: {e}"))
        })?;
        if (cw, chh) != (dw, dh) {
            return Err(SceneError::DepthSize(format!(
                "{depth_path} is {dw}x{dh} but {rgb_path} is {cw}x{chh}; TUM colour and depth must be registered at one size"
            )));
        }
        if let Some(s) = size.filter(|s| *s != (cw, chh)) {
            return Err(SceneError::BadImage(format!(
                "{rgb_path} is {cw}x{chh} but earlier frames are {}x{}",
                s.0, s.1
            )));
        }
        size = Some((cw, chh));
        out.color_image(&name, &color_file, &format!("rgb.txt: {rgb_path}"))?;
        let mm = raw
            .iter()
            .map(|&v| ((v as f64) * 1000.0 / DEPTH_SCALE).round() as u16)
            .collect();
        out.depth_mm(&name, dw, dh, mm)?;
        let pose = interpolate(&gt, *t, opts.max_pose_gap).unwrap_or_else(nan_pose);
        out.pose(&name, &pose)?;
        written += 1;
    }
    if written == 0 {
        return Err(SceneError::Malformed(format!(
            "rgb.txt: no colour frame has a depth image within {PAIR_TOLERANCE} s"
        )));
    }
    Ok(written)
}
