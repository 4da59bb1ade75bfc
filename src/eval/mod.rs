//! Evaluation: metrics, the oracle VLM, `grounder eval`, dataset converters.

pub mod cli;
pub mod dataset;
pub mod metrics;
pub mod plot;
pub mod report;
pub mod trace;
pub mod runner;
pub mod convert;
