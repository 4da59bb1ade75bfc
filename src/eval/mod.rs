//! Evaluation: metrics, the oracle VLM, `grounder eval`, dataset converters.

pub mod cli;
pub mod convert;
pub mod dataset;
pub mod metrics;
pub mod plot;
pub mod report;
pub mod runner;
pub mod trace;
