//! End to end: `grounder serve` and `grounder oracle-vlm` as real processes on port 0, two
//! small synthetic scenes uploaded over HTTP, every query run through `grounder eval`, and
//! the ScanRefer accuracy read back from `summary.json`. Oracle detector, depth segmenter,
//! no sensor noise: what remains is the real pipeline (prompts, parsing, pre-selection,
//! stitching, segmentation, multi-view projection).

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_grounder");

/// Kills and reaps the child when dropped, so a failing assertion leaves no process behind.
struct ChildGuard {
    name: &'static str,
    child: Child,
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start `grounder <args>` with `envs`, wait for its `listening on http://ADDR` line and
/// return the guard and the base URL. Stderr goes to `log` for post-mortems.
fn spawn_server(
    name: &'static str,
    args: &[&str],
    envs: &[(&str, String)],
    log: &Path,
) -> (ChildGuard, String) {
    let stderr = std::fs::File::create(log).expect("create log file");
    let mut cmd = Command::new(BIN);
    cmd.args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(stderr)
        .env("GROUNDER_LOG", "warn");
    for (k, v) in envs {
        cmd.env(k, v);
    }
    let mut child = cmd
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
    let stdout = child.stdout.take().expect("piped stdout");
    let guard = ChildGuard { name, child };
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        // Keep reading so the child never blocks on a full pipe.
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if let Some(url) = line.strip_prefix("listening on ") {
                let _ = tx.send(url.trim().to_string());
            }
        }
    });
    let url = rx
        .recv_timeout(Duration::from_secs(60))
        .unwrap_or_else(|_| {
            let log = std::fs::read_to_string(log).unwrap_or_default();
            panic!(
                "{} did not print its address within 60 s; stderr:\n{log}",
                guard.name
            )
        });
    (guard, url)
}

fn run(args: &[&str]) {
    let out = Command::new(BIN)
        .args(args)
        .env("GROUNDER_LOG", "warn")
        .output()
        .expect("run grounder");
    assert!(
        out.status.success(),
        "grounder {args:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// What one end-to-end run gives back.
struct E2e {
    summary: serde_json::Value,
    n_queries: usize,
    acc25: f64,
    acc05: f64,
    /// Up to ten result lines of failed or missed queries.
    failures: Vec<String>,
}

/// Two small noise-free scenes of `family` from `seed`, both servers, `grounder eval` over
/// every query; the summary read back.
fn run_e2e(dir: &Path, family: &str, seed: &str) -> E2e {
    let p = |s: &str| dir.join(s).to_string_lossy().into_owned();
    let (scenes, ds, data, report) = (p("scenes"), p("ds"), p("data"), p("report"));

    run(&[
        "synth",
        "--family",
        family,
        "--out",
        &scenes,
        "--seed",
        seed,
        "--scenes",
        "2",
        "--frames",
        "14",
        "--color-size",
        "320x240",
        "--depth-size",
        "160x120",
        "--noise",
        "none",
        "--dataset",
        &ds,
    ]);
    let n_queries = std::fs::read_to_string(dir.join("ds/queries.jsonl"))
        .expect("queries.jsonl")
        .lines()
        .count();
    assert!(n_queries >= 20, "synth wrote only {n_queries} queries");

    let (_oracle, oracle_url) = spawn_server(
        "oracle-vlm",
        &[
            "oracle-vlm",
            "--addr",
            "127.0.0.1:0",
            "--dataset",
            &ds,
            "--scenes",
            &scenes,
        ],
        &[],
        &dir.join("oracle.log"),
    );
    let (_serve, serve_url) = spawn_server(
        "serve",
        &["serve", "--addr", "127.0.0.1:0", "--data-dir", &data],
        &[
            ("GROUNDER_DETECTOR", "oracle".into()),
            (
                "GROUNDER_SEGMENTER",
                std::env::var("E2E_SEGMENTER").unwrap_or_else(|_| "depth".into()),
            ),
            ("GROUNDER_VLM_BASE_URL", format!("{oracle_url}/v1")),
            ("GROUNDER_VLM_MODEL", "oracle".into()),
            ("GROUNDER_VLM_API_KEY", "x".into()),
            ("GROUNDER_WORKERS", "2".into()),
        ],
        &dir.join("serve.log"),
    );

    let eval = Command::new(BIN)
        .args([
            "eval",
            "--dataset",
            &ds,
            "--scenes",
            &scenes,
            "--server",
            &serve_url,
            "--jobs",
            "2",
            "--out",
            &report,
            "--job-timeout-s",
            "120",
            "--scene-timeout-s",
            "120",
        ])
        .env("GROUNDER_LOG", "warn")
        .output()
        .expect("run grounder eval");
    let serve_log = std::fs::read_to_string(dir.join("serve.log")).unwrap_or_default();
    assert!(
        eval.status.success(),
        "grounder eval failed:\n{}\n{}\nserve stderr:\n{serve_log}",
        String::from_utf8_lossy(&eval.stdout),
        String::from_utf8_lossy(&eval.stderr)
    );

    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("report/summary.json")).expect("summary.json"),
    )
    .expect("summary.json is JSON");
    assert_eq!(
        summary["n_queries"].as_u64(),
        Some(n_queries as u64),
        "{summary}"
    );
    let overall = &summary["scanrefer"]["overall"];
    let acc25 = overall["acc_025"].as_f64().expect("acc_025");
    let acc05 = overall["acc_05"].as_f64().expect("acc_05");
    let results = std::fs::read_to_string(dir.join("report/results.jsonl")).unwrap_or_default();
    let failures: Vec<String> = results
        .lines()
        .filter(|l| !l.contains("\"failure_stage\":null"))
        .take(10)
        .map(str::to_string)
        .collect();
    // Every query asks the VLM at least to choose an image.
    let calls = summary["mean_vlm_calls"].as_f64().unwrap_or(0.0);
    assert!(
        calls >= 1.0,
        "mean VLM calls per query {calls}: usage is not being counted"
    );
    E2e {
        summary,
        n_queries,
        acc25,
        acc05,
        failures,
    }
}

