//! Part of stage 5 (ours): before an object whose pixels were ended on the room's box is
//! fused, the wall it hangs on is placed by the object's own colours when no frame
//! measured that wall (`geometry::wall_sweep`). Only the frames that see the object are
//! decoded, and only in this case.

use nalgebra::Point3;
use std::sync::Arc;

use super::grounding::Choice;
use super::VlmGrounder;
use crate::geometry::camera::transform_point;
use crate::geometry::{sweep_wall, wall_moved, RoomLayout, WallSweep};
use crate::jobs::{JobContext, JobFailure};

/// The sweep's finding, and the room with the wall moved when it moved.
pub struct Refined {
    pub sweep: Option<WallSweep>,
    pub room: Option<Arc<RoomLayout>>,
}

/// Sweep the wall under `anchor_points` (the chosen view's points, ended on `room`).
pub async fn refine(
    g: &VlmGrounder,
    ctx: &JobContext,
    choice: &Choice,
    anchor_points: &[Point3<f64>],
    room: &Arc<RoomLayout>,
) -> Result<Refined, JobFailure> {
    let none = Refined {
        sweep: None,
        room: None,
    };
    let params = g.params.geometry.clone();
    if !params.wall_sweep.enabled || anchor_points.is_empty() || room.faced.iter().all(|f| *f) {
        return Ok(none);
    }
    let scene = ctx.scene.clone();
    let others: Vec<usize> = scene
        .usable_frames()
        .map(|f| f.idx)
        .filter(|&i| i != choice.frame_idx)
        .collect();
    // Every frame that sees the middle of the object on the wall as placed (a sweep needs
    // the widest baselines, not the views most like the chosen one), at most
    // `max_views` of them spread over the scan.
    let n = anchor_points.len() as f64;
    let mid = anchor_points
        .iter()
        .fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords)
        / n;
    let mid = Point3::from(mid);
    let seeing: Vec<usize> = others
        .into_iter()
        .filter(|&i| {
            let c = &scene.frames[i].camera;
            c.cam_to_out().try_inverse().is_some_and(|inv| {
                let q = transform_point(&inv, &mid);
                c.color.project(&q).is_some_and(|(x, y, _)| {
                    x >= 0.0
                        && y >= 0.0
                        && x < f64::from(c.color.width)
                        && y < f64::from(c.color.height)
                })
            })
        })
        .collect();
    let most = params.wall_sweep.max_views.max(1);
    let idxs: Vec<usize> = if seeing.len() <= most {
        seeing
    } else {
        (0..most).map(|k| seeing[k * seeing.len() / most]).collect()
    };
    if idxs.len() < params.wall_sweep.min_views {
        return Ok(none);
    }
    let decoded = super::stitching::decode(&scene, &idxs).await?;
    let (image, bbox, anchor, rm) = (
        choice.image.clone(),
        choice.bbox,
        choice.frame_idx,
        room.clone(),
    );
    let sweep = tokio::task::spawn_blocking(move || {
        let others: Vec<_> = idxs
            .iter()
            .filter_map(|i| Some((&scene.frames[*i].camera, decoded.get(i)?.as_ref())))
            .collect();
        sweep_wall(
            &scene.frames[anchor].camera,
            &image,
            bbox,
            &rm,
            &others,
            &params.wall_sweep,
        )
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("wall sweep failed: {e}")))?;
    let room = sweep
        .filter(|s| s.shift > 0.0)
        .map(|s| Arc::new(wall_moved(room, s.side, s.shift)));
    Ok(Refined { sweep, room })
}
