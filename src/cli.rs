//! Command-line entry point: one subcommand per tool.

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Debug, Parser)]
#[command(
    name = "grounder",
    version,
    about = "Find the object a sentence describes in a scanned room and return its 3D box"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the HTTP service.
    Serve(crate::config::ServeArgs),
    /// Generate a synthetic posed RGB-D scene with exact ground truth.
    Synth(crate::synth::cli::SynthArgs),
    /// Print the dynamic-stitching layout plan for N images as JSON.
    StitchPlan(crate::stitch::cli::StitchPlanArgs),
    /// Run the visual-retrieval benchmark against the configured VLM.
    RetrievalBench(crate::stitch::cli::RetrievalBenchArgs),
    /// Run a 2D detector on images and print one JSON line per detection.
    Detect(crate::vision::cli::DetectArgs),
    /// Draw the class-agnostic object candidates of a scene directory's frames.
    Candidates(crate::vision::candidates_cli::CandidatesArgs),
    /// Serve an OpenAI-compatible chat API that answers from ground truth.
    OracleVlm(crate::eval::cli::OracleVlmArgs),
    /// Evaluate the service on an annotated dataset.
    Eval(crate::eval::cli::EvalArgs),
    /// Convert ScanRefer / Nr3D / ScanNet ground truth into grounder annotations.
    Convert(crate::eval::cli::ConvertArgs),
    /// Print the service's OpenAPI document (YAML).
    Openapi,
    /// Manage API keys (create, list, revoke, webhook-secret).
    Keys(crate::keys::KeysArgs),
}

/// Parse arguments, run the subcommand, print a one-line error on failure.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    init_tracing();
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let result = rt.block_on(async move {
        match cli.command {
            Command::Serve(a) => crate::startup::serve(a).await,
            Command::Synth(a) => crate::synth::cli::run(a),
            Command::StitchPlan(a) => crate::stitch::cli::run_plan(a),
            Command::RetrievalBench(a) => crate::stitch::cli::run_retrieval_bench(a).await,
            Command::Detect(a) => crate::vision::cli::run(a),
            Command::Candidates(a) => crate::vision::candidates_cli::run(a),
            Command::OracleVlm(a) => crate::eval::cli::run_oracle_vlm(a).await,
            Command::Eval(a) => crate::eval::cli::run_eval(a).await,
            Command::Convert(a) => crate::eval::cli::run_convert(a),
            Command::Keys(a) => crate::keys::run(a).await,
            Command::Openapi => {
                print!("{}", crate::api::openapi::yaml());
                Ok(())
            }
        }
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the chain of causes joined.
            let msg = e
                .chain()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(": ");
            eprintln!("error: {msg}");
            ExitCode::FAILURE
        }
    }
}

fn init_tracing() {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_env("GROUNDER_LOG").unwrap_or_else(|_| EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}
