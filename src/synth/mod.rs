//! Synthetic posed RGB-D scenes with exact ground truth (`grounder synth`).

pub mod cli;
