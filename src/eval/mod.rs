//! Evaluation: metrics, the oracle VLM, `grounder eval`, dataset converters.
//!
//! - [`dataset`]: FORMATS §2 annotations (load, validate, write).
//! - [`metrics`]: per-query [`metrics::QueryRecord`] and the FORMATS §3 [`metrics::Summary`].
//! - [`trace`]: a job's trace + the scene's instance masks -> [`metrics::StageOutcome`].
//! - [`report`]: `results.jsonl` (append-only, resumable), `summary.json`, `summary.md`.
//! - [`interval`]: 95 % intervals by a bootstrap over target objects.
//! - [`plot`]: `iou_hist.png`, IoU histogram per subset.
//! - [`runner`]: `grounder eval --server URL`: upload scenes, run jobs, score, report.
//! - [`compare`]: `grounder compare BASE RUN`, two reports query by query.
//! - [`convert`]: `grounder convert scannet-gt|scanrefer|nr3d`.
//!
//! Typical use: `grounder convert scannet-gt --scans S --out D`, then
//! `grounder convert scanrefer --input ScanRefer.json --objects D --out D`, then
//! `grounder eval --dataset D --scenes SCENES --server http://127.0.0.1:8080 --jobs 4 --out report/`.

pub mod cli;
pub mod compare;
pub mod convert;
pub mod dataset;
pub mod interval;
pub mod metrics;
pub mod oracle_vlm;
pub mod oracle_vlm_answer;
pub mod oracle_vlm_truth;
pub mod plot;
pub mod report;
pub mod runner;
pub mod summary;
pub mod trace;
