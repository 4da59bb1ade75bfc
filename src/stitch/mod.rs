//! Dynamic stitching of frames into grid images, id labels, instance annotation,
//! and the visual-retrieval benchmark.
//!
//! Entry points for the agent: [`plan`], [`render_grid`], [`encode_jpeg`], [`stitch_all`],
//! [`annotate_instances`], [`resize_to_limit`]. The visual-retrieval benchmark lives in
//! [`retrieval`].

pub mod annotate;
pub mod cli;
pub mod decode;
pub mod label;
pub mod plan;
pub mod render;
pub mod retrieval;
pub mod tiles;

pub use annotate::{annotate_instances, AnnotateOptions};
pub use decode::{
    decode_image, load_frames, make_preview, tile_scales, use_previews, PREVIEW_SCALE,
};
pub use plan::{grid_starts, plan, GridSpec, DEFAULT_LIMIT};
pub use render::{
    encode_jpeg, jpeg_data_url, render_grid, render_grid_with_placements, resize_to_limit,
    resize_to_limit_with, stitch_all, stitch_with_specs, ResizeFilter, StitchOptions,
    StitchedImage, TilePlacement,
};
pub use tiles::{stitch_files, StitchStats, TileCache, DEFAULT_TILE_CACHE_MB};
