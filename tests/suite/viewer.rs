//! End to end: `grounder demo` (synthetic scene, oracle VLM, the service, three queries) as
//! a real process; then its exports read with an independent PLY reader, `grounder ground`
//! against it, and the viewer pages rendered by headless Chromium (DOM, console errors,
//! screenshot pixels of the 3D canvas). `grounder demo --once` is tested on its own.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_grounder");
const CHROMIUM: &str = "/usr/bin/chromium";

struct ChildGuard(Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// What the demo printed: service URL, scene id, queries and job ids (in order).
struct Demo {
    _guard: ChildGuard,
    url: String,
    scene: String,
    queries: Vec<String>,
    jobs: Vec<String>,
}

fn start_demo(data: &Path) -> Demo {
    let mut child = Command::new(BIN)
        .args([
            "demo",
            "--addr",
            "127.0.0.1:0",
            "--frames",
            "12",
            "--data-dir",
        ])
        .arg(data)
        .env("GROUNDER_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start grounder demo");
    let out = child.stdout.take().expect("stdout");
    let guard = ChildGuard(child);
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            let done = line.starts_with("serving on");
            let _ = tx.send(line);
            if done {
                break;
            }
        }
    });
    let (mut url, mut scene) = (String::new(), String::new());
    let (mut queries, mut jobs) = (Vec::new(), Vec::new());
    let mut lines = Vec::new();
    loop {
        let line = rx
            .recv_timeout(Duration::from_secs(240))
            .unwrap_or_else(|_| {
                panic!("the demo stopped early; it printed:\n{}", lines.join("\n"))
            });
        lines.push(line.clone());
        if let Some(u) = line.strip_prefix("listening on ") {
            url = u.trim().to_string();
        } else if let Some(s) = line.strip_prefix("scene: ") {
            scene = s
                .trim()
                .trim_end_matches("/view")
                .rsplit('/')
                .next()
                .unwrap()
                .to_string();
        } else if line.starts_with('"') {
            queries.push(line.trim_matches('"').to_string());
        } else if let Some(v) = line.trim().strip_prefix("view: ") {
            jobs.push(
                v.trim_end_matches("/view")
                    .rsplit('/')
                    .next()
                    .unwrap()
                    .to_string(),
            );
        } else if line.starts_with("serving on") {
            break;
        }
    }
    assert_eq!(
        jobs.len(),
        3,
        "the demo ran three queries:\n{}",
        lines.join("\n")
    );
    assert_eq!(queries.len(), 3);
    let found = lines
        .iter()
        .filter(|l| l.contains("IoU with the truth"))
        .count();
    assert!(
        found >= 2,
        "most demo queries are found:\n{}",
        lines.join("\n")
    );
    Demo {
        _guard: guard,
        url,
        scene,
        queries,
        jobs,
    }
}

/// GET with curl (status, body).
fn get(url: &str) -> (u16, Vec<u8>) {
    let body = tempfile::NamedTempFile::new().expect("temp file");
    let out = Command::new("curl")
        .args(["-s", "-o"])
        .arg(body.path())
        .args(["-w", "%{http_code}", url])
        .output()
        .expect("run curl");
    let status = String::from_utf8_lossy(&out.stdout)
        .trim()
        .parse()
        .expect("status");
    (status, std::fs::read(body.path()).expect("body"))
}

fn get_json(url: &str) -> serde_json::Value {
    let (s, b) = get(url);
    assert_eq!(s, 200, "{url}");
    serde_json::from_slice(&b).expect("JSON")
}

/// Parse with ply-rs (not our code): vertex count and the xyz + rgb of every vertex.
fn read_ply(bytes: &[u8]) -> Vec<([f32; 3], [u8; 3])> {
    use ply_rs::parser::Parser;
    use ply_rs::ply::{DefaultElement, Property};
    let p = Parser::<DefaultElement>::new();
    let ply = p
        .read_ply(&mut std::io::Cursor::new(bytes))
        .expect("a valid PLY");
    let v = ply.payload.get("vertex").expect("a vertex element");
    assert_eq!(ply.header.elements["vertex"].count, v.len());
    let f = |e: &DefaultElement, k: &str| match e.get(k) {
        Some(Property::Float(x)) => *x,
        other => panic!("{k}: {other:?}"),
    };
    let c = |e: &DefaultElement, k: &str| match e.get(k) {
        Some(Property::UChar(x)) => *x,
        other => panic!("{k}: {other:?}"),
    };
    v.iter()
        .map(|e| {
            (
                [f(e, "x"), f(e, "y"), f(e, "z")],
                [c(e, "red"), c(e, "green"), c(e, "blue")],
            )
        })
        .collect()
}

