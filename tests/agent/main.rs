//! The VLM-Grounder pipeline end to end: the real service against a scripted fake VLM,
//! covering every feedback path, retries, the retry limit and cancellation.

#[allow(dead_code)]
#[path = "../api/helpers.rs"]
mod helpers;

mod fake_vlm;
mod fixture;
mod paths;
