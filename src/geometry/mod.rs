//! Pure geometry: cameras, masks, point clouds, boxes. No I/O, no HTTP, no models.

pub mod boxes;
pub mod camera;
pub mod mask;

pub use boxes::Aabb;
pub use camera::{DepthMap, FrameCamera, Intrinsics};
pub use mask::Mask;
