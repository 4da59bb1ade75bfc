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

/// Floors of the two open-vocabulary runs, below what they measured on these scenes on
/// 2026-11-25 (Acc@0.25 / Acc@0.5; the oracle detector gives 0.985 / 0.897): CenterNet +
/// set-of-marks 0.838 / 0.735 at first, 0.882 / 0.735 once "no region is the target" led
/// to a VLM box and ensemble views took their own candidates; VLM boxes 0.912 / 0.721,
/// then 0.985 / 0.750.
const E2E_MARKS_FLOOR_025: f64 = 0.82;
const E2E_VLM_BOX_FLOOR_025: f64 = 0.92;

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
    // Run from an empty directory: nothing may depend on the checkout being the working
    // directory (the default detector's model, the fonts, the ONNX Runtime library).
    let cwd = log.with_extension("cwd");
    std::fs::create_dir_all(&cwd).expect("create empty working directory");
    cmd.current_dir(&cwd);
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

/// What one end-to-end run measured.
struct E2e {
    n_queries: usize,
    acc25: f64,
    acc05: f64,
    summary: serde_json::Value,
    /// One JSON line per query (`grounder eval`'s results.jsonl).
    results: String,
}

impl E2e {
    fn failures(&self) -> Vec<&str> {
        self.results
            .lines()
            .filter(|l| !l.contains("\"failure_stage\":null"))
            .collect()
    }
}

/// Two small noise-free scenes of `family` (seeds 1 and 2) grounded over HTTP with the
/// oracle VLM and the given detector spec and service environment.
fn run_e2e(family: &str, detector: &str, extra_env: &[(&str, String)]) -> E2e {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = |s: &str| dir.path().join(s).to_string_lossy().into_owned();
    let (scenes, ds, data, report) = (p("scenes"), p("ds"), p("data"), p("report"));

    run(&[
        "synth",
        "--family",
        family,
        "--out",
        &scenes,
        "--seed",
        "1",
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
    let n_queries = std::fs::read_to_string(dir.path().join("ds/queries.jsonl"))
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
        &dir.path().join("oracle.log"),
    );
    let mut envs = vec![
        (
            "GROUNDER_SEGMENTER",
            std::env::var("E2E_SEGMENTER").unwrap_or_else(|_| "depth".into()),
        ),
        ("GROUNDER_VLM_BASE_URL", format!("{oracle_url}/v1")),
        ("GROUNDER_VLM_MODEL", "grounder-oracle".into()),
        ("GROUNDER_VLM_API_KEY", "x".into()),
        ("GROUNDER_WORKERS", "2".into()),
    ];
    // "centernet" is the default: left unset, so that the default is what is tested.
    if detector != "centernet" {
        envs.push(("GROUNDER_DETECTOR", detector.to_string()));
    }
    envs.extend(extra_env.iter().cloned());
    let (_serve, serve_url) = spawn_server(
        "serve",
        &["serve", "--addr", "127.0.0.1:0", "--data-dir", &data],
        &envs,
        &dir.path().join("serve.log"),
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
    let serve_log = std::fs::read_to_string(dir.path().join("serve.log")).unwrap_or_default();
    assert!(
        eval.status.success(),
        "grounder eval failed:\n{}\n{}\nserve stderr:\n{serve_log}",
        String::from_utf8_lossy(&eval.stdout),
        String::from_utf8_lossy(&eval.stderr)
    );

    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("report/summary.json")).expect("summary.json"),
    )
    .expect("summary.json is JSON");
    assert_eq!(
        summary["n_queries"].as_u64(),
        Some(n_queries as u64),
        "{summary}"
    );
    let overall = &summary["scanrefer"]["overall"];
    E2e {
        n_queries,
        acc25: overall["acc_025"].as_f64().expect("acc_025"),
        acc05: overall["acc_05"].as_f64().expect("acc_05"),
        results: std::fs::read_to_string(dir.path().join("report/results.jsonl"))
            .unwrap_or_default(),
        summary,
    }
}