fn check_exports(d: &Demo) {
    let job = get_json(&format!("{}/v1/jobs/{}", d.url, d.jobs[0]));
    assert_eq!(job["status"], "succeeded", "{job}");
    let b = &job["result"]["box"];
    let corners = b["corners"].as_array().expect("box.corners");
    assert_eq!(corners.len(), 8);
    assert!(job["result"]["box_scene_frame"]["corners"]
        .as_array()
        .is_some_and(|c| c.len() == 8));
    let (lo, hi): (Vec<f64>, Vec<f64>) = (0..3)
        .map(|i| (b["min"][i].as_f64().unwrap(), b["max"][i].as_f64().unwrap()))
        .unzip();

    let (s, obj) = get(&format!("{}/v1/jobs/{}/object.ply", d.url, d.jobs[0]));
    assert_eq!(s, 200);
    let pts = read_ply(&obj);
    assert!(pts.len() >= 30, "object has {} points", pts.len());
    let inside = pts
        .iter()
        .filter(|(p, _)| {
            (0..3).all(|i| (p[i] as f64) >= lo[i] - 0.02 && (p[i] as f64) <= hi[i] + 0.02)
        })
        .count();
    assert!(
        inside * 100 >= pts.len() * 95,
        "{inside} of {} object points inside the box",
        pts.len()
    );

    let (s, scene) = get(&format!(
        "{}/v1/scenes/{}/points.ply?voxel=0.05",
        d.url, d.scene
    ));
    assert_eq!(s, 200);
    let sp = read_ply(&scene);
    assert!(sp.len() > 1000, "scene has {} points", sp.len());
    assert!(
        sp.iter().any(|(_, c)| c != &sp[0].1),
        "scene points are coloured"
    );
    // Coarser voxels, fewer points; a voxel out of range is a problem.
    let (_, coarse) = get(&format!(
        "{}/v1/scenes/{}/points.ply?voxel=0.2",
        d.url, d.scene
    ));
    assert!(read_ply(&coarse).len() < sp.len());
    let (s, body) = get(&format!(
        "{}/v1/scenes/{}/points.ply?voxel=5",
        d.url, d.scene
    ));
    assert_eq!(s, 400);
    assert!(String::from_utf8_lossy(&body).contains("invalid_voxel"));

    let image_id = job["result"]["image_id"].as_str().unwrap();
    let (s, png) = get(&format!(
        "{}/v1/jobs/{}/masks/{image_id}.png",
        d.url, d.jobs[0]
    ));
    assert_eq!(s, 200);
    let m = image::load_from_memory(&png).expect("mask PNG").to_luma8();
    assert_eq!((m.width(), m.height()), (640, 480));
    assert!(m.pixels().any(|p| p.0[0] == 255));
    let (s, _) = get(&format!("{}/v1/jobs/{}/masks/99999.png", d.url, d.jobs[0]));
    assert_eq!(s, 404);
}

