//! `grounder stitch-plan` and `grounder retrieval-bench`.

use super::decode::load_frames;
use super::plan::plan;
use super::render::StitchOptions;
use super::retrieval::{
    ask, case_rng, generate_case, parse_answer, prompt, score, synthetic_pool, GeneratorOptions,
};
use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments of `grounder stitch-plan`.
#[derive(Debug, clap::Args)]
pub struct StitchPlanArgs {
    /// Number of images to stitch.
    #[arg(long)]
    pub images: usize,
    /// Soft limit on the number of stitched images.
    #[arg(long, default_value_t = super::plan::DEFAULT_LIMIT)]
    pub limit: usize,
}

/// Arguments of `grounder retrieval-bench`.
#[derive(Debug, Clone, clap::Args)]
pub struct RetrievalBenchArgs {
    /// Folder of source images (JPEG/PNG); without it, simple synthetic images are used.
    #[arg(long)]
    pub images_dir: Option<PathBuf>,
    /// Layouts to test, as ROWSxCOLS, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "4x1,2x4,8x2,3x3,9x3")]
    pub layouts: Vec<String>,
    /// Stitched images per request.
    #[arg(long, default_value_t = 1)]
    pub count: usize,
    /// Requests per layout.
    #[arg(long, default_value_t = 3)]
    pub trials: usize,
    /// Random seed (cases are reproducible).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Longer side of each stitched image sent.
    #[arg(long, default_value_t = 2048)]
    pub max_side: u32,
    /// JPEG quality.
    #[arg(long, default_value_t = 75)]
    pub jpeg_quality: u8,
    /// Base URL of the OpenAI-compatible API (".../v1").
    #[arg(long, env = "GROUNDER_VLM_BASE_URL")]
    pub base_url: String,
    /// Model name.
    #[arg(long, env = "GROUNDER_VLM_MODEL")]
    pub model: String,
    /// API key (optional for local servers).
    #[arg(long, env = "GROUNDER_VLM_API_KEY", hide_env_values = true)]
    pub api_key: Option<String>,
    /// Per-request timeout in seconds.
    #[arg(long, default_value_t = 180)]
    pub timeout_secs: u64,
}

/// Results for one layout.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LayoutResult {
    /// Rows of the layout.
    pub rows: u32,
    /// Columns of the layout.
    pub cols: u32,
    /// Stitched images per request.
    pub images_per_request: usize,
    /// Requests that got a usable answer.
    pub trials_ok: usize,
    /// Requests that failed (network, timeout, unparsable reply); not in the accuracy.
    pub trials_failed: usize,
    /// Mean recall over the answered requests.
    pub accuracy: f64,
    /// Mean request time over the answered requests, seconds.
    pub mean_request_secs: f64,
}

/// Print the plan as a JSON array.
pub fn run_plan(args: StitchPlanArgs) -> Result<()> {
    if args.limit == 0 {
        bail!("--limit must be at least 1");
    }
    let specs = plan(args.images, args.limit);
    println!(
        "{}",
        serde_json::to_string(&specs).context("cannot serialise the plan")?
    );
    Ok(())
}

/// Run the benchmark, print one JSON array of [`LayoutResult`] on stdout and a table on stderr.
pub async fn run_retrieval_bench(args: RetrievalBenchArgs) -> Result<()> {
    let results = retrieval_bench(&args).await?;
    eprintln!("layout  per-request  ok/failed  accuracy  mean request s");
    for r in &results {
        eprintln!(
            "{:>2}x{:<3} {:>11}  {:>4}/{:<6} {:>8.3}  {:>14.2}",
            r.rows,
            r.cols,
            r.images_per_request,
            r.trials_ok,
            r.trials_failed,
            r.accuracy,
            r.mean_request_secs
        );
    }
    println!(
        "{}",
        serde_json::to_string(&results).context("cannot serialise the results")?
    );
    Ok(())
}

/// Parse "ROWSxCOLS".
pub fn parse_layout(s: &str) -> Result<(u32, u32)> {
    let (r, c) = s
        .trim()
        .split_once(['x', 'X'])
        .with_context(|| format!("layout {s:?} is not ROWSxCOLS"))?;
    let r: u32 = r
        .trim()
        .parse()
        .with_context(|| format!("bad rows in layout {s:?}"))?;
    let c: u32 = c
        .trim()
        .parse()
        .with_context(|| format!("bad columns in layout {s:?}"))?;
    if r == 0 || c == 0 {
        bail!("layout {s:?} has no cells");
    }
    Ok((r, c))
}

fn load_pool(args: &RetrievalBenchArgs) -> Result<Vec<image::RgbImage>> {
    let Some(dir) = &args.images_dir else {
        return Ok(synthetic_pool(64, 640, 480, args.seed));
    };
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let ext = p
                .extension()
                .and_then(|e| e.to_str())
                .unwrap_or("")
                .to_lowercase();
            matches!(ext.as_str(), "jpg" | "jpeg" | "png")
        })
        .collect();
    paths.sort();
    if paths.is_empty() {
        bail!("no JPEG or PNG images in {}", dir.display());
    }
    load_frames(&paths)
}

/// Run every layout's trials against the configured VLM and return the results.
pub async fn retrieval_bench(args: &RetrievalBenchArgs) -> Result<Vec<LayoutResult>> {
    let layouts: Vec<(u32, u32)> = args
        .layouts
        .iter()
        .map(|s| parse_layout(s))
        .collect::<Result<_>>()?;
    if args.count == 0 || args.trials == 0 {
        bail!("--count and --trials must be at least 1");
    }
    let pool = load_pool(args)?;
    let opts = GeneratorOptions {
        stitch: StitchOptions {
            max_side: args.max_side,
            jpeg_quality: args.jpeg_quality,
            ..StitchOptions::default()
        },
        ..GeneratorOptions::default()
    };
    let timeout = Duration::from_secs(args.timeout_secs.max(1));
    let mut results = Vec::with_capacity(layouts.len());
    for (li, &layout) in layouts.iter().enumerate() {
        let (mut ok, mut failed, mut acc, mut secs) = (0usize, 0usize, 0.0f64, 0.0f64);
        for trial in 0..args.trials {
            let case = generate_case(
                &pool,
                layout,
                args.count,
                &mut case_rng(args.seed, li, trial),
                &opts,
            )?;
            let jpegs: Vec<Vec<u8>> = case.images.iter().map(|i| i.jpeg.clone()).collect();
            let started = Instant::now();
            let reply = ask(
                &args.base_url,
                &args.model,
                args.api_key.as_deref(),
                &prompt(&case),
                &jpegs,
                timeout,
            )
            .await;
            let elapsed = started.elapsed().as_secs_f64();
            match reply.and_then(|text| parse_answer(&text)) {
                Ok(answer) => {
                    ok += 1;
                    acc += score(&case.truth, &answer).recall;
                    secs += elapsed;
                }
                Err(e) => {
                    failed += 1;
                    tracing::warn!("layout {}x{} trial {trial}: {e:#}", layout.0, layout.1);
                }
            }
        }
        let mean = |x: f64| if ok == 0 { 0.0 } else { x / ok as f64 };
        results.push(LayoutResult {
            rows: layout.0,
            cols: layout.1,
            images_per_request: args.count,
            trials_ok: ok,
            trials_failed: failed,
            accuracy: mean(acc),
            mean_request_secs: mean(secs),
        });
    }
    Ok(results)
}
