//! The VLM-Grounder pipeline (paper Sec. 3), one file per stage:
//! query analysis → view pre-selection → dynamic stitching → grounding with feedback
//! (→ instance selection) → segmentation + multi-view ensemble projection.
//! Every stage appends a step `{step, inputs, outputs, ms}` to the job's trace.

mod bottom;
mod candidate_cache;
pub mod conversation;
pub mod ensemble_boxes;
pub mod exports;
pub mod grounding;
pub mod instance;
pub mod marks;
pub mod preselect;
pub mod projection;
pub mod proposal;
pub mod query_analysis;
pub mod stitching;
pub mod view_box;
mod view_clouds;
pub mod vlm_box;
pub mod vlm_log;
pub mod wall_sweep;

use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::geometry::GeometryParams;
use crate::jobs::{Grounder, GroundingOutput, JobContext, JobFailure};
use crate::stitch::annotate::AnnotateOptions;
use crate::stitch::render::StitchOptions;
use crate::vision::candidates::CandidateParams;
use crate::vision::{Detector, Segmenter};
use crate::vlm::boxes::BoxFormat;
use crate::vlm::json::QueryAnalysis;
use crate::vlm::prompts::Prompts;
use crate::vlm::{CallBudget, VlmClient, VlmError};

/// Tunables of the method (defaults: REFERENCE-PARAMS.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AgentParams {
    /// Soft image limit L of dynamic stitching.
    pub image_limit: usize,
    /// Feedback rounds M before a job fails.
    pub max_retries: usize,
    /// Score a cached detection needs to pre-select its frame.
    pub preselect_score: f32,
    /// Also offer the frames that see, by depth and pose, an object the detector found in
    /// another frame (`geometry::reseen`; the paper offers only frames with a detection).
    pub preselect_reseen: bool,
    /// Frames shown when pre-selection finds nothing (evenly sampled usable frames).
    pub fallback_frames: usize,
    /// Share of valid depth pixels a frame's detection of the target class needs for the
    /// frame to be offered (a box with no depth cannot become a 3D box).
    pub min_depth_fraction: f64,
    /// Share of valid depth pixels that makes a detection well measured: when some frames
    /// have a well-measured detection of the target class, only they are offered (a
    /// window mostly beyond the sensor's range gives a poor box). The default equals
    /// `min_depth_fraction`, which turns this off: with 0.6 the realistic benchmark gained
    /// 4 points of Acc@0.25 but lost 3 of Nr3D accuracy, because when several instances
    /// exist, the one seen only from afar is no longer offered at all.
    pub good_depth_fraction: f64,
    /// Frames a job may leave out because the box chosen in them measured nothing of the
    /// object in 3D (no mask pixel with depth, or no point left after outlier removal):
    /// the VLM then chooses again among the other offered frames. 0: the job fails there.
    pub max_left_out: usize,
    /// VLM calls a job may make.
    pub max_vlm_calls: u32,
    /// Wall time a job may take, seconds.
    pub max_job_seconds: u64,
    /// How a VLM asked for a box (`detector = "vlm"`) writes it: "pixels",
    /// "norm1000" ([x1, y1, x2, y2] in 0–1000) or "yxyx1000" ([ymin, xmin, ymax, xmax]).
    pub box_format: BoxFormat,
    pub stitch: StitchOptions,
    pub annotate: AnnotateOptions,
    pub geometry: GeometryParams,
    /// Class-agnostic candidates from the scan (set-of-marks when no detector can help).
    pub candidates: CandidateParams,
}

impl Default for AgentParams {
    fn default() -> Self {
        Self {
            image_limit: 6,
            max_retries: 3,
            preselect_score: 0.2,
            preselect_reseen: true,
            fallback_frames: 48,
            min_depth_fraction: 0.2,
            good_depth_fraction: 0.2,
            max_left_out: 2,
            max_vlm_calls: 16,
            max_job_seconds: 600,
            box_format: BoxFormat::default(),
            stitch: StitchOptions::default(),
            annotate: AnnotateOptions::default(),
            geometry: GeometryParams::default(),
            candidates: CandidateParams::default(),
        }
    }
}

/// The pipeline the workers run.
pub struct VlmGrounder {
    pub client: VlmClient,
    pub prompts: Prompts,
    pub detector: Arc<dyn Detector>,
    /// Name under which the scene indexer cached this detector's detections.
    pub detector_key: String,
    pub segmenter: Arc<dyn Segmenter>,
    pub params: AgentParams,
    /// The detector is "vlm": the VLM is asked for the target's box in the chosen image.
    pub vlm_boxes: bool,
    analysis_cache: Mutex<HashMap<String, QueryAnalysis>>,
    /// Slots for the compute stages (layout, pre-selection, stitching; projection), one per
    /// core: jobs beyond that wait between stages instead of all holding their decoded
    /// frames and point clouds at once while sharing the same cores (docs/memory.md).
    compute: tokio::sync::Semaphore,
    /// Resized grid tiles kept between queries (`tile_cache_mb`).
    pub tiles: Arc<crate::stitch::TileCache>,
}

