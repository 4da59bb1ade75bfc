//! The scene as the pipeline sees it: cameras, depth maps (decoded once), colour paths.

use crate::geometry::{DepthMap, FrameCamera, Intrinsics};
use nalgebra::Matrix4;
use std::path::PathBuf;
use std::sync::Arc;

/// One frame of a stored scene.
#[derive(Debug, Clone)]
pub struct FrameData {
    /// Position in numeric frame order: the five-digit image id shown to the VLM.
    pub idx: usize,
    pub name: String,
    pub usable: bool,
    pub camera: FrameCamera,
    pub depth: Arc<DepthMap>,
    pub color_path: PathBuf,
    /// Instance-id mask file (evaluation only), if the scene has one.
    pub instance_path: Option<PathBuf>,
}

impl FrameData {
    /// The five-digit image id (00000, 00001, ...).
    pub fn image_id(&self) -> String {
        format!("{:05}", self.idx)
    }

    /// Where indexing stores the frame's half-size preview (beside the colour image), which
    /// stitching reads instead of the full frame when a grid shows it at half size or less.
    pub fn preview_path(&self) -> PathBuf {
        self.color_path.with_extension("preview.jpg")
    }
}

/// A whole stored scene.
#[derive(Debug, Clone)]
pub struct SceneData {
    pub id: String,
    pub color: Intrinsics,
    pub depth: Option<Intrinsics>,
    pub axis_align: Option<Matrix4<f64>>,
    pub frames: Vec<FrameData>,
    /// Instance labels (evaluation only): instance id -> label.
    pub instance_labels: Option<std::collections::BTreeMap<u32, String>>,
    /// The room's layout, estimated once for all the jobs holding this scene
    /// ([`SceneData::room_layout`]).
    pub room: super::RoomMemo,
}

impl SceneData {
    pub fn usable_frames(&self) -> impl Iterator<Item = &FrameData> {
        self.frames.iter().filter(|f| f.usable)
    }
}

/// Encode a depth map for storage (lz4 over little-endian u16).
pub fn compress_depth(d: &DepthMap) -> Vec<u8> {
    let mut raw = Vec::with_capacity(d.data.len() * 2);
    for v in d.data.iter() {
        raw.extend_from_slice(&v.to_le_bytes());
    }
    lz4_flex::compress_prepend_size(&raw)
}

/// Decode a stored depth map; `None` when the blob does not hold width*height values.
pub fn decompress_depth(blob: &[u8], width: u32, height: u32) -> Option<DepthMap> {
    let raw = lz4_flex::decompress_size_prepended(blob).ok()?;
    if raw.len() != width as usize * height as usize * 2 {
        return None;
    }
    let data = raw
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    Some(DepthMap::new(width, height, data))
}

/// Pose matrix to storage bytes (16 little-endian f64, row-major).
pub fn pose_to_blob(m: &Matrix4<f64>) -> Vec<u8> {
    let mut out = Vec::with_capacity(128);
    for r in 0..4 {
        for c in 0..4 {
            out.extend_from_slice(&m[(r, c)].to_le_bytes());
        }
    }
    out
}

pub fn pose_from_blob(b: &[u8]) -> Option<Matrix4<f64>> {
    if b.len() != 128 {
        return None;
    }
    let vals: Vec<f64> = b
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
        .collect();
    Some(Matrix4::from_row_slice(&vals))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_and_pose_round_trip() {
        let d = DepthMap::new(3, 2, vec![0, 1, 65535, 1000, 2000, 3]);
        let blob = compress_depth(&d);
        assert_eq!(decompress_depth(&blob, 3, 2).unwrap(), d);
        assert!(decompress_depth(&blob, 2, 2).is_none());
        let mut m = Matrix4::identity();
        m[(0, 3)] = 1.5;
        m[(2, 1)] = f64::INFINITY;
        let back = pose_from_blob(&pose_to_blob(&m)).unwrap();
        assert_eq!(back[(0, 3)], 1.5);
        assert!(back[(2, 1)].is_infinite());
    }
}
