//! Evaluation: metrics, the oracle VLM, `grounder eval`, dataset converters.

pub mod cli;
pub mod oracle_vlm;
pub mod oracle_vlm_answer;
pub mod oracle_vlm_truth;
