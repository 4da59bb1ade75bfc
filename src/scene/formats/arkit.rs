//! ARKitScenes raw captures (`<video>_frames/` as the dataset ships them).
//!
//! Conventions:
//! - `lowres_wide/<video>_<t>.png` colour and `lowres_depth/<video>_<t>.png` depth
//!   (16-bit, millimetres) share the stem; `<t>` is the frame time in seconds. Every colour
//!   frame needs its depth image.
//! - `lowres_wide_intrinsics/<video>_<t>.pincam`: one line `width height fx fy cx cy`;
//!   all frames must share them within 1 % (the first frame's are used).
//! - `lowres_wide.traj`: lines `t ax ay az tx ty tz`, an angle-axis rotation (radians) and
//!   a translation that map world to camera (camera axes x right, y down, z forward);
//!   its inverse is the camera-to-world pose. Times must increase strictly and every
//!   number be finite. A frame's pose is interpolated between the two samples around its
//!   time when both lie within `max_pose_gap`; otherwise the frame is kept but unusable.
//! - Frames are ordered by time and named by position.

use nalgebra::{Matrix4, Rotation3, UnitQuaternion, Vector3};
use std::path::{Path, PathBuf};

use super::{
    data_lines, finite, interpolate, k_matrix, nan_pose, read_depth_u16, read_text, FormatOptions,
    SceneOut, TimedPose,
};
use crate::scene::SceneError;

fn bad(msg: String) -> SceneError {
    SceneError::Malformed(msg)
}

fn read_traj(dir: &Path) -> Result<Vec<TimedPose>, SceneError> {
    let file = "lowres_wide.traj";
    let text = read_text(&dir.join(file), file)?;
    let mut out: Vec<TimedPose> = Vec::new();
    for (line, toks) in data_lines(&text) {
        let what = format!("{file} line {line}");
        if toks.len() != 7 {
            return Err(bad(format!(
                "{what}: expected `t ax ay az tx ty tz` (7 numbers), found {}",
                toks.len()
            )));
        }
        let v: Vec<f64> = toks
            .iter()
            .map(|t| finite(t, &what))
            .collect::<Result<_, _>>()?;
        if let Some(p) = out.last() {
            if v[0] <= p.t {
                return Err(bad(format!(
                    "{what}: time {} does not come after {}; times must increase",
                    v[0], p.t
                )));
            }
        }
        let r_wc = Rotation3::from_scaled_axis(Vector3::new(v[1], v[2], v[3]));
        let t_wc = Vector3::new(v[4], v[5], v[6]);
        // camera-to-world: R^T, -R^T t
        let r_cw = r_wc.inverse();
        out.push(TimedPose {
            t: v[0],
            rot: UnitQuaternion::from_rotation_matrix(&r_cw),
            pos: -(r_cw * t_wc),
        });
    }
    Ok(out)
}

fn read_pincam(path: &Path, what: &str) -> Result<[f64; 6], SceneError> {
    let text = read_text(path, what)?;
    let toks: Vec<&str> = data_lines(&text).flat_map(|(_, t)| t).collect();
    if toks.len() != 6 {
        return Err(bad(format!(
            "{what}: expected one line `width height fx fy cx cy`"
        )));
    }
    let mut k = [0.0; 6];
    for (i, t) in toks.iter().enumerate() {
        k[i] = finite(t, what)?;
    }
    Ok(k)
}

/// Frame time from a stem `<video>_<t>`.
fn frame_time(stem: &str) -> Option<f64> {
    stem.rsplit_once('_')
        .and_then(|(_, t)| t.parse::<f64>().ok())
        .filter(|t| t.is_finite())
}

/// Convert an ARKitScenes folder; returns the number of frames written.
pub fn convert(dir: &Path, out: &mut SceneOut, opts: &FormatOptions) -> Result<usize, SceneError> {
    let traj = read_traj(dir)?;
    let mut frames: Vec<(f64, String, PathBuf)> = Vec::new();
    let rd = std::fs::read_dir(dir.join("lowres_wide"))
        .map_err(|e| bad(format!("lowres_wide: cannot list: {e}")))?;
    for e in rd.flatten() {
        let p = e.path();
        if !p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png")) {
            continue;
        }
        let stem = p
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let t = frame_time(&stem).ok_or_else(|| {
            bad(format!(
                "lowres_wide/{stem}.png: the name must be <video>_<time in seconds>.png"
            ))
        })?;
        frames.push((t, stem, p));
    }
    frames.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut first_k: Option<[f64; 6]> = None;
    let mut written = 0;
    for (pos, (t, stem, color)) in frames.iter().enumerate() {
        let depth = dir.join("lowres_depth").join(format!("{stem}.png"));
        if !depth.is_file() {
            return Err(bad(format!(
                "lowres_depth/{stem}.png is missing; every lowres_wide frame needs its depth image"
            )));
        }
        if !(pos as u64).is_multiple_of(opts.every) {
            continue;
        }
        let kfile = format!("lowres_wide_intrinsics/{stem}.pincam");
        let k = read_pincam(&dir.join(&kfile), &kfile)?;
        match first_k {
            None => {
                if k[2] <= 0.0 || k[3] <= 0.0 {
                    return Err(bad(format!("{kfile}: fx and fy must be positive")));
                }
                out.intrinsics(&k_matrix(k[2], k[3], k[4], k[5]), None)?;
                first_k = Some(k);
            }
            Some(f) if f.iter().zip(&k).any(|(a, b)| (a - b).abs() > 0.01 * a.abs().max(1.0)) => {
                return Err(bad(format!(
                    "{kfile}: intrinsics {k:?} differ from the first frame's {f:?}; all frames must share one camera"
                )))
            }
            _ => {}
        }
        let name = (opts.first_name + pos as u64).to_string();
        let (dw, dh, mm) =
            read_depth_u16(&depth, &format!("lowres_depth/{stem}.png"), opts.max_pixels)?;
        out.color_image(&name, color, &format!("lowres_wide/{stem}.png"))?;
        out.depth_mm(&name, dw, dh, mm)?;
        let m: Matrix4<f64> = interpolate(&traj, *t, opts.max_pose_gap).unwrap_or_else(nan_pose);
        out.pose(&name, &m)?;
        written += 1;
    }
    Ok(written)
}
