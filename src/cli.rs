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
    /// Print the effective configuration (defaults, file, environment, flags) as TOML.
    Config(crate::config::ServeArgs),
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
    /// Segment one box in one frame of a scene directory: an overlay PNG and a JSON line.
    Segment(crate::vision::segment_cli::SegmentArgs),
    /// Serve an OpenAI-compatible chat API that answers from ground truth.
    OracleVlm(crate::eval::cli::OracleVlmArgs),
    /// Evaluate the service on an annotated dataset.
    Eval(crate::eval::cli::EvalArgs),
    /// Compare two evaluation reports of the same queries: accuracies, their difference and
    /// its 95 % interval (objects resampled), and the objects that changed.
    Compare(crate::eval::compare::CompareArgs),
    /// Convert ScanRefer / Nr3D / ScanNet ground truth into grounder annotations.
    Convert(crate::eval::cli::ConvertArgs),
    /// Print the service's OpenAPI document (YAML).
    Openapi,
    /// Manage API keys (create, list, revoke, webhook-secret).
    Keys(crate::keys::KeysArgs),
    /// Ground sentences in a scene on a running service (exit 0 found, 1 failed, 2 error).
    Ground(crate::client::ground::GroundArgs),
    /// Run the whole service on a small synthetic scene with an oracle VLM: no key needed.
    Demo(crate::client::demo::DemoArgs),
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
        let done = |r: anyhow::Result<()>| r.map(|()| ExitCode::SUCCESS);
        match cli.command {
            // These two choose their own exit codes (0 found, 1 job failed, 2 error).
            Command::Ground(a) => Ok(crate::client::ground::run(a).await),
            Command::Demo(a) => Ok(crate::client::demo::run(a).await),
            Command::Serve(a) => done(crate::startup::serve(a).await),
            Command::Config(a) => done(crate::config::show::run(&a)),
            Command::Synth(a) => done(crate::synth::cli::run(a)),
            Command::StitchPlan(a) => done(crate::stitch::cli::run_plan(a)),
            Command::RetrievalBench(a) => done(crate::stitch::cli::run_retrieval_bench(a).await),
            Command::Detect(a) => done(crate::vision::cli::run(a)),
            Command::Candidates(a) => done(crate::vision::candidates_cli::run(a)),
            Command::Segment(a) => done(crate::vision::segment_cli::run(a)),
            Command::OracleVlm(a) => done(crate::eval::cli::run_oracle_vlm(a).await),
            Command::Eval(a) => done(crate::eval::cli::run_eval(a).await),
            Command::Convert(a) => done(crate::eval::cli::run_convert(a)),
            Command::Compare(a) => done(crate::eval::compare::run(a)),
            Command::Keys(a) => done(crate::keys::run(a).await),
            Command::Openapi => {
                print!("{}", crate::api::openapi::yaml());
                Ok(ExitCode::SUCCESS)
            }
        }
    });
    match result {
        Ok(code) => code,
        Err(e) if e.downcast_ref::<crate::config::ConfigError>().is_some() => {
            // A configuration that cannot be used: exit code 2, as for bad arguments.
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
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