#[test]
fn oracle_pipeline_grounds_synthetic_scenes_over_http() {
    let r = run_e2e("rooms", "oracle", &[]);
    let (acc25, acc05, n_queries) = (r.acc25, r.acc05, r.n_queries);
    // Issue 8's bar for these scenes is Acc@0.25 >= 0.9. Measured: 0.985 / 0.897
    // (Acc@0.25 / Acc@0.5, measured 2026-11-24; docs/benchmark-e2e.md has the
    // realistic-noise figures). E2E_SEGMENTER picks another segmenter spec for a
    // comparison (e.g. depth:colour=off); the bar applies to the default.
    println!("e2e: Acc@0.25 {acc25:.3}, Acc@0.5 {acc05:.3} over {n_queries} queries");
    const FLOOR_025: f64 = 0.9;
    const FLOOR_05: f64 = 0.75;
    assert!(
        acc25 >= FLOOR_025 && acc05 >= FLOOR_05,
        "Acc@0.25 {acc25:.3} / Acc@0.5 {acc05:.3} over {n_queries} queries is below the bar {FLOOR_025} / {FLOOR_05}; first failures:\n{}",
        r.failures().iter().take(10).copied().collect::<Vec<_>>().join("\n")
    );
    // Every query asks the VLM at least to choose an image.
    let calls = r.summary["mean_vlm_calls"].as_f64().unwrap_or(0.0);
    assert!(
        calls >= 1.0,
        "mean VLM calls per query {calls}: usage is not being counted"
    );
}

/// The default install: CenterNet knows few of these classes (COCO-80), so most boxes come
/// from the class-agnostic candidates as set-of-marks. No job may fail for its class.
/// `serve` runs from an empty directory with no detector setting: the default detector's
/// model comes from the binary.
#[test]
fn default_detector_grounds_classes_it_does_not_know() {
    let r = run_e2e("rooms", "centernet", &[]);
    let failures = r.failures();
    let by_class: Vec<&&str> = failures
        .iter()
        .filter(|l| l.contains("detector_cannot_see_class") || l.contains("retry_limit_reached"))
        .collect();
    println!(
        "e2e centernet + marks: Acc@0.25 {:.3}, Acc@0.5 {:.3} over {} queries, {} failed",
        r.acc25,
        r.acc05,
        r.n_queries,
        failures.len()
    );
    assert!(
        by_class.is_empty(),
        "jobs failed for their class: {by_class:?}"
    );
    assert!(
        r.acc25 >= E2E_MARKS_FLOOR_025,
        "Acc@0.25 {:.3} below {E2E_MARKS_FLOOR_025}; failures:\n{}",
        r.acc25,
        failures.join("\n")
    );
}

/// `detector = "vlm"`: the VLM answers the box, here in Gemini's [ymin, xmin, ymax, xmax]
/// 0-1000 convention (the oracle reads the convention from the prompt).
#[test]
fn vlm_boxes_ground_every_query() {
    let cfg = tempfile::tempdir().expect("tempdir");
    let file = cfg.path().join("grounder.toml");
    std::fs::write(&file, "[agent]\nbox_format = \"yxyx1000\"\n").expect("config file");
    let r = run_e2e(
        "rooms",
        "vlm",
        &[("GROUNDER_CONFIG", file.to_string_lossy().into_owned())],
    );
    let failures = r.failures();
    println!(
        "e2e vlm boxes: Acc@0.25 {:.3}, Acc@0.5 {:.3} over {} queries, {} failed",
        r.acc25,
        r.acc05,
        r.n_queries,
        failures.len()
    );
    assert!(
        r.acc25 >= E2E_VLM_BOX_FLOOR_025,
        "Acc@0.25 {:.3} below {E2E_VLM_BOX_FLOOR_025}; failures:\n{}",
        r.acc25,
        failures.join("\n")
    );
}

/// The props family runs through the same oracle VLM, service and evaluator unchanged:
/// every query gets a result, the oracle's image choice is right (so it reads the new
/// family's masks and labels), and the accuracy is reported. The bar is only a floor under
/// what the pipeline does on this world today (not a target, see docs/benchmark-e2e.md).
#[test]
fn oracle_pipeline_runs_on_the_props_family_over_http() {
    let r = run_e2e("props", "oracle", &[]);
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
        r.failures()
            .iter()
            .take(10)
            .copied()
            .collect::<Vec<_>>()
            .join("\n")
    );
}