impl VlmGrounder {
    pub fn new(
        client: VlmClient,
        prompts: Prompts,
        detector: Arc<dyn Detector>,
        detector_key: String,
        segmenter: Arc<dyn Segmenter>,
        params: AgentParams,
    ) -> Self {
        Self {
            client,
            prompts,
            vlm_boxes: detector.name() == "vlm",
            detector,
            detector_key,
            segmenter,
            params,
            analysis_cache: Mutex::new(HashMap::new()),
            compute: tokio::sync::Semaphore::new(
                std::thread::available_parallelism().map_or(2, |n| n.get()),
            ),
            tiles: Arc::new(crate::stitch::TileCache::default()),
        }
    }

    /// Keep at most `bytes` of resized grid tiles between queries (0: none).
    pub fn with_tile_cache(mut self, bytes: u64) -> Self {
        self.tiles = Arc::new(crate::stitch::TileCache::new(bytes));
        self
    }

    /// Wait for a compute slot (see `compute`); a cancel while waiting ends the job.
    pub(crate) async fn compute_slot(
        &self,
        ctx: &JobContext,
    ) -> Result<tokio::sync::SemaphorePermit<'_>, JobFailure> {
        tokio::select! {
            _ = ctx.cancel.cancelled() => Err(JobFailure::new("canceled", "canceled while waiting for a compute slot")),
            p = self.compute.acquire() => p.map_err(|_| JobFailure::new("internal", "the compute slots were closed")),
        }
    }
}

/// Checked between the pipeline's stages: a canceled job stops before `next` reads its
/// scene again (its scene may be deleted once the cancel is answered).
pub(crate) fn still_wanted(
    cancel: &tokio_util::sync::CancellationToken,
    next: &str,
) -> Result<(), JobFailure> {
    if cancel.is_cancelled() {
        return Err(JobFailure::new(
            "canceled",
            format!("canceled before {next}"),
        ));
    }
    Ok(())
}

/// Milliseconds since `t`.
pub(crate) fn ms(t: Instant) -> f64 {
    (t.elapsed().as_secs_f64() * 1e6).round() / 1e3
}

/// Append a step with inputs, outputs and its duration.
pub(crate) async fn step(
    ctx: &JobContext,
    name: &str,
    inputs: Value,
    outputs: Value,
    started: Instant,
) {
    ctx.trace
        .step(
            name,
            json!({"inputs": inputs, "outputs": outputs, "ms": ms(started)}),
        )
        .await;
}

/// Map a VLM client error to the job's failure (codes: [`VlmError::code`]).
pub(crate) fn vlm_failure(e: VlmError) -> JobFailure {
    let detail = match &e {
        VlmError::Cancelled => "canceled while waiting for the VLM".to_string(),
        VlmError::CallBudgetExhausted { max_calls } => {
            format!("the job used its budget of {max_calls} VLM calls")
        }
        VlmError::DeadlineExceeded => "the job ran out of wall time".to_string(),
        other => other.to_string(),
    };
    JobFailure::new(e.code(), detail)
}

impl Grounder for VlmGrounder {
    fn ground(&self, ctx: JobContext) -> BoxFuture<'_, Result<GroundingOutput, JobFailure>> {
        Box::pin(async move { self.run(ctx).await })
    }
}

impl VlmGrounder {
    async fn run(&self, ctx: JobContext) -> Result<GroundingOutput, JobFailure> {
        let started = Instant::now();
        let budget = CallBudget::with_cancel(
            self.params.max_vlm_calls,
            Some(Duration::from_secs(self.params.max_job_seconds)),
            ctx.cancel.clone(),
        );
        let log = vlm_log::VlmLog::default();
        match self.stages(&ctx, &budget, &log, started).await {
            Ok(out) => Ok(out),
            Err(e) => {
                log.record_failure(&ctx, &e, &budget).await;
                Err(e)
            }
        }
    }

