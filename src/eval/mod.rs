//! Evaluation: metrics, the oracle VLM, `grounder eval`, dataset converters.

pub mod cli;
pub mod dataset;
pub mod metrics;
