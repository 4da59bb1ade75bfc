//! grounder: 3D visual grounding as a service (the VLM-Grounder method).
//!
//! Data flows one way: `api` → `jobs` → `agent` → (`vlm`, `vision`, `stitch`, `geometry`,
//! `scene`) ← `store`;
//! `jobs` keeps scene files and artifacts through `storage` (a folder or a bucket). `geometry` is pure; `api` knows nothing of geometry.

pub mod agent;
pub mod api;
pub mod cli;
pub mod client;
pub mod config;
pub mod eval;
pub mod geometry;
pub mod jobs;
pub mod keys;
pub mod metrics;
pub mod scene;
pub mod startup;
pub mod stitch;
pub mod storage;
pub mod store;
pub mod synth;
pub mod vision;
pub mod vlm;
