//! Vision benchmarks: CenterNet per frame (2 intra-op threads), indexing a 100-frame scene,
//! and resident memory after loading each model (printed, not timed).
//! Needs the runtime: run scripts/setup-ort.sh first.

use std::path::PathBuf;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion};
use grounder::vision::{build_detector, build_segmenter, runtime, DetectInput, VisionConfig};
use image::RgbImage;

fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn cfg() -> VisionConfig {
    VisionConfig {
        model_dir: repo("models"),
        intra_threads: 2,
        ..VisionConfig::default()
    }
}

fn frames() -> Vec<RgbImage> {
    let load = |p: &str| {
        image::open(repo(p)).map(|i| {
            i.resize_exact(640, 480, image::imageops::FilterType::Triangle)
                .to_rgb8()
        })
    };
    let a = load("tests/fixtures/vision/images/coffee.png").expect("coffee.png");
    let b = load("tests/fixtures/vision/images/astronaut.png").expect("astronaut.png");
    (0..100)
        .map(|i| if i % 2 == 0 { a.clone() } else { b.clone() })
        .collect()
}

fn memory(_c: &mut Criterion) {
    let base = rss_mb();
    if let Err(e) = runtime::environment() {
        panic!("{e:#}");
    }
    let rt = rss_mb();
    let det = build_detector("centernet", &cfg()).expect("centernet");
    let cn = rss_mb();
    let img = image::open(repo("tests/fixtures/vision/images/coffee.png"))
        .expect("img")
        .to_rgb8();
    det.detect(&DetectInput::image(&img)).expect("detect");
    let cn_run = rss_mb();
    let t = Instant::now();
    let det2 = build_detector("centernet", &cfg()).expect("centernet");
    let load_ms = t.elapsed().as_secs_f64() * 1000.0;
    drop(det2);
    let y = build_detector(
        &format!(
            "yolo:{}",
            repo("tests/fixtures/vision/yolo-signature.onnx").display()
        ),
        &cfg(),
    )
    .expect("yolo");
    let sam = build_segmenter(
        &format!(
            "sam:{},{}",
            repo("tests/fixtures/vision/sam-encoder-signature.onnx").display(),
            repo("tests/fixtures/vision/sam-decoder-signature.onnx").display()
        ),
        &cfg(),
    )
    .expect("sam");
    let fixtures = rss_mb();
    println!("memory (RSS MB): start {base:.1}, +runtime {rt:.1}, +centernet loaded {cn:.1}, after first inference {cn_run:.1}, +yolo/sam signature fixtures {fixtures:.1}");
    println!("centernet session load: {load_ms:.1} ms");
    drop((y, sam));
}

fn centernet(c: &mut Criterion) {
    let det = build_detector("centernet", &cfg()).expect("centernet");
    let f = frames();
    let mut g = c.benchmark_group("centernet");
    g.sample_size(30);
    g.bench_function("per_frame_640x480", |b| {
        b.iter(|| det.detect(&DetectInput::image(&f[0])).expect("detect"))
    });
    g.finish();
    let mut g = c.benchmark_group("indexing");
    g.sample_size(10);
    g.bench_function("scene_100_frames", |b| {
        b.iter(|| {
            let mut n = 0;
            for (i, img) in f.iter().enumerate() {
                let input = DetectInput {
                    frame_key: i as u64,
                    ..DetectInput::image(img)
                };
                n += det.detect(&input).expect("detect").len();
            }
            n
        })
    });
    g.finish();
}

criterion_group!(benches, memory, centernet);
criterion_main!(benches);
