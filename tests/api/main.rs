//! Integration tests of the HTTP service: a real server on port 0, talking HTTP.

mod helpers;
mod jobs;
mod openapi;
mod restart;
mod scenes;
