//! The box itself as the mask (ablation baseline).

use anyhow::Result;

use super::{SegmentInput, Segmenter};
use crate::geometry::mask::Mask;

/// Returns the filled box at colour resolution.
#[derive(Debug, Clone, Copy, Default)]
pub struct BoxSegmenter;

impl Segmenter for BoxSegmenter {
    fn name(&self) -> String {
        "box".into()
    }

    fn segment(&self, input: &SegmentInput<'_>, bbox: [f32; 4]) -> Result<Mask> {
        Ok(Mask::from_box(
            input.color.width(),
            input.color.height(),
            bbox,
        ))
    }
}
