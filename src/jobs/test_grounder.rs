//! A pipeline for tests of the service itself (`pipeline = "test:delay_ms=N"`): it waits,
//! writes a trace and answers the box of the scene's usable camera centres. It exercises
//! the queue, cancellation, traces and restarts without any model. A query containing
//! `[fail]` fails, one containing `[panic]` panics (tests of the workers' isolation). A job
//! that succeeds also leaves what the real pipeline exports (a mask of its first usable
//! view and the points of its box), so the export routes have something to serve.

use futures::future::BoxFuture;
use serde_json::json;
use std::time::Duration;

use super::{mask_artifact, Grounder, GroundingOutput, JobContext, JobFailure, OBJECT_PLY};
use crate::agent::exports::write_mask_png;
use crate::geometry::camera::transform_point;
use crate::geometry::export::{encode_ply, ColoredPoint};
use crate::geometry::{Aabb, Mask};

pub struct TestGrounder {
    pub delay: Duration,
}

impl TestGrounder {
    /// Parse "test" or "test:delay_ms=N".
    pub fn from_spec(spec: &str) -> anyhow::Result<Self> {
        let mut delay = Duration::from_millis(50);
        if let Some(rest) = spec.strip_prefix("test:") {
            for kv in rest.split(',') {
                match kv.split_once('=') {
                    Some(("delay_ms", v)) => {
                        delay = Duration::from_millis(
                            v.parse()
                                .map_err(|_| anyhow::anyhow!("bad delay_ms {v:?}"))?,
                        )
                    }
                    _ => anyhow::bail!("unknown test pipeline option {kv:?} (known: delay_ms=N)"),
                }
            }
        }
        Ok(Self { delay })
    }
}

impl Grounder for TestGrounder {
    fn ground(&self, ctx: JobContext) -> BoxFuture<'_, Result<GroundingOutput, JobFailure>> {
        Box::pin(async move {
            ctx.trace
                .step(
                    "start",
                    json!({"query": ctx.query, "frames": ctx.scene.frames.len()}),
                )
                .await;
            // An artifact, as the real pipeline writes (tests of retention and deletes).
            ctx.trace
                .artifact("test.txt", ctx.query.clone().into_bytes())
                .await?;
            if ctx.query.contains("[panic]") {
                // A test hook: a bug in a pipeline must end its job, not the worker.
                panic!("the test pipeline panics on queries containing [panic]");
            }
            if ctx.query.contains("[fail]") {
                return Err(JobFailure::new(
                    "no_target_found",
                    "the test pipeline fails queries containing [fail]",
                ));
            }
            tokio::select! {
                _ = tokio::time::sleep(self.delay) => {}
                _ = ctx.cancel.cancelled() => return Err(JobFailure::new("canceled", "canceled while running")),
            }
            let centres: Vec<_> = ctx
                .scene
                .usable_frames()
                .map(|f| transform_point(&f.camera.cam_to_out(), &nalgebra::Point3::origin()))
                .collect();
            let bbox = Aabb::from_points(&centres).ok_or_else(|| {
                JobFailure::new("no_usable_frames", "the scene has no usable frame")
            })?;
            let first = ctx.scene.usable_frames().next().map(|f| f.image_id());
            if let Some(id) = &first {
                ctx.trace.artifact(&mask_artifact(id), tiny_mask()).await?;
            }
            let points: Vec<ColoredPoint> = centres.iter().map(|p| (*p, [200, 80, 40])).collect();
            ctx.trace
                .artifact(
                    OBJECT_PLY,
                    encode_ply(&points, &["test pipeline: camera centres".into()]),
                )
                .await?;
            ctx.trace
                .step("done", json!({"cameras": centres.len(), "mask_of": first}))
                .await;
            Ok(GroundingOutput {
                bbox,
                extra: Default::default(),
            })
        })
    }
}

/// An 8x6 mask (255 inside a 4x2 block) as PNG bytes, written as the real pipeline writes
/// its masks.
fn tiny_mask() -> Vec<u8> {
    let mut out = Vec::new();
    // Writing a mask of the right size into a vector cannot fail.
    let _ = write_mask_png(&mut out, &Mask::from_box(8, 6, [2.0, 2.0, 6.0, 4.0]));
    out
}