fn ground(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(BIN)
        .arg("ground")
        .args(args)
        .env("GROUNDER_LOG", "warn")
        .output()
        .expect("run grounder ground");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn check_ground(d: &Demo) -> String {
    let (code, out, err) = ground(&["--server", &d.url, "--scene", &d.scene, &d.queries[0]]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(out.contains("center") && out.contains("/view"), "{out}");
    // A progress line per step.
    for step in ["query_analysis", "stitching", "projection"] {
        assert!(err.contains(step), "no progress line for {step}:\n{err}");
    }
    let (code, out, _) = ground(&[
        "--server",
        &d.url,
        "--scene",
        &d.scene,
        "--json",
        &d.queries[1],
    ]);
    assert_eq!(code, 0);
    let v: serde_json::Value = serde_json::from_str(out.trim()).expect("one JSON line");
    assert_eq!(v["status"], "succeeded");
    assert_eq!(v["box"]["corners"].as_array().map(Vec::len), Some(8));
    // A sentence the oracle cannot answer: the job fails, the reason is printed, exit 1.
    let (code, out, err) = ground(&[
        "--server",
        &d.url,
        "--scene",
        &d.scene,
        "the purple unicorn on the ceiling",
    ]);
    assert_eq!(code, 1, "{out}\n{err}");
    assert!(out.contains("failed"), "{out}");
    let failed = out
        .lines()
        .find_map(|l| l.trim().strip_prefix("view: "))
        .expect("view URL");
    let failed_job = failed
        .trim_end_matches("/view")
        .rsplit('/')
        .next()
        .unwrap()
        .to_string();
    // No service there: exit 2. No scene given: exit 2 (usage).
    let (code, _, err) = ground(&["--server", "http://127.0.0.1:9", "--scene", "x", "q"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.starts_with("error: "), "{err}");
    let (code, _, _) = ground(&["--server", &d.url, "q"]);
    assert_eq!(code, 2);
    failed_job
}

/// Render `url` in headless Chromium: (DOM after scripts, screenshot RGB, stderr).
fn chromium(url: &str, shot: &Path) -> (String, image::RgbImage, String) {
    assert!(
        Path::new(CHROMIUM).exists(),
        "{CHROMIUM} is missing: .ci/run installs the Debian package chromium"
    );
    let common = [
        "--headless",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--hide-scrollbars",
        "--window-size=1280,1800",
        "--virtual-time-budget=20000",
    ];
    let profile = tempfile::tempdir().expect("profile dir");
    let run = |extra: &str| {
        let out = Command::new(CHROMIUM)
            .args(common)
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg(extra)
            .arg(url)
            .output()
            .expect("run chromium");
        assert!(
            out.status.success(),
            "chromium failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        out
    };
    let dom = run("--dump-dom");
    let _ = run(&format!("--screenshot={}", shot.display()));
    let img = image::open(shot).expect("screenshot").to_rgb8();
    (
        String::from_utf8_lossy(&dom.stdout).into_owned(),
        img,
        String::from_utf8_lossy(&dom.stderr).into_owned(),
    )
}

/// Distinct colours in the 3D canvas' area of the screenshot (header ~45 px, section title
/// ~40 px, canvas 460 px high): a blank canvas has one.
fn canvas_colours(img: &image::RgbImage) -> usize {
    let mut set = std::collections::HashSet::new();
    for y in 110..520 {
        for x in 40..1200 {
            set.insert(img.get_pixel(x, y).0);
        }
    }
    set.len()
}

fn check_page(dom: &str, stderr: &str, img: &image::RgbImage, must: &[&str]) {
    assert!(
        dom.contains("data-ready=\"1\""),
        "page did not finish:\n{dom}"
    );
    assert!(dom.contains("data-errors=\"0\""), "console errors:\n{dom}");
    assert!(!stderr.contains("Uncaught"), "{stderr}");
    for m in must {
        assert!(dom.contains(m), "the page lacks {m:?}:\n{dom}");
    }
    let n = canvas_colours(img);
    assert!(n > 50, "the 3D canvas looks blank ({n} colours)");
}

#[test]
fn demo_exports_terminal_client_and_viewer_pages() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = start_demo(&dir.path().join("demo"));
    check_exports(&d);
    let failed_job = check_ground(&d);

    let shots = std::env::var("VIEWER_SCREENSHOTS")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|_| dir.path().to_path_buf());
    let job = get_json(&format!("{}/v1/jobs/{}", d.url, d.jobs[0]));
    let (dom, img, err) = chromium(
        &format!("{}/v1/jobs/{}/view", d.url, d.jobs[0]),
        &shots.join("viewer-job.png"),
    );
    let min_x = format!("{:.3}", job["result"]["box"]["min"][0].as_f64().unwrap());
    check_page(
        &dom,
        &err,
        &img,
        &[
            &d.queries[0],
            "class=\"gridwrap\"",
            "id=\"chosen-in-grid\"",
            "id=\"chosen-frame\"",
            "id=\"box-table\"",
            &min_x,
            "<details class=\"exchange\"",
        ],
    );

    let (dom, img, err) = chromium(
        &format!("{}/v1/jobs/{failed_job}/view", d.url),
        &shots.join("viewer-failed-job.png"),
    );
    check_page(&dom, &err, &img, &["id=\"failure\"", "failed at "]);

    let (dom, img, err) = chromium(
        &format!("{}/v1/scenes/{}/view", d.url, d.scene),
        &shots.join("viewer-scene.png"),
    );
    check_page(
        &dom,
        &err,
        &img,
        &[
            "id=\"jobs-table\"",
            "data-image-id=\"00011\"",
            &d.queries[2],
        ],
    );
}

#[test]
fn demo_once_exits_zero_when_every_box_is_found() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = Command::new(BIN)
        .args([
            "demo",
            "--once",
            "--addr",
            "127.0.0.1:0",
            "--frames",
            "12",
            "--data-dir",
        ])
        .arg(dir.path())
        .env("GROUNDER_LOG", "warn")
        .output()
        .expect("run grounder demo --once");
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(text.matches("IoU with the truth").count(), 3, "{text}");
    assert_eq!(text.matches("/view").count(), 4, "{text}");
}
