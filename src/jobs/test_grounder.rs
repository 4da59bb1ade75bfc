//! A pipeline for tests of the service itself (`pipeline = "test:delay_ms=N"`): it waits,
//! writes a trace and answers the box of the scene's usable camera centres. It exercises
//! the queue, cancellation, traces and restarts without any model. A query containing
//! `[fail]` fails, one containing `[panic]` panics (tests of the workers' isolation).

use futures::future::BoxFuture;
use serde_json::json;
use std::time::Duration;

use super::{Grounder, GroundingOutput, JobContext, JobFailure};
use crate::geometry::camera::transform_point;
use crate::geometry::Aabb;

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
            ctx.trace
                .step("done", json!({"cameras": centres.len()}))
                .await;
            Ok(GroundingOutput {
                bbox,
                extra: Default::default(),
            })
        })
    }
}
