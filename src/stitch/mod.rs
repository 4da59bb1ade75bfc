//! Dynamic stitching of frames into grid images, id labels, instance annotation,
//! and the visual-retrieval benchmark.

pub mod cli;
pub mod plan;

pub use plan::{grid_starts, plan, GridSpec, DEFAULT_LIMIT};
