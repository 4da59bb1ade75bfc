//! nerfstudio `transforms.json` captures (Record3D, Polycam and ARKit exports).
//!
//! Conventions:
//! - `frames[*].transform_matrix` is a camera-to-world 4x4 (or 3x4) in OpenGL camera axes
//!   (x right, y up, z backward); it is turned into our axes (x right, y down, z forward)
//!   by negating its y and z columns. Its rotation part must be orthonormal.
//! - Intrinsics `fl_x`, `fl_y`, `cx`, `cy` (pixels) at the top level or per frame; all
//!   frames must share them (within 1 %). Distortion coefficients are ignored (images are
//!   taken as undistorted).
//! - Every frame needs `depth_file_path`: a 16-bit PNG whose unit is `depth_unit` metres
//!   (nerfstudio's `depth_unit_scale_factor`, default 0.001, i.e. millimetres).
//! - `file_path` and `depth_file_path` are relative to `transforms.json` and must stay
//!   inside the archive.
//! - Frames are ordered by `file_path` (as nerfstudio's loader does) and named by position.

use nalgebra::Matrix4;
use serde_json::Value;
use std::path::Path;

use super::{is_rotation, k_matrix, read_depth_u16, read_text, safe_join, FormatOptions, SceneOut};
use crate::scene::SceneError;

const FILE: &str = "transforms.json";

fn bad(msg: String) -> SceneError {
    SceneError::Malformed(format!("{FILE}: {msg}"))
}

fn num(v: Option<&Value>) -> Option<f64> {
    v.and_then(Value::as_f64).filter(|x| x.is_finite())
}

fn intrinsics(top: &Value, frame: &Value, i: usize) -> Result<[f64; 4], SceneError> {
    let mut k = [0.0; 4];
    for (j, key) in ["fl_x", "fl_y", "cx", "cy"].iter().enumerate() {
        k[j] = num(frame.get(key))
            .or_else(|| num(top.get(key)))
            .ok_or_else(|| {
                bad(format!(
                    "frames[{i}]: no {key} (per frame or at the top level); intrinsics are required"
                ))
            })?;
    }
    if k[0] <= 0.0 || k[1] <= 0.0 {
        return Err(bad(format!("frames[{i}]: fl_x and fl_y must be positive")));
    }
    Ok(k)
}

fn pose(frame: &Value, i: usize) -> Result<Matrix4<f64>, SceneError> {
    let rows = frame
        .get("transform_matrix")
        .and_then(Value::as_array)
        .ok_or_else(|| bad(format!("frames[{i}]: no transform_matrix")))?;
    if rows.len() != 4 && rows.len() != 3 {
        return Err(bad(format!(
            "frames[{i}].transform_matrix: expected 4 rows of 4 numbers"
        )));
    }
    let mut m = Matrix4::identity();
    for (r, row) in rows.iter().enumerate() {
        let row = row.as_array().filter(|a| a.len() == 4).ok_or_else(|| {
            bad(format!(
                "frames[{i}].transform_matrix: expected 4 rows of 4 numbers"
            ))
        })?;
        for (c, x) in row.iter().enumerate() {
            m[(r, c)] = num(Some(x)).ok_or_else(|| {
                bad(format!(
                    "frames[{i}].transform_matrix holds {x}; every entry must be a finite number"
                ))
            })?;
        }
    }
    if !is_rotation(&m, 1e-3) {
        return Err(bad(format!(
            "frames[{i}].transform_matrix: its rotation part is not orthonormal; camera-to-world poses must be rigid"
        )));
    }
    // OpenGL camera axes to ours: negate the y and z columns.
    for r in 0..4 {
        m[(r, 1)] = -m[(r, 1)];
        m[(r, 2)] = -m[(r, 2)];
    }
    Ok(m)
}

/// Convert a nerfstudio folder; returns the number of frames written.
pub fn convert(dir: &Path, out: &mut SceneOut, opts: &FormatOptions) -> Result<usize, SceneError> {
    let text = read_text(&dir.join(FILE), FILE)?;
    let top: Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("not valid JSON: {e}")))?;
    let frames = top
        .get("frames")
        .and_then(Value::as_array)
        .ok_or_else(|| bad("no frames array".into()))?;
    if !(opts.depth_unit.is_finite() && opts.depth_unit > 0.0) {
        return Err(SceneError::Malformed(
            "depth_unit must be a positive number".into(),
        ));
    }
    let mut order: Vec<(usize, &str)> = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let p = f
            .get("file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| bad(format!("frames[{i}]: no file_path")))?;
        order.push((i, p));
    }
    order.sort_by(|a, b| a.1.cmp(b.1));
    let mut shared: Option<[f64; 4]> = None;
    let mut written = 0;
    for (pos, (i, file_path)) in order.into_iter().enumerate() {
        let f = &frames[i];
        let k = intrinsics(&top, f, i)?;
        match shared {
            None => {
                out.intrinsics(&k_matrix(k[0], k[1], k[2], k[3]), None)?;
                shared = Some(k);
            }
            Some(s) if s.iter().zip(&k).any(|(a, b)| (a - b).abs() > 0.01 * a.abs().max(1.0)) => {
                return Err(bad(format!(
                    "frames[{i}]: intrinsics {k:?} differ from the first frame's {s:?}; all frames must share one camera"
                )))
            }
            _ => {}
        }
        let what = format!("{FILE} frames[{i}]");
        let color = safe_join(dir, file_path, &format!("{what}.file_path"))?;
        let depth_rel = f
            .get("depth_file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| {
                bad(format!(
                    "frames[{i}]: no depth_file_path; every frame needs depth"
                ))
            })?;
        let depth = safe_join(dir, depth_rel, &format!("{what}.depth_file_path"))?;
        let m = pose(f, i)?;
        if !(pos as u64).is_multiple_of(opts.every) {
            continue;
        }
        if !color.is_file() {
            return Err(bad(format!(
                "frames[{i}].file_path {file_path:?} is missing"
            )));
        }
        let name = (opts.first_name + pos as u64).to_string();
        let (dw, dh, raw) =
            read_depth_u16(&depth, &format!("{what}: {depth_rel}"), opts.max_pixels)?;
        let scale = opts.depth_unit * 1000.0;
        let mm = raw
            .iter()
            .map(|&v| (v as f64 * scale).round().min(65535.0) as u16)
            .collect();
        out.color_image(&name, &color, &format!("{what}: {file_path}"))?;
        out.depth_mm(&name, dw, dh, mm)?;
        out.pose(&name, &m)?;
        written += 1;
    }
    Ok(written)
}
