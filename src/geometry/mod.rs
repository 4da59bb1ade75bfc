//! Pure geometry: cameras, masks, point clouds, boxes. No I/O, no HTTP, no models.
//!
//! Pipeline used by the agent (paper Sec. 3.4, with reprojection instead of image matching):
//! [`mask_points`] (erode + largest components + back-project) on the anchor view →
//! [`find_views`] over the other frames → the agent segments each returned view →
//! [`mask_points`] and [`cut_wall_leaks`] per view → [`chamfer_decisions`] → [`mask_votes`]
//! among the kept views → [`fuse_clouds`] (union, [`free_space_votes`], outlier removal,
//! AABB; [`fuse_views`] is the paper's version of these steps) → [`extend_to_support`]
//! (faces moved through unseen space onto the floor or wall the object rests on; ours) →
//! [`snap_planar_to_wall`] (a flat object's depth measured against its wall in one view; ours)
//! → [`round_back::round_back`] (a round body seen from one side given its hidden back; ours).
//! Before segmenting, [`fill_depth`] completes the chosen view's missing depth from the other
//! frames and, for flat objects no frame measured, from the room's box ([`estimate_room`]).
//! Pre-selection also offers the frames that see what a detection shows elsewhere
//! ([`reseen`]; ours).

pub mod bound;
pub mod boxes;
pub mod bridge;
pub mod camera;
pub mod cloud;
mod complement;
pub mod consensus;
pub mod depth_fill;
pub mod ensemble;
pub mod export;
pub mod floor_reach;
pub mod fusion;
pub mod hidden_base;
pub mod knn;
pub mod layout;
pub mod mask;
pub mod morph;
pub mod params;
pub mod partial;
pub mod planar;
pub mod projection;
pub mod reseen;
pub mod round_back;
pub mod sightline;
pub mod support;
mod support_layer;
pub(crate) use support_layer::percentile;
#[cfg(test)]
pub(crate) mod test_grid;
#[cfg(test)]
pub(crate) mod test_scene;
pub mod wall_colour;
pub mod wall_sweep;
pub mod walls;

pub use bound::{view_bound, within_bound, ViewBound};
pub use boxes::Aabb;
pub use camera::{DepthMap, FrameCamera, Intrinsics};
pub use cloud::{
    chamfer_distance, remove_statistical_outliers, statistical_outlier_indices, voxel_downsample,
};
pub use consensus::{free_space_votes, mask_votes, ConsensusParams, MaskView};
pub use depth_fill::{fill_depth, DepthFillParams, DepthFillStats};
pub use ensemble::{
    chamfer_decisions, find_views, find_views_with_room, fuse_clouds, fuse_views, mask_points,
    single_view_box, CandidateFrame, FusionResult, ViewCandidate, ViewDecision,
};
pub use knn::neighbour_mean_distances;
pub use layout::{estimate_room, LayoutParams, RoomLayout};
pub use mask::Mask;
pub use morph::{dilate_square, erode_square, keep_largest_components, postprocess_mask};
pub use params::GeometryParams;
pub use partial::{face_depth_ratio, hidden_sides, partial_view, PartialParams, PartialView};
pub use planar::{snap_planar_to_wall, PlanarSnap};
pub use projection::{
    backproject_mask, project_points, BackprojectOptions, Projected, ProjectionError,
};
pub use sightline::{sightings, Sighting};
pub use support::{
    context_points, extend_to_support, median_point, SupportExtension, SupportParams,
};
pub use wall_sweep::{sweep_wall, wall_moved, WallSweep, WallSweepParams};
pub use walls::{cut_room_walls, cut_wall_leaks, ColourLookup, WallCut};