    async fn stages(
        &self,
        ctx: &JobContext,
        budget: &CallBudget,
        log: &vlm_log::VlmLog,
        started: Instant,
    ) -> Result<GroundingOutput, JobFailure> {
        let analysis = query_analysis::run(self, ctx, budget, log).await?;
        let slot = self.compute_slot(ctx).await?;
        still_wanted(&ctx.cancel, "room layout")?;
        let layout = projection::room_layout(self, ctx, &analysis.target_class).await?;
        still_wanted(&ctx.cancel, "view pre-selection")?;
        let mut pre = preselect::run(self, ctx, &analysis, layout.as_deref()).await?;
        still_wanted(&ctx.cancel, "stitching")?;
        let mut grids = stitching::run(self, ctx, &pre).await?;
        drop(slot);
        // Frames left out after their chosen box measured nothing of the object.
        let mut left_out: Vec<usize> = Vec::new();
        let (choice, projected) = loop {
            let choice = loop {
                still_wanted(&ctx.cancel, "grounding")?;
                let room = layout.as_deref();
                match grounding::run(self, ctx, budget, log, &analysis, &pre, &grids, room).await? {
                    grounding::Grounded::Chosen(c) => break c,
                    grounding::Grounded::NoneOffered(why) => {
                        // Once: the frames the detector left out, else the VLM's "not here".
                        let slot = self.compute_slot(ctx).await?;
                        let wider = preselect::widened(self, ctx, &analysis, &pre).await;
                        // A frame left out below stays out.
                        let Some(wider) = wider
                            .map(|mut w| {
                                w.frames.retain(|i| !left_out.contains(i));
                                w
                            })
                            .filter(|w| !w.frames.is_empty())
                        else {
                            let why = format!(
                                "the VLM saw the target in none of the offered frames: {why}"
                            );
                            return Err(JobFailure::new("target_not_found", why));
                        };
                        still_wanted(&ctx.cancel, "stitching")?;
                        grids = stitching::run(self, ctx, &wider).await?;
                        pre = wider;
                        drop(slot);
                    }
                }
            };
            // The grids' JPEGs are on disk as artifacts; projection does not need them (they
            // are made again if the VLM must choose again).
            drop(grids);
            // Projection takes its compute slot itself: it lets it go while it waits for the
            // VLM (`view_box`).
            still_wanted(&ctx.cancel, "projection")?;
            let attempt = Instant::now();
            let err = match projection::run(
                self,
                ctx,
                budget,
                log,
                &analysis.target_class,
                &pre,
                &choice,
                layout.clone(),
            )
            .await
            {
                Ok(p) => break (choice, p),
                Err(e) => e,
            };
            // The chosen view measured nothing of the object (a floor lamp's pole with no
            // reading, the rest hidden): that frame is left out and the VLM chooses again
            // among the others, up to `max_left_out` times.
            let unmeasured = err.code == "empty_mask" || err.code == "projection_failed";
            if !unmeasured || left_out.len() >= self.params.max_left_out || pre.frames.len() < 2 {
                return Err(err);
            }
            left_out.push(choice.frame_idx);
            step(
                ctx,
                "reselection",
                json!({"image_id": format!("{:05}", choice.frame_idx), "failure": err.code, "detail": err.detail}),
                json!({"left_out": left_out.iter().map(|i| format!("{i:05}")).collect::<Vec<_>>(), "offered": pre.frames.len() - 1}),
                // Its time is the projection that measured nothing (no step of its own).
                attempt,
            )
            .await;
            let slot = self.compute_slot(ctx).await?;
            pre.frames.retain(|&i| i != choice.frame_idx);
            pre.round += 1;
            still_wanted(&ctx.cancel, "stitching")?;
            grids = stitching::run(self, ctx, &pre).await?;
            drop(slot);
        };

        let total_ms = ms(started);
        let usage = budget.total_usage();
        let vlm_ms = log.vlm_ms();
        let summary = json!({
            "total_ms": total_ms,
            "vlm_ms": vlm_ms,
            "non_vlm_ms": (total_ms - vlm_ms).max(0.0),
            "vlm_calls": budget.calls_used(),
            "tokens": {"prompt": usage.prompt, "completion": usage.completion, "total": usage.total},
            "feedback_rounds": choice.feedback_rounds,
        });
        // How many times this process estimated the scene's room layout so far: it is
        // estimated once per loaded scene (at indexing, or by the first job needing it).
        let mut traced = summary.clone();
        traced["room_layout_estimates"] = json!(ctx.scene.room.estimates());
        ctx.trace
            .step("summary", json!({"outputs": traced, "ms": total_ms}))
            .await;
        let mut extra = serde_json::Map::new();
        extra.insert("image_id".into(), json!(format!("{:05}", choice.frame_idx)));
        extra.insert(
            "frame".into(),
            json!(ctx.scene.frames[choice.frame_idx].name),
        );
        extra.insert("detection_box".into(), json!(choice.bbox));
        extra.insert("box_source".into(), json!(choice.source));
        extra.insert("target_class".into(), json!(analysis.target_class));
        extra.insert("views_used".into(), json!(projected.views_used));
        extra.insert("usage".into(), json!({"vlm_calls": budget.calls_used(), "total_tokens": usage.total, "prompt_tokens": usage.prompt, "completion_tokens": usage.completion}));
        extra.insert("stats".into(), summary);
        // The box in the scene's own frame when boxes come back axis-aligned.
        if let Some(b) = ctx
            .scene
            .axis_align
            .and_then(|a| crate::geometry::export::box_in_scene_frame(&projected.bbox, &a))
        {
            extra.insert("box_scene_frame".into(), json!(b));
        }
        Ok(GroundingOutput {
            bbox: projected.bbox,
            extra,
        })
    }
}

#[cfg(test)]
mod cancel_tests {
    #[test]
    fn a_canceled_job_stops_before_the_next_stage() {
        let t = tokio_util::sync::CancellationToken::new();
        assert!(super::still_wanted(&t, "stitching").is_ok());
        t.cancel();
        let e = super::still_wanted(&t, "stitching").expect_err("stopped");
        assert_eq!(e.code, "canceled");
        assert!(e.detail.contains("stitching"), "{}", e.detail);
    }
}
