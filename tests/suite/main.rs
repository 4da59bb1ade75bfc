//! Most integration tests, in one binary: one link step and one set of debug symbols
//! instead of twenty (the CI disk and clock both pay for every test binary).

mod e2e_oracle;
mod eval_convert;
mod eval_runner;
mod geometry_open3d;
mod geometry_props;
mod geometry_scene;
mod geometry_synthetic;
mod oracle_vlm;
mod readme;
mod stitch_plan;
mod stitch_render;
mod stitch_retrieval;
mod synth_backproject;
mod synth_output;
mod synth_props;
mod synth_queries;
mod viewer;
mod vision_centernet;
mod vision_depth_seg;
mod vision_sam;
mod vision_segment_cli;
mod vision_support;
mod vision_yolo;
mod vlm_client;
mod vlm_errors;
mod vlm_json;
mod vlm_prompts;
