//! Integration tests of the HTTP service: a real server on port 0, talking HTTP.
//! The `agent_*` modules run the VLM-Grounder pipeline end to end through that server
//! against a scripted fake VLM, covering every feedback path, retries, the retry limit
//! and cancellation.

mod helpers;
mod jobs;
mod openapi;
mod restart;
mod scenes;
mod viewer;

mod agent_fixture;
mod agent_paths;
mod fake_vlm;
