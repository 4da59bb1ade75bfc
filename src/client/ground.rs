//! `grounder ground`: ground sentences in a scene on a running service from the terminal.

use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use super::{step_line, Service};

/// Flags of `grounder ground`.
#[derive(Debug, clap::Args)]
pub struct GroundArgs {
    /// Base URL of the service, e.g. http://127.0.0.1:8080.
    #[arg(long)]
    pub server: String,
    /// API key (sent as `Authorization: Bearer`).
    #[arg(long, env = "GROUNDER_KEY")]
    pub key: Option<String>,
    /// A scene already on the service.
    #[arg(long, conflicts_with = "upload", required_unless_present = "upload")]
    pub scene: Option<String>,
    /// Upload this scene folder or archive (.tar, .tar.gz, .zip) first.
    #[arg(long)]
    pub upload: Option<PathBuf>,
    /// Print the boxes as JSON (one object per query per line) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Give up on a job (or an upload's indexing) after this many seconds.
    #[arg(long, default_value_t = 600)]
    pub timeout_s: u64,
    /// The sentences to ground.
    #[arg(required = true)]
    pub queries: Vec<String>,
}

/// Table rows of a box: min, max, centre, size.
pub fn box_table(b: &Value) -> String {
    let row = |k: &str| {
        let v: Vec<String> = (0..3)
            .map(|i| format!("{:>8.3}", b[k][i].as_f64().unwrap_or(f64::NAN)))
            .collect();
        format!("  {k:<7}{}", v.join(" "))
    };
    let mut out = format!("  {:<7}{:>8} {:>8} {:>8}\n", "", "x", "y", "z");
    for k in ["min", "max", "center", "size"] {
        out.push_str(&row(k));
        out.push('\n');
    }
    out
}

/// Run it: 0 when every query was found, 1 when a job failed, 2 on usage or connection
/// errors.
pub async fn run(a: GroundArgs) -> ExitCode {
    match go(&a).await {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            let msg = e
                .chain()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(": ");
            eprintln!("error: {msg}");
            ExitCode::from(2)
        }
    }
}

async fn go(a: &GroundArgs) -> anyhow::Result<bool> {
    let svc = Service::new(&a.server, a.key.clone());
    let timeout = Duration::from_secs(a.timeout_s);
    let scene = match (&a.scene, &a.upload) {
        (Some(s), _) => s.clone(),
        (None, Some(p)) => {
            eprintln!("uploading {} ...", p.display());
            let id = svc.upload(p, timeout).await?;
            eprintln!("scene {id} ready");
            id
        }
        (None, None) => anyhow::bail!("give --scene ID or --upload DIR|ARCHIVE"),
    };
    let mut all_found = true;
    for q in &a.queries {
        let id = svc.submit(&scene, q).await?;
        eprintln!("job {id}: {q}");
        let job = svc
            .follow_job(&id, timeout, |s| eprintln!("{}", step_line(s)))
            .await?;
        let view = format!("{}/v1/jobs/{id}/view", svc.base);
        let found = job["status"] == "succeeded";
        if a.json {
            let line = json!({"query": q, "job": id, "status": job["status"], "box": job["result"]["box"],
                              "error": job["error"], "view": view});
            println!("{line}");
        } else if found {
            println!("{q}\n{}  view: {view}", box_table(&job["result"]["box"]));
        } else {
            println!(
                "{q}\n  {}: {}: {}\n  view: {view}",
                job["status"].as_str().unwrap_or("failed"),
                job["error"]["code"].as_str().unwrap_or(""),
                job["error"]["detail"].as_str().unwrap_or("")
            );
        }
        all_found &= found;
    }
    Ok(all_found)
}
