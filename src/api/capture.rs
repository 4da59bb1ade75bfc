//! Query parameters that name and tune a capture format on upload and append.

use axum::http::StatusCode;
use serde::Deserialize;

use super::ApiError;
use crate::jobs::ingest::Capture;
use crate::scene::formats::{CaptureFormat, FormatOptions};

/// Capture-format parameters (all optional; the format is detected when not named).
#[derive(Debug, Default, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct CaptureParams {
    /// `sens` (ScanNet .sens; a raw body with `Content-Type: application/octet-stream`
    /// or inside an archive), `tum` (TUM RGB-D folder), `nerfstudio` (`transforms.json`
    /// with depth) or `arkitscenes` (ARKitScenes raw `lowres_*`). Omitted: detected.
    #[param(value_type = Option<FormatName>, inline)]
    pub format: Option<String>,
    /// Keep every N-th frame of a capture (default 1: all).
    #[param(value_type = Option<u64>, minimum = 1)]
    pub every: Option<String>,
    /// Longest time in seconds between a frame and each pose it is interpolated from
    /// (TUM, ARKitScenes; default 0.1). Frames further away are kept but unusable.
    #[param(value_type = Option<f64>, exclusive_minimum = 0)]
    pub max_pose_gap: Option<String>,
    /// TUM intrinsics when the folder has no `intrinsics.txt` (pixels; `fx`, `fy`, `cx`
    /// and `cy` together or none of them).
    #[param(value_type = Option<f64>, exclusive_minimum = 0)]
    pub fx: Option<String>,
    #[param(value_type = Option<f64>, exclusive_minimum = 0)]
    pub fy: Option<String>,
    #[param(value_type = Option<f64>)]
    pub cx: Option<String>,
    #[param(value_type = Option<f64>)]
    pub cy: Option<String>,
    /// nerfstudio: metres per depth-image unit (default 0.001).
    #[param(value_type = Option<f64>, exclusive_minimum = 0)]
    pub depth_unit: Option<String>,
}

/// The capture formats `format` names (the schema of that parameter).
#[derive(utoipa::ToSchema)]
#[schema(rename_all = "lowercase")]
#[allow(dead_code)] // Only documents the parameter, which is parsed by `CaptureFormat::parse`.
enum FormatName {
    Sens,
    Tum,
    Nerfstudio,
    Arkitscenes,
}

fn invalid(detail: String) -> ApiError {
    ApiError::new(StatusCode::BAD_REQUEST, "invalid_parameter", detail)
}

fn positive(name: &str, v: &Option<String>) -> Result<Option<f64>, ApiError> {
    match v {
        None => Ok(None),
        Some(s) => match s.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 => Ok(Some(x)),
            _ => Err(invalid(format!("{name}={s:?}: expected a positive number"))),
        },
    }
}

impl CaptureParams {
    pub fn to_capture(&self) -> Result<Capture, ApiError> {
        let format = match &self.format {
            None => None,
            Some(f) => Some(CaptureFormat::parse(f).ok_or_else(|| {
                invalid(format!(
                    "format={f:?}: expected sens, tum, nerfstudio or arkitscenes"
                ))
            })?),
        };
        let mut opts = FormatOptions::default();
        if let Some(e) = &self.every {
            opts.every = e
                .parse::<u64>()
                .ok()
                .filter(|&n| n >= 1)
                .ok_or_else(|| invalid(format!("every={e:?}: expected a whole number >= 1")))?;
        }
        if let Some(g) = positive("max_pose_gap", &self.max_pose_gap)? {
            opts.max_pose_gap = g;
        }
        if let Some(d) = positive("depth_unit", &self.depth_unit)? {
            opts.depth_unit = d;
        }
        let k = [
            positive("fx", &self.fx)?,
            positive("fy", &self.fy)?,
            match &self.cx {
                None => None,
                Some(s) => Some(
                    s.parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| invalid(format!("cx={s:?}: expected a number")))?,
                ),
            },
            match &self.cy {
                None => None,
                Some(s) => Some(
                    s.parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| invalid(format!("cy={s:?}: expected a number")))?,
                ),
            },
        ];
        opts.intrinsics = match k {
            [Some(fx), Some(fy), Some(cx), Some(cy)] => Some([fx, fy, cx, cy]),
            [None, None, None, None] => None,
            _ => return Err(invalid("fx, fy, cx and cy must be given together".into())),
        };
        Ok(Capture { format, opts })
    }
}