#[test]
fn oracle_pipeline_grounds_synthetic_scenes_over_http() {
    let dir = tempfile::tempdir().expect("tempdir");
    let E2e {
        n_queries,
        acc25,
        acc05,
        failures,
        ..
    } = run_e2e(dir.path(), "rooms", "1");
    // Issue 8's bar for these scenes is Acc@0.25 >= 0.9. Measured: 0.985 / 0.897
    // (Acc@0.25 / Acc@0.5, measured 2026-11-24; docs/benchmark-e2e-rooms-dev.md has the
    // realistic-noise figures). E2E_SEGMENTER picks another segmenter spec for a
    // comparison (e.g. depth:colour=off); the bar applies to the default.
    println!("e2e: Acc@0.25 {acc25:.3}, Acc@0.5 {acc05:.3} over {n_queries} queries");
    const FLOOR_025: f64 = 0.9;
    const FLOOR_05: f64 = 0.75;
    assert!(
        acc25 >= FLOOR_025 && acc05 >= FLOOR_05,
        "Acc@0.25 {acc25:.3} / Acc@0.5 {acc05:.3} over {n_queries} queries is below the bar {FLOOR_025} / {FLOOR_05}; first failures:\n{}",
        failures.join("\n")
    );
}

/// The props family runs through the same oracle VLM, service and evaluator unchanged:
/// every query gets a result, the oracle's image choice is right (so it reads the new
/// family's masks and labels), and the accuracy is reported. The bar is only a floor under
/// what the pipeline does on this world today (not a target, see docs/benchmark-e2e.md).
#[test]
fn oracle_pipeline_runs_on_the_props_family_over_http() {
    let dir = tempfile::tempdir().expect("tempdir");
    let r = run_e2e(dir.path(), "props", "1");
    println!(
        "e2e props: Acc@0.25 {:.3}, Acc@0.5 {:.3} over {} queries",
        r.acc25, r.acc05, r.n_queries
    );
    let image = &r.summary["stages"]["image_choice_correct"];
    let rate = image["rate"].as_f64().unwrap_or(0.0);
    assert!(
        rate >= 0.9,
        "the oracle chose the right image for only {rate:.2} of the props queries: {image}"
    );
    // Measured 2026-11-25 at branch `world` (pipeline of main b712e87): Acc@0.25 0.575,
    // Acc@0.5 0.299 over 174 queries; the gap to the rooms family is issue 18's subject.
    const FLOOR_025: f64 = 0.5;
    assert!(
        r.acc25 >= FLOOR_025,
        "props: Acc@0.25 {:.3} over {} queries is below {FLOOR_025}; first failures:\n{}",
        r.acc25,
        r.n_queries,
        r.failures.join("\n")
    );
}
