//! Integration tests of the HTTP service: a real server on port 0, talking HTTP.
//! The `agent_*` modules run the VLM-Grounder pipeline end to end through that server
//! against a scripted fake VLM, covering every feedback path, retries, the retry limit
//! and cancellation.

mod bench_sse;
mod compose;
mod config;
mod crash;
mod depth_file;
mod events;
mod failover;
mod format_writers;
mod formats;
mod formats_bench;
mod frames;
mod helpers;
mod hostile;
mod idempotency;
mod index_stop;
mod internal_errors;
mod jobs;
mod keys;
mod llama_cpp;
mod memory;
mod openapi;
mod pg_leases;
mod pg_replicas;
mod polling;
mod postgres;
mod problems;
mod restart;
mod scenes;
mod spawned;
mod storage;
mod storage_timeouts;
mod viewer;
mod warm_points;
mod webhooks;

mod agent_candidate_cache;
mod agent_fixture;
mod agent_marks;
mod agent_paths;
mod agent_reselect;
mod agent_room;
mod agent_vlm_errors;
mod agent_widen;
mod fake_vlm;
