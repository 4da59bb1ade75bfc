//! `grounder oracle-vlm`, `grounder eval`, `grounder convert`.

use std::path::PathBuf;

pub use super::oracle_vlm::OracleVlmArgs;

/// `grounder eval`: run every query of an annotated dataset and write a report.
#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Dataset folder (objects/<scene>.json and queries.jsonl, FORMATS §2).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Folder with one scene directory per scene id.
    #[arg(long)]
    pub scenes: PathBuf,
    /// Base URL of a running `grounder serve`; without it the service runs in this process
    /// (configured from the same environment variables as `grounder serve`).
    #[arg(long)]
    pub server: Option<String>,
    /// Evaluate only the first N queries.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Concurrent jobs.
    #[arg(long, default_value_t = 1)]
    pub jobs: usize,
    /// Report folder (results.jsonl, summary.json, summary.md, iou_hist.png).
    #[arg(long)]
    pub out: PathBuf,
    /// Status poll interval in milliseconds.
    #[arg(long, default_value_t = 200)]
    pub poll_ms: u64,
    /// Per-job timeout in seconds.
    #[arg(long, default_value_t = 900)]
    pub job_timeout_s: u64,
    /// Timeout for a scene upload to become ready, in seconds.
    #[arg(long, default_value_t = 1800)]
    pub scene_timeout_s: u64,
    /// TTF font for the plot's text (default: assets/fonts/DejaVuSans-Bold.ttf if present;
    /// without a font the plot has no text and summary.md describes it).
    #[arg(long)]
    pub font: Option<PathBuf>,
}

/// `grounder convert`: original dataset formats into grounder annotations.
#[derive(Debug, clap::Args)]
pub struct ConvertArgs {
    #[command(subcommand)]
    pub format: crate::eval::convert::ConvertCommand,
}

pub async fn run_oracle_vlm(args: OracleVlmArgs) -> anyhow::Result<()> {
    super::oracle_vlm::run(args).await
}

/// Run `grounder eval` and print the headline numbers.
pub async fn run_eval(args: EvalArgs) -> anyhow::Result<()> {
    // Without --server, run the service in this process (configured from the environment,
    // as `grounder serve` is) on a loopback port with its data under the report folder.
    let mut in_process = None;
    let server = match args.server.clone() {
        Some(s) => s,
        None => {
            let mut cfg = crate::config::Config::load(&crate::config::ServeArgs {
                addr: Some("127.0.0.1:0".into()),
                data_dir: None,
                config: None,
                role: None,
                allow_anonymous: false,
            })?;
            cfg.addr = "127.0.0.1:0".into();
            cfg.data_dir = args.out.join("service-data");
            let app = crate::startup::Application::build(cfg).await?;
            let url = format!("http://{}", app.local_addr()?);
            let (tx, rx) = tokio::sync::oneshot::channel::<()>();
            let handle = tokio::spawn(app.run_until(async move {
                let _ = rx.await;
            }));
            in_process = Some((tx, handle));
            url
        }
    };
    let fonts = match &args.font {
        Some(f) => vec![f.clone()],
        None => crate::eval::plot::default_font_paths(),
    };
    if !crate::eval::plot::register_font_from(&fonts) {
        tracing::warn!("no usable font found; the IoU plot will have no text");
    }
    let cfg = crate::eval::runner::EvalConfig {
        dataset: args.dataset,
        scenes: args.scenes,
        server: server.trim_end_matches('/').to_string(),
        limit: args.limit,
        jobs: args.jobs,
        out: args.out.clone(),
        poll: std::time::Duration::from_millis(args.poll_ms.max(1)),
        job_timeout: std::time::Duration::from_secs(args.job_timeout_s),
        scene_timeout: std::time::Duration::from_secs(args.scene_timeout_s),
    };
    let outcome = crate::eval::runner::run(&cfg).await;
    if let Some((tx, handle)) = in_process {
        let _ = tx.send(());
        let _ = handle.await;
    }
    let o = outcome?;
    let s = &o.summary.scanrefer.overall;
    println!(
        "{} queries ({} run now, {} resumed): Acc@0.25 {:.1} %, Acc@0.5 {:.1} %, Nr3D {:.1} %; report in {}",
        o.summary.n_queries,
        o.ran,
        o.skipped,
        100.0 * s.acc_025,
        100.0 * s.acc_05,
        100.0 * o.summary.nr3d.overall.rate,
        args.out.display()
    );
    if !o.errors.is_empty() {
        anyhow::bail!(
            "{} queries could not be run (first: {}); rerun the same command to retry them",
            o.errors.len(),
            o.errors[0]
        );
    }
    Ok(())
}

/// Run `grounder convert`.
pub fn run_convert(args: ConvertArgs) -> anyhow::Result<()> {
    crate::eval::convert::run(args.format)
}
